"""What a plan made to a probability carries (``gcs plan --target-probability``).

The loop (:mod:`gcs.assess.target`) plans, assesses the plan under the disturbances of
``gcs assess``, tightens the clauses that fail and plans again; the plan file then records
how far it got, so that ``gcs verify`` and ``gcs fly`` can say it: the target, the
disturbance model, the probability the final assessment (on runs the loop did not tune on)
gave with its interval, and the margin (m) each clause was tightened by
(:mod:`planner.spec.margins`).  The plan's own spec stays the one the scenario wrote: the
margins are how it was planned, not what it must meet.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Assurance", "AssuranceGoal", "assurance_from_json"]


@dataclass(frozen=True, slots=True)
class AssuranceGoal:
    """A scenario's ``assurance`` section: what ``gcs plan`` plans to when it has one (the
    command's ``--target-probability`` and its options override it).

    Attributes:
        probability: the target, 0 < P < 1.
        disturbances: per disturbance name, its distribution as text (``gcs assess -d``).
        runs: runs of each round's assessment; ``final_runs``: of each check on fresh seeds.
        rounds: most plans made; ``seed``: the base campaign seed.
        budget_s: the loop's wall time (s).
    """

    probability: float
    disturbances: Mapping[str, str] = field(default_factory=dict)
    runs: int = 2000
    final_runs: int = 4000
    rounds: int = 6
    seed: int = 0
    budget_s: float = 240.0


@dataclass(frozen=True, slots=True)
class Assurance:
    """A plan's probability record.

    Attributes:
        target: the probability asked for (0 < target < 1).
        met: whether the final assessment's 95 % interval lies at or above ``target``
            (its lower end >= target).
        p: P(spec holds) in the final assessment; ``ci``: its 95 % Clopper-Pearson interval.
        runs: runs of the final assessment; ``seed``: its campaign seed (the loop tuned on
            others).
        disturbances: per disturbance name, its distribution as text, as asked (the others
            at ``gcs assess --list-disturbances``'s calm-day defaults).
        profile: the simulated vehicle (``gcs assess --profile``).
        margins: per top-level clause (its text), the margin (m) it was planned with.
        dwells: per clause, how much longer (s) its hover was planned
            (:func:`planner.spec.margins.lengthened`).
        rounds: plans made by the loop; ``elapsed_s``: the loop's wall time.
        limiting: when not met, the clause that limits it (its text), else ``None``.
    """

    target: float
    met: bool
    p: float
    ci: tuple[float, float]
    runs: int
    seed: int
    disturbances: Mapping[str, str] = field(default_factory=dict)
    profile: str = "px4"
    margins: Mapping[str, float] = field(default_factory=dict)
    dwells: Mapping[str, float] = field(default_factory=dict)
    rounds: int = 1
    elapsed_s: float = 0.0
    limiting: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "target": self.target,
            "met": self.met,
            "p_holds": self.p,
            "ci95": list(self.ci),
            "runs": self.runs,
            "seed": self.seed,
            "disturbances": dict(self.disturbances),
            "profile": self.profile,
            "margins": [{"clause": k, "margin_m": v} for k, v in self.margins.items()],
            "dwells": [{"clause": k, "dwell_s": v} for k, v in self.dwells.items()],
            "rounds": self.rounds,
            "elapsed_s": self.elapsed_s,
            "limiting": self.limiting,
        }

    def summary(self) -> str:
        """One line: the target, P with its interval, on how many fresh runs, the margins."""
        verdict = "met" if self.met else "NOT met"
        dist = ", ".join(f"{k}={v}" for k, v in self.disturbances.items()) or "calm day"
        dist += ", the rest calm" if self.disturbances else ""
        tight = [m for m in self.margins.values() if m > 0]
        line = (
            f"planned to P >= {self.target:g} ({verdict}): P(spec holds) = {self.p:.4f} "
            f"[{self.ci[0]:.4f}, {self.ci[1]:.4f}] on {self.runs} fresh runs (seed {self.seed}, "
            f"{self.profile}, {dist}); {len(tight)} clause(s) tightened"
            + (f", by up to {max(tight):.2f} m" if tight else "")
            + (
                f"; {len(self.dwells)} hover(s) longer, by up to {max(self.dwells.values()):g} s"
                if self.dwells
                else ""
            )
        )
        if self.limiting:
            line += f"; limited by {self.limiting}"
        return line


def assurance_from_json(v: Any, fail: Any) -> Assurance:
    """Read the plan file's ``assurance`` object; ``fail(key, problem)`` makes the error."""
    if not isinstance(v, dict):
        raise fail("assurance", "expected an object")

    def number(key: str, lo: float, hi: float) -> float:
        x = v.get(key)
        if isinstance(x, bool) or not isinstance(x, int | float) or not math.isfinite(x):
            raise fail(f"assurance.{key}", f"expected a number, got {x!r}")
        if not lo <= x <= hi:
            raise fail(f"assurance.{key}", f"must be in [{lo:g}, {hi:g}], got {x:g}")
        return float(x)

    def whole(key: str) -> int:
        x = v.get(key)
        if isinstance(x, bool) or not isinstance(x, int) or x < 0:
            raise fail(f"assurance.{key}", f"expected a whole number >= 0, got {x!r}")
        return x

    ci = v.get("ci95")
    if not (
        isinstance(ci, list)
        and len(ci) == 2
        and all(isinstance(x, int | float) and not isinstance(x, bool) for x in ci)
    ):
        raise fail("assurance.ci95", "expected [low, high]")
    if not 0.0 <= ci[0] <= ci[1] <= 1.0:
        raise fail("assurance.ci95", f"expected 0 <= low <= high <= 1, got {ci}")
    dist = v.get("disturbances", {})
    if not (isinstance(dist, dict) and all(isinstance(x, str) for x in dist.values())):
        raise fail("assurance.disturbances", "expected {name: distribution text}")
    margins: dict[str, float] = {}
    raw = v.get("margins", [])
    if not isinstance(raw, list):
        raise fail("assurance.margins", "expected a list of {clause, margin_m}")
    for i, m in enumerate(raw):
        ok = isinstance(m, dict) and isinstance(m.get("clause"), str)
        val = m.get("margin_m") if isinstance(m, dict) else None
        if not ok or isinstance(val, bool) or not isinstance(val, int | float):
            raise fail(f"assurance.margins[{i}]", "expected {clause: text, margin_m: number}")
        margins[m["clause"]] = float(val)
    dwells: dict[str, float] = {}
    raw_d = v.get("dwells", [])
    if not isinstance(raw_d, list):
        raise fail("assurance.dwells", "expected a list of {clause, dwell_s}")
    for i, d in enumerate(raw_d):
        ok = isinstance(d, dict) and isinstance(d.get("clause"), str)
        val = d.get("dwell_s") if isinstance(d, dict) else None
        if not ok or isinstance(val, bool) or not isinstance(val, int | float):
            raise fail(f"assurance.dwells[{i}]", "expected {clause: text, dwell_s: number}")
        dwells[d["clause"]] = float(val)
    limiting = v.get("limiting")
    if limiting is not None and not isinstance(limiting, str):
        raise fail("assurance.limiting", "expected the clause's text or null")
    met = v.get("met")
    if not isinstance(met, bool):
        raise fail("assurance.met", f"expected true or false, got {met!r}")
    profile = v.get("profile", "px4")
    if not isinstance(profile, str):
        raise fail("assurance.profile", "expected a profile name")
    return Assurance(
        target=number("target", 0.0, 1.0),
        met=met,
        p=number("p_holds", 0.0, 1.0),
        ci=(float(ci[0]), float(ci[1])),
        runs=whole("runs"),
        seed=whole("seed"),
        disturbances=dict(dist),
        profile=profile,
        margins=margins,
        dwells=dwells,
        rounds=whole("rounds"),
        elapsed_s=number("elapsed_s", 0.0, math.inf),
        limiting=limiting,
    )
