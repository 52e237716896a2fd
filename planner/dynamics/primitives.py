"""Mueller's closed-form minimum-jerk motion primitive, per axis, vectorised.

Reference: M. W. Mueller, M. Hehn, R. D'Andrea, "A computationally efficient motion
primitive for quadrocopter trajectory generation", IEEE Trans. Robotics 31(6), 2015
(here "[M]").

For one axis with initial state ``(p0, v0, a0)`` and duration ``T`` the jerk-optimal
trajectory (cost ``J = 1/T * integral_0^T j(t)^2 dt`` per axis, [M] "Motion primitive
generation") is the quintic::

    p(t) = alpha/120 t^5 + beta/24 t^4 + gamma/6 t^3 + a0/2 t^2 + v0 t + p0

with the end-state residuals of [M]::

    dp = pf - p0 - v0 T - a0 T^2 / 2,   dv = vf - v0 - a0 T,   da = af - a0.

The parameters ``(alpha, beta, gamma)`` have closed forms that depend on which end
components are fixed:

* fully defined end state ([M] "Fully defined end state")::

    [alpha, beta, gamma]^T = 1/T^5 [[720, -360 T, 60 T^2],
                                    [-360 T, 168 T^2, -24 T^3],
                                    [60 T^2, -24 T^3, 3 T^4]] [dp, dv, da]^T

* partially defined end state ([M] "Partially defined end state"): every free
  end component adds a transversality condition on the costate (free ``af``:
  ``j(T) = 0``; free ``vf``: ``alpha T + beta = 0``; free ``pf``: ``alpha = 0``), giving
  the six further closed forms in :data:`_CLOSED_FORMS` (the same values as Mueller's
  reference implementation; :func:`optimality_system` re-derives all of them from the
  optimality conditions so the tests can check each entry).

The minimal cost ([M], closed-form cost of the primitive)::

    J = gamma^2 + beta gamma T + beta^2 T^2 / 3 + alpha gamma T^2 / 3
        + alpha beta T^3 / 4 + alpha^2 T^4 / 20

Everything here is vectorised: arrays broadcast against each other, so ``10^5``
primitives are one call.
"""

from __future__ import annotations

import enum

import numpy as np
from numpy.typing import ArrayLike, NDArray

from planner.dynamics.errors import DynamicsError

__all__ = [
    "EndState",
    "jerk_cost",
    "min_jerk_parameters",
    "optimality_system",
    "parameters_to_coefficients",
    "primitive_coefficients",
]


class EndState(enum.Enum):
    """Which components of the end state ``(pf, vf, af)`` a primitive must reach.

    Free components are chosen optimally ([M] "Partially defined end state").
    """

    POS_VEL_ACC = "pos_vel_acc"
    POS_VEL = "pos_vel"
    POS_ACC = "pos_acc"
    VEL_ACC = "vel_acc"
    POS = "pos"
    VEL = "vel"
    ACC = "acc"

    @property
    def fixed(self) -> tuple[bool, bool, bool]:
        """``(pos, vel, acc)`` flags: True where the end component is fixed."""
        v = self.value
        return ("pos" in v, "vel" in v, "acc" in v)


def closed_forms(T: NDArray[np.float64], e: EndState) -> NDArray[np.float64]:
    """Closed-form map ``(..., 3, 3)`` from ``[dp, dv, da]`` to ``[alpha, beta, gamma]``."""
    T2 = T * T
    T3 = T2 * T
    T4 = T3 * T
    T5 = T4 * T
    z = np.zeros_like(T)
    if e is EndState.POS_VEL_ACC:  # [M] fully defined end state
        rows = [
            [720 / T5, -360 / T4, 60 / T3],
            [-360 / T4, 168 / T3, -24 / T2],
            [60 / T3, -24 / T2, 3 / T],
        ]
    elif e is EndState.POS_VEL:  # [M] partially defined, free end acceleration
        rows = [
            [320 / T5, -120 / T4, z],
            [-200 / T4, 72 / T3, z],
            [40 / T3, -12 / T2, z],
        ]
    elif e is EndState.POS_ACC:  # [M] partially defined, free end velocity
        rows = [
            [45 / T5, z, -7.5 / T3],
            [-45 / T4, z, 7.5 / T2],
            [15 / T3, z, -1.5 / T],
        ]
    elif e is EndState.VEL_ACC:  # [M] partially defined, free end position
        rows = [
            [z, z, z],
            [z, -12 / T3, 6 / T2],
            [z, 6 / T2, -2 / T],
        ]
    elif e is EndState.POS:  # [M] partially defined, free end velocity and acceleration
        rows = [[20 / T5, z, z], [-20 / T4, z, z], [10 / T3, z, z]]
    elif e is EndState.VEL:  # [M] partially defined, only end velocity fixed
        rows = [[z, z, z], [z, -3 / T3, z], [z, 3 / T2, z]]
    else:  # EndState.ACC: only end acceleration fixed
        rows = [[z, z, z], [z, z, z], [z, z, 1 / T]]
    return np.stack([np.stack(np.broadcast_arrays(*r), axis=-1) for r in rows], axis=-2)


def optimality_system(T: float, end: EndState) -> NDArray[np.float64]:
    """The ``3x3`` linear optimality conditions that the closed forms solve.

    Rows: for each fixed end component its end condition
    (``dp = alpha T^5/120 + beta T^4/24 + gamma T^3/6``, ``dv = alpha T^4/24 + beta T^3/6
    + gamma T^2/2``, ``da = alpha T^3/6 + beta T^2/2 + gamma T``), for each free one the
    transversality condition (``alpha = 0``, ``alpha T + beta = 0``,
    ``alpha T^2/2 + beta T + gamma = 0``). Returns ``A`` with
    ``A @ [alpha, beta, gamma] = [dp or 0, dv or 0, da or 0]``; used by the tests as an
    independent derivation of :func:`min_jerk_parameters`.
    """
    fixed = end.fixed
    end_rows = [
        [T**5 / 120, T**4 / 24, T**3 / 6],
        [T**4 / 24, T**3 / 6, T**2 / 2],
        [T**3 / 6, T**2 / 2, T],
    ]
    free_rows = [[1.0, 0.0, 0.0], [T, 1.0, 0.0], [T**2 / 2, T, 1.0]]
    return np.array([end_rows[i] if fixed[i] else free_rows[i] for i in range(3)], dtype=float)


def _check_duration(T: NDArray[np.float64]) -> None:
    if not np.all(np.isfinite(T)) or np.any(T <= 0.0):
        raise DynamicsError("primitive duration T must be finite and > 0 s")


def min_jerk_parameters(
    p0: ArrayLike,
    v0: ArrayLike,
    a0: ArrayLike,
    pf: ArrayLike,
    vf: ArrayLike,
    af: ArrayLike,
    T: ArrayLike,
    end: EndState = EndState.POS_VEL_ACC,
) -> NDArray[np.float64]:
    """Mueller's ``(alpha, beta, gamma)`` for broadcastable per-axis inputs.

    Args:
        p0, v0, a0: initial position (m), velocity (m/s), acceleration (m/s^2).
        pf, vf, af: end position, velocity, acceleration; components that ``end``
            leaves free are ignored (pass 0).
        T: duration in seconds, > 0.
        end: which end components are fixed.

    Returns:
        ``(..., 3)`` array ``[alpha, beta, gamma]`` (units m/s^5, m/s^4, m/s^3), ``...``
        the broadcast shape of the inputs.
    """
    Tf = np.asarray(T, dtype=float)
    _check_duration(Tf)
    p0, v0, a0, pf, vf, af, Tf = np.broadcast_arrays(
        *(np.asarray(x, dtype=float) for x in (p0, v0, a0, pf, vf, af)), Tf
    )
    d = np.stack(
        [pf - p0 - v0 * Tf - 0.5 * a0 * Tf * Tf, vf - v0 - a0 * Tf, af - a0], axis=-1
    )  # residuals of [M]
    return np.einsum("...ij,...j->...i", closed_forms(Tf, end), d)


def parameters_to_coefficients(
    p0: ArrayLike, v0: ArrayLike, a0: ArrayLike, params: ArrayLike
) -> NDArray[np.float64]:
    """Ascending power-basis coefficients ``(..., 6)`` of ``p(t)`` from ``(alpha, beta, gamma)``.

    ``p(t) = sum_k c[..., k] t^k``, ``t`` in seconds from the primitive's start.
    """
    prm = np.asarray(params, dtype=float)
    p0, v0, a0 = np.broadcast_arrays(*(np.asarray(x, dtype=float) for x in (p0, v0, a0)))
    return np.stack(
        [p0, v0, a0 / 2.0, prm[..., 2] / 6.0, prm[..., 1] / 24.0, prm[..., 0] / 120.0], axis=-1
    )


def primitive_coefficients(
    p0: ArrayLike,
    v0: ArrayLike,
    a0: ArrayLike,
    pf: ArrayLike,
    vf: ArrayLike,
    af: ArrayLike,
    T: ArrayLike,
    end: EndState = EndState.POS_VEL_ACC,
) -> NDArray[np.float64]:
    """Power-basis coefficients ``(..., 6)`` of the jerk-optimal quintic (see module doc)."""
    prm = min_jerk_parameters(p0, v0, a0, pf, vf, af, T, end)
    return parameters_to_coefficients(p0, v0, a0, prm)


def jerk_cost(params: ArrayLike, T: ArrayLike) -> NDArray[np.float64]:
    """Mueller's per-axis cost ``1/T integral j^2 dt`` ([M]); ``params`` ``(..., 3)``."""
    prm = np.asarray(params, dtype=float)
    Tf = np.asarray(T, dtype=float)
    a, b, g = prm[..., 0], prm[..., 1], prm[..., 2]
    return (
        g * g
        + b * g * Tf
        + b * b * Tf**2 / 3.0
        + a * g * Tf**2 / 3.0
        + a * b * Tf**3 / 4.0
        + a * a * Tf**4 / 20.0
    )
