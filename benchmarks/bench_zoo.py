"""The scenario zoo: every scenario of ``benchmarks/scenarios/`` planned cold by ``gcs plan``.

Each scenario is planned in a fresh ``gcs plan FILE -o TMP --time-limit S --json`` process (a
cold build: no structure cache survives between scenarios), one at a time.  Measured per
scenario: the wall time of the process; read from its output: the exact robustness, the
iterations, the starts of the multi-start, the build time, the status and the weakest clause;
solved = exit status 0 (the mission is met: exact robustness >= epsilon and every check
passes).  Each scenario file says ``# expected: feasible`` or ``# expected: infeasible`` in its
header.  For the stlpy benchmarks (``stlpy_<name>_<spelling>.yaml``) the certified MILP optimum
(Kurtz & Lin 2022, Gurobi) and the ratio robustness / optimum are shown.

Printed: a table, the failures with their weakest clause, summary lines (feasible scenarios
solved, any over the time limit, median wall time, stlpy satisfied per spelling, median ratio
to the certified optimum, infeasible ones ended in bounded time with exit 1), then one JSON
line with every figure.

    .venv/bin/python benchmarks/bench_zoo.py                        # everything, 60 s each
    .venv/bin/python benchmarks/bench_zoo.py --only stlpy_reach powerline_line4 --time-limit 30
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

Row = dict[str, Any]
ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "benchmarks" / "scenarios"
GCS = ROOT / ".venv" / "bin" / "gcs"

#: Certified optima of stlpy's benchmarks (mixed-integer programming, Gurobi; Kurtz & Lin,
#: "Mixed-integer programming for signal temporal logic with fewer binary variables", 2022),
#: for stlpy's own discretisation (p+ = p + v) and samples y_0 .. y_T.
CERTIFIED = {
    "reach_avoid": 0.5,
    "narrow_passage": 0.4,
    "either_or": 0.5,
    "multitarget": 0.5,
    "door_puzzle": 0.4,
    "stepping_stones": 0.0527,
}
SPELLINGS = ("regions", "halfplanes")
_EXPECTED = re.compile(r"^#\s*expected:\s*(feasible|infeasible)\b", re.MULTILINE)
_STLPY = re.compile(r"^stlpy_(.+)_(regions|halfplanes)$")


def expected_of(path: Path) -> str:
    """``feasible`` / ``infeasible`` from the file's ``# expected:`` line, or ``?``."""
    m = _EXPECTED.search(path.read_text(encoding="utf-8"))
    return m.group(1) if m else "?"


def run_one(path: Path, time_limit: float, gcs: Path, extra: tuple[str, ...] = ()) -> Row:
    """Plan ``path`` in a fresh ``gcs plan`` process (``extra``: more of its options); the
    figures of one table row."""
    row: Row = {"scenario": path.stem, "expected": expected_of(path)}
    m = _STLPY.match(path.stem)
    if m and m.group(1) in CERTIFIED:
        row["stlpy"] = m.group(1)
        row["spelling"] = m.group(2)
        row["certified"] = CERTIFIED[m.group(1)]
    env = dict(os.environ, OMP_NUM_THREADS="1")  # MUMPS threads only fight on 2 shared cores
    with tempfile.TemporaryDirectory(prefix="zoo-") as tmp:
        out = Path(tmp) / f"{path.stem}.plan.json"
        cmd = [str(gcs), "plan", str(path), "-o", str(out), "--time-limit", f"{time_limit:g}",
               "--json", *extra]  # fmt: skip
        # The time limit covers build and solve; the guard only catches a process that hangs.
        guard = 2 * time_limit + 120 if time_limit > 0 else None
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)  # fmt: skip
        try:
            stdout, stderr = proc.communicate(timeout=guard)
            killed = False
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            stdout, stderr = proc.communicate()
            killed = True
        wall = time.perf_counter() - t0
    row.update(exit=proc.returncode, wall_s=round(wall, 3), killed=killed)
    row["solved"] = proc.returncode == 0
    summary = None
    for line in reversed(stdout.splitlines()):
        if line.startswith("{"):
            try:
                summary = json.loads(line)
                break
            except json.JSONDecodeError:
                pass
    if summary is not None:
        stats = summary.get("stats") or {}
        weakest = summary.get("weakest") or {}
        row.update(
            robustness=summary.get("robustness"),
            iterations=summary.get("iterations"),
            build_s=stats.get("build_s"),
            solver_s=stats.get("solver_s"),
            solve_time_s=summary.get("solve_time_s"),
            status=summary.get("status"),
            weakest=weakest.get("formula"),
            weakest_robustness=weakest.get("robustness"),
            weakest_t_s=weakest.get("t_s"),
            weakest_clause=weakest.get("clause"),
            n_variables=stats.get("n_variables"),
            n_constraints=stats.get("n_constraints"),
            starts=stats.get("starts"),
            coarse=(stats.get("coarse") or {}).get("status"),
            coarse_s=(lambda c: None if not c else c["build_s"] + c["solve_s"])(
                stats.get("coarse")
            ),
            started_from=(summary.get("status") or "").split("; start ")[-1]
            if "; start " in (summary.get("status") or "")
            else "first start",
        )
    else:  # no summary: a load error (exit 2, one line on stderr) or a crash
        lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("gcs plan:")]
        row["status"] = (
            f"killed by the guard after {wall:.0f} s"
            if killed
            else (lines[-1] if lines else f"exit {proc.returncode}, no summary")
        )
    rho = row.get("robustness")
    if "certified" in row and isinstance(rho, int | float):
        row["ratio"] = rho / float(row["certified"])
    return row


def _num(x: object, fmt: str, width: int) -> str:
    return format(x, fmt).rjust(width) if isinstance(x, int | float) else "-".rjust(width)


def table_header() -> str:
    head = (f"{'scenario':<38} {'expected':>10} {'solved':>6} {'robust':>9} {'wall s':>7} "
            f"{'iter':>5} {'starts':>6} {'build s':>7} {'optimum':>8} {'ratio':>6} "
            f"{'coarse':>12} {'coarse s':>8}")  # fmt: skip
    return head + "\n" + "-" * len(head)


def table_line(r: Row) -> str:
    return (
        f"{r['scenario']!s:<38} {r['expected']!s:>10} "
        f"{'yes' if r['solved'] else 'no':>6} {_num(r.get('robustness'), '.4f', 9)} "
        f"{_num(r.get('wall_s'), '.1f', 7)} {_num(r.get('iterations'), 'd', 5)} "
        f"{_num(r.get('starts'), 'd', 6)} {_num(r.get('build_s'), '.2f', 7)} {_num(r.get('certified'), '.4g', 8)} "
        f"{_num(r.get('ratio'), '.2f', 6)} {r.get('coarse') or '-':>12} "
        f"{_num(r.get('coarse_s'), '.2f', 8)}"
    )


def summarise(rows: list[Row], time_limit: float) -> Row:
    feas = [r for r in rows if r["expected"] == "feasible"]
    infeas = [r for r in rows if r["expected"] == "infeasible"]
    walls = [float(r["wall_s"]) for r in rows]
    # The limit bounds build + solve; the process also loads, checks and writes the plan.
    over = [str(r["scenario"]) for r in rows if time_limit > 0 and float(r["wall_s"]) > time_limit]
    stlpy = {s: [r for r in rows if r.get("spelling") == s] for s in SPELLINGS}
    ratios = [float(r["ratio"]) for r in rows if isinstance(r.get("ratio"), int | float)]
    bounded = [r for r in infeas if r["exit"] == 1 and not r["killed"]
               and (time_limit <= 0 or float(r["wall_s"]) <= time_limit + 30)]  # fmt: skip
    return {
        "scenarios": len(rows),
        "feasible_solved": sum(bool(r["solved"]) for r in feas),
        "feasible": len(feas),
        "over_time_limit": over,
        "max_wall_s": max(walls) if walls else None,
        "median_wall_s": statistics.median(walls) if walls else None,
        "median_wall_feasible_s": statistics.median(float(r["wall_s"]) for r in feas)
        if feas
        else None,
        "stlpy_satisfied": {s: sum(bool(r["solved"]) for r in rs) for s, rs in stlpy.items()},
        "stlpy_count": {s: len(rs) for s, rs in stlpy.items()},
        "median_ratio_to_certified": statistics.median(ratios) if ratios else None,
        "infeasible": len(infeas),
        "infeasible_bounded_exit1": len(bounded),
        "infeasible_solved": [str(r["scenario"]) for r in infeas if r["solved"]],
    }


def print_summary(rows: list[Row], s: Row, time_limit: float) -> None:
    failed = [r for r in rows if (r["expected"] == "feasible") != bool(r["solved"])]
    if failed:
        print("\nnot as expected:")
        for r in failed:
            w = r.get("weakest")
            where = (f"; weakest {w} = {r['weakest_robustness']:+.4f} at t = {r['weakest_t_s']:g} s"
                     if w is not None else "")  # fmt: skip
            print(f"  {r['scenario']} ({r['expected']}): exit {r['exit']}, "
                  f"{_num(r.get('robustness'), '+.4f', 0)} in {r['wall_s']:.1f} s{where}")  # fmt: skip
            print(f"    status: {r.get('status')}")
    over = s["over_time_limit"]
    print()
    print(f"feasible scenarios solved: {s['feasible_solved']}/{s['feasible']}")
    print(
        f"over the {time_limit:g} s limit (wall): "
        + (", ".join(over) if over else f"none (max {s['max_wall_s']:.1f} s)")
    )
    print(f"median wall time: {s['median_wall_s']:.1f} s (feasible only: "
          f"{s['median_wall_feasible_s']:.1f} s)")  # fmt: skip
    sat, cnt = s["stlpy_satisfied"], s["stlpy_count"]
    print("stlpy satisfied: " + ", ".join(f"{sat[k]}/{cnt[k]} {k}" for k in SPELLINGS))
    mr = s["median_ratio_to_certified"]
    print("median ratio to the certified optimum: " + ("-" if mr is None else f"{mr:.2f}"))
    print(f"infeasible ones ended in bounded time with exit 1: "
          f"{s['infeasible_bounded_exit1']}/{s['infeasible']}"
          + (f" (solved, unexpectedly: {', '.join(s['infeasible_solved'])})"
             if s["infeasible_solved"] else ""))  # fmt: skip


def planner_version() -> str:
    """The commit planned with (the planner changes often), ``+dirty`` with local changes."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                              capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "planner", "gcs"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="+", metavar="SUBSTRING",
                    help="only the scenarios whose file name contains one of these")  # fmt: skip
    ap.add_argument("--time-limit", type=float, default=60.0, metavar="S",
                    help="gcs plan --time-limit per scenario (default 60)")  # fmt: skip
    ap.add_argument("--dir", type=Path, default=SCENARIOS, help="scenario directory")
    ap.add_argument("--gcs", type=Path, default=GCS, help="the gcs command (default .venv/bin/gcs)")
    ap.add_argument("--coarse-s", type=float, metavar="S",
                    help="gcs plan --coarse-s (the combinatorial stage's budget; 0: off)")  # fmt: skip
    args = ap.parse_args(argv)
    extra = () if args.coarse_s is None else ("--coarse-s", f"{args.coarse_s:g}")
    files = sorted(args.dir.glob("*.yaml"))
    if args.only:
        files = [f for f in files if any(s in f.name for s in args.only)]
    if not files:
        print("no scenarios match", file=sys.stderr)
        return 2
    version = planner_version()
    print(f"{len(files)} scenarios, cold gcs plan each, --time-limit {args.time_limit:g} s, "
          f"planner {version}\n")  # fmt: skip
    rows: list[Row] = []
    print(table_header(), flush=True)
    t0 = time.perf_counter()
    for f in files:  # one at a time: 2 shared cores, and a cold process each
        rows.append(run_one(f, args.time_limit, args.gcs, extra))
        print(table_line(rows[-1]), flush=True)
    s = summarise(rows, args.time_limit)
    print_summary(rows, s, args.time_limit)
    print(f"bench time {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    print(json.dumps({"bench": "zoo", "planner": version, "time_limit_s": args.time_limit,
                      "coarse_s": args.coarse_s, "rows": rows, "summary": s}))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
