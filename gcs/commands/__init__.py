"""The ``gcs`` subcommands (one module each, see :mod:`gcs.cli`) and their shared options."""

from __future__ import annotations

import argparse


def add_link_arguments(
    p: argparse.ArgumentParser, *, plan_order: bool, timeout_s: float, timeout_help: str
) -> None:
    """``--connection`` (repeatable), ``--timeout`` and ``--signing-key``: how ``gcs fly``,
    ``gcs upload`` and ``gcs status`` reach their vehicles, declared once."""
    order = "repeat, plan order" if plan_order else "repeat"
    p.add_argument(
        "--connection",
        action="append",
        metavar="URL",
        help=f"connection URL of the next vehicle ({order}); default "
        "udpin://0.0.0.0:14540+i (PX4 SITL)",
    )
    p.add_argument("--timeout", type=float, default=timeout_s, metavar="S", help=timeout_help)
    p.add_argument(
        "--signing-key",
        metavar="FILE",
        help="sign what the GCS sends (MAVLink 2 signing, through a local proxy; udpin only)",
    )
