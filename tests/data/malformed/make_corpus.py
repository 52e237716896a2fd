"""Write the malformed-input corpus of tests/reliability/test_malformed.py (run from the repo root).

    .venv/bin/python tests/data/malformed/make_corpus.py

Scenario files are variants of tests/mavlink/data/link_reach_avoid.yaml, plan
files variants of tests/mavlink/data/reach_avoid_2.plan.json.  ``manifest.json``
says, per file, which command reads it, the exit status it must give and a
fragment its one error line (exit 2) or its failing checks (exit 1) must contain.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import yaml

HERE = Path(__file__).parent
ROOT = HERE.parents[2]
BASE_SCENARIO = ROOT / "tests/mavlink/data/link_reach_avoid.yaml"
BASE_PLAN = ROOT / "tests/mavlink/data/reach_avoid_2.plan.json"

manifest: dict[str, dict[str, Any]] = {}


#: Files the code does not yet handle as it must (a traceback instead of one line);
#: the defect, its file and line are in the value.  Remove an entry once it is fixed.
DEFECTS: dict[str, str] = {}  # files whose handling is a known, unfixed defect


def put(name: str, text: str | bytes, cmd: str, code: int, needle: str) -> None:
    path = HERE / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    manifest[name] = {"cmd": cmd, "exit": code, "needle": needle}
    if name in DEFECTS:
        manifest[name]["defect"] = DEFECTS[name]


def scenario(name: str, edit, needle: str) -> None:  # type: ignore[no-untyped-def]
    data = yaml.safe_load(BASE_SCENARIO.read_text(encoding="utf-8"))
    data["vehicles"] = data["vehicles"][:2]
    edit(data)
    put(name, yaml.safe_dump(data, sort_keys=False), "plan", 2, needle)


def plan(name: str, edit, needle: str, code: int = 2, cmd: str = "verify") -> None:  # type: ignore[no-untyped-def]
    data = json.loads(BASE_PLAN.read_text(encoding="utf-8"))
    edit(data)
    put(name, json.dumps(data), cmd, code, needle)


def setv(path: str, value: Any):  # type: ignore[no-untyped-def]
    def edit(d: dict[str, Any]) -> None:
        *keys, last = path.split(".")
        for k in keys:
            d = d[int(k)] if isinstance(d, list) else d[k]
        if isinstance(d, list):
            d[int(last)] = value
        else:
            d[last] = value

    return edit


def delete(key: str):  # type: ignore[no-untyped-def]
    return lambda d: d.pop(key)


# ---- scenario files: YAML itself
base_text = BASE_SCENARIO.read_text(encoding="utf-8")
put(
    "s_yaml_syntax.yaml",
    base_text.replace("limits: {", "limits: {{"),
    "plan",
    2,
    "s_yaml_syntax.yaml",
)
put(
    "s_yaml_tab.yaml",
    base_text.replace("  - {name: d1", "\t- {name: d1"),
    "plan",
    2,
    "s_yaml_tab.yaml",
)
put(
    "s_python_object_tag.yaml",
    "!!python/object/apply:os.system ['touch /tmp/stl_gcs_pwned']\n",
    "plan",
    2,
    "s_python_object_tag.yaml",
)
put(
    "s_python_tag_in_field.yaml",
    base_text.replace("name: link_reach_avoid", "name: !!python/name:os.system ''"),
    "plan",
    2,
    "s_python_tag_in_field.yaml",
)
put("s_empty.yaml", "", "plan", 2, "s_empty.yaml")
put("s_top_level_list.yaml", "- 1\n- 2\n", "plan", 2, "s_top_level_list.yaml")
put("s_not_utf8.yaml", b"\xff\xfe\x00name: \x80\x81\n", "plan", 2, "s_not_utf8.yaml")
put(
    "s_deep_yaml.yaml",
    "name: x\nextra: " + "[" * 20000 + "]" * 20000 + "\n",
    "plan",
    2,
    "s_deep_yaml.yaml",
)
put(
    "s_deep_spec.yaml",
    base_text.replace(
        "formula: eventually[0, $horizon] inside(d, goal)",
        "formula: " + "(" * 5000 + "eventually[0, $horizon] inside(d, goal)" + ")" * 5000,
    ),
    "plan",
    2,
    "s_deep_spec.yaml",
)
# ---- scenario files: types, values, names
scenario("s_lat_string.yaml", setv("origin.lat", "north"), "lat")
scenario("s_lat_nan.yaml", setv("origin.lat", float("nan")), "lat")
scenario("s_lat_out_of_range.yaml", setv("origin.lat", 95.0), "lat")
scenario("s_alt_inf.yaml", setv("origin.alt", float("inf")), "alt")
scenario("s_vmax_negative.yaml", setv("limits.v_max_m_s", -1.5), "v_max")
scenario("s_vmax_zero.yaml", setv("limits.v_max_m_s", 0.0), "v_max")
scenario("s_amax_inf.yaml", setv("limits.a_max_m_s2", float("inf")), "a_max")
scenario("s_vmax_string.yaml", setv("limits.v_max_m_s", "fast"), "v_max")
scenario("s_horizon_huge.yaml", setv("timing.horizon_s", 1e308), "horizon")
scenario("s_horizon_negative.yaml", setv("timing.horizon_s", -6), "horizon")
scenario("s_segment_longer_than_horizon.yaml", setv("timing.segment_s", 60), "segment")
scenario("s_ts_zero.yaml", setv("timing.Ts_s", 0), "Ts")
scenario(
    "s_workspace_inverted.yaml",
    setv("workspace", {"min": [4, 4, 3], "max": [-4, -4, 0]}),
    "workspace",
)
scenario("s_start_outside_workspace.yaml", setv("vehicles.0.start", [40.0, 0.0, 1.5]), "d1")
scenario("s_start_two_numbers.yaml", setv("vehicles.0.start", [1.0, 2.0]), "start")
scenario("s_duplicate_vehicles.yaml", setv("vehicles.1.name", "d1"), "d1")
scenario("s_no_vehicles.yaml", setv("vehicles", []), "vehicles")
scenario("s_vehicles_not_list.yaml", setv("vehicles", "d1, d2"), "vehicles")
scenario("s_region_unknown_kind.yaml", setv("regions.goal.kind", "wormhole"), "wormhole")
scenario("s_region_negative_size.yaml", setv("regions.goal.half_size", -0.7), "goal")
scenario("s_separation_negative.yaml", setv("separation_m", -0.5), "separation")
scenario("s_epsilon_nan.yaml", setv("epsilon", float("nan")), "epsilon")
scenario("s_unknown_model.yaml", setv("model", "helicopter"), "helicopter")
scenario("s_unknown_key.yaml", setv("colour", "red"), "colour")
scenario("s_timing_missing.yaml", delete("timing"), "timing")
scenario(
    "s_spec_syntax.yaml", setv("spec.0.formula", "eventually[0, $horizon inside(d, goal)"), "spec"
)
scenario(
    "s_spec_unknown_function.yaml",
    setv("spec.0.formula", "eventually[0, $horizon] inside2(d, goal)"),
    "inside2",
)
scenario(
    "s_spec_unknown_region.yaml",
    setv("spec.0.formula", "eventually[0, $horizon] inside(d, nowhere)"),
    "nowhere",
)
scenario(
    "s_spec_unknown_variable.yaml",
    setv("spec.0.formula", "eventually[0, $nope] inside(d, goal)"),
    "nope",
)
scenario(
    "s_spec_reversed_interval.yaml",
    setv("spec.0.formula", "eventually[5, 1] inside(d, goal)"),
    "spec",
)
scenario("s_spec_not_text.yaml", setv("spec.0.formula", 42), "formula")

# ---- plan files that are not plans
put(
    "p_not_json.plan.json",
    '{"format": "stl-gcs-plan", "version": 1,',
    "verify",
    2,
    "p_not_json.plan.json",
)
put("p_deep_json.plan.json", "[" * 100000 + "]" * 100000, "verify", 2, "p_deep_json.plan.json")
put("p_not_utf8.plan.json", b'{"format": "stl-gcs-plan\xff\xfe"}', "verify", 2, "p_not_utf8")
put("p_not_json_fly.plan.json", "vehicles: [d1]", "fly", 2, "p_not_json_fly.plan.json")
plan("p_wrong_format.plan.json", setv("format", "qgc-plan"), "format")
plan("p_version_99.plan.json", setv("version", 99), "version")
plan("p_no_vehicles_key.plan.json", delete("vehicles"), "vehicles")
COEFF = "vehicles[0].segments[0].coeffs[0][0]"
plan("p_coeff_nan.plan.json", setv("vehicles.0.segments.0.coeffs.0.0", float("nan")), COEFF)
plan("p_coeff_huge.plan.json", setv("vehicles.0.segments.0.coeffs.0.0", 1e400), COEFF)
plan("p_coeff_shape.plan.json", setv("vehicles.0.segments.0.coeffs", [[1.0, 2.0]]), "coeffs")
plan("p_segments_empty.plan.json", setv("vehicles.0.segments", []), "segments")
plan("p_origin_string.plan.json", setv("origin.lat", "north"), "lat")
plan("p_sysid_300.plan.json", setv("vehicles.1.sysid", 300), "sysid")
plan(
    "p_coeff_nan_fly.plan.json",
    setv("vehicles.0.segments.0.coeffs.0.0", float("nan")),
    COEFF,
    cmd="fly",
)
# ---- plan files whose spec or timing does not fit the plan (named as the plan's, not the
# scenario's, and before any evaluation)
plan("p_spec_syntax.plan.json", setv("spec", "always[0, 6] dist(d1, d2 >= 0.5"), "spec: line 1")
plan(
    "p_spec_unknown_region.plan.json",
    setv("spec", "eventually[0, 6] inside(d1, gaol)"),
    "spec: unknown region 'gaol'",
)
plan(
    "p_spec_unknown_region_fly.plan.json",
    setv("spec", "eventually[0, 6] inside(d1, gaol)"),
    "spec: unknown region 'gaol'",
    cmd="fly",
)
plan(
    "p_spec_unknown_vehicle.plan.json",
    setv("spec", "always[0, 6] dist(d1, d9) >= 0.5"),
    "spec: unknown vehicle 'd9'",
)
plan("p_spec_vehicle_as_number.plan.json", setv("spec", "always[0, 6] d1 >= 1"), "'d1'")
plan("p_horizon_short.plan.json", setv("horizon_s", 3.0), "horizon_s: 3 s is shorter")
plan("p_horizon_huge.plan.json", setv("horizon_s", 1e308), "horizon_s")
plan("p_check_dt_zero.plan.json", setv("check_dt_s", 0), "check_dt_s: must be > 0")
plan("p_check_dt_nan.plan.json", setv("check_dt_s", float("nan")), "check_dt_s")
plan("p_check_dt_tiny.plan.json", setv("check_dt_s", 1e-12), "check_dt_s")


# ---- plan files edited by hand: valid files that violate the plan's own rules (exit 1)
def scale_d1(d: dict[str, Any]) -> None:
    for seg in d["vehicles"][0]["segments"]:
        for axis in seg["coeffs"]:
            for k in range(1, len(axis)):
                axis[k] *= 3.0


def d2_onto_d1(d: dict[str, Any]) -> None:
    d["vehicles"][1]["segments"] = copy.deepcopy(d["vehicles"][0]["segments"])
    d["vehicles"][1]["start"] = d["vehicles"][0]["start"]


def shift_d1_x(dx: float):  # type: ignore[no-untyped-def]
    def edit(d: dict[str, Any]) -> None:
        for seg in d["vehicles"][0]["segments"]:
            seg["coeffs"][0][0] += dx

    return edit


plan("h_speed_tripled.plan.json", scale_d1, "d1 velocity / v_max", code=1)
plan("h_separation_lost.plan.json", d2_onto_d1, "separation d1-d2", code=1)
plan(
    "h_vmax_lowered.plan.json",
    setv("vehicles.0.limits.v_max_m_s", [0.5, 0.5, 0.5]),
    "d1 velocity / v_max",
    code=1,
)
plan(
    "h_start_moved.plan.json",
    setv("vehicles.0.start", [-3.0, -2.0, 1.5]),
    "d1 start offset",
    code=1,
)
plan(
    "h_workspace_shrunk.plan.json",
    setv("workspace.max", [1.0, 1.0, 3.0]),
    "workspace margin",
    code=1,
)
plan("h_epsilon_raised.plan.json", setv("epsilon", 5.0), "spec:", code=1)
plan("h_through_obstacle.plan.json", shift_d1_x(1.5), "obstacle", code=1)


def _duplicated_region() -> str:
    """The base scenario with a second ``goal:`` pasted under ``regions:`` (issue 39: the
    second silently replaced the first, and the mission flew to the wrong place)."""
    data = yaml.safe_load(BASE_SCENARIO.read_text(encoding="utf-8"))
    data["vehicles"] = data["vehicles"][:2]
    text = yaml.safe_dump(data, sort_keys=False)
    lines = text.splitlines(keepends=True)
    i = next(j for j, ln in enumerate(lines) if ln.startswith("  goal:"))
    j = i + 1
    while j < len(lines) and lines[j].startswith("    "):
        j += 1
    pasted = "".join(lines[i:j]).replace("1.75", "-1.25")
    return "".join(lines[:j]) + pasted + "".join(lines[j:])


put("s_duplicate_region.yaml", _duplicated_region(), "plan", 2, "duplicate key 'goal' (lines")
_plan_text = BASE_PLAN.read_text(encoding="utf-8")
put(
    "p_duplicate_key.plan.json",
    _plan_text.replace('"epsilon":', '"epsilon": 0.5, "epsilon":', 1),
    "verify",
    2,
    "duplicate key 'epsilon'",
)
# binary files where text is expected: a KMZ (zip) given as a scenario, a PNG as a plan
put("s_kmz.yaml", b"PK\x03\x04\x14\x00\x00\x00\x08\x00" + bytes(range(256)), "plan", 2, "zip")
put("p_png.plan.json", b"\x89PNG\r\n\x1a\n" + bytes(range(256)), "verify", 2, "PNG image")

(HERE / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
print(f"{len(manifest)} files")
