"""How an offboard flight streams: its settings, and the sender of one setpoint.

:class:`OffboardConfig` holds the settings of :func:`mavlink.offboard.fly_offboard`
(setpoint rate, pre-stream, drag feed-forward, end action, and the start tolerance, arrival
gate and take-off of every flight: :class:`mavlink.flight.StartGate`); :func:`offboard_sender` puts one setpoint on the wire through MAVSDK's Offboard
plugin. The plan is sampled into setpoints by :func:`mavlink.plan_setpoints.plan_setpoints_ned`,
which the batch simulator shares.

A room of its own, apart from the running of the flight (:mod:`mavlink.offboard`): these
are values and functions of a plan that never wait on a vehicle (the sender only queues a
datagram), so they are tested and benchmarked on their own.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum

from mavsdk.plugins.offboard import (
    AccelerationNed,
    Offboard,
    PositionNedYaw,
    VelocityNedYaw,
)

from mavlink.errors import LinkError
from mavlink.flight import StartGate
from mavlink.offboard.stream import MAX_RATE_HZ, Setpoint


class EndAction(Enum):
    """What every vehicle does after the last setpoint has been held."""

    HOLD = "hold"
    LAND = "land"
    RETURN = "return"


@dataclass(frozen=True, slots=True)
class OffboardConfig(StartGate):
    """Settings of an offboard flight: how the vehicles get onto their starts (the
    :class:`~mavlink.flight.StartGate` it extends: start tolerance, arrival gate, take-off),
    and how it streams.

    Attributes:
        rate_hz: setpoint rate, 2 < rate <= 100 (default 20 Hz).
        prestream_s: how long the start setpoint is streamed before the
            switch to offboard (>= 1 s; PX4 needs a live stream; a denied
            switch is retried twice, 0.5 s apart, while the stream goes on).
        drag_per_s: the vehicles' drag per unit mass (1/s; one for all or per vehicle name),
            added to the acceleration feed-forward (:func:`mavlink.plan_setpoints.plan_setpoints_ned`); 0: none.
        mode_timeout_s: time allowed for all vehicles to report OFFBOARD.
        start_delay_s: the shared start time is this long after the switch.
        hold_after_s: keep streaming the final setpoint this long.
        end_action: hold, land or return to launch afterwards.
        land_at: with ``end_action`` LAND, per vehicle name a point ``(lat_deg, lon_deg,
            alt_amsl_m)`` to fly to first (at the altitude given) and land at, where landing
            straight down would not be safe (:mod:`gcs.flight.landing`); others land where they are.
        land_goto_timeout_s: time allowed to reach that point (plus 1 s per metre away);
            a vehicle that does not arrive is left holding, and the end action is reported
            failed for it.
        late_threshold_s: lateness that counts as late (default a quarter period).
        send_groups: spread the vehicles over this many send instants per
            period (:class:`~mavlink.offboard.stream.SetpointStreamer`); each vehicle's
            setpoints are sampled at its own send times. ``None``: one group
            per 16 vehicles (measured in ``benchmarks/bench_stream.py``:
            bursts of more vehicles raise the p99 lateness); 1: all at the tick.
    """

    rate_hz: float = 20.0
    prestream_s: float = 1.2
    drag_per_s: float | Mapping[str, float] = 0.0
    mode_timeout_s: float = 5.0
    start_delay_s: float = 0.3
    hold_after_s: float = 1.0
    end_action: EndAction = EndAction.HOLD
    land_at: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    land_goto_timeout_s: float = 20.0
    late_threshold_s: float | None = None
    send_groups: int | None = None

    def drag_of(self, name: str) -> float:
        """The drag fed forward for vehicle ``name`` (1/s)."""
        if isinstance(self.drag_per_s, Mapping):
            return float(self.drag_per_s.get(name, 0.0))
        return float(self.drag_per_s)

    def __post_init__(self) -> None:
        StartGate.__post_init__(self)
        if self.send_groups is not None and not (
            isinstance(self.send_groups, int) and self.send_groups >= 1
        ):
            raise LinkError(f"send_groups must be an integer >= 1, got {self.send_groups!r}")
        if not (2.0 < self.rate_hz <= MAX_RATE_HZ):
            raise LinkError(f"offboard rate_hz {self.rate_hz!r} outside (2, {MAX_RATE_HZ:g}]")
        if not self.prestream_s >= 1.0:
            raise LinkError(f"prestream_s {self.prestream_s!r} must be >= 1 s (PX4 offboard rule)")
        value = self.mode_timeout_s
        if not (math.isfinite(value) and value > 0):
            raise LinkError(f"mode_timeout_s must be a finite number > 0, got {value!r}")
        drags = (
            self.drag_per_s.values() if isinstance(self.drag_per_s, Mapping) else [self.drag_per_s]
        )
        if not all(math.isfinite(c) and c >= 0 for c in drags):
            raise LinkError(f"drag_per_s must be finite numbers >= 0, got {self.drag_per_s!r}")
        for name in ("start_delay_s", "hold_after_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise LinkError(f"{name} must be a finite number >= 0, got {value!r}")


def offboard_sender(offboard: Offboard) -> Callable[[Setpoint], None]:
    """A :class:`~mavlink.offboard.stream.StreamTarget` sender over MAVSDK's blocking-free setpoint
    call."""
    set_pva = offboard.set_position_velocity_acceleration_ned

    def send(sp: Setpoint) -> None:
        set_pva(
            PositionNedYaw(sp.n_m, sp.e_m, sp.d_m, sp.yaw_deg),
            VelocityNedYaw(sp.vn_m_s, sp.ve_m_s, sp.vd_m_s, sp.yaw_deg),
            AccelerationNed(sp.an_m_s2, sp.ae_m_s2, sp.ad_m_s2),
        )

    return send
