"""Row-wise constraints only where they can bind: constraint screening with row generation.

A long line's NLP has a row for every keep-out, every pair of vehicles and every face of the
workspace at every constraint step: the 40-pole line has 98,126 of them (79 keep-outs, 4
drones, 301 steps), of which about 3 % are within 5 m of binding in any plan that flies the
line. The rest cost build time (CasADi differentiates each) and every IPOPT iteration
(each is a row of the KKT system), and none of them changes the optimum: a row that holds
by metres has a zero multiplier.

So, on large problems, the NLP keeps a row-wise leaf's step only where the leaf's exact
value on a reference plan (the start) is below :data:`REACH_M`, and one segment either side
of such a step (a plan's timing moves). That is a guess about where the solution will be,
and it is checked: after every solve, the rows left out are evaluated at the solution, and
any that comes within :data:`GUARD_M` of the NLP's robustness joins the NLP, which is solved
again from there (row generation, as in cutting-plane methods: the screened NLP is a
relaxation, so the solution of the last round, with no row missed, is a solution of the
whole). Whatever happens, the plan is judged afterwards on the exact semantics of every
clause (:func:`planner.solve.plan_check.evaluate`): screening can make a plan worse, never
make a failing plan look good.

Screening is on by default (``solver.screen: auto``) where the rows are many and most of
them are far from binding at the start (:func:`chosen_screen`): lines, where each drone
meets a few of the keep-outs at a time (the 12 drones at 6 poles: 8.9 s in full, 2.6 s
screened). Crowded missions keep most rows anyway and gain nothing (reach-avoid with 16
drones keeps all 9,272; the power line with 8 drones would keep 34 % and plan less robust,
+0.302 against +0.327, in the same time), so they are not screened.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import maximum_filter1d

from planner.problem import Problem
from planner.stl import Formula
from planner.stl.exact import robustness_trace

__all__ = [
    "AUTO_KEEP_SHARE",
    "AUTO_MIN_ROWS",
    "GUARD_M",
    "REACH_M",
    "Screen",
    "chosen_screen",
    "near_rows",
]

#: ``solver.screen: auto`` screens NLPs with more step rows (a row-wise leaf at one
#: constraint step) than this ...
AUTO_MIN_ROWS = 2_000
#: ... of which the screen keeps at most this share.
AUTO_KEEP_SHARE = 0.25
#: A step row is kept where its leaf's value on the reference plan is below this (m).
REACH_M = 5.0
#: After a solve, a row left out whose value is within this (m) of the NLP's robustness
#: joins the NLP, which is solved again.
GUARD_M = 0.5


@dataclass(frozen=True, slots=True)
class Screen:
    """The constraint steps the NLP keeps of each row-wise leaf (a leaf absent has none)."""

    steps: Mapping[Formula, frozenset[int]]
    #: step rows of every row-wise leaf, kept or not
    total: int

    @property
    def kept(self) -> int:
        return sum(len(s) for s in self.steps.values())

    def key(self) -> tuple[Any, ...]:
        """Hashable and equal for equal screens (the NLP structure cache's key)."""
        return tuple(sorted((str(leaf), tuple(sorted(s))) for leaf, s in self.steps.items()))

    def covers(self, rows: Mapping[Formula, set[int]]) -> bool:
        return all(s <= self.steps.get(leaf, frozenset()) for leaf, s in rows.items())

    def left_out(self, rows: Mapping[Formula, set[int]]) -> dict[Formula, set[int]]:
        """The steps of ``rows`` this screen does not keep (leaves with none left out
        absent)."""
        out = {}
        for leaf, steps in rows.items():
            left = steps - self.steps.get(leaf, frozenset())
            if left:
                out[leaf] = left
        return out

    def grown(self, rows: Mapping[Formula, set[int]]) -> Screen:
        """This screen with ``rows`` kept as well."""
        steps = dict(self.steps)
        for leaf, s in rows.items():
            steps[leaf] = steps.get(leaf, frozenset()) | frozenset(s)
        return Screen(steps, self.total)

    def describe(self) -> str:
        return (
            f"{self.kept:,} of {self.total:,} step rows of keep-outs, separations and boxes "
            f"kept (within {REACH_M:g} m of binding)"
        )


def chosen_screen(
    problem: Problem,
    rows: Mapping[Formula, Sequence[int]],
    near: Callable[[], Mapping[Formula, set[int]]],
) -> Screen | None:
    """The NLP's screen, or None for every row: ``solver.screen`` if set (``near()``: the
    rows within reach of binding at the reference); by default (auto) screened where the
    rows are many (more than :data:`AUTO_MIN_ROWS`) and most of them far from binding (the
    screen keeps at most :data:`AUTO_KEEP_SHARE` of them)."""
    asked = problem.solver.screen
    total = sum(len(s) for s in rows.values())
    if asked is False or (asked is None and total <= AUTO_MIN_ROWS):
        return None
    screen = Screen({leaf: frozenset(s) for leaf, s in near().items()}, total)
    if asked is None and screen.kept > AUTO_KEEP_SHARE * total:
        return None
    return screen


def near_rows(
    rows: Mapping[Formula, Sequence[int]],
    signals: Mapping[str, Any],
    dt: float,
    below: float,
    spread_steps: int,
) -> dict[Formula, set[int]]:
    """The constraint steps of each leaf of ``rows`` where its exact value on ``signals``
    (sampled every ``dt``) is below ``below``, or is so within ``spread_steps`` samples."""
    out: dict[Formula, set[int]] = {}
    for leaf, steps in rows.items():
        close = np.asarray(robustness_trace(leaf, signals, dt)) < below
        if not close.any():
            continue
        if spread_steps > 0:
            close = maximum_filter1d(close.astype(np.uint8), 2 * spread_steps + 1) > 0
        st = np.asarray(steps, dtype=int)
        kept = st[close[st]]
        if kept.size:
            out[leaf] = {int(s) for s in kept}
    return out
