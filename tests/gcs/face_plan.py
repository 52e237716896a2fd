"""A small plan whose spec asks a vehicle to face a pole (``face``), made by ``gcs plan``.

The scenario is test_heading's (:data:`tests.planner.test_heading._SCENARIO`: a power line of
three poles, one vehicle) cut to what a flight test can afford: one inspection hover, facing
pole1, within a 14 s horizon.
"""

from __future__ import annotations

from pathlib import Path

from gcs.cli import main
from tests.planner.test_heading import _SCENARIO

#: The face clause of the plan (as the spec prints it).
FACE_CLAUSE = "eventually[0,11] always[0,2] (inside(d1, insp1) and face(d1, pole1))"


def write_face_plan(directory: Path) -> Path:
    """``gcs plan`` the short facing scenario into ``directory``; the plan file's path."""
    text = _SCENARIO.replace(
        "timing: {horizon_s: 40, segment_s: 2, Ts_s: 0.25}",
        "timing: {horizon_s: 14, segment_s: 2, Ts_s: 0.25}",
    )
    clauses = (
        "  - formula: eventually[0, 20] always[0, 2] (inside(d1, insp1) and face(d1, pole1))\n"
        "  - formula: eventually[0, 37] always[0, 2] (inside(d1, insp3) and face(d1, pole3))\n"
    )
    assert clauses in text and "horizon_s: 14" in text
    text = text.replace(
        clauses,
        "  - formula: eventually[0, 11] always[0, 2] (inside(d1, insp1) and face(d1, pole1))\n",
    )
    scenario = directory / "facing.yaml"
    scenario.write_text(text, encoding="utf-8")
    plan = directory / "facing.plan.json"
    assert main(["plan", str(scenario), "-o", str(plan), "--json"]) == 0
    return plan
