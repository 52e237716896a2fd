"""Regenerate the plan files the link tests fly (run from the repository root).

    .venv/bin/python tests/mavlink/data/make_plans.py

Planning these takes tens of seconds per fleet size, too long for every test run, so the
planner's output is stored; the tests re-check each plan's robustness with the exact STL
semantics before flying it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

from planner.optimize import plan
from planner.planfile import save_plan
from planner.scenario import parse_scenario

HERE = Path(__file__).parent
SCENARIO = HERE / "link_reach_avoid.yaml"


def scenario_for(n: int):
    """The test scenario restricted to its first ``n`` vehicles."""
    data = yaml.safe_load(SCENARIO.read_text(encoding="utf-8"))
    data["vehicles"] = data["vehicles"][:n]
    return parse_scenario(data, str(SCENARIO))


def main() -> int:
    for n in (2, 4):
        result = plan(scenario_for(n))
        print(n, result.status, f"{result.solve_time_s:.1f} s")
        if not result.success:
            return 1
        save_plan(
            HERE / f"reach_avoid_{n}.plan.json", result, str(SCENARIO.relative_to(HERE.parents[2]))
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
