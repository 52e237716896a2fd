"""``gcs export PLAN.json --format qgc|csv|json|homes|kml [-o DIR|FILE]``: files for other tools.

* ``qgc``: one QGroundControl ``.plan`` per vehicle (the mission items ``gcs upload`` sends,
  and the geofence), written to a directory (default: beside the plan file);
* ``csv``: setpoints ``t,vehicle,x,y,z,vx,vy,vz,ax,ay,az,yaw`` (mission ENU, SI units);
* ``json``: the same setpoints as JSON;
* ``homes``: where each vehicle must stand (the ground below its start) as PX4's
  ``PX4_HOME_LAT/LON/ALT``, one line per vehicle, for PX4 SITL's spawn points;
* ``kml``: the plan for review in Google Earth (paths, poles, keep-outs, inspection places;
  :mod:`gcs.kml`), ``.kml`` or, with ``-o FILE.kmz``, zipped.

See :mod:`gcs.export` for the exact layouts.

What reaches a vehicle (``qgc`` missions, ``csv``/``json`` setpoints) is written only for a plan
that passes ``gcs verify``: otherwise exit 1 naming the failed check, as ``gcs fly`` and
``gcs upload`` refuse it, unless ``--force`` (then a warning on standard error). ``homes``
places simulated vehicles and ``kml`` is for people to look at: both are always written.
"""

from __future__ import annotations

import argparse
import sys

from gcs.commands import add_photo_argument, photo_interval
from gcs.errors import UserError
from gcs.export import DEFAULT_RATE_HZ, ExportFormat, QgcOptions, write_export
from gcs.flight import FlightRefused, preflight_interlock
from mavlink.mission import MissionEnd
from planner.planfile import load_plan

HELP = (
    "export a plan: QGroundControl .plan files, setpoint CSV or JSON, SITL home positions, "
    "KML/KMZ for Google Earth"
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``gcs export``."""
    p.add_argument("plan", help="plan file written by gcs plan")
    p.add_argument(
        "--format",
        help="qgc (QGroundControl .plan per vehicle), csv or json (setpoints), homes (the "
        "ground below each start as PX4_HOME_LAT/LON/ALT, for PX4 SITL), kml (paths, poles, "
        "keep-outs and inspection places for Google Earth; -o FILE.kmz zips it)",
    )
    p.add_argument(
        "-o",
        "--output",
        help="directory for qgc, file for csv/json/homes/kml (default: beside the plan file)",
    )
    p.add_argument(
        "--rate", type=float, default=None, help="setpoint rate in Hz for csv/json (default 20)"
    )
    p.add_argument(
        "--acceptance-radius",
        type=float,
        default=None,
        metavar="M",
        help="qgc: waypoint acceptance radius in m (default: as gcs upload chooses it for "
        "PX4's defaults, from the plan's speeds)",
    )
    p.add_argument(
        "--end",
        default=None,
        help="qgc: what the mission ends with: land (default), return or hold",
    )
    p.add_argument("--no-fence", action="store_true", help="qgc: leave the geofence out")
    add_photo_argument(p)
    p.add_argument(
        "--force",
        action="store_true",
        help="write missions or setpoints for a plan that fails its checks (gcs verify)",
    )


def run(args: argparse.Namespace) -> int:
    """Export; 0 when the files are written."""

    fmt = ExportFormat.parse(args.format)
    qgc: QgcOptions | None = None
    if fmt is ExportFormat.QGC:
        end = None
        if args.end is not None:
            try:
                end = MissionEnd(args.end.lower())
            except ValueError:
                raise UserError(
                    f"--end: unknown {args.end!r} (choose land, return or hold)"
                ) from None
        radius = args.acceptance_radius
        if radius is not None and not radius > 0:
            raise UserError(f"--acceptance-radius: must be > 0 m, got {radius!r}")
        qgc = QgcOptions(
            acceptance_radius_m=radius,
            end=end,
            fence=not args.no_fence,
            photo_interval_s=photo_interval(args),
        )
    elif args.end is not None or args.acceptance_radius is not None or args.no_fence:
        raise UserError("--end, --acceptance-radius and --no-fence apply to --format qgc only")
    if fmt in (ExportFormat.QGC, ExportFormat.HOMES, ExportFormat.KML) and args.rate is not None:
        raise UserError("--rate applies to --format csv and json only")
    plan = load_plan(args.plan)
    if fmt not in (ExportFormat.HOMES, ExportFormat.KML):
        try:
            checks = preflight_interlock(plan, force=args.force)
        except FlightRefused as exc:
            print(
                f"gcs export: refused: {exc.summary} (gcs verify lists them; --force exports "
                "anyway)",
                file=sys.stderr,
            )
            return 1
        failed = [c for c in checks if not c.ok]
        if failed:
            print(
                f"gcs export: warning: exported with --force although {len(failed)} of "
                f"{len(checks)} checks fail (first: {failed[0].name}); these files go to vehicles",
                file=sys.stderr,
            )
    rate = DEFAULT_RATE_HZ if args.rate is None else args.rate
    paths = write_export(plan, args.plan, fmt, args.output, rate_hz=rate, qgc=qgc)
    for p in paths:
        print(f"wrote {p}")
    return 0
