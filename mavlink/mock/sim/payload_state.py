"""The state of the mock vehicle's payload (:mod:`mavlink.mock.payload`): the gimbal's
setpoint, control and attitude, and the camera's pictures and capture under way."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import numpy as np

__all__ = ["CameraState", "GimbalControl", "GimbalState"]

Msg: TypeAlias = Any


class GimbalControl(enum.Enum):
    """What the gimbal manager points the gimbal by (PX4's ``ControlData::Type``)."""

    NEUTRAL = "neutral"
    ANGLE = "angle"
    ROI = "roi"


@dataclass(slots=True)
class GimbalState:
    """The gimbal: the manager's setpoint and control, the device's attitude.

    ``pitch_rad`` (to the horizon, up positive) and ``yaw_rad`` (to the vehicle's heading,
    right positive) are where the device points now; the setpoint is ``control`` with
    ``pitch_sp_rad`` / ``yaw_sp_rad`` (NaN: none, the rates ``*_rate_rad_s`` drive that axis)
    and ``yaw_lock`` (the yaw setpoint is to north), or the ROI ``roi_ned_m`` (local NED, m).
    ``primary`` is the (sysid, compid) in primary control, (0, 0) for nobody; ``updated_s``
    when the setpoint last came (rates stop 2 s later).
    """

    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    pitch_rate_now_rad_s: float = 0.0
    yaw_rate_now_rad_s: float = 0.0
    control: GimbalControl = GimbalControl.NEUTRAL
    pitch_sp_rad: float = 0.0
    yaw_sp_rad: float = 0.0
    pitch_rate_rad_s: float = math.nan
    yaw_rate_rad_s: float = math.nan
    yaw_lock: bool = False
    roi_ned_m: np.ndarray | None = None
    primary: tuple[int, int] = (0, 0)
    updated_s: float = 0.0


@dataclass(slots=True)
class CameraState:
    """The camera: its pictures and the capture under way.

    ``capturing``: an interval capture runs, the next picture due at ``next_s`` (simulation
    time, s), ``remaining`` more to take (-1: until stopped) every ``interval_s``.
    ``images``: every CAMERA_IMAGE_CAPTURED sent, by image index (kept for re-requests).
    """

    capturing: bool = False
    interval_s: float = 0.0
    remaining: int = 0
    next_s: float = math.inf
    last_sequence: int = 0
    images: list[Msg] = field(default_factory=list)

    @property
    def image_count(self) -> int:
        """Pictures taken since boot."""
        return len(self.images)
