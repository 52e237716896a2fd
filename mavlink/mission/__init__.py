"""Trajectories as PX4 missions: conversion, geofence, upload, read-back, the path flown.

The package's public names are importable from here (``from mavlink.mission import
trajectory_to_mission``); each lives in the room named for what it holds::

    mavlink.mission.items       MAV_CMD / MAV_FRAME / mission type values, MissionItem
                                (one MISSION_ITEM_INT), compare_items: a read-back
                                compared field by field as PX4 stores items
    mavlink.mission.conversion  trajectory -> MISSION items (MissionPlan), with camera and
                                gimbal items where the camera takes pictures
                                (CaptureSpan), the
                                piecewise-linear path the mission flies, its deviation
                                from the plan and its STL robustness
    mavlink.mission.geofence    workspace and full-height keep-outs (boxes, prisms,
                                cylinders) -> FENCE polygons and circles, the braking
                                distance PX4's predictive fence looks ahead
    mavlink.mission.transfer    one upload / download through MAVSDK's mission_raw,
                                verified by its read-back; the transfer's timing report
    mavlink.mission.retries     whole-transfer retries within a time budget on a bad
                                link (RetryPolicy, upload_with_retries)
    mavlink.mission.run         a mission started and confirmed, followed as it is
                                flown (MissionRun, MissionFollower)

Dependencies run down the list: items uses nothing of the package; conversion and geofence
build items; transfer sends and compares them; retries builds on transfer; run acts on a
plan already on the vehicles.
"""

from __future__ import annotations

from mavlink.mission.conversion import (
    CaptureSpan,
    MissionPlan,
    PathDeviation,
    PiecewiseLinearPath,
    ScheduledCapture,
    keep_waypoints,
    path_deviation,
    path_robustness,
    trajectory_to_mission,
)
from mavlink.mission.geofence import (
    FenceBox,
    FenceCircle,
    FencePolygon,
    FenceZone,
    braking_distance_m,
    fence_boxes,
    fence_zones,
    geofence_items,
)
from mavlink.mission.items import (
    COMPARED_FIELDS,
    Cmd,
    Frame,
    MissionEnd,
    MissionItem,
    MissionType,
    compare_items,
)
from mavlink.mission.retries import RetryPolicy, TransferProgress, upload_with_retries
from mavlink.mission.run import (
    MissionFollower,
    MissionRun,
    MissionStart,
    start_mission_confirmed,
)
from mavlink.mission.transfer import (
    TransferReport,
    TransferStep,
    download,
    upload,
    upload_and_verify,
    verify,
)

__all__ = [
    "COMPARED_FIELDS",
    "CaptureSpan",
    "Cmd",
    "FenceBox",
    "FenceCircle",
    "FencePolygon",
    "FenceZone",
    "Frame",
    "MissionEnd",
    "MissionFollower",
    "MissionItem",
    "MissionPlan",
    "MissionRun",
    "MissionStart",
    "MissionType",
    "PathDeviation",
    "PiecewiseLinearPath",
    "RetryPolicy",
    "ScheduledCapture",
    "TransferProgress",
    "TransferReport",
    "TransferStep",
    "braking_distance_m",
    "compare_items",
    "download",
    "fence_boxes",
    "fence_zones",
    "geofence_items",
    "keep_waypoints",
    "path_deviation",
    "path_robustness",
    "start_mission_confirmed",
    "trajectory_to_mission",
    "upload",
    "upload_and_verify",
    "upload_with_retries",
    "verify",
]
