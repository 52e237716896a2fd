"""One mission model for scenario and plan file, and the plan file's published JSON Schema,
checked with an independent validator (jsonschema) on plans and on the malformed corpus."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from planner.mission_model import plan_file_schema
from planner.planfile import PlanFileError, load_plan
from planner.scenario import ScenarioError, load_scenario

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = ROOT / "docs" / "plan-file.schema.json"
PLANS = sorted((ROOT / "tests" / "mavlink" / "data").glob("*.plan.json"))
CORPUS = ROOT / "tests" / "data" / "malformed"

_SCENARIO = """\
name: limits
origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}
workspace: {min: [-1, -1, 0], max: [5, 5, 3]}
regions:
  goal: {kind: goal, min: [3, 3, 1], max: [4, 4, 2]}
limits: {v_max_m_s: 2.0, a_max_m_s2: 3.0}
vehicles:
  - {name: d1, start: [0, 0, 1], limits: LIMITS}
timing: {horizon_s: 6, segment_s: 1, Ts_s: 0.1}
spec:
  - eventually[0, 6] inside(d1, goal)
"""


def _validator() -> jsonschema.protocols.Validator:
    schema = json.loads(SCHEMA.read_text(encoding="utf-8"))
    cls = jsonschema.validators.validator_for(schema)
    cls.check_schema(schema)  # a valid draft 2020-12 schema
    return cls(schema)


def test_the_published_schema_is_the_models() -> None:
    published = json.loads(SCHEMA.read_text(encoding="utf-8"))
    assert published == plan_file_schema(), (
        "docs/plan-file.schema.json is out of date: "
        "python -m planner.mission_model > docs/plan-file.schema.json"
    )
    assert published["$schema"] == "https://json-schema.org/draft/2020-12/schema"


@pytest.mark.parametrize("path", PLANS + sorted(CORPUS.glob("h_*.plan.json")), ids=lambda p: p.name)
def test_plans_written_by_the_planner_are_valid_under_the_schema(path: Path) -> None:
    data = json.loads(path.read_text(encoding="utf-8"))
    _validator().validate(data)
    load_plan(path)  # and the reader takes them (the h_ files fail only their checks)


@pytest.mark.parametrize(
    ("name", "key"),
    [
        ("p_wrong_format.plan.json", "format"),
        ("p_version_99.plan.json", "version"),
        ("p_no_vehicles_key.plan.json", "vehicles"),
        ("p_origin_string.plan.json", "origin.lat"),
        ("p_sysid_300.plan.json", "vehicles[1].sysid"),
        ("p_segments_empty.plan.json", "vehicles[0].segments"),
        ("p_check_dt_zero.plan.json", "check_dt_s"),
    ],
)
def test_malformed_plans_fail_the_schema_where_the_reader_refuses_them(name: str, key: str) -> None:
    path = CORPUS / name
    data = json.loads(path.read_text(encoding="utf-8"))
    errors = list(_validator().iter_errors(data))
    assert errors, f"{name}: the schema lets it through"
    with pytest.raises(PlanFileError, match=rf"{name}: {_re(key)}: "):
        load_plan(path)


def _re(key: str) -> str:
    return key.replace(".", r"\.").replace("[", r"\[").replace("]", r"\]")


@pytest.mark.parametrize(
    ("limits", "problem", "in_schema"),
    [
        # what a JSON Schema cannot say (one field against another) only the model checks
        ("{thrust_m_s2: [12, 10]}", "thrust_m_s2: min 12 must be below max 10", False),
        ("{thrust_m_s2: [0, 9]}", "thrust_m_s2: max thrust 9 m/s\\^2 cannot hover", False),
        ("{v_up_max_m_s: 0}", "v_up_max_m_s: must be > 0, got 0", True),
        ("{a_max_m_s2: [1, -2, 1]}", r"a_max_m_s2\[1\]: must be > 0, got -2", True),
        ("{v_xy_max_m_s: fast}", "v_xy_max_m_s: expected a number, got str 'fast'", True),
    ],
)
def test_a_scenario_and_a_plan_file_refuse_the_same_limits_in_the_same_words(
    tmp_path: Path, limits: str, problem: str, in_schema: bool
) -> None:
    scenario = tmp_path / "s.yaml"
    scenario.write_text(_SCENARIO.replace("LIMITS", limits), encoding="utf-8")
    with pytest.raises(ScenarioError, match=rf"vehicles\[0\]\.limits\.{problem}"):
        load_scenario(scenario)
    # the same limits in a plan file (a YAML flow mapping is a JSON object here)
    data = json.loads(PLANS[0].read_text(encoding="utf-8"))
    data["vehicles"][0]["limits"].update(yaml.safe_load(limits))
    bad = tmp_path / "p.plan.json"
    bad.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(PlanFileError, match=rf"vehicles\[0\]\.limits\.{problem}"):
        load_plan(bad)
    assert bool(list(_validator().iter_errors(data))) == in_schema


def test_a_scenarios_scalar_limit_is_every_axis_and_its_own_limits_are_over_the_scenarios(
    tmp_path: Path,
) -> None:
    scenario = tmp_path / "s.yaml"
    scenario.write_text(_SCENARIO.replace("LIMITS", "{v_xy_max_m_s: 1.5}"), encoding="utf-8")
    (v,) = load_scenario(scenario).vehicles
    assert v.v_max_m_s == (2.0, 2.0, 2.0) and v.a_max_m_s2 == (3.0, 3.0, 3.0)
    assert v.v_xy_max_m_s == 1.5


@pytest.mark.parametrize(
    ("origin", "key", "problem"),
    [
        ("{lat: 123, lon: 8.5, alt: 488}", "origin.lat", r"latitude 123 is outside \[-90, 90\]"),
        ("{lat: 47, lon: -181, alt: 488}", "origin.lon", r"longitude -181 is outside \[-180"),
        ("{lat: 47, lon: 8.5, alt: .nan}", "origin.alt", "must be finite, got nan"),
        ("{lat: 47, lon: 8.5}", "origin.alt", "missing"),
    ],
)
def test_a_scenario_and_a_plan_file_refuse_the_same_origin_in_the_same_words(
    tmp_path: Path, origin: str, key: str, problem: str
) -> None:
    text = _SCENARIO.replace("LIMITS", "{}").replace(
        "origin: {lat: 47.397742, lon: 8.545594, alt: 488.0}", f"origin: {origin}"
    )
    scenario = tmp_path / "s.yaml"
    scenario.write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError, match=rf"{_re(key)}: {problem}"):
        load_scenario(scenario)
    data = json.loads(PLANS[0].read_text(encoding="utf-8"))
    data["origin"] = yaml.safe_load(origin)
    bad = tmp_path / "p.plan.json"
    bad.write_text(json.dumps(data), encoding="utf-8")  # NaN as JSON's NaN, which json reads
    with pytest.raises(PlanFileError, match=rf"{_re(key)}: {problem}"):
        load_plan(bad)


@pytest.mark.parametrize(
    ("vehicle", "key", "problem"),
    [
        ("{name: always, start: [0, 0, 1]}", "name", "'always' is a reserved word"),
        ("{name: d 1, start: [0, 0, 1]}", "name", r"expected an identifier \(letters, digits, _\)"),
        ("{name: d1, sysid: 300, start: [0, 0, 1]}", "sysid", r"expected 1\.\.255, got 300"),
        ("{name: d1, start: [0, 0]}", "start", r"expected a list of 3 numbers \[x, y, z\]"),
        ("{name: d1, start: [0, a, 1]}", r"start\[1\]", "expected a number, got str 'a'"),
    ],
)
def test_a_scenarios_vehicle_and_a_plan_files_are_one_model(
    tmp_path: Path, vehicle: str, key: str, problem: str
) -> None:
    text = _SCENARIO.replace("{name: d1, start: [0, 0, 1], limits: LIMITS}", vehicle)
    scenario = tmp_path / "s.yaml"
    scenario.write_text(text, encoding="utf-8")
    with pytest.raises(ScenarioError, match=rf"vehicles\[0\]\.{key}: {problem}"):
        load_scenario(scenario)
    data = json.loads(PLANS[0].read_text(encoding="utf-8"))
    data["vehicles"][0].update(yaml.safe_load(vehicle))
    bad = tmp_path / "p.plan.json"
    bad.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(PlanFileError, match=rf"vehicles\[0\]\.{key}: {problem}"):
        load_plan(bad)
