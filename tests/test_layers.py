"""The layers of docs/architecture.md ("The parts and their direction"), read from every
module's imports (nested ones too): planner -> mavlink -> gcs, nothing running back up;
mavlink uses of planner only its trajectories, frames and STL engine; gcs's flight code no
command module.  `lint-imports` (import-linter, in `make test`) checks the layers too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
MAVLINK_MAY_USE = ("planner.trajectory", "planner.frames", "planner.stl")


def imports(package: str) -> dict[str, set[str]]:
    """Module file -> every module it imports (absolute names)."""
    out: dict[str, set[str]] = {}
    for path in sorted((REPO / package).rglob("*.py")):
        names: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module)
        out[str(path.relative_to(REPO))] = names
    return out


def test_the_planner_imports_neither_the_link_nor_the_ground_station() -> None:
    bad = {f: sorted(n for n in ns if n.split(".")[0] in ("mavlink", "gcs"))
           for f, ns in imports("planner").items()}  # fmt: skip
    assert {f: v for f, v in bad.items() if v} == {}


def test_the_link_uses_only_trajectories_frames_and_stl_of_the_planner_and_no_gcs() -> None:
    bad = {}
    for f, ns in imports("mavlink").items():
        wrong = sorted(
            n
            for n in ns
            if n.startswith("gcs")
            or (n.startswith("planner") and not n.startswith(MAVLINK_MAY_USE))
        )
        if wrong:
            bad[f] = wrong
    assert bad == {}


def test_the_flight_code_imports_no_command_module() -> None:
    flight_code = [
        str(p.relative_to(REPO)) for p in sorted((REPO / "gcs" / "flight").glob("*.py"))
    ] + ["gcs/checks.py", "gcs/telemetry.py"]
    found = imports("gcs")
    assert len(flight_code) >= 12
    for module in flight_code:
        assert not [n for n in found[module] if n.startswith("gcs.commands")], module


@pytest.mark.slow
def test_no_module_imports_another_modules_private_names() -> None:
    """A name with a leading underscore is its module's own: no other module of the
    packages imports it, nor does a test (a helper worth testing on its own is public)."""
    bad = []
    for package in ("planner", "mavlink", "gcs", "tests"):
        for path in sorted((REPO / package).rglob("*.py")):
            own = ".".join(path.relative_to(REPO).with_suffix("").parts)
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not (isinstance(node, ast.ImportFrom) and node.module and node.level == 0):
                    continue
                if node.module.split(".")[0] not in ("planner", "mavlink", "gcs"):
                    continue
                if node.module == own.removesuffix(".__init__"):
                    continue
                bad += [
                    f"{own}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_") and not a.name.startswith("__")
                ]
    assert bad == []


def test_no_test_reaches_into_an_objects_private_attributes() -> None:
    """A test uses what an object offers (its public attributes and properties), not its
    underscored ones; a test's own helper class may use its own (``self._x``)."""
    bad = []
    for path in sorted((REPO / "tests").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.Attribute) and node.attr.startswith("_")):
                continue
            if node.attr.startswith("__"):
                continue
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                continue
            bad.append(f"{path.relative_to(REPO)}:{node.lineno}: .{node.attr}")
    assert bad == []


def test_no_module_is_over_800_lines() -> None:
    long = {
        str(path.relative_to(REPO)): n
        for package in ("planner", "mavlink", "gcs")
        for path in (REPO / package).rglob("*.py")
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > 800
    }
    assert long == {}


def test_no_folder_holds_more_than_15_modules() -> None:
    crowded = {
        str(folder.relative_to(REPO)): n
        for package in ("planner", "mavlink", "gcs")
        for folder in [REPO / package, *(REPO / package).rglob("*/")]
        if folder.is_dir() and folder.name != "__pycache__"
        if (n := sum(1 for p in folder.glob("*.py") if p.name != "__init__.py")) > 15
    }
    assert crowded == {}
