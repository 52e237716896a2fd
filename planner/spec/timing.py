"""Clauses and timing error: how many seconds a clause tolerates, and a clause made to.

A vehicle flown as a PX4 mission keeps the plan's path but not exactly its clock: PX4's
navigator slows at corners and stops, and on SITL it kept the power line's missions within
about 0.5 s of each other (docs/px4-sitl.md). A clause *tolerates* ``d`` seconds of timing
error on a flight when it stays at or above ``epsilon`` with any one of its vehicles ``d``
seconds early or late, and with two of them off by ``d`` the opposite ways (a separation
between two vehicles then sees ``2 d`` between them): the temporal robustness of Donzé and
Maler ("Robust satisfaction of temporal logic over real-valued signals", FORMATS 2010), taken
per vehicle (:func:`time_tolerance`, :func:`worst_shifted`).

:func:`widened` writes a top-level clause so that it holds whenever the original holds under
every shift of the whole signal by up to ``tau`` (``always[-tau, tau] phi``, which the spec
language cannot say, by a sufficient formula in it): an ``eventually[a, b]`` looks in
``[a + tau, b - tau]``, an ``always[a, b]`` over ``[a - tau, b + tau]`` (clipped to the
plan's time: the vehicles wait at their starts before 0 and hold after the horizon). It
covers a late or early mission as a whole; vehicles off against each other are what the
margins of :mod:`planner.spec.margins` add room for (:mod:`planner.for_missions`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import numpy as np

from planner.stl import Always, And, Eventually, Formula, Or

__all__ = ["SignalAt", "time_tolerance", "widened", "worst_shifted"]

#: A vehicle's signal at the instants given (s): ``signal(name, t)`` -> (n, 3) or (n, 4).
SignalAt = Callable[[str, np.ndarray], np.ndarray]


def _shifts(names: Sequence[str], d: float) -> list[dict[str, float]]:
    """Each vehicle ``d`` early and late alone, and each pair off the opposite ways."""
    out: list[dict[str, float]] = [{n: s * d} for n in names for s in (-1.0, 1.0)]
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            out += [{a: d, b: -d}, {a: -d, b: d}]
    return out


def worst_shifted(
    clause: Formula, signal: SignalAt, names: Sequence[str], t: np.ndarray, dt: float, d: float
) -> float:
    """The clause's lowest robustness with its vehicles off by ``d`` seconds
    (:func:`_shifts`: one early or late, or two the opposite ways); the others on time."""
    mine = [n for n in names if n in clause.signal_names()]
    base = {n: signal(n, t) for n in names}
    worst = float(clause.robustness(base, dt))
    for shift in _shifts(mine, d) if d > 0.0 else []:
        sig = base | {n: signal(n, t + d_n) for n, d_n in shift.items()}
        worst = min(worst, float(clause.robustness(sig, dt)))
    return worst


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
    ``epsilon`` under :func:`worst_shifted`; 0 for a clause already below ``epsilon``."""

    def holds(d: float) -> bool:
        return worst_shifted(clause, signal, names, t, dt, d) >= epsilon

    if not holds(0.0):
        return 0.0
    if holds(up_to_s):
        return up_to_s
    lo, hi = 0.0, up_to_s
    while hi - lo > resolution_s:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if holds(mid) else (lo, mid)
    return round(lo, 2)


def widened(node: Formula, tau: float, horizon_s: float) -> Formula:
    """``node`` (a top-level clause, evaluated at 0) made to hold under every shift of the
    whole signal by up to ``tau`` seconds (module docstring): sufficient, not equivalent.

    ``and`` and ``or`` are looked through (each operand widened: for ``or`` sufficient, as
    the option that holds may not change with the shift); an ``eventually[a, b]`` whose
    window is shorter than ``2 tau`` keeps it (no window inside it is safe: the clause
    tolerates less, which :func:`time_tolerance` reports); an ``always`` ends at most where
    its look-ahead still fits the horizon; anything else is left as it is.
    """
    if tau <= 0.0:
        return node
    if isinstance(node, And | Or):
        return type(node)(tuple(widened(c, tau, horizon_s) for c in node.operands))
    if isinstance(node, Eventually):
        a, b = node.start_s + tau, node.end_s - tau
        return dataclasses.replace(node, start_s=a, end_s=b) if a <= b else node
    if isinstance(node, Always):
        room = horizon_s - node.child.horizon
        a, b = max(0.0, node.start_s - tau), max(node.end_s, min(node.end_s + tau, room))
        return dataclasses.replace(node, start_s=a, end_s=b)
    return node
