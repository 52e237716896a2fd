"""The ``gcs`` subcommands (one module each, see :mod:`gcs.cli`) and their shared options."""

from __future__ import annotations

import argparse
import math

from gcs.errors import UserError
from mavlink.mock.sim.profiles import DEFAULT_PROFILE, PROFILES
from mavlink.mock.sim.px4 import PARAM_SPECS


def add_link_arguments(
    p: argparse.ArgumentParser,
    *,
    plan_order: bool,
    timeout_s: float,
    timeout_help: str,
    timeout_flag: str = "--timeout",
) -> None:
    """``--connection`` (repeatable), ``--timeout`` and ``--signing-key``: how ``gcs fly``,
    ``gcs upload`` and ``gcs status`` reach their vehicles, declared once.

    ``timeout_flag`` names the connection timeout where ``--timeout`` means something else
    (``gcs upload``: ``--connect-timeout``, its ``--timeout`` being the transfer budget).
    """
    order = "repeat, plan order" if plan_order else "repeat"
    p.add_argument(
        "--connection",
        action="append",
        metavar="URL",
        help=f"connection URL of the next vehicle ({order}); default "
        "udpin://0.0.0.0:14540+i (PX4 SITL)",
    )
    p.add_argument(
        "--base-port",
        type=int,
        default=14540,
        metavar="PORT",
        help="without --connection, vehicle i is udpin://0.0.0.0:PORT+i (14540: PX4 SITL); "
        "other ports keep clear of another program's vehicles (gcs mock --base-port)",
    )
    p.add_argument(timeout_flag, type=float, default=timeout_s, metavar="S", help=timeout_help)
    p.add_argument(
        "--signing-key",
        metavar="FILE",
        help="sign what the GCS sends (MAVLink 2 signing, through a local proxy; udpin only)",
    )


def add_mock_vehicle_arguments(p: argparse.ArgumentParser, *, param_flag: str) -> None:
    """``--profile``, ``--seed`` and the parameter override flag of the mock vehicles.

    Declared once for ``gcs mock`` (``--param``) and the dry runs of ``gcs fly`` and
    ``gcs demo`` (``--mock-param``).
    """

    p.add_argument(
        "--profile",
        choices=list(PROFILES),
        default=DEFAULT_PROFILE,
        help="mock vehicle: px4 (PX4 v1.17 SITL with SIH: drag, estimator, PX4's navigator; "
        "the default) or ideal (an exact vehicle)",
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the mock vehicles (estimator, noise, wind)"
    )
    p.add_argument(
        param_flag,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="mock vehicle parameter over the profile, e.g. SIH_KDV=0 (repeatable)",
    )


def add_speed_argument(p: argparse.ArgumentParser) -> None:
    """``--speed`` of the dry runs (``gcs fly --dry-run``, ``gcs demo``)."""
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        metavar="K",
        help="dry run: the mock vehicles run K times faster than real time and the flight on "
        "their clock (default $STL_GCS_SIM_SPEED or 1; at most 20), as PX4 SITL's "
        "PX4_SIM_SPEED_FACTOR",
    )


def parse_param_overrides(items: list[str], flag: str) -> dict[str, float]:
    """``NAME=VALUE`` strings -> a dict; a malformed one raises :class:`gcs.errors.UserError`
    naming the flag, and so does a name the mock vehicle does not have."""

    specs = {p.name: p for p in PARAM_SPECS}
    params: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise UserError(f"{flag} {item!r}: expected NAME=VALUE")
        spec = specs.get(name)
        if spec is None:
            raise UserError(f"{flag} {item!r}: the mock vehicle has no parameter {name!r}")
        try:
            number = float(value)
        except ValueError:
            raise UserError(f"{flag} {item!r}: VALUE must be a number") from None
        if not spec.accepts(number):
            raise UserError(f"{flag} {item!r}: {name} must be in [{spec.min:g}, {spec.max:g}]")
        params[name] = number
    return params


def add_photo_argument(p: argparse.ArgumentParser) -> None:
    """``--photo-interval``: the camera's pictures where the plan faces an inspection target
    (:mod:`gcs.flight.payload`), declared once for ``gcs fly``, ``gcs upload`` and ``gcs export``."""
    p.add_argument(
        "--photo-interval",
        type=float,
        default=1.0,
        metavar="S",
        help="seconds between pictures where the plan faces an inspection target (face(d, T)): "
        "camera and gimbal commands in missions and offboard (1; 0: leave the camera alone)",
    )


def photo_interval(args: argparse.Namespace) -> float:
    """``--photo-interval`` checked: a finite number >= 0 (:class:`gcs.errors.UserError`)."""

    value = float(args.photo_interval)
    if not (math.isfinite(value) and value >= 0):
        raise UserError(f"--photo-interval: must be a number >= 0 s, got {args.photo_interval:g}")
    return value
