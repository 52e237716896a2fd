"""``gcs assess``: the campaign's statistics against independent references (the ordinary STL
evaluation of each run, scipy's binomial distribution), its reproducibility, its bad input,
and its files.  Ray itself is in ``test_assess_ray.py`` (slow: Ray's start-up)."""

from __future__ import annotations

import dataclasses
import json
import socket
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom

from gcs import cli
from gcs.assess import AssessOptions, assess, evaluate_batch, replay
from gcs.assess.stats import clopper_pearson
from gcs.errors import UserError
from gcs.flight.evaluation import plan_formula
from mavlink.mock.sim.batch import prepare, run_seed, simulate
from mavlink.mock.sim.disturbances import parse_disturbances
from planner.planfile import Plan, load_plan

PLAN = Path(__file__).resolve().parents[1] / "mavlink" / "data" / "reach_avoid_2.plan.json"


@pytest.fixture(scope="module")
def plan():  # type: ignore[no-untyped-def]
    return load_plan(PLAN)


def test_the_robustness_of_every_run_is_the_ordinary_exact_robustness(plan) -> None:  # type: ignore[no-untyped-def]
    setup = prepare(plan)
    flights = simulate(
        setup, [run_seed(1, r) for r in range(6)], parse_disturbances({"wind_m_s": "uniform(0, 8)"})
    )
    true, rep, c_true, _c_rep = evaluate_batch(plan, flights)
    phi = plan_formula(plan)
    names = [v.name for v in plan.vehicles]
    for r in range(6):
        sig = {n: flights.true_enu_m[r, i] for i, n in enumerate(names)}
        sig_rep = {n: flights.reported_enu_m[r, i] for i, n in enumerate(names)}
        assert true[r] == pytest.approx(phi.robustness(sig, plan.check_dt_s), abs=1e-12)
        assert rep[r] == pytest.approx(phi.robustness(sig_rep, plan.check_dt_s), abs=1e-12)
        for k, c in enumerate(phi.clauses):
            assert c_true[r, k] == pytest.approx(c.robustness(sig, plan.check_dt_s), abs=1e-12)
    assert len(set(np.round(true, 6))) > 1  # the runs differ


@pytest.mark.parametrize("k,n", [(0, 10), (3, 10), (10, 10), (171, 200), (999, 1000)])
def test_clopper_pearson_is_the_exact_binomial_interval(k: int, n: int) -> None:
    lo, hi = clopper_pearson(k, n)
    assert 0.0 <= lo <= k / n <= hi <= 1.0
    # the bounds are where the binomial tails hold 2.5 % each (or the ends of [0, 1])
    if k > 0:
        assert binom.sf(k - 1, n, lo) == pytest.approx(0.025, abs=1e-6)
    else:
        assert lo == 0.0
    if k < n:
        assert binom.cdf(k, n, hi) == pytest.approx(0.025, abs=1e-6)
    else:
        assert hi == 1.0


@pytest.mark.slow
def test_a_campaign_is_the_same_whatever_its_split_and_replays_run_by_run(plan) -> None:  # type: ignore[no-untyped-def]
    dist = {"wind_m_s": "uniform(0, 10)"}
    a = assess(plan, AssessOptions(runs=30, seed=5, disturbances=dist, workers=0, batch_size=30))
    b = assess(plan, AssessOptions(runs=30, seed=5, disturbances=dist, workers=0, batch_size=7))
    for name in a.runs_table.dtype.names or ():
        np.testing.assert_array_equal(a.runs_table[name], b.runs_table[name])
    assert (a.p, a.ci, a.quantiles) == (b.p, b.ci, b.quantiles)
    assert a.runs == 30 and a.holds == int((a.runs_table["robustness"] > 0).sum())
    assert a.p == a.holds / 30
    assert a.ci == clopper_pearson(a.holds, 30)
    worst = a.worst[0]
    assert worst.true == a.runs_table["robustness"].min()
    again = replay(plan, AssessOptions(runs=1, seed=5, disturbances=dist, workers=0), worst.seed)
    true, _, _, _ = evaluate_batch(plan, again)
    assert float(true[0]) == worst.true
    # per clause: failures counted on the true positions
    assert sum(c.first_to_fail for c in a.clauses) == a.runs - a.holds


def test_strong_wind_breaks_a_plan_that_holds_in_calm_air(plan) -> None:  # type: ignore[no-untyped-def]
    calm = assess(plan, AssessOptions(runs=20, workers=0, disturbances={"wind_m_s": "0"}))
    storm = assess(plan, AssessOptions(runs=20, workers=0, disturbances={"wind_m_s": "14"}))
    assert storm.quantiles["p50"] < calm.quantiles["p50"] - 0.1
    assert storm.p <= calm.p


@pytest.mark.slow
def test_the_command_reports_and_writes_its_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "rep"
    args = ["assess", str(PLAN), "--runs", "12", "--workers", "0", "--batch-size", "5"]
    assert cli.main([*args, "-o", str(out), "--wind", "uniform(0, 4)"]) == 0
    text = capsys.readouterr().out
    assert "P(spec holds) = " in text and "Clopper-Pearson" in text and "worst runs" in text
    report = json.loads((out / "report.json").read_text())
    assert report["runs"] == 12 and report["disturbances"]["wind_m_s"] == "uniform(0, 4)"
    rows = (out / "runs.csv").read_text().splitlines()
    assert rows[0].startswith("run,seed,robustness,reported") and len(rows) == 13
    assert (out / "assess.png").stat().st_size > 10_000
    assert cli.main([*args, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["runs"] == 12


def test_replay_writes_the_runs_tracks_for_gcs_verify(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    seed = run_seed(0, 3)
    assert cli.main(["assess", str(PLAN), "--replay", str(seed), "-o", str(tmp_path)]) == 0
    true_csv = tmp_path / f"replay_{seed}_true.csv"
    assert true_csv.exists() and (tmp_path / f"replay_{seed}_reported.csv").exists()
    capsys.readouterr()
    status = cli.main(["verify", str(PLAN), "--telemetry", str(true_csv)])
    assert status in (0, 1)  # it reads the tracks and judges them
    assert "flown" in capsys.readouterr().out


CALM = {"gust_m_s": "0", "estimator": "0", "ekf_origin": "0", "wind_m_s": "0"}


@pytest.mark.slow
def test_the_monitor_stops_runs_and_every_vehicle_then_holds_where_it_was(plan) -> None:  # type: ignore[no-untyped-def]
    """``--monitor``: each run flown twice on the same draws.  The unmonitored flights are the
    campaign without the monitor; a stop is decided on the run's reported state and every
    vehicle then holds (it stops following the plan, which goes on moving); the counts agree
    with the runs table."""
    tight = AssessOptions(runs=10, seed=4, workers=0, monitor=True, max_off_plan_m=0.2,
                          disturbances=CALM)  # fmt: skip
    r = assess(plan, tight)
    plain = assess(plan, dataclasses.replace(tight, monitor=False))
    np.testing.assert_array_equal(r.runs_table["robustness"], plain.runs_table["robustness"])
    m = r.monitor
    assert m is not None and plain.monitor is None
    table = r.runs_table
    stopped = table["stop_code"] != 0
    assert m.stops == int(stopped.sum()) >= 3 and sum(k for _, k in m.reasons) == m.stops
    assert m.p_stop == m.stops / 10 and m.ci_stop == clopper_pearson(m.stops, 10)
    assert m.holds == int((table["monitored"] > 0).sum())
    assert m.spurious == int((stopped & (table["robustness"] > 0)).sum())
    assert np.isnan(table["stop_s"][~stopped]).all()
    # a run the monitor left alone flies as without it
    np.testing.assert_array_equal(table["monitored"][~stopped], table["robustness"][~stopped])
    for row in table[stopped][:2]:
        seed = int(row["seed"])
        held = replay(plan, tight, seed)
        free = replay(plan, dataclasses.replace(tight, monitor=False), seed)
        assert held.stop_s is not None and held.stop_s[0] == row["stop_s"]
        assert held.stop is not None and held.stop.verdict(0) is not None
        k = int(np.ceil(row["stop_s"] / plan.check_dt_s))
        later = slice(k + int(3.0 / plan.check_dt_s), None)
        assert k + int(3.0 / plan.check_dt_s) < held.t_s.size - 10  # seconds of hold seen
        # held: within a few dm of where it was at the stop, and still
        drift = np.linalg.norm(
            held.true_enu_m[0, :, later] - held.true_enu_m[0, :, k : k + 1], axis=2
        )
        assert drift.max() < 0.4
        # the same run without the monitor flies on along its plan
        moved = np.linalg.norm(
            free.true_enu_m[0, :, later] - free.true_enu_m[0, :, k : k + 1], axis=2
        )
        assert moved.max() > 2.0


@pytest.mark.slow
def test_the_monitor_in_the_command_report_and_replay(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["assess", str(PLAN), "--runs", "6", "--workers", "0", "--monitor",
            "--max-off-plan", "0.2", "-d", "gust_m_s=0"]  # fmt: skip
    assert cli.main(args) == 0
    text = capsys.readouterr().out
    assert "safety monitor (--monitor" in text and "off its plan (tracking alarm)" in text
    assert cli.main([*args, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)["monitor"]
    assert doc["stops"] >= 1 and len(doc["watched"]) == 3
    assert sum(x["runs"] for x in doc["reasons"]) == doc["stops"]
    seed = run_seed(0, 0)
    assert cli.main([*args, "--replay", str(seed), "-o", str(tmp_path)]) == 0
    assert "safety monitor: stopped the flight at t = " in capsys.readouterr().out


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize(
    "extra,words",
    [
        (["--runs", "0"], "--runs: must be a whole number > 0"),
        (["-d", "wnd=1"], "unknown disturbance 'wnd'"),
        (["-d", "wind_m_s=weibull(1, 2)"], "unknown distribution 'weibull'"),
        (["-d", "loss=-0.5"], "loss: const(-0.5) lies outside [0, 1]"),
        (["-d", "latency_s"], "expected NAME=DIST"),
        (["--rate", "1"], "--rate"),
        (["--realtime"], "--realtime needs --replay"),
        (["--monitor", "--max-off-plan", "-1"], "--max-off-plan: must be a number >= 0"),
        (["--param", "NOPE=1"], "no parameter 'NOPE'"),
        (["--ray-address", "127.0.0.1:PORT", "--workers", "2"], "no Ray cluster answers there"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    extra: list[str], words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    extra = [e.replace("PORT", str(_closed_port())) for e in extra]
    out = tmp_path / "never"
    assert (
        cli.main(["assess", str(PLAN), "--runs", "3", "--workers", "0", *extra, "-o", str(out)])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not out.exists()  # nothing half-written


def test_a_missing_plan_file_is_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["assess", str(tmp_path / "none.json"), "--workers", "0"]) == 2
    assert "none.json" in capsys.readouterr().err


def test_options_are_checked_in_the_python_api() -> None:
    with pytest.raises(UserError, match="--runs"):
        AssessOptions(runs=-1)
    with pytest.raises(UserError, match="--batch-size"):
        AssessOptions(runs=1, batch_size=0)


def test_list_disturbances_names_every_one(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["assess", "--list-disturbances"]) == 0
    text = capsys.readouterr().out
    for name in ("wind_m_s", "gust_m_s", "estimator", "ekf_origin", "latency_s", "loss", "derate"):
        assert name in text


def test_the_assessment_picture_draws_each_region_as_seen_from_above(
    plan: Plan, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A turned keep-out and a pole are drawn as their footprints (corners; a 48-gon through
    the circle), a box as its rectangle: the outlines handed to matplotlib, recorded."""
    import math

    import matplotlib.patches

    from gcs.assess.figure import plot_assessment
    from planner.spec.regions import Cylinder, Prism, Region, RegionKind

    turned = Prism.oriented_box((2.0, -2.0, 1.5), (0.8, 0.2, 1.5), math.radians(40.0))
    shaped = dataclasses.replace(
        plan,
        regions=(
            *plan.regions,
            Region.of_shape("turned", RegionKind.NO_FLY, turned),
            Region.of_shape("mast", RegionKind.POLE, Cylinder((-2.5, 2.5), 0.3, 0.0, 3.0)),
        ),
    )
    result = assess(shaped, AssessOptions(runs=2, workers=0, batch_size=2))
    outlines: list[np.ndarray] = []

    class Outline(matplotlib.patches.Polygon):
        def __init__(self, xy, *args, **kwargs):  # type: ignore[no-untyped-def]
            outlines.append(np.asarray(xy, dtype=float))
            super().__init__(xy, *args, **kwargs)

    monkeypatch.setattr(matplotlib.patches, "Polygon", Outline)
    path = plot_assessment(shaped, result, None, tmp_path / "a.png")
    assert path.stat().st_size > 10_000
    assert len(outlines) == len(shaped.regions)
    c, s = math.cos(math.radians(40.0)), math.sin(math.radians(40.0))
    corners = [
        (2.0 + a * 0.8 * c - b * 0.2 * s, -2.0 + a * 0.8 * s + b * 0.2 * c)
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    np.testing.assert_allclose(outlines[-2], corners, atol=1e-12)
    assert outlines[-1].shape == (48, 2)
    np.testing.assert_allclose(np.hypot(*(outlines[-1] - [-2.5, 2.5]).T), 0.3, atol=1e-12)
    (x0, y0, _), (x1, y1, _) = plan.regions[0].lo_enu_m, plan.regions[0].hi_enu_m
    np.testing.assert_allclose(outlines[0], [[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def test_random_vehicle_loss_is_counted_and_the_monitor_stops_on_the_lost_link(
    capsys: pytest.CaptureFixture[str],
) -> None:
    # issue 43: P(spec holds) under random vehicle loss, the baseline replanning is to beat
    rc = cli.main(["assess", str(PLAN), "--runs", "60", "-d", "lost=0.5", "--monitor", "--json",
               "--workers", "0"])  # fmt: skip
    assert rc in (0, 1)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    # each of 2 vehicles lost with probability 0.5: about 3 runs in 4 lose one
    assert 30 <= out["lost"] <= 58
    reasons = {r["why"]: r["runs"] for r in out["monitor"]["reasons"]}
    assert reasons.get("a vehicle lost (its link silent)", 0) > 0.5 * out["lost"]
    assert out["p_holds"] < 0.75
