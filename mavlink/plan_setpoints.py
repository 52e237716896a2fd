"""A plan's trajectory as one vehicle's setpoints in its own local NED frame.

Both sides of the link sample plans the same way: the ground station streams these setpoints
to PX4 (:mod:`mavlink.offboard`), and the batch simulator of ``gcs assess``
(:mod:`mavlink.mock.sim.batch`) flies them without sockets. A module of its own, apart from both:
it speaks no MAVLink and imports neither side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mavlink.errors import StreamError
from planner.frames import GeodeticPoint, enu_to_ned, enu_vector_to_ned, yaw_enu_to_ned
from planner.trajectory import Trajectory

__all__ = ["NedSetpoints", "plan_setpoints_ned"]


@dataclass(frozen=True, slots=True, eq=False)
class NedSetpoints:
    """One vehicle's setpoints in its own local NED frame.

    Attributes:
        t_s: ``(n,)`` seconds from the shared start, step ``1 / rate_hz``.
        pos_ned_m: ``(n, 3)`` north, east, down.
        vel_ned_m_s: ``(n, 3)`` velocity feed-forward.
        acc_ned_m_s2: ``(n, 3)`` acceleration feed-forward.
        yaw_ned_rad: ``(n,)`` heading, 0 = north, clockwise.
    """

    t_s: np.ndarray
    pos_ned_m: np.ndarray
    vel_ned_m_s: np.ndarray
    acc_ned_m_s2: np.ndarray
    yaw_ned_rad: np.ndarray

    def __post_init__(self) -> None:
        n = self.t_s.shape[0]
        for name in ("pos_ned_m", "vel_ned_m_s", "acc_ned_m_s2"):
            if getattr(self, name).shape != (n, 3):
                raise StreamError(
                    f"setpoints: {name} has shape {getattr(self, name).shape}, expected ({n}, 3)"
                )
        if self.yaw_ned_rad.shape != (n,):
            raise StreamError(
                f"setpoints: yaw_ned_rad has shape {self.yaw_ned_rad.shape}, expected ({n},)"
            )
        if n == 0:
            raise StreamError("setpoints: empty")

    def __len__(self) -> int:
        return int(self.t_s.shape[0])

    def constant(self, index: int, n: int) -> NedSetpoints:
        """``n`` copies of setpoint ``index`` with zero velocity and acceleration (a hover)."""
        z = np.zeros((n, 3))
        return NedSetpoints(
            t_s=np.arange(n, dtype=float),
            pos_ned_m=np.repeat(self.pos_ned_m[index : index + 1], n, axis=0),
            vel_ned_m_s=z,
            acc_ned_m_s2=z.copy(),
            yaw_ned_rad=np.full(n, self.yaw_ned_rad[index]),
        )


def plan_setpoints_ned(
    trajectory: Trajectory,
    rate_hz: float,
    mission_origin: GeodeticPoint,
    vehicle_origin: GeodeticPoint,
    *,
    t_offset_s: float = 0.0,
    drag_per_s: float = 0.0,
) -> NedSetpoints:
    """Sample ``trajectory`` at ``rate_hz`` and express it in the vehicle's local NED frame.

    Positions go mission ENU -> geodetic -> vehicle NED; velocity and
    acceleration are rotated between the two tangent planes; yaw becomes a
    NED heading (planner.frames).

    Args:
        t_offset_s: sample at ``k / rate_hz + t_offset_s`` (the vehicle's send
            offset within the period, :func:`mavlink.offboard.stream.send_offsets`).
        drag_per_s: the vehicle's linear drag per unit mass ``c`` (1/s). PX4's position
            controller does not model drag, so without help the vehicle settles
            ``c / (MPC_XY_P * MPC_XY_VEL_P_ACC)`` seconds behind a moving setpoint
            (0.585 s on SIH's quad); the acceleration feed-forward then carries the force
            the drag takes: ``a_ff = a_plan + c * v_plan``.

    Returns:
        :class:`NedSetpoints` for ``k = 0 .. ceil(T * rate)`` (the trajectory
        holds its end state past its duration).
    """
    n = math.ceil(trajectory.duration_s * rate_hz - 1e-9) + 1  # as Trajectory.sample
    t = np.arange(n) / rate_hz + t_offset_s
    vel = trajectory.velocity(t)
    acc = trajectory.acceleration(t) + drag_per_s * vel
    return NedSetpoints(
        t_s=t,
        pos_ned_m=enu_to_ned(trajectory.position(t), mission_origin, vehicle_origin),
        vel_ned_m_s=enu_vector_to_ned(vel, mission_origin, vehicle_origin),
        acc_ned_m_s2=enu_vector_to_ned(acc, mission_origin, vehicle_origin),
        yaw_ned_rad=np.asarray(
            yaw_enu_to_ned(trajectory.yaw_rad(t), mission_origin, vehicle_origin), dtype=float
        ),
    )
