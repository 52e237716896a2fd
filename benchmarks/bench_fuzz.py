"""Fuzzing figures (issue 8): hostile MAVLink frames per receiver, frames per second, findings.

Receivers (``tests.reliability.fuzzrun``), ``--frames`` datagrams each (default 10^5)
from :class:`mavlink.fuzz.FrameFuzzer` (random, valid-random, bad CRC,
truncated, oversized, unknown id, mutated, MAVLink 1, bogus signature, wrong
target system):

* mock vehicle, in process: every datagram through ``MockVehicle.datagram_received``;
  errors raised and state changes from frames not addressed to it;
* mock vehicle over UDP from a stranger's socket, then its GCS is served;
* MAVSDK :class:`mavlink.link.fleet.Fleet` connected to a mock: the datagrams at its
  port; its vehicle's state and a command round trip afterwards;
* the ``.tlog`` reader :func:`mavlink.tlog.tracks_from_tlog` on a file of the
  frames with valid records mixed in.

Prints a table, then one JSON line.  Usage::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_fuzz.py [--frames 100000]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import tempfile
from pathlib import Path

# the tests' helpers come from the repository, which need not be on the path
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reliability.fuzzrun import fuzz_fleet, fuzz_mock_in_process, fuzz_mock_udp, fuzz_tlog


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    n, seed = args.frames, args.seed
    rows = []

    def row(name: str, rep, ok: bool, extra: str = "") -> None:  # type: ignore[no-untyped-def]
        rows.append(
            {
                "receiver": name,
                "frames": rep.frames,
                "frames_per_s": round(rep.frames_per_s),
                "addressed": rep.addressed,
                "errors": dict(rep.errors),
                "changed_by_others": dict(rep.changed),
                "ok": ok,
                "notes": rep.notes + ([extra] if extra else []),
            }
        )
        errs = sum(rep.errors.values())
        print(
            f"{name:<28} {rep.frames:>8} {rep.frames_per_s:>10.0f} {errs:>7} "
            f"{sum(rep.changed.values()):>8} {'yes' if ok else 'NO':>5}  {extra}",
            flush=True,
        )

    print(f"{'receiver':<28} {'frames':>8} {'frames/s':>10} {'errors':>7} {'changed':>8} {'ok':>5}")
    rep = asyncio.run(fuzz_mock_in_process(n, seed))
    row("mock (in process)", rep, not rep.errors and not rep.changed, f"addressed={rep.addressed}")
    rep = fuzz_mock_udp(n, seed + 1)
    row("mock (UDP)", rep, rep.alive and not rep.errors)
    rep, before, after = asyncio.run(fuzz_fleet(n, seed + 2))
    same = (before.mode, before.armed, before.home) == (after.mode, after.armed, after.home)
    row("MAVSDK Fleet (UDP)", rep, rep.alive and same, f"state unchanged={same}")
    with tempfile.TemporaryDirectory() as tmp:
        rep, tracks, valid = fuzz_tlog(Path(tmp) / "hostile.tlog", n, seed + 3)
    got = len(tracks["d1"].t_s) if "d1" in tracks else 0
    row("tlog reader", rep, not rep.errors, f"recovered {got} of {len(valid)} valid samples")
    print(json.dumps({"bench": "fuzz", "rows": rows}))


if __name__ == "__main__":
    main()
