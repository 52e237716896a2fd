"""Exit statuses that mean one thing each, and one error tree per package with its root.

0 ok, 1 a check failed or the mission was not met, 2 bad input, 3 a vehicle or its link
failed, 130 interrupted (``gcs.errors``); a vehicle that refuses to arm is not bad input.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

from gcs.cli import main
from gcs.errors import (
    EXIT_BAD_INPUT,
    EXIT_CHECK_FAILED,
    EXIT_VEHICLE_FAILED,
    GcsError,
    exit_status_of,
)
from gcs.flight.dryrun import mock_vehicles
from mavlink.errors import LinkError
from mavlink.mock.sim.errors import MockError
from mavlink.mock.sim.px4 import Px4Mode
from planner.errors import PlannerError
from planner.planfile import load_plan

REPO = Path(__file__).resolve().parents[2]
PLAN = REPO / "tests" / "mavlink" / "data" / "reach_avoid_2.plan.json"


def _bare(module: str, name: str) -> BaseException:
    """An instance of ``module.name`` without running its constructor (only its type counts)."""
    cls = getattr(importlib.import_module(module), name)
    exc: BaseException = cls.__new__(cls)
    return exc


@pytest.mark.parametrize(
    ("module", "name", "status"),
    [
        # a vehicle or its link failed
        ("mavlink.errors", "CommandError", EXIT_VEHICLE_FAILED),
        ("mavlink.errors", "LinkLostError", EXIT_VEHICLE_FAILED),
        ("mavlink.errors", "MissionError", EXIT_VEHICLE_FAILED),
        ("mavlink.errors", "TransferGaveUpError", EXIT_VEHICLE_FAILED),
        ("mavlink.px4_modes", "UnknownModeError", EXIT_VEHICLE_FAILED),
        # a check refused
        ("mavlink.errors", "PreflightError", EXIT_CHECK_FAILED),
        # bad input: files, fields, specs, options, connections, keys
        ("mavlink.errors", "UrlError", EXIT_BAD_INPUT),
        ("mavlink.errors", "ConnectTimeoutError", EXIT_BAD_INPUT),
        ("mavlink.errors", "DuplicateSystemError", EXIT_BAD_INPUT),
        ("mavlink.errors", "StreamError", EXIT_BAD_INPUT),
        ("mavlink.link.signing", "SigningError", EXIT_BAD_INPUT),
        ("planner.scenario.sections", "ScenarioError", EXIT_BAD_INPUT),
        ("planner.planfile", "PlanFileError", EXIT_BAD_INPUT),
        ("planner.stl", "SpecError", EXIT_BAD_INPUT),
        ("planner.frames", "FrameError", EXIT_BAD_INPUT),
        ("gcs.errors", "UserError", EXIT_BAD_INPUT),
        ("gcs.errors", "InputFileError", EXIT_BAD_INPUT),
        # a bug: its traceback is what a report needs
        ("planner.stl", "EvaluationError", None),
        ("builtins", "RuntimeError", None),
    ],
)
def test_each_error_has_the_exit_status_of_what_it_means(
    module: str, name: str, status: int | None
) -> None:
    assert exit_status_of(_bare(module, name)) == status


@pytest.mark.parametrize(
    ("package", "roots"),
    [
        ("planner", (PlannerError,)),
        ("mavlink", (LinkError, MockError)),
        ("gcs", (GcsError,)),
    ],
)
def test_every_error_a_package_defines_derives_from_its_root(
    package: str, roots: tuple[type[BaseException], ...]
) -> None:
    found = []
    for path in sorted((REPO / package).rglob("*.py")):
        module = ".".join(path.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__")
        classes = [n.name for n in ast.parse(path.read_text()).body if isinstance(n, ast.ClassDef)]
        mod = importlib.import_module(module)
        for name in classes:
            cls = getattr(mod, name)
            if isinstance(cls, type) and issubclass(cls, BaseException):
                found.append(cls)
                assert issubclass(cls, roots), f"{module}.{name} is outside {roots}"
    assert len(found) >= 3  # the walk saw the package's errors


@pytest.mark.slow  # a real-time connection to mock vehicles over UDP
def test_a_vehicle_that_refuses_to_arm_is_a_vehicle_failure_with_its_reason(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with mock_vehicles(load_plan(PLAN)) as dry:
        refusing = dry.mock.vehicles[1]
        refusing.arming_denied_reason = lambda: "Preflight Fail: Accel 0 missing"  # type: ignore[method-assign]  # fmt: skip
        rc = main(["fly", str(PLAN), *(a for u in dry.urls for a in ("--connection", u))])
        err = capsys.readouterr().err
        states = [v.state for v in dry.mock.vehicles]
    assert rc == EXIT_VEHICLE_FAILED, err
    lines = err.strip().splitlines()
    assert lines[-1].startswith("gcs fly: error: vehicle d2 (") and "Traceback" not in err
    assert 'arm failed: COMMAND_DENIED (the vehicle said: "Arming denied: Preflight Fail' in err
    assert not states[1].armed
    # the vehicle that had armed was held where it was, not left to fly on
    assert states[0].mode is Px4Mode.AUTO_LOITER
