"""Named regions of a mission: axis-aligned boxes in the mission frame and what they mean.

Shared by the scenario reader (:mod:`planner.scenario`), the predicates
(:mod:`planner.predicates`) and the plan files, with no dependency on any of them.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

__all__ = ["KEEP_OUT_KINDS", "Region", "RegionKind"]


class RegionKind(enum.Enum):
    """What a named box means to the mission (documentation and plots; the spec decides)."""

    WORKSPACE = "workspace"
    OBSTACLE = "obstacle"
    NO_FLY = "no_fly"
    POLE = "pole"
    CONDUCTOR = "conductor"
    INSPECTION = "inspection"
    GOAL = "goal"
    REGION = "region"


#: Kinds of region no vehicle may ever be inside of, whatever the spec says: where it
#: may not start (:mod:`planner.scenario_checks`) and not descend or fly through when it
#: lands (:mod:`gcs.landing`).
KEEP_OUT_KINDS = frozenset(
    {RegionKind.OBSTACLE, RegionKind.NO_FLY, RegionKind.POLE, RegionKind.CONDUCTOR}
)


@dataclass(frozen=True, slots=True)
class Region:
    """An axis-aligned box in the mission frame (ENU, metres)."""

    name: str
    kind: RegionKind
    lo_enu_m: tuple[float, float, float]
    hi_enu_m: tuple[float, float, float]

    @property
    def center_enu_m(self) -> np.ndarray:
        """Centre of the box, shape (3,)."""
        return (np.asarray(self.lo_enu_m) + np.asarray(self.hi_enu_m)) / 2.0

    def contains(self, pos_enu_m: np.ndarray) -> np.ndarray:
        """Whether each point (shape (n, 3) or (3,)) lies in the closed box."""
        p = np.asarray(pos_enu_m, dtype=float)
        return np.all((p >= self.lo_enu_m) & (p <= self.hi_enu_m), axis=-1)
