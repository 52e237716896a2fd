"""Timed setpoint streaming against absolute deadlines.

:class:`SetpointStreamer` sends setpoint ``k`` of every vehicle at the
deadline ``t0 + k / rate_hz`` (on the flight's clock, :mod:`mavlink.clock`), so errors never
accumulate: a late tick does not shift the following ones. If the loop falls
more than one period behind, the stale setpoints are skipped (counted in
``skipped``) and the current one is sent, as a vehicle gains nothing from an
outdated target.

Lateness of a setpoint is the time from its deadline to the moment its send
call returned; :class:`StreamStats` summarises it per vehicle.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mavlink.errors import StreamError
from mavlink.plan_setpoints import NedSetpoints

#: Highest stream rate accepted (docs/architecture.md, "The MAVLink side": configurable up to 100 Hz).
MAX_RATE_HZ = 100.0
#: Lowest rate PX4 accepts for offboard (it needs > 2 Hz).
MIN_RATE_HZ = 2.0


@dataclass(frozen=True, slots=True)
class StreamStats:
    """Per-vehicle statistics of one stream.

    Attributes:
        vehicle: name.
        sent: setpoints sent.
        skipped: setpoints not sent because the loop was more than one period late.
        failed: send calls that raised (the stream went on).
        late: setpoints whose lateness exceeded ``late_threshold_s``.
        late_threshold_s: the threshold used for ``late``.
        mean_lateness_s, p99_lateness_s, max_lateness_s: lateness of the sent setpoints.
        rate_hz: the stream rate.
    """

    vehicle: str
    sent: int
    skipped: int
    failed: int
    late: int
    late_threshold_s: float
    mean_lateness_s: float
    p99_lateness_s: float
    max_lateness_s: float
    rate_hz: float

    def row(self) -> str:
        """One table row (milliseconds)."""
        return (
            f"{self.vehicle:>8} {self.sent:6d} {self.skipped:5d} {self.failed:5d} {self.late:5d} "
            f"{self.mean_lateness_s * 1e3:8.3f} {self.p99_lateness_s * 1e3:8.3f} "
            f"{self.max_lateness_s * 1e3:8.3f}"
        )


STATS_HEADER = f"{'vehicle':>8} {'sent':>6} {'skip':>5} {'fail':>5} {'late':>5} {'mean ms':>8} {'p99 ms':>8} {'max ms':>8}"


#: Vehicles per send instant when the grouping is automatic.
VEHICLES_PER_GROUP = 16


def auto_send_groups(n_vehicles: int) -> int:
    """Send groups for ``n_vehicles``: one per :data:`VEHICLES_PER_GROUP` vehicles."""
    return max(1, math.ceil(n_vehicles / VEHICLES_PER_GROUP))


def send_offsets(n_vehicles: int, rate_hz: float, groups: int) -> np.ndarray:
    """``(n_vehicles,)`` send delay of each vehicle after its tick: ``(i % groups) / groups / rate``."""
    return (np.arange(n_vehicles) % groups) / groups / rate_hz


class Setpoint(NamedTuple):
    """One setpoint as it goes on the wire: local NED, plain floats (the hot path builds
    them once, before the flight, and never touches numpy)."""

    n_m: float
    e_m: float
    d_m: float
    vn_m_s: float
    ve_m_s: float
    vd_m_s: float
    an_m_s2: float
    ae_m_s2: float
    ad_m_s2: float
    yaw_deg: float


@dataclass(frozen=True, slots=True)
class StreamTarget:
    """What to stream to one vehicle.

    Attributes:
        name: vehicle name.
        send: non-blocking call ``send(setpoint)`` run on the event loop thread.
        setpoints: the vehicle's setpoints.
    """

    name: str
    send: Callable[[Setpoint], None]
    setpoints: NedSetpoints


class SetpointStreamer:
    """Stream setpoints to many vehicles from one asyncio task.

    Args:
        targets: one :class:`StreamTarget` per vehicle. Setpoint ``k`` of
            each is sent at ``t0 + k / rate_hz``; a vehicle whose setpoints
            are shorter than the others holds its last one.
        rate_hz: stream rate (2 < rate <= 100).
        late_threshold_s: lateness above which a setpoint counts as late
            (default a quarter period).
        groups: spread the vehicles over this many send instants per period
            (vehicle ``i`` in group ``i % groups``, sent ``(i % groups) /
            groups`` of a period after the tick), so a large fleet's
            datagrams do not leave in one burst. Each vehicle's setpoints
            must then be sampled at its own send times: ``t_k +`` its entry
            of :attr:`offsets_s` (see :func:`send_offsets`).
        clock, sleep: the time source and the way to wait (tests replace
            both with a simulated clock).

    The vehicles sent at one instant go back to back in a rotating order, so
    no vehicle is always last.
    """

    def __init__(
        self,
        targets: Sequence[StreamTarget],
        rate_hz: float,
        *,
        late_threshold_s: float | None = None,
        groups: int = 1,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], Awaitable[None]] = asyncio.sleep,
    ) -> None:
        self._clock = clock
        self._sleep = sleep
        if not (MIN_RATE_HZ < rate_hz <= MAX_RATE_HZ) or not math.isfinite(rate_hz):
            raise StreamError(
                f"stream rate {rate_hz!r} Hz outside ({MIN_RATE_HZ:g}, {MAX_RATE_HZ:g}]"
            )
        if not targets:
            raise StreamError("nothing to stream: no vehicles")
        self.targets = tuple(targets)
        self.rate_hz = float(rate_hz)
        self.period_s = 1.0 / self.rate_hz
        if not 1 <= groups <= len(self.targets):
            raise StreamError(f"send groups {groups!r} outside 1..{len(self.targets)} (vehicles)")
        self.groups = int(groups)
        #: Send time of each vehicle after its tick, seconds.
        self.offsets_s = send_offsets(len(self.targets), self.rate_hz, self.groups)
        self.late_threshold_s = self.period_s / 4 if late_threshold_s is None else late_threshold_s
        self.n_ticks = max(len(t.setpoints) for t in self.targets)
        # Plain Python floats per setpoint: the hot loop must not touch numpy.
        self._rows = [_rows_of(t.setpoints) for t in self.targets]
        self._last = [len(r) - 1 for r in self._rows]
        self._index = {t.name: i for i, t in enumerate(self.targets)}
        self._dropped_i: set[int] = set()  # vehicles no longer sent to (:meth:`drop`)
        #: the tick the stream sends next (0 before it runs)
        self.next_tick = 0

    def drop(self, name: str) -> None:
        """Send nothing more to vehicle ``name`` (it left the flight); on the event loop."""
        self._dropped_i.add(self._index[name])

    def splice(self, name: str, setpoints: NedSetpoints, from_tick: int) -> None:
        """Send ``setpoints`` to vehicle ``name`` from tick ``from_tick`` on (a replanned
        trajectory, sampled at the same ticks); on the event loop, between two sends."""
        i = self._index[name]
        new = _rows_of(setpoints)
        k = max(0, min(int(from_tick), len(new)))
        self._rows[i] = self._rows[i][:k] + new[k:]
        self._last[i] = len(self._rows[i]) - 1

    async def run(
        self,
        t0_s: float,
        *,
        stop: asyncio.Event | None = None,
        extra_ticks: int = 0,
    ) -> dict[str, StreamStats]:
        """Stream every setpoint, then ``extra_ticks`` more of the last one.

        Args:
            t0_s: ``time.monotonic()`` deadline of setpoint 0.
            stop: if set, streaming ends before the next tick.
            extra_ticks: ticks to keep sending the final setpoints (a hold).

        Returns:
            :class:`StreamStats` per vehicle name.
        """
        n_v = len(self.targets)
        n_g = self.groups
        total = self.n_ticks + extra_ticks
        lateness = np.full((total, n_v), np.nan)
        failed = [0] * n_v
        skipped = [0] * n_v
        errors: list[BaseException | None] = [None] * n_v
        members = [list(range(g, n_v, n_g)) for g in range(n_g)]
        sends = [t.send for t in self.targets]
        rows = self._rows
        last = self._last
        dropped = self._dropped_i
        clock = self._clock
        sleep = self._sleep
        period = self.period_s
        step = period / n_g
        total_steps = total * n_g
        j = 0  # send instant: tick j // n_g, group j % n_g
        while j < total_steps:
            if stop is not None and stop.is_set():
                break
            deadline = t0_s + j * step
            delay = deadline - clock()
            if delay > 0:
                await sleep(delay)
                if stop is not None and stop.is_set():
                    break
            behind = int((clock() - deadline) // period)
            if behind >= 1:  # more than a period late: skip to the current instant
                jump = min(behind * n_g, total_steps - 1 - j)
                for jj in range(j, j + jump):
                    for i in members[jj % n_g]:
                        skipped[i] += 1
                j += jump
                deadline = t0_s + j * step
            k, g = divmod(j, n_g)
            self.next_tick = k + 1
            group = members[g]
            start = k % len(group)
            for m in range(len(group)):
                i = group[(start + m) % len(group)]
                if dropped and i in dropped:
                    continue
                r = rows[i][min(k, last[i])]
                try:
                    sends[i](r)
                except Exception as exc:  # counted and reported below
                    failed[i] += 1
                    errors[i] = exc
                    continue
                lateness[k, i] = clock() - deadline
            j += 1
        out: dict[str, StreamStats] = {}
        for i, t in enumerate(self.targets):
            lat = lateness[:, i]
            lat = lat[~np.isnan(lat)]
            out[t.name] = StreamStats(
                vehicle=t.name,
                sent=int(lat.size),
                skipped=skipped[i],
                failed=failed[i],
                late=int(np.count_nonzero(lat > self.late_threshold_s)),
                late_threshold_s=self.late_threshold_s,
                mean_lateness_s=float(lat.mean()) if lat.size else math.nan,
                p99_lateness_s=float(np.percentile(lat, 99)) if lat.size else math.nan,
                max_lateness_s=float(lat.max()) if lat.size else math.nan,
                rate_hz=self.rate_hz,
            )
        #: Lateness of every send, ``(ticks, vehicles)`` seconds, NaN where none was sent.
        self.last_lateness = lateness
        self.last_errors = {
            t.name: e for t, e in zip(self.targets, errors, strict=True) if e is not None
        }
        return out


def _rows_of(setpoints: NedSetpoints) -> list[Setpoint]:
    """``setpoints`` as plain :class:`Setpoint` rows."""
    return [
        Setpoint(*row)
        for row in np.column_stack(
            [
                setpoints.pos_ned_m,
                setpoints.vel_ned_m_s,
                setpoints.acc_ned_m_s2,
                np.degrees(setpoints.yaw_ned_rad),
            ]
        ).tolist()
    ]
