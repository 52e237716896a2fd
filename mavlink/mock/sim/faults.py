"""Fault injection on one vehicle's datagram link (either direction).

A :class:`FaultyChannel` sits between a producer of datagrams and the
function that delivers them (the socket's ``sendto`` for the downlink, the
vehicle's parser for the uplink).  It drops, duplicates, delays and reorders
datagrams as its :class:`~mavlink.mock.sim.config.FaultConfig` says, with a seeded
``random.Random`` so a run is reproducible for a given seed and traffic.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass

from mavlink.mock.sim.config import FaultConfig


@dataclass(slots=True)
class ChannelStats:
    """Counters of one direction of a link (datagrams)."""

    offered: int = 0
    dropped: int = 0
    duplicated: int = 0
    delayed: int = 0
    reordered: int = 0


class FaultyChannel:
    """One direction of a vehicle link with faults.

    ``deliver(data)`` is called (possibly later, possibly twice) for each
    datagram pushed that survives; ``later(delay_s, deliver, data)`` calls it ``delay_s``
    seconds of simulated time from now (:meth:`MockFleet.call_later
    <mavlink.mock.fleet.MockFleet.call_later>`), so latencies hold at any speed and load.
    ``clock_s()`` gives the simulation time used for outages.
    """

    def __init__(
        self,
        faults: FaultConfig,
        loss: float,
        rng: random.Random,
        later: Callable[[float, Callable[[bytes], None], bytes], None],
        deliver: Callable[[bytes], None],
        clock_s: Callable[[], float],
    ) -> None:
        self.faults = faults
        self.loss = loss
        self.rng = rng
        self.later = later
        self.deliver = deliver
        self.clock_s = clock_s
        self.stats = ChannelStats()
        self._clean = faults.is_clean and loss == 0.0

    def push(self, data: bytes) -> None:
        """Offer one datagram to the channel."""
        st = self.stats
        st.offered += 1
        if self._clean:
            self.deliver(data)
            return
        f = self.faults
        rng = self.rng
        if (f.outages and f.in_outage(self.clock_s())) or (self.loss and rng.random() < self.loss):
            st.dropped += 1
            return
        copies = 1
        if f.duplicate and rng.random() < f.duplicate:
            copies = 2
            st.duplicated += 1
        for _ in range(copies):
            delay_s = f.latency_s
            if f.jitter_s:
                delay_s += rng.uniform(0.0, f.jitter_s)
            if f.reorder and rng.random() < f.reorder:
                delay_s += f.reorder_delay_s
                st.reordered += 1
            if delay_s > 0.0:
                st.delayed += 1
                self.later(delay_s, self.deliver, data)
            else:
                self.deliver(data)
