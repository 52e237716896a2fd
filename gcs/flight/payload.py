"""The camera's part of a flight: when each vehicle takes pictures, and telling it to.

A plan whose spec asks a vehicle to face an inspection target (``face(d, T)``) has *capture
windows* (:func:`planner.spec.captures.capture_windows`: the stretches in which the vehicle is
in the inspection place and faces its target).  :func:`capture_spans` makes them the
stretches the camera takes pictures in (:class:`mavlink.mission.CaptureSpan`), each trimmed
by a little at both ends (:data:`TRIM_S`, at most a quarter of the window) so that a
vehicle a fraction of a second behind its plan is still in place for the first and the last
picture, with the gimbal pitched to the target and a picture every ``interval_s``.

How the spans reach the vehicle depends on how it flies:

* a **mission** carries them as items (``DO_GIMBAL_MANAGER_PITCHYAW``,
  ``IMAGE_START_CAPTURE``, ``IMAGE_STOP_CAPTURE``: :func:`mavlink.mission.trajectory_to_mission`),
  which PX4 runs as it reaches them;
* in **offboard** flight the ground station sends the same commands on the plan's clock
  (:func:`run_offboard_captures`): the gimbal's to the autopilot (PX4 is the gimbal manager,
  and obeys only the one in control: the ground station takes it first), the camera's to the
  camera component PX4 routes to (heard by its HEARTBEAT, type MAV_TYPE_CAMERA; PX4 answers
  IMAGE_START_CAPTURE sent to itself UNSUPPORTED).  A vehicle without a camera, or a command refused, is said in one line
  per vehicle and command (the flight goes on: pictures are not a safety matter), and the
  flight's coverage report then shows what was not pictured.

A room of its own: it reads the plan (planner) and speaks to vehicles (mavlink), and
:mod:`gcs.flight`, :mod:`gcs.flight.missions` and the commands use it.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mavlink.errors import CommandError
from mavlink.link.fleet import GCS_SYSID
from mavlink.mission.conversion import CaptureSpan
from planner.planfile import plan_formula
from planner.spec.captures import capture_windows

if TYPE_CHECKING:
    from mavlink.link.fleet import Fleet
    from mavlink.link.vehicle import Vehicle
    from planner.planfile import Plan

__all__ = [
    "DEFAULT_INTERVAL_S",
    "TRIM_S",
    "CameraCommands",
    "capture_spans",
    "run_offboard_captures",
]

#: Time between pictures unless told (s).
DEFAULT_INTERVAL_S = 1.0
#: What a span leaves out at each end of its window (s; at most a quarter of the window).
TRIM_S = 0.5

MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW = 1000
MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE = 1001
#: The ground station's component id (MAVSDK as a ground station: MAV_COMP_ID_MISSIONPLANNER).
GCS_COMPID = 190
MAV_CMD_IMAGE_START_CAPTURE = 2000
MAV_CMD_IMAGE_STOP_CAPTURE = 2001


def capture_spans(
    plan: Plan, interval_s: float = DEFAULT_INTERVAL_S
) -> dict[str, tuple[CaptureSpan, ...]]:
    """The camera's spans per vehicle of ``plan`` (module docstring), by start time; every
    vehicle of the plan has an entry (empty: it takes no pictures; all are empty when
    ``interval_s`` is 0, the camera left alone)."""
    if not interval_s > 0:
        return {v.name: () for v in plan.vehicles}

    out: dict[str, list[CaptureSpan]] = {v.name: [] for v in plan.vehicles}
    windows = capture_windows(
        plan_formula(plan),
        plan,
        [v.trajectory for v in plan.vehicles],
        plan.check_dt_s,
        plan.horizon_s,
    )
    for w in windows:
        trim = min(TRIM_S, 0.25 * w.duration_s)
        out[w.vehicle].append(
            CaptureSpan(
                w.t_start_s + trim,
                w.t_end_s - trim,
                gimbal_pitch_deg=w.gimbal_pitch_deg,
                interval_s=interval_s,
                target=w.target,
            )
        )
    return {name: tuple(spans) for name, spans in out.items()}


@dataclass(slots=True)
class CameraCommands:
    """What the ground station told the cameras in an offboard flight.

    Attributes:
        sent: per vehicle, (plan time, command name) of each command accepted.
        refused: per vehicle, one line per command that failed (names the command, result).
        no_camera: vehicles with spans but no camera heard.
    """

    sent: dict[str, list[tuple[float, str]]] = field(default_factory=dict)
    refused: dict[str, list[str]] = field(default_factory=dict)
    no_camera: list[str] = field(default_factory=list)


async def run_offboard_captures(
    fleet: Fleet,
    spans: Mapping[str, Sequence[CaptureSpan]],
    started: asyncio.Future[float],
    note: Callable[[str], None],
    out: CameraCommands,
) -> None:
    """Send each vehicle's camera and gimbal commands on the plan's clock (module docstring).

    Waits for ``started`` (the shared start, on the fleet's clock), then at each span's start
    sends, at once and side by side, DO_GIMBAL_MANAGER_PITCHYAW to the autopilot (the first
    time after DO_GIMBAL_MANAGER_CONFIGURE putting the ground station in control of the
    gimbal: PX4 denies a PITCHYAW from anyone else) and IMAGE_START_CAPTURE with the span's
    interval and count to the camera, and at its end IMAGE_STOP_CAPTURE.  A gimbal that does
    not answer (PX4 without its gimbal module never ACKs) or refuses is not asked again: the
    camera then looks where it is mounted, straight ahead, which the vehicle's heading aims.
    Runs until the last span ends or it is cancelled (the flight ended); never raises for a
    refusal.  What it sent and what was refused goes into ``out`` as it happens.
    """

    t0 = await started
    clock = fleet.clock
    vehicles = {v.name: v for v in fleet}

    async def one(v: Vehicle, todo: Sequence[CaptureSpan]) -> None:
        comp = v.camera_component
        if comp is None:  # said before the flight (gcs.flight), and in its outcome
            out.no_camera.append(v.name)
            return
        sent = out.sent.setdefault(v.name, [])
        gimbal = {"ok": True, "taken": False}

        async def send(when: float, what: str, command: int, *p: float, to: int) -> bool:
            try:
                await v.command_long(what, command, *p, component=to)
            except CommandError as exc:
                line = f"{v.name}: {what} at t={when:.1f} s: {exc.result}"
                out.refused.setdefault(v.name, []).append(line)
                note(line)
                return False
            sent.append((when, what))
            return True

        async def aim(span: CaptureSpan) -> None:
            if not gimbal["taken"]:
                gimbal["taken"] = True
                if not await send(
                    span.t_start_s,
                    "take the gimbal",
                    MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                    float(GCS_SYSID),
                    float(GCS_COMPID),
                    -1.0,
                    -1.0,
                    to=1,
                ):
                    gimbal["ok"] = False
                    return
            gimbal["ok"] = await send(
                span.t_start_s,
                f"gimbal pitch {span.gimbal_pitch_deg:+.0f} deg",
                MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
                span.gimbal_pitch_deg,
                0.0,
                math.nan,
                math.nan,
                to=1,
            )

        for span in todo:
            await clock.sleep(t0 + span.t_start_s - clock.monotonic())
            start = send(
                span.t_start_s,
                f"start capture ({span.target})",
                MAV_CMD_IMAGE_START_CAPTURE,
                0.0,
                span.interval_s,
                float(span.pictures()),
                to=comp,
            )
            if gimbal["ok"]:
                await asyncio.gather(aim(span), start)
            else:
                await start
            await clock.sleep(t0 + span.t_end_s - clock.monotonic())
            await send(span.t_end_s, "stop capture", MAV_CMD_IMAGE_STOP_CAPTURE, 0.0, to=comp)

    await asyncio.gather(
        *(one(vehicles[name], todo) for name, todo in spans.items() if todo and name in vehicles)
    )
