"""An acoustic modem channel: range, bandwidth, propagation delay, loss and intermittent links.

Time is simulated, never slept, and everything random comes from one seeded generator per channel (and
one per link for random outages), so a seed reproduces a run exactly. Medium access is TDMA: robots
transmit in turn, one slot each, which also keeps every modem half-duplex (a robot cannot hear while it
transmits; `AcousticChannel.half_duplex_loss` drops what arrives then).

Defaults follow what acoustic modems offer: 100 to 1000 bit/s (issue #5; e.g. the Water Linked M64 at
64 bit/s and the EvoLogics S2C M at up to ~13.9 kbit/s bracket it), sound speed 1500 m/s in water.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Outage:
    """A scheduled outage: links are down from start_s to end_s, for one pair or (robots None) for all."""

    start_s: float
    end_s: float
    robots: tuple[int, int] | None = None

    def covers(self, a: int, b: int, time_s: float) -> bool:
        """True when this outage takes the a-b link down at time_s."""
        if not self.start_s <= time_s < self.end_s:
            return False
        return self.robots is None or set(self.robots) == {a, b}


@dataclass(frozen=True)
class ChannelParams:
    """Acoustic channel parameters.

    bandwidth_bps: modem bit rate (math.inf for an ideal channel); loss: probability that a packet is
    lost on a link; range_m: links longer than this do not work; latency_s: fixed modem latency on top
    of transmission and propagation; jitter_s: uniform extra delay (lets packets overtake each other);
    outages: scheduled link outages; mean_up_s / mean_down_s: random on/off links with exponential
    periods (0 = off) until random_outages_until_s; max_frame_bytes: the modem's largest packet;
    guard_s: TDMA guard time; slot_s: TDMA slot (default: one full frame + propagation across range_m
    + latency + jitter + guard)."""

    bandwidth_bps: float = 500.0
    loss: float = 0.0
    range_m: float = 100.0
    latency_s: float = 0.0
    jitter_s: float = 0.0
    sound_speed_mps: float = 1500.0
    seed: int = 1
    outages: tuple[Outage, ...] = ()
    mean_up_s: float = 0.0
    mean_down_s: float = 0.0
    random_outages_until_s: float = math.inf
    max_frame_bytes: int = 256
    guard_s: float = 0.05
    slot_s: float | None = None

    def __post_init__(self) -> None:
        checks = {
            "bandwidth_bps must be > 0": self.bandwidth_bps > 0,
            "loss must be in [0, 1)": 0 <= self.loss < 1,
            "range_m must be > 0": self.range_m > 0,
            "latency_s and jitter_s must be >= 0": self.latency_s >= 0 and self.jitter_s >= 0,
            "sound_speed_mps must be > 0": self.sound_speed_mps > 0,
            "mean_up_s and mean_down_s must be >= 0": self.mean_up_s >= 0 and self.mean_down_s >= 0,
            "max_frame_bytes must be >= 64": self.max_frame_bytes >= 64,
            "guard_s must be >= 0": self.guard_s >= 0,
            "slot_s must be > 0": self.slot_s is None or self.slot_s > 0,
        }
        for message, ok in checks.items():
            if not ok:
                raise ValueError(f"channel: {message}")
        for outage in self.outages:
            if not outage.end_s >= outage.start_s:
                raise ValueError(f"channel: outage ends before it starts: {outage}")

    @property
    def ideal(self) -> bool:
        """True for unlimited bandwidth (frames have no size limit)."""
        return math.isinf(self.bandwidth_bps)

    def transmit_time(self, n_bytes: int) -> float:
        """Seconds to put n_bytes on the water."""
        return 0.0 if self.ideal else 8.0 * n_bytes / self.bandwidth_bps

    @property
    def tdma_slot_s(self) -> float:
        """The TDMA slot length."""
        if self.slot_s is not None:
            return self.slot_s
        propagation = 0.0 if math.isinf(self.range_m) else self.range_m / self.sound_speed_mps
        frame = self.transmit_time(self.max_frame_bytes)
        return frame + propagation + self.latency_s + self.jitter_s + self.guard_s

    @property
    def healthy_after_s(self) -> float:
        """Time after which no scheduled or random outage takes a link down."""
        scheduled = max((o.end_s for o in self.outages), default=0.0)
        randomised = self.random_outages_until_s if self.mean_down_s > 0 and self.mean_up_s > 0 else 0.0
        return max(scheduled, randomised)


@dataclass
class Delivery:
    """A packet on its way: who receives what, and when it arrives."""

    arrival_s: float
    receiver: int
    sender: int
    data: bytes
    sent_s: float = 0.0


@dataclass
class ChannelStats:
    """Counters of what happened to packets."""

    transmissions: int = 0
    bytes: int = 0
    delivered: int = 0
    lost: int = 0
    out_of_range: int = 0
    link_down: int = 0
    half_duplex: int = 0


class AcousticChannel:
    """Deterministic simulated acoustic broadcast channel (see module docstring)."""

    def __init__(self, params: ChannelParams) -> None:
        self.params = params
        self.stats = ChannelStats()
        self._rng = np.random.default_rng(params.seed)
        self._links: dict[tuple[int, int], list[float]] = {}

    def _random_link_up(self, a: int, b: int, time_s: float) -> bool:
        p = self.params
        if p.mean_up_s <= 0 or p.mean_down_s <= 0 or time_s >= p.random_outages_until_s:
            return True
        pair = (min(a, b), max(a, b))
        switches = self._links.setdefault(pair, [])
        # up until switches[0], down until switches[1], ...; each period drawn from its own seed, so the
        # schedule does not depend on the order in which links are queried
        while not switches or switches[-1] <= time_s:
            n = len(switches)
            mean = p.mean_up_s if n % 2 == 0 else p.mean_down_s
            period = float(np.random.default_rng([p.seed, *pair, n]).exponential(mean))
            switches.append((switches[-1] if switches else 0.0) + period)
        down = int(np.searchsorted(switches, time_s, side="right")) % 2 == 1
        return not down

    def link_up(self, a: int, b: int, time_s: float) -> bool:
        """True when the a-b link is not in a scheduled or random outage at time_s."""
        if any(o.covers(a, b, time_s) for o in self.params.outages):
            return False
        return self._random_link_up(a, b, time_s)

    def in_range(self, position_a: np.ndarray, position_b: np.ndarray) -> bool:
        """True when two positions are within the modem range."""
        return float(np.linalg.norm(np.asarray(position_a) - np.asarray(position_b))) <= self.params.range_m

    def transmit(
        self, sender: int, data: bytes, time_s: float, positions: dict[int, np.ndarray]
    ) -> list[Delivery]:
        """Broadcast data from sender at time_s to every other robot in `positions`; returns what arrives."""
        p = self.params
        self.stats.transmissions += 1
        self.stats.bytes += len(data)
        duration = p.transmit_time(len(data))
        deliveries = []
        for receiver in sorted(positions):
            if receiver == sender:
                continue
            distance = float(np.linalg.norm(positions[receiver] - positions[sender]))
            lost_draw, jitter_draw = self._rng.random(2)  # two draws per link, always, for determinism
            if distance > p.range_m:
                self.stats.out_of_range += 1
                continue
            if not self.link_up(sender, receiver, time_s):
                self.stats.link_down += 1
                continue
            if lost_draw < p.loss:
                self.stats.lost += 1
                continue
            arrival = (
                time_s + duration + distance / p.sound_speed_mps + p.latency_s + jitter_draw * p.jitter_s
            )
            deliveries.append(Delivery(arrival, receiver, sender, data, time_s))
            self.stats.delivered += 1
        return deliveries
