"""``gcs plot PLAN.json [-o FILE.png|.html] [--telemetry LOG] [--view {auto,3d,map}]``: draw
a plan.

One figure: the regions and paths in 3-D or on a map, the robustness of every top-level
clause over time, per-axis velocity and acceleration against the limits, and flown over
planned when telemetry is given (see :mod:`gcs.plot`). ``.html`` output embeds the PNG and
adds a table of clause robustness, and in the map view the map to pan and zoom.

``--view auto`` (the default) draws the map when the workspace is at least 200 m across
its diagonal (:data:`gcs.plot.map_view.MAP_FROM_M`), the 3-D view otherwise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gcs.plot import plot_plan
from gcs.plot.map_view import MAP_FROM_M, View
from gcs.telemetry import load_telemetry
from planner.planfile import load_plan

HELP = (
    "draw a plan: regions and paths (3-D or map), clause robustness over time, speed/acceleration"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs plot``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument(
        "-o",
        "--output",
        help="picture to write, .png or .html (default: the plan's name with .png)",
    )
    p.add_argument(
        "--telemetry",
        metavar="LOG",
        help="flown telemetry to draw over the plan: CSV (t,vehicle,x,y,z or the link's track "
        "CSV) or .tlog (with --t0)",
    )
    p.add_argument(
        "--t0",
        type=float,
        metavar="UNIX_S",
        help="for a .tlog: Unix time (s) of the plan's start (t = 0)",
    )
    p.add_argument("--dt", type=float, help="sample step in s (default: the plan's check step)")
    p.add_argument(
        "--view",
        choices=[v.value for v in View],
        default=View.AUTO.value,
        help="regions and paths as a 3-D view or a top-down map (north up, metres, time ticks "
        "and hovers on the paths; in .html also a map to pan and zoom); auto (default): the "
        f"map when the workspace is at least {MAP_FROM_M:g} m across its diagonal, else 3d",
    )


def run(args: argparse.Namespace) -> int:
    """Draw; 0 when the picture is written."""

    plan = load_plan(args.plan)
    telemetry = load_telemetry(args.telemetry, plan, args.t0) if args.telemetry else None
    output = args.output or str(Path(args.plan).with_suffix(".png"))
    result = plot_plan(plan, output, telemetry, args.dt, name=Path(args.plan).name, view=args.view)
    worst = min(result.traces, key=lambda c: c.robustness)
    for problem in dict.fromkeys(c.flown_problem for c in result.traces if c.flown_problem):
        note = f"gcs plot: note: {problem}: the clauses that read it have no flown value"
        print(note, file=sys.stderr)
    print(
        f"wrote {result.path} ({result.view.value} view; {len(result.traces)} clauses; "
        f"weakest {worst.robustness:+.4f}: {' '.join(worst.text.split())[:80]})"
    )
    return 0
