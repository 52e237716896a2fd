"""A link that drops for 10 s in the middle of a flight (issue 42), on the px4 mock.

In mission mode the mission runs on board (PX4's NAV_DLL_ACT is 0 by default: a lost data link
is no failsafe), so the flight goes on; the ground station rides the loss out, hears the
vehicle again, judges the whole flight from the telemetry it has and says what it missed.
Offboard, the same drop starves PX4 of setpoints: its offboard-loss failsafe takes the vehicle
out of offboard (COM_OF_LOSS_T), and the ground station stops and says so.

References: PX4's documented behaviour (NAV_DLL_ACT, COM_OF_LOSS_T), what the mock does with a
real UDP outage (nothing passes either way), and the flown record itself (its sample times).
"""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gcs.cli import main
from gcs.flight import FlyOptions, fly_plan, vehicle_specs
from gcs.flight.dryrun import DryRun, mock_vehicles
from gcs.flight.outcome import FlightMode, FlightOutcome, format_outcome
from gcs.report import report_markdown
from mavlink.mock.sim.config import FaultConfig, Outage
from mavlink.mock.sim.px4 import Px4Mode
from mavlink.monitor_findings import Verdict
from planner.planfile import Plan, load_plan

pytestmark = pytest.mark.slow

#: Two drones 20 m apart, each to hold 3 s in its own box 15 m away within [5, 25] s.
SCENARIO = """
name: patrol
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-5, -5, 0], max: [25, 25, 10]}
regions:
  a1: {kind: goal, center: [15, 0, 4], half_size: 2}
  a2: {kind: goal, center: [15, 20, 4], half_size: 2}
limits: {v_max_m_s: 2.0, a_max_m_s2: 1.0}
vehicles:
  count: 2
  name: "d{i}"
  starts: {positions: [[0, 0, 4], [0, 20, 4]]}
timing: {horizon_s: 30, segment_s: 2, Ts_s: 0.25, check_dt_s: 0.05}
separation_m: 2.0
epsilon: 0.01
model: minimum_jerk
spec:
  - formula: eventually[5, 25] always[0, 3] inside(d1, a1)
  - formula: eventually[5, 25] always[0, 3] inside(d2, a2)
  - formula: always[0, 30] inside(d1, workspace)
  - formula: always[0, 30] inside(d2, workspace)
  - formula: always[0, 30] dist(d1, d2) >= 2
"""

DROP_AT_S = 6.0  # of flight in the mode, d2's link goes silent both ways
DROP_S = 10.0


@pytest.fixture(scope="module")
def plan_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("patrol")
    (out / "patrol.yaml").write_text(SCENARIO, encoding="utf-8")
    path = out / "patrol.json"
    assert main(["plan", str(out / "patrol.yaml"), "-o", str(path), "--json"]) == 0
    return path


async def _drop(dry: DryRun, index: int, mode: Px4Mode) -> float:
    """Silence vehicle ``index``'s link for DROP_S once it has flown DROP_AT_S in ``mode``;
    returns when (simulated time) the drop began."""
    victim = dry.mock.vehicles[index]
    while victim.mode is not mode:
        await dry.clock.sleep(0.1)
    await dry.clock.sleep(DROP_AT_S)
    now = dry.mock.time_s
    victim.set_faults(FaultConfig(outages=(Outage(now, now + DROP_S),)))
    return now


def _fly(plan: Plan, mode: FlightMode) -> tuple[FlightOutcome, list[Px4Mode]]:
    """The flight with d2's drop, and the mock vehicles' own modes at its end (the truth)."""

    async def run() -> tuple[FlightOutcome, list[Px4Mode]]:
        with mock_vehicles(plan, seed=0) as dry:
            target = Px4Mode.AUTO_MISSION if mode is FlightMode.MISSION else Px4Mode.OFFBOARD
            drop = asyncio.create_task(_drop(dry, 1, target))
            try:
                out = await fly_plan(
                    plan,
                    vehicle_specs(plan, dry.urls),
                    FlyOptions(mode=mode, connect_timeout_s=20.0),
                    clock=dry.clock,
                )
                return out, [v.mode for v in dry.mock.vehicles]
            finally:
                assert drop.done(), "the link never dropped"

    return asyncio.run(asyncio.wait_for(run(), 300.0))


def test_a_mission_flies_on_through_a_10s_link_loss_and_is_judged_on_what_was_heard(
    plan_path: Path,
) -> None:
    plan = load_plan(plan_path)
    out, _ = _fly(plan, FlightMode.MISSION)
    text = format_outcome(plan, out)
    # not a stop: the flight completed, both missions finished, and it was judged whole
    assert out.completed and out.safety_event is None and not out.interrupted, text
    assert all(r.finished for r in out.missions.values()), text
    ev = out.evaluation
    assert ev is not None and ev.flown_robustness is not None and ev.flown_robustness > 0, text
    # the monitor lost d2 once, for about the drop, and checked it again afterwards
    assert out.monitor is not None and set(out.monitor.unheard) == {"d2"}, text
    ((a, b),) = out.monitor.unheard["d2"]
    assert b is not None and DROP_S - 1.0 <= b - a <= DROP_S + 1.5, (a, b)
    assert DROP_AT_S - 1.0 <= a <= DROP_AT_S + 2.0, (a, b)
    # the record: one gap in d2's telemetry where the link was down, none in d1's
    assert set(ev.gaps) == {"d2"}, ev.gaps
    ((g0, g1),) = ev.gaps["d2"]
    assert DROP_S - 1.0 <= g1 - g0 <= DROP_S + 1.0 and abs(g0 - a) < 1.0, (g0, g1, a)
    # and the operator is told, in the summary and the report
    assert "link lost and ridden out" in text and "d2: no telemetry from t = " in text, text
    report = report_markdown(plan, out, title="patrol", base_dir=plan_path.parent)
    assert "| link lost |" in report and "| telemetry missed |" in report


def test_offboard_under_the_same_drop_is_px4s_offboard_loss_failsafe_and_says_so(
    plan_path: Path,
) -> None:
    plan = load_plan(plan_path)
    out, truth = _fly(plan, FlightMode.OFFBOARD)
    ev = out.safety_event
    assert not out.completed and ev is not None and ev.verdict is Verdict.LINK_LOST
    # (the plan's clock starts after the switch to offboard: the drop comes a little earlier
    # on it than on the mode's)
    assert ev.vehicles == ("d2",) and 0.0 < ev.t_s <= DROP_AT_S + 2.0, ev
    assert "offboard-loss failsafe" in ev.describe()
    # PX4 took d2 out of offboard by itself; the other was held by the ground station
    assert truth[1] is not Px4Mode.OFFBOARD and out.final_modes["d1"] == "AUTO.LOITER", truth
    # d2, still silent at the end, is not reported in a mode it has left
    assert out.final_modes["d2"].startswith("unknown (link lost; OFFBOARD when last heard")
