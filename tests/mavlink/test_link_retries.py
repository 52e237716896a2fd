"""Whole-transfer retries (:func:`mavlink.mission.upload_with_retries`) and connecting on a bad
link: real MAVSDK against the mock vehicle over loopback UDP, with its fault injectors.

The reference is always the vehicle's own stored copy (what the mock took from the mission
protocol), never what MAVSDK read back. Every wait is bounded (``HANG_S``) so a hang fails
instead of blocking the suite; no timing is asserted.
"""

from __future__ import annotations

import asyncio
import dataclasses

import pytest

from mavlink.errors import TransferGaveUpError
from mavlink.mission import (
    FenceBox,
    MissionItem,
    MissionType,
    RetryPolicy,
    TransferProgress,
    compare_items,
    geofence_items,
    trajectory_to_mission,
    upload_with_retries,
)
from mavlink.mock import FaultConfig
from planner.frames import GeodeticPoint
from tests.mavlink.linkutil import mock_and_fleet, stored_plan
from tests.mavlink.test_link_mission import min_jerk

pytestmark = pytest.mark.slow  # flights or transfers over UDP (make test-fast skips)

HANG_S = 90.0
LOSS_30_BOTH = FaultConfig(loss_to_vehicle=0.30, loss_to_gcs=0.30)


def _mission() -> tuple[MissionItem, ...]:
    """A 7-item mission (take-off, 3 waypoints, 2 speed changes, land): short, so the lossy
    runs stay quick; long enough that MAVSDK alone often fails it at 30 % loss."""
    plan = stored_plan(2)
    traj = min_jerk([(0, 0, 2), (2, 0, 2), (2, 2, 2)], 2.0)
    return trajectory_to_mission(traj, plan.origin, acceptance_radius_m=0.3).items


def _rally(origin: GeodeticPoint) -> tuple[MissionItem, ...]:
    """Two NAV_RALLY_POINT items near ``origin``."""
    return tuple(
        MissionItem(
            seq=k,
            frame=5,  # GLOBAL_INT
            command=5100,  # NAV_RALLY_POINT
            current=1 if k == 0 else 0,
            autocontinue=1,
            param1=0.0,
            param2=0.0,
            param3=0.0,
            param4=0.0,
            x=round(origin.lat_deg * 1e7) + 100 * k,
            y=round(origin.lon_deg * 1e7) - 100 * k,
            z=origin.alt_m + 10.0,
            mission_type=MissionType.RALLY,
        )
        for k in range(2)
    )


def _stored(vehicle, mission_type: int) -> list[MissionItem]:  # type: ignore[no-untyped-def]
    return [MissionItem(**dataclasses.asdict(i)) for i in vehicle.mission_items(mission_type)]


def test_backoff_doubles_up_to_its_ceiling_with_seeded_jitter() -> None:
    import random

    policy = RetryPolicy(backoff_s=0.25, backoff_max_s=2.0, jitter=0.5, seed=3)
    full = [0.25, 0.5, 1.0, 2.0, 2.0, 2.0]
    waits = [policy.backoff(k, random.Random(3)) for k in range(1, 7)]
    assert all(0.5 * w <= got <= w for got, w in zip(waits, full, strict=True))
    assert waits == [policy.backoff(k, random.Random(3)) for k in range(1, 7)]  # seeded
    exact = RetryPolicy(jitter=0.0)
    assert [exact.backoff(k, random.Random()) for k in range(1, 7)] == full
    for bad in ({"budget_s": 0.0}, {"budget_s": float("nan")}, {"jitter": 1.5}, {"readbacks": 0}):
        with pytest.raises(ValueError):
            RetryPolicy(**bad)  # type: ignore[arg-type]


def test_under_30pct_loss_both_ways_the_fleet_connects_and_every_plan_reads_back_as_sent() -> None:
    # Three vehicles, each link losing 30 % both ways from the first datagram: discovery,
    # heartbeats and the telemetry-rate requests (retried) must get through, then d1 and d2
    # upload a mission and d3 a geofence and rally points, all retried as whole transfers.
    plan = stored_plan(2)
    mission = _mission()
    fence = geofence_items([FenceBox("ws", (-5.0, -5.0, 0.0), (5.0, 5.0, 3.0), True)], plan.origin)
    rally = _rally(plan.origin)
    spawns = [(float(i), 0.0, 0.0) for i in range(3)]
    seen: list[TransferProgress] = []

    async def fence_then_rally(v):  # type: ignore[no-untyped-def]
        a = await upload_with_retries(
            v, fence, MissionType.FENCE, policy=RetryPolicy(seed=3), progress=seen.append
        )
        b = await upload_with_retries(
            v, rally, MissionType.RALLY, policy=RetryPolicy(seed=4), progress=seen.append
        )
        return a, b

    async def run():  # type: ignore[no-untyped-def]
        names = ["d1", "d2", "d3"]
        async with mock_and_fleet(names, plan.origin, spawns, faults=LOSS_30_BOTH, seed=11) as (
            mock,
            fleet,
        ):
            # (``connected`` itself flickers at 30 % loss: two heartbeats in a row get lost)
            connected = [s.heartbeat_age_s is not None for s in fleet.statuses()]
            reports = await asyncio.wait_for(
                asyncio.gather(
                    upload_with_retries(fleet["d1"], mission, policy=RetryPolicy(seed=1)),
                    upload_with_retries(fleet["d2"], mission, policy=RetryPolicy(seed=2)),
                    fence_then_rally(fleet["d3"]),
                ),
                HANG_S,
            )
            for v in mock.vehicles:
                v.set_faults(FaultConfig())
            stored = [_stored(v, 0) for v in mock.vehicles[:2]]
            d3 = mock.vehicles[2]
            return connected, reports, stored, _stored(d3, 1), _stored(d3, 2)

    connected, (r1, r2, (rf, rr)), stored, fence_back, rally_back = asyncio.run(run())
    assert connected == [True, True, True]
    for report, items, held in (
        (r1, mission, stored[0]),
        (r2, mission, stored[1]),
        (rf, fence, fence_back),
        (rr, rally, rally_back),
    ):
        # Reported as read back identical, and the vehicle holds exactly the plan.
        assert report.steps[-1].outcome == "identical" and report.attempts >= 1
        assert report.items == len(items)
        assert compare_items(items, held, exact=True) == [], report
    assert rf.mission_type is MissionType.FENCE and rr.mission_type is MissionType.RALLY
    assert {p.step for p in seen} >= {"upload", "read-back", "verified"}
    assert all(p.vehicle == "d3" for p in seen)


def test_a_read_back_that_differs_is_uploaded_again_until_it_matches() -> None:
    plan = stored_plan(2)
    mission = _mission()

    async def run():  # type: ignore[no-untyped-def]
        async with mock_and_fleet(["d1"], plan.origin, [(0.0, 0.0, 0.0)]) as (mock, fleet):
            vehicle = mock.vehicles[0]
            send = vehicle.missions.send
            corrupted: list[int] = []

            def corrupt_first_download(msg):  # type: ignore[no-untyped-def]
                # The first copy of item 3 read back reaches the GCS 5 m higher.
                if msg.get_type() == "MISSION_ITEM_INT" and msg.seq == 3 and not corrupted:
                    corrupted.append(msg.seq)
                    msg.z += 5.0
                send(msg)

            vehicle.missions.send = corrupt_first_download
            report = await asyncio.wait_for(
                upload_with_retries(fleet["d1"], mission, policy=RetryPolicy(seed=0)), HANG_S
            )
            return report, _stored(vehicle, 0)

    report, stored = asyncio.run(run())
    assert [(s.attempt, s.kind, s.outcome) for s in report.steps] == [
        (1, "upload", "ok"),
        (1, "read-back", "mismatch"),
        (2, "upload", "ok"),
        (2, "read-back", "identical"),
    ]
    assert report.attempts == 2
    assert report.last_error.startswith("verify_mission: mismatch: item 3: z sent")
    assert compare_items(mission, stored, exact=True) == []


def test_an_empty_mission_is_a_clear_read_back_as_no_items() -> None:
    plan = stored_plan(2)

    async def run():  # type: ignore[no-untyped-def]
        async with mock_and_fleet(["d1"], plan.origin, [(0.0, 0.0, 0.0)]) as (mock, fleet):
            await upload_with_retries(fleet["d1"], _mission(), policy=RetryPolicy(seed=0))
            held = len(mock.vehicles[0].mission_items(0))
            report = await asyncio.wait_for(
                upload_with_retries(fleet["d1"], (), policy=RetryPolicy(seed=0)), HANG_S
            )
            return held, report, mock.vehicles[0].mission_items(0)

    held, report, left = asyncio.run(run())
    assert held == 7 and left == ()
    assert [(s.kind, s.outcome) for s in report.steps] == [
        ("clear", "ok"),
        ("read-back", "identical"),
    ]


def test_total_loss_gives_up_within_the_budget_naming_the_vehicle_attempts_and_cause() -> None:
    plan = stored_plan(2)
    mission = _mission()
    previous = trajectory_to_mission(
        plan.vehicles[1].trajectory, plan.origin, acceptance_radius_m=0.3
    ).items
    seen: list[TransferProgress] = []

    async def run():  # type: ignore[no-untyped-def]
        async with mock_and_fleet(["d1"], plan.origin, [(0.0, 0.0, 0.0)]) as (mock, fleet):
            vehicle, v = mock.vehicles[0], fleet["d1"]
            await upload_with_retries(v, previous, policy=RetryPolicy(seed=0))
            vehicle.set_faults(FaultConfig(loss_to_vehicle=1.0, loss_to_gcs=1.0))
            with pytest.raises(TransferGaveUpError) as gave_up:
                await asyncio.wait_for(
                    upload_with_retries(
                        v, mission, policy=RetryPolicy(budget_s=3.0, seed=0), progress=seen.append
                    ),
                    HANG_S,
                )
            kept = _stored(vehicle, 0)
            # The link back: the abandoned transfers left neither MAVSDK nor the vehicle busy.
            vehicle.set_faults(FaultConfig())
            again = await asyncio.wait_for(
                upload_with_retries(v, mission, policy=RetryPolicy(seed=0)), HANG_S
            )
            return gave_up.value, kept, again, _stored(vehicle, 0)

    exc, kept, again, stored = asyncio.run(run())
    text = str(exc)
    assert text.startswith("vehicle d1 (udpin://127.0.0.1:") and "\n" not in text
    assert "upload_mission" in text and f"gave up after {exc.attempts} attempt(s)" in text
    assert exc.attempts >= 1 and "last cause: upload_mission: transfer_failed (TIMEOUT)" in text
    assert exc.held is None and "MISSION plan is unknown" in text  # nothing was read back
    assert [p.step for p in seen][-1] == "failed" and "verified" not in {p.step for p in seen}
    assert compare_items(previous, kept, exact=True) == []  # never a partial mission
    assert again.steps[-1].outcome == "identical"
    assert compare_items(mission, stored, exact=True) == []
