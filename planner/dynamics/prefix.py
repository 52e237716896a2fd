"""A plan's waypoints up to a time fixed: the decisions of the minimum-jerk chain through
given trajectories (:class:`Prefix`, :func:`fixed_entries`, :func:`warm_start`).

A replan (:mod:`planner.replan`) keeps the part of the plan the vehicles fly before the switch
time: the waypoints at or before it are fixed (equal bounds in the NLP) to the current plan's
states there, position, velocity and (with explicit accelerations) acceleration.  Each
segment of the chain depends only on the states at its two ends, so the new plan equals the
current one up to the switch time, exactly.  Only :class:`MinimumJerkChain` has such
waypoints; any other model is refused (:class:`PrefixError`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from planner.dynamics.chain import MinimumJerkChain
from planner.dynamics.errors import DynamicsError
from planner.trajectory import Trajectory

__all__ = ["Prefix", "PrefixError", "decisions_of", "fixed_entries", "warm_start"]


class PrefixError(DynamicsError):
    """A prefix that cannot be fixed: a model without waypoints, a vehicle without a
    trajectory."""


@dataclass(frozen=True, slots=True)
class Prefix:
    """A plan's waypoints up to ``until_s`` (s) fixed to those of ``trajectories`` (by name)."""

    until_s: float
    trajectories: Mapping[str, Trajectory]


def _chain(model: object) -> MinimumJerkChain:
    if not isinstance(model, MinimumJerkChain):
        raise PrefixError(
            "a flown part can be kept only on the minimum-jerk model's waypoints "
            "(model: minimum_jerk)"
        )
    return model


def decisions_of(model: object, trajectory: Trajectory) -> np.ndarray:
    """``Z`` ``(n_dec, 3)`` of the minimum-jerk chain ``model`` through ``trajectory``'s
    states at its waypoints (exact for a trajectory of the same chain)."""
    chain = _chain(model)
    t = np.asarray(chain.waypoint_times_s, dtype=float)
    parts = [trajectory.position(t), trajectory.velocity(t)]
    if chain.explicit_acc:
        parts.append(trajectory.acceleration(t))
    return np.vstack(parts)


def warm_start(
    model: object, names: Sequence[str], trajectories: Mapping[str, Trajectory]
) -> np.ndarray:
    """The decision vector of ``trajectories`` for vehicles ``names``, in that order."""
    return np.concatenate(
        [decisions_of(model, _of(trajectories, n)).reshape(-1, order="F") for n in names]
    )


def fixed_entries(
    model: object, names: Sequence[str], prefix: Prefix
) -> tuple[np.ndarray, np.ndarray]:
    """The indices into the decision vector (vehicles ``names`` in order) of the waypoints
    at or before ``prefix.until_s``, and their values."""
    chain = _chain(model)
    k = int(np.count_nonzero(np.asarray(chain.waypoint_times_s) <= prefix.until_s + 1e-9))
    blocks = (chain.pos_rows, chain.vel_rows, chain.acc_rows)
    rows = np.concatenate(
        [np.arange(s.start, s.start + k) for s in blocks if s.stop > s.start]
    ).astype(int)
    idx, vals = [], []
    for i, name in enumerate(names):
        z = decisions_of(chain, _of(prefix.trajectories, name))
        for axis in range(3):
            idx.append((i * 3 + axis) * chain.n_dec + rows)
            vals.append(z[rows, axis])
    return np.concatenate(idx), np.concatenate(vals)


def _of(trajectories: Mapping[str, Trajectory], name: str) -> Trajectory:
    tr = trajectories.get(name)
    if tr is None:
        raise PrefixError(f"no trajectory for vehicle {name} to keep its flown part")
    return tr
