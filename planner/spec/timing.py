"""Clauses and timing error: how many seconds of it a clause tolerates on a flight.

A vehicle flown as a PX4 mission keeps the plan's path but not exactly its clock: PX4's
navigator slows at corners and stops, and on SITL it kept the power line's missions within
about 0.5 s of each other (docs/px4-sitl.md). A clause *tolerates* ``d`` seconds of timing
error on a flight when it stays at or above ``epsilon`` with any one of its vehicles ``d``
seconds early or late, and with two of them off by ``d`` the opposite ways (a separation
between two vehicles then sees ``2 d`` between them): the temporal robustness of Donzé and
Maler ("Robust satisfaction of temporal logic over real-valued signals", FORMATS 2010), taken
per vehicle (:func:`time_tolerance`).

The mission conversion of ``gcs upload`` and ``gcs fly --mode mission`` reports it per clause
on PX4's predicted flight (:func:`gcs.flight.missions.time_tolerance`), and ``gcs upload
--start`` refuses missions with a clause that tolerates less than PX4 keeps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from planner.stl import Formula

__all__ = ["SignalAt", "time_tolerance"]

#: A vehicle's signal at the instants given (s): ``signal(name, t)`` -> (n, 3) or (n, 4).
SignalAt = Callable[[str, np.ndarray], np.ndarray]


def _shifts(names: Sequence[str], d: float) -> list[dict[str, float]]:
    """Each vehicle ``d`` early and late alone, and each pair off the opposite ways."""
    out: list[dict[str, float]] = [{n: s * d} for n in names for s in (-1.0, 1.0)]
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            out += [{a: d, b: -d}, {a: -d, b: d}]
    return out


def time_tolerance(
    clause: Formula,
    signal: SignalAt,
    names: Sequence[str],
    t: np.ndarray,
    dt: float,
    *,
    epsilon: float = 0.0,
    up_to_s: float = 3.0,
    resolution_s: float = 0.05,
) -> float:
    """How many seconds of timing error ``clause`` tolerates on the flight ``signal``: the
    largest ``d`` (to ``resolution_s``, at most ``up_to_s``) at which it stays at or above
    ``epsilon`` with its vehicles off by ``d`` (:func:`_shifts`: one early or late, or two the
    opposite ways; the others on time); 0 for a clause already below ``epsilon``."""
    mine = [n for n in names if n in clause.signal_names()]
    base = {n: signal(n, t) for n in names}  # once: each step shifts only its vehicles

    def holds(d: float) -> bool:
        for shift in _shifts(mine, d) or [{}]:
            sig = base | {n: signal(n, t + d_n) for n, d_n in shift.items()}
            if float(clause.robustness(sig, dt)) < epsilon:
                return False
        return True

    if not holds(0.0):
        return 0.0
    if holds(up_to_s):
        return up_to_s
    lo, hi = 0.0, up_to_s
    while hi - lo > resolution_s:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return round(lo, 2)
