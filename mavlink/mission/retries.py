"""Transfers on a bad link: whole-transfer retries within a time budget.

:func:`upload_with_retries` uploads a plan until the vehicle reads back exactly it, telling
the vehicle to drop each failed transfer and backing off between attempts
(:class:`RetryPolicy`); :class:`TransferProgress` is what its progress callback is told.

A room of its own because it is policy on top of the single transfer of
:mod:`mavlink.mission.transfer`: budget, back-off, cancels and the bookkeeping of its steps.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import logging
import math
import random
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mavsdk.plugins.mavlink_direct import MavlinkDirectError, MavlinkMessage
from mavsdk.plugins.mission_raw import MissionRawError

from mavlink.errors import MissionError, MissionResult, TransferGaveUpError
from mavlink.link.mavsdk_glue import mavsdk_call
from mavlink.mission.items import MissionItem, MissionType, compare_items
from mavlink.mission.transfer import (
    TransferReport,
    TransferStep,
    download,
    raise_for,
    upload,
)

if TYPE_CHECKING:
    from mavlink.link.vehicle import Vehicle

log = logging.getLogger(__name__)

#: MAVSDK results after which another attempt can succeed: the link failed (or a stale
#: message of an earlier attempt confused this one), not the plan. The others
#: (TOO_MANY_MISSION_ITEMS, UNSUPPORTED, DENIED, INVALID_ARGUMENT, ...) are the vehicle's
#: answer to the plan itself, and a retry would get the same.
_TRANSIENT_RESULTS = frozenset(
    {
        "TIMEOUT",
        "BUSY",
        "TRANSFER_CANCELLED",
        "PROTOCOL_ERROR",
        "ERROR",
        "UNKNOWN",
        "NO_SYSTEM",
        "INVALID_SEQUENCE",
    }
)
#: MAV_MISSION_OPERATION_CANCELLED (MISSION_ACK.type).
_OPERATION_CANCELLED = 15
#: Copies of that cancel sent: each lost one would leave PX4 busy for its 5 s timeout.
_CANCEL_COPIES = 3
#: The operation names :func:`upload` and :func:`download` give each plan type.
_UPLOAD_ORIGIN = {
    MissionType.MISSION: "upload_mission",
    MissionType.FENCE: "upload_geofence",
    MissionType.RALLY: "upload_rally_points",
}
_DOWNLOAD_ORIGIN = {
    MissionType.MISSION: "download_mission",
    MissionType.FENCE: "download_geofence",
    MissionType.RALLY: "download_rallypoints",
}


@dataclass(frozen=True, slots=True)
class RetryPolicy:
    """How :func:`upload_with_retries` retries a whole transfer on a bad link.

    Attributes:
        budget_s: total time for the transfer, every upload, read-back and wait included (s).
        backoff_s: wait after the first failure in a row (s); it doubles with each further
            one, up to ``backoff_max_s``.
        backoff_max_s: the longest wait (s).
        jitter: the wait is drawn from ``[(1 - jitter) w, w]``, so vehicles that failed
            together do not retry in step on a shared radio.
        readbacks: read-backs of an acknowledged upload that may fail in transfer before
            the plan is uploaded again.
        seed: seeds the jitter (``None``: from the OS); tests pass one.
    """

    budget_s: float = 60.0
    backoff_s: float = 0.25
    backoff_max_s: float = 2.0
    jitter: float = 0.5
    readbacks: int = 3
    seed: int | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.budget_s) and self.budget_s > 0):
            raise ValueError(f"budget_s must be a number > 0, got {self.budget_s!r}")
        if not (0.0 <= self.backoff_s <= self.backoff_max_s < math.inf):
            raise ValueError(
                f"need 0 <= backoff_s <= backoff_max_s < inf, got {self.backoff_s!r}, "
                f"{self.backoff_max_s!r}"
            )
        if not 0.0 <= self.jitter <= 1.0:
            raise ValueError(f"jitter must be in [0, 1], got {self.jitter!r}")
        if self.readbacks < 1:
            raise ValueError(f"readbacks must be >= 1, got {self.readbacks!r}")

    def backoff(self, failures: int, rng: random.Random) -> float:
        """The wait (s) after the ``failures``-th failure in a row (see the attributes)."""
        wait = min(self.backoff_max_s, self.backoff_s * 2.0 ** max(0, failures - 1))
        return wait * (1.0 - self.jitter * rng.random())


@dataclass(frozen=True, slots=True)
class TransferProgress:
    """Where a transfer of :func:`upload_with_retries` stands (its ``progress`` callback).

    Attributes:
        vehicle, mission_type: whose plan, which plan.
        attempt: the upload under way (1-based).
        step: ``"upload"`` or ``"read-back"`` (starting), ``"retry"`` (a step failed:
            ``detail`` says why; the next comes in ``wait_s``), ``"verified"`` (read back as
            sent: done) or ``"failed"`` (given up: ``detail`` says why).
        items: items of the plan.
        elapsed_s: seconds since the transfer began.
        detail: why a step failed, or the verdict.
        wait_s: the back-off before the next step (``"retry"`` only).
    """

    vehicle: str
    mission_type: MissionType
    attempt: int
    step: str
    items: int
    elapsed_s: float
    detail: str = ""
    wait_s: float = 0.0


def _transient(exc: MissionError) -> bool:
    """Whether another attempt can mend ``exc`` (a lost datagram, a differing read-back)."""
    if exc.result is MissionResult.MISMATCH:
        return True
    return exc.result is MissionResult.TRANSFER_FAILED and exc.mavsdk_result in _TRANSIENT_RESULTS


def _send_cancel(v: Vehicle, mission_type: MissionType) -> None:
    """Tell the vehicle to drop a transfer MAVSDK abandoned (MISSION_ACK, OPERATION_CANCELLED).

    MAVSDK 4.1 gives up on a transfer without telling the vehicle, which stays in it until
    its own protocol timeout (PX4: 5 s, during which a new upload gets "IGN MISSION_COUNT:
    Busy"). PX4 v1.17 leaves an upload or a download at once on this ACK from its transfer
    partner and ignores it when idle, so sending it after every failed step is safe.
    Best effort: a send that fails is logged (the vehicle then times out by itself).
    """

    fields_json = json.dumps(
        {
            "target_system": v.spec.sysid,
            "target_component": 1,
            "type": _OPERATION_CANCELLED,
            "mission_type": int(mission_type),
            "opaque_id": 0,
        }
    )
    msg = MavlinkMessage(
        message_name="MISSION_ACK",
        target_system_id=v.spec.sysid,
        target_component_id=1,
        fields_json=fields_json,
    )
    try:
        for _ in range(_CANCEL_COPIES):
            v.direct.send_message(msg)
    except MavlinkDirectError as exc:
        log.info("vehicle %s: cancel of the %s transfer not sent: %s", v.name, mission_type, exc)


def _abandon(v: Vehicle, kind: str) -> None:
    """Cancel MAVSDK's own transfer still under way (the budget ran out before it ended)."""

    cancel = (
        v.mission_raw.cancel_mission_download
        if kind == "read-back"
        else v.mission_raw.cancel_mission_upload
    )
    try:
        cancel()
    except MissionRawError as exc:  # nothing under way: it ended meanwhile
        log.debug("vehicle %s: no %s to cancel: %s", v.name, kind, exc)


@contextlib.contextmanager
def _requests_watched(v: Vehicle, mission_type: MissionType) -> Iterator[list[int]]:
    """The highest item seq ``v`` asks for (MISSION_REQUEST_INT of ``mission_type``) while the
    block runs, as ``[seq]`` (-1: none). A vehicle that never asked for the last item cannot
    hold the plan: PX4 stores an upload only once it is complete."""
    highest = [-1]
    sysid, mtype = v.spec.sysid, int(mission_type)

    def on_request(msg: Any, _ud: Any) -> None:
        if msg.system_id != sysid:
            return
        f = json.loads(msg.fields_json)
        if int(f.get("mission_type", 0)) == mtype:
            highest[0] = max(highest[0], int(f.get("seq", -1)))

    handle = v.direct.subscribe_message("MISSION_REQUEST_INT", on_request)
    try:
        yield highest
    finally:
        v.direct.unsubscribe_message(handle)


async def _put(v: Vehicle, items: Sequence[MissionItem], mission_type: MissionType) -> None:
    """Upload ``items``; an empty MISSION plan is cleared instead (MAVSDK uploads none)."""
    if items:
        await upload(v, items, mission_type)
        return

    try:
        result = await mavsdk_call(v.mission_raw.clear_mission_async, timeout_s=60.0)
    except TimeoutError:
        result = "TIMEOUT"
    raise_for(result, "clear_mission", v)


async def upload_with_retries(
    v: Vehicle,
    items: Sequence[MissionItem],
    mission_type: MissionType = MissionType.MISSION,
    *,
    policy: RetryPolicy | None = None,
    progress: Callable[[TransferProgress], None] | None = None,
) -> TransferReport:
    """Upload ``items`` until the vehicle reads back exactly them, within ``policy.budget_s``.

    MAVSDK retries single items (5 times each); on a link that loses a third of its
    datagrams both ways a 15-item upload + read-back still fails most of the time
    (``benchmarks/bench_faults.py``). This retries the transfer as a whole, on top:

    * every upload is followed by a read-back compared with :func:`compare_items`; only a
      read-back equal to the plan is a success, so a partial or different plan is never
      reported as the plan;
    * an acknowledged upload whose read-back fails in transfer is read back again (up to
      ``policy.readbacks`` times) before it is uploaded again; a failed upload is read back
      only if the vehicle asked for the last item (its final MISSION_ACK may be what was
      lost: MAVSDK never recovers that), since before that PX4 keeps its previous plan;
    * after a failed step the vehicle is told to drop the transfer (MISSION_ACK
      OPERATION_CANCELLED, which MAVSDK does not send) and the next step waits an
      exponential back-off with jitter (:meth:`RetryPolicy.backoff`);
    * every step counts against the budget; one still running when it runs out is cancelled.

    An empty MISSION plan is a clear (MISSION_CLEAR_ALL), read back as 0 items.

    Args:
        v: the vehicle.
        items: the plan, ``seq`` 0..n-1, all of ``mission_type``.
        mission_type: MISSION, FENCE or RALLY.
        policy: budget, back-off and read-backs (default :class:`RetryPolicy`).
        progress: called on the event loop at each step (:class:`TransferProgress`).

    Returns:
        The report: attempts, times, every step, the last failure overcome.

    Raises:
        TransferGaveUpError: the budget ran out first; names the vehicle, the attempts, the
            last cause and what the vehicle held at its last read-back (or that it is
            unknown).
        MissionError: a failure no retry mends (too many items, an item the vehicle
            refuses, an empty FENCE or RALLY plan), at once.
    """

    policy = policy if policy is not None else RetryPolicy()
    plan = tuple(items)
    origin = _UPLOAD_ORIGIN[mission_type]
    if not plan and mission_type is not MissionType.MISSION:
        raise MissionError(
            MissionResult.INVALID_ITEM,
            origin,
            f"no {mission_type.name} items: MAVSDK's mission_raw clears the MISSION plan only",
            vehicle=v.name,
            url=v.url,
        )
    rng = random.Random(policy.seed)
    t0 = time.monotonic()
    deadline = t0 + policy.budget_s
    steps: list[TransferStep] = []
    spent = {"upload": 0.0, "read-back": 0.0}
    attempt = failures = readbacks_left = 0
    last: MissionError | None = None
    held: int | None = None  # items read back at the last read-back since the last upload

    def tell(step: str, detail: str = "", wait_s: float = 0.0) -> None:
        if progress is not None:
            progress(
                TransferProgress(
                    v.name,
                    mission_type,
                    attempt,
                    step,
                    len(plan),
                    time.monotonic() - t0,
                    detail,
                    wait_s,
                )
            )

    async def run(kind: str, call: Callable[[], Any]) -> tuple[Any, MissionError | None]:
        """One MAVSDK transfer, cut short where the budget ends; recorded as a step."""
        t_step = time.monotonic()
        value: Any = None
        err: MissionError | None = None
        try:
            value = await asyncio.wait_for(call(), max(0.0, deadline - t_step))
        except TimeoutError:
            _abandon(v, kind)
            err = MissionError(
                MissionResult.TRANSFER_FAILED,
                _DOWNLOAD_ORIGIN[mission_type] if kind == "read-back" else origin,
                "the time budget ran out during it",
                mavsdk_result="TIMEOUT",
                vehicle=v.name,
                url=v.url,
            )
        except MissionError as exc:
            err = exc
        dt = time.monotonic() - t_step
        spent["read-back" if kind == "read-back" else "upload"] += dt
        outcome = "ok" if err is None else "failed"
        steps.append(
            TransferStep(attempt, kind, t_step - t0, dt, outcome, "" if err is None else err.detail)
        )
        return value, err

    def failed_step(err: MissionError) -> None:
        """A step failed: a refusal no retry mends is raised; otherwise the vehicle is told to
        drop the transfer and the failure counted."""
        nonlocal last, failures
        if not _transient(err):
            tell("failed", err.detail)
            raise err
        last = err
        _send_cancel(v, mission_type)
        failures += 1

    async def back_off(err: MissionError) -> None:
        wait = min(policy.backoff(failures, rng), max(0.0, deadline - time.monotonic()))
        tell("retry", err.detail, wait)
        await asyncio.sleep(wait)

    def give_up() -> TransferGaveUpError:
        cause = last or MissionError(
            MissionResult.TRANSFER_FAILED,
            origin,
            "the time budget ran out before the plan was read back",
            mavsdk_result="TIMEOUT",
            vehicle=v.name,
            url=v.url,
        )
        exc = TransferGaveUpError(
            origin,
            cause,
            attempts=attempt,
            elapsed_s=time.monotonic() - t0,
            budget_s=policy.budget_s,
            held=held,
            mission_type=mission_type.name,
        )
        tell("failed", exc.detail)
        return exc

    while True:
        if time.monotonic() >= deadline:
            raise give_up()
        if readbacks_left <= 0:
            attempt += 1
            held = None  # what an earlier read-back showed may be overwritten from here on
            tell("upload")
            with _requests_watched(v, mission_type) as asked:
                _, err = await run(
                    "upload" if plan else "clear", lambda: _put(v, plan, mission_type)
                )
            if err is None:
                failures = 0
                readbacks_left = policy.readbacks
            else:
                failed_step(err)
                if plan and asked[0] >= len(plan) - 1:
                    readbacks_left = 1  # complete on the vehicle, its final ACK lost?
                    tell(
                        "retry", f"{err.detail}; the vehicle asked for the last item: reading back"
                    )
                else:
                    await back_off(err)
                    continue
            if time.monotonic() >= deadline:
                raise give_up()
        tell("read-back")
        back, err = await run("read-back", lambda: download(v, mission_type))
        readbacks_left -= 1
        if err is not None:
            failed_step(err)
            await back_off(err)
            continue
        diffs = compare_items(plan, back)
        if not diffs:
            steps[-1] = dataclasses.replace(steps[-1], outcome="identical")
            report = TransferReport(
                v.name,
                len(plan),
                spent["upload"],
                spent["read-back"],
                mission_type,
                attempt,
                time.monotonic() - t0,
                tuple(steps),
                last.detail if last is not None else "",
            )
            tell("verified", f"read back identical after {attempt} attempt(s)")
            return report
        held = len(back)
        more = f" (+{len(diffs) - 3} more)" if len(diffs) > 3 else ""
        last = MissionError(
            MissionResult.MISMATCH,
            f"verify_{mission_type.name.lower()}",
            "; ".join(diffs[:3]) + more,
            vehicle=v.name,
            url=v.url,
        )
        steps[-1] = dataclasses.replace(steps[-1], outcome="mismatch", detail=last.detail)
        readbacks_left = 0
        failures += 1
        await back_off(last)
