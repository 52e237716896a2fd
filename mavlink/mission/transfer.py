"""One transfer of a plan: upload, download, and an upload verified by its read-back.

Upload and download go through MAVSDK's ``mission_raw`` plugin (the
MISSION_COUNT / MISSION_REQUEST_INT / MISSION_ITEM_INT / MISSION_ACK
transactions with their retries); :func:`verify` compares the read-back with the plan
(:func:`mavlink.mission.items.compare_items`). :class:`TransferReport` is the timing of a
transfer, also of the retried ones of :mod:`mavlink.mission.retries`.

A room of its own because it is the single attempt, as MAVSDK makes it; retrying a whole
transfer on a bad link builds on it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mavsdk.plugins.mission_raw import MissionRawResult

from mavlink.errors import MissionError, MissionResult
from mavlink.link.mavsdk_glue import mavsdk_call
from mavlink.mission.items import MissionItem, MissionType, compare_items

if TYPE_CHECKING:
    from mavlink.link.vehicle import Vehicle


def raise_for(result: Any, origin: str, v: Vehicle) -> None:
    if result != MissionRawResult.SUCCESS:
        name = getattr(result, "name", str(result))
        kind = (
            MissionResult.TOO_MANY_ITEMS
            if result == MissionRawResult.TOO_MANY_MISSION_ITEMS
            else MissionResult.TRANSFER_FAILED
        )
        raise MissionError(kind, origin, mavsdk_result=name, vehicle=v.name, url=v.url)


async def upload(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> None:
    """Upload a MISSION or FENCE plan with MAVSDK mission_raw (replacing the vehicle's)."""

    raw = [i.to_mavsdk() for i in items]
    if mission_type is MissionType.MISSION:
        origin, start = "upload_mission", v.mission_raw.upload_mission_async
    elif mission_type is MissionType.FENCE:
        origin, start = "upload_geofence", v.mission_raw.upload_geofence_async
    else:
        origin, start = "upload_rally_points", v.mission_raw.upload_rally_points_async
    try:
        result = await mavsdk_call(start, raw, timeout_s=60.0)
    except TimeoutError:
        result = "TIMEOUT"
    raise_for(result, origin, v)


async def download(
    v: Vehicle, mission_type: MissionType = MissionType.MISSION
) -> tuple[MissionItem, ...]:
    """Download the vehicle's MISSION, FENCE or RALLY plan."""

    if mission_type is MissionType.MISSION:
        origin, start = "download_mission", v.mission_raw.download_mission_async
    elif mission_type is MissionType.FENCE:
        origin, start = "download_geofence", v.mission_raw.download_geofence_async
    else:
        origin, start = "download_rallypoints", v.mission_raw.download_rallypoints_async
    try:
        result, raw = await mavsdk_call(start, timeout_s=60.0)
    except TimeoutError:
        result, raw = "TIMEOUT", None
    raise_for(result, origin, v)
    return tuple(MissionItem.from_mavsdk(r) for r in raw)


@dataclass(frozen=True, slots=True)
class TransferStep:
    """One upload or read-back of a transfer (:func:`upload_with_retries`).

    Attributes:
        attempt: the upload it belongs to (1-based).
        kind: ``"upload"``, ``"clear"`` (an empty MISSION plan) or ``"read-back"``.
        t_start_s: when it began, seconds from the transfer's start.
        duration_s: how long it took.
        outcome: ``"ok"`` (acknowledged), ``"identical"`` (read back as sent),
            ``"mismatch"`` (read back, differs) or ``"failed"`` (no answer / refused).
        detail: the error or the first differences (empty when it went well).
    """

    attempt: int
    kind: str
    t_start_s: float
    duration_s: float
    outcome: str
    detail: str = ""


@dataclass(frozen=True, slots=True)
class TransferReport:
    """Timing of an upload + read-back + comparison, and of its retries.

    Attributes:
        vehicle: name.
        items: items sent.
        upload_s, download_s: time spent uploading / reading back (and comparing), summed
            over the attempts.
        mission_type: MISSION, FENCE or RALLY.
        attempts: uploads it took (1 without a retry).
        elapsed_s: wall time from the first upload to the read-back that matched.
        steps: every upload and read-back, in order (empty from :func:`upload_and_verify`).
        last_error: the last failure that a retry overcame (empty if none).
    """

    vehicle: str
    items: int
    upload_s: float
    download_s: float
    mission_type: MissionType = MissionType.MISSION
    attempts: int = 1
    elapsed_s: float = math.nan
    steps: tuple[TransferStep, ...] = ()
    last_error: str = ""


async def upload_and_verify(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> TransferReport:
    """Upload, download back and compare item by item (``download_s`` includes the comparison).

    An upload that times out but whose read-back is identical succeeded (the vehicle's final
    MISSION_ACK was lost; see below).

    Raises:
        MissionError: ``MISMATCH`` naming the first differing items and fields,
            or the transfer's own failure.
    """
    t0 = time.perf_counter()
    try:
        await upload(v, items, mission_type)
    except MissionError as exc:
        if exc.mavsdk_result != "TIMEOUT":
            raise
        # MAVSDK 4.1 never recovers a lost final MISSION_ACK: the vehicle then holds the
        # complete plan while the upload reports TIMEOUT. The read-back decides; if it differs,
        # the upload's own failure is what the caller gets.
        t1 = time.perf_counter()
        try:
            await verify(v, items, mission_type)
        except MissionError:
            raise exc from None
        t2 = time.perf_counter()
        return TransferReport(v.name, len(items), t1 - t0, t2 - t1, mission_type, 1, t2 - t0)
    t1 = time.perf_counter()
    await verify(v, items, mission_type)
    t2 = time.perf_counter()
    return TransferReport(v.name, len(items), t1 - t0, t2 - t1, mission_type, 1, t2 - t0)


async def verify(
    v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType = MissionType.MISSION
) -> None:
    """Download the vehicle's plan and require it to equal ``items`` (:func:`compare_items`).

    Raises:
        MissionError: ``MISMATCH`` naming the first three differences.
    """
    back = await download(v, mission_type)
    diffs = compare_items(items, back)
    if diffs:
        more = f" (+{len(diffs) - 3} more)" if len(diffs) > 3 else ""
        raise MissionError(
            MissionResult.MISMATCH,
            f"verify_{mission_type.name.lower()}",
            "; ".join(diffs[:3]) + more,
            vehicle=v.name,
            url=v.url,
        )
