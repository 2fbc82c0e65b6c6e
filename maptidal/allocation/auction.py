"""A team auction over the acoustic channel, in simulated time.

`AuctionSimulation` runs one CBBAAgent per robot on a TDMA schedule over an AcousticChannel. In its
slot a robot reads what has arrived, declares silent robots failed, runs its bundle phase and transmits
whatever its neighbours lack. Scheduled events model the mission: robots fail or join, tasks are
discovered by a robot at a given time, tasks are completed.

The run stops once the team is quiet after the last event and after the links are healthy again: no
robot has anything its reachable neighbours lack, nothing with content is in flight, and no robot would
bid. Quiet is checked by the simulator, which sees everything; the robots themselves never do.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from maptidal.allocation.agent import AgentParams, CBBAAgent
from maptidal.allocation.messages import DONE
from maptidal.allocation.scoring import AuctionParams, RobotProfile
from maptidal.allocation.tasks import Task
from maptidal.comms.channel import AcousticChannel, ChannelParams, Delivery

EVENT_KINDS = ("fail", "join", "discover", "done")


@dataclass(frozen=True)
class AuctionEvent:
    """Something that happens to the team at time_s.

    fail: robot stops (silently); join: `profile` enters the water; discover: `robot` finds `task`
    (its key should carry that robot's index as origin); done: `robot` completes the task `task_key`."""

    time_s: float
    kind: str
    robot: int = -1
    task: Task | None = None
    task_key: int = -1
    profile: RobotProfile | None = None

    def __post_init__(self) -> None:
        if self.kind not in EVENT_KINDS:
            raise ValueError(f"unknown event kind {self.kind!r}; known: {', '.join(EVENT_KINDS)}")
        if not math.isfinite(self.time_s) or self.time_s < 0:
            raise ValueError(f"event time must be a finite time >= 0, got {self.time_s}")


@dataclass
class AuctionReport:
    """Outcome of one simulated auction (see AuctionSimulation.run)."""

    converged: bool
    sim_time_s: float
    end_time_s: float
    rounds: int
    messages: int
    bytes: int
    conflicts: int
    disagreements: int
    unassigned: list[int]
    infeasible: list[int]
    lost: list[int]
    done: list[int]
    paths: dict[int, list[int]]
    lengths: dict[int, float]
    names: dict[int, str]
    alive: list[int]
    rejected: Counter = field(default_factory=Counter)
    transmissions: list[tuple[float, int, int]] = field(default_factory=list)
    channel: dict = field(default_factory=dict)

    @property
    def max_message_bytes(self) -> int:
        """The largest message sent."""
        return max((n for _, _, n in self.transmissions), default=0)


class AuctionSimulation:
    """Decentralised CBBA over a simulated acoustic channel (see the module docstring).

    robots: the team at the start; tasks: the mission plan every starting robot knows; events: what
    happens later. Robot indices are the TDMA slot order."""

    def __init__(
        self,
        robots: list[RobotProfile],
        tasks: list[Task],
        channel: ChannelParams | None = None,
        auction: AuctionParams | None = None,
        agent_params: AgentParams | None = None,
        events: list[AuctionEvent] | tuple[AuctionEvent, ...] = (),
    ) -> None:
        self.channel = AcousticChannel(channel or ChannelParams())
        self.auction = auction or AuctionParams()
        self.agent_params = agent_params or AgentParams()
        self.events = sorted(events, key=lambda e: e.time_s)
        joiners = [e.profile for e in self.events if e.kind == "join" and e.profile is not None]
        everyone = [*robots, *joiners]
        indices = [r.index for r in everyone]
        if len(set(indices)) != len(indices):
            raise ValueError(f"robot indices must be unique, got {indices}")
        self.order = sorted(indices)
        self.names = {r.index: r.name for r in everyone}
        self.agents: dict[int, CBBAAgent] = {}
        start_indices = tuple(r.index for r in robots)
        for robot in robots:
            agent = CBBAAgent(robot, self.auction, self.agent_params)
            agent.add_tasks(list(tasks), known_to=start_indices)
            agent.clocks[list(start_indices)] = 0  # the team knows who dived together
            self.agents[robot.index] = agent
        self._inbox: dict[int, list[tuple[Delivery, bool]]] = {i: [] for i in self.order}
        self._transmitting: dict[int, list[tuple[float, float]]] = {i: [] for i in self.order}
        self.transmissions: list[tuple[float, int, int]] = []
        self.time_s = 0.0
        self._next_slot = 0  # for advance_to
        self._due_events = list(self.events)  # for advance_to, which applies them as their time comes

    # ------------------------------------------------------------------ events
    def _apply_event(self, event: AuctionEvent) -> None:
        if event.kind == "join":
            agent = CBBAAgent(event.profile, self.auction, self.agent_params)  # type: ignore[arg-type]
            agent.clocks[agent.index] = int(event.time_s * 1000)
            self.agents[agent.index] = agent
            return
        agent = self.agents.get(event.robot)
        if agent is None or not agent.alive:
            return
        if event.kind == "fail":
            agent.alive = False
        elif event.kind == "discover" and event.task is not None:
            agent.add_tasks([event.task], now_s=event.time_s)
            agent.last_change_s = event.time_s
        elif event.kind == "done":
            agent.mark_done(event.task_key, event.time_s)

    # ------------------------------------------------------------------ the loop
    def _positions(self) -> dict[int, np.ndarray]:
        return {i: a.robot.position for i, a in self.agents.items() if a.alive}

    def _slot(self, owner: int, now: float) -> None:
        agent = self.agents.get(owner)
        if agent is None or not agent.alive:
            self._inbox[owner] = []
            return
        arrived = sorted(
            (d for d in self._inbox[owner] if d[0].arrival_s <= now), key=lambda d: d[0].arrival_s
        )
        self._inbox[owner] = [d for d in self._inbox[owner] if d[0].arrival_s > now]
        for delivery, _ in arrived:
            if any(start <= delivery.arrival_s <= end for start, end in self._transmitting[owner]):
                self.channel.stats.half_duplex += 1  # it was talking when this arrived
                continue
            agent.receive(delivery.data, delivery.arrival_s)
        agent.check_failures(now)
        agent.build_bundle(now)
        capacity = None if self.channel.params.ideal else self.channel.params.max_frame_bytes
        data = agent.make_message(now, capacity)
        if data is None:
            return
        has_content = agent.last_message_had_content
        self.transmissions.append((now, owner, len(data)))
        self._transmitting[owner] = [
            *self._transmitting[owner][-3:],
            (now, now + self.channel.params.transmit_time(len(data))),
        ]
        for delivery in self.channel.transmit(owner, data, now, self._positions()):
            self._inbox[delivery.receiver].append((delivery, has_content))

    def _reachable(self, a: int, now: float) -> list[int]:
        pa = self.agents[a].robot.position
        return [
            b
            for b, other in self.agents.items()
            if b != a
            and other.alive
            and self.channel.link_up(a, b, now)
            and self.channel.in_range(pa, other.robot.position)
        ]

    def quiet(self, now: float) -> bool:
        """True when no live robot has news for a reachable neighbour, nothing with content is in flight,
        no live robot still counts on a failed one, and no robot would bid."""
        alive = [a for a in self.agents.values() if a.alive]
        dead = [i for i, a in self.agents.items() if not a.alive]
        if dead and any(np.isin(a.z, dead).any() for a in alive):
            return False
        if any(
            has
            for i in self.order
            for _, has in self._inbox[i]
            if self.agents.get(i) and self.agents[i].alive
        ):
            return False
        if any(a.has_pending(self._reachable(a.index, now)) for a in alive):
            return False
        return not any(a.would_bid() for a in alive)

    def advance_to(self, now_s: float) -> int:
        """Run every TDMA slot due by ``now_s``, and apply the events due by then (a robot joining, say),
        for a mission that steps its physics and its auction together; returns how many slots ran. (Do
        not mix with :meth:`run`.)"""
        slot_s = self.channel.params.tdma_slot_s
        ran = 0
        while self._next_slot * slot_s <= now_s:
            slot_time = self._next_slot * slot_s
            self.apply_events_due(slot_time)
            self._slot(self.order[self._next_slot % len(self.order)], slot_time)
            self._next_slot += 1
            ran += 1
        self.apply_events_due(now_s)
        self.time_s = now_s
        return ran

    def apply_events_due(self, now_s: float) -> None:
        """Apply the constructor's events due by ``now_s`` that have not been applied yet (for a mission
        that steps the auction with :meth:`advance_to`; each event is applied once)."""
        while self._due_events and self._due_events[0].time_s <= now_s:
            self._apply_event(self._due_events.pop(0))

    def run(
        self, max_time_s: float = 7200.0, progress: Callable[[float], None] | None = None
    ) -> AuctionReport:
        """Run TDMA slots until the team is quiet after the last event (or max_time_s); report."""
        slot_s = self.channel.params.tdma_slot_s
        n = len(self.order)
        settle_after = max(
            self.channel.params.healthy_after_s, max((e.time_s for e in self.events), default=0.0)
        )
        pending_events = list(self.events)
        slot = 0
        converged = False
        while True:
            now = slot * slot_s
            if now > max_time_s:
                break
            while pending_events and pending_events[0].time_s <= now:
                self._apply_event(pending_events.pop(0))
            self._slot(self.order[slot % n], now)
            slot += 1
            if slot % n == 0:
                if progress is not None:
                    progress(now)
                if now >= settle_after and not pending_events and self.quiet(now):
                    converged = True
                    break
        self.time_s = slot * slot_s
        return self.report(converged)

    # ------------------------------------------------------------------ outcome
    def report(self, converged: bool) -> AuctionReport:
        """The state of the team now, as an AuctionReport."""
        alive = [a for a in self.agents.values() if a.alive]
        holders: Counter = Counter(a.tasks[j].key for a in alive for j in a.bundle)
        conflicts = sum(1 for c in holders.values() if c > 1)
        views = [a.winners() for a in alive]
        # every task any robot ever knew, so that tasks of a team that died out are not forgotten
        tasks_by_key = {t.key: t for a in self.agents.values() for t in a.tasks}
        all_keys = sorted(tasks_by_key)
        disagreements = sum(1 for k in all_keys if len({v.get(k) for v in views}) > 1)
        done = {k for v in views for k, w in v.items() if w == DONE}
        known_alive = {t.key for a in alive for t in a.tasks}
        # infeasible: no live robot has what the task needs; lost: only failed robots ever knew it
        unassigned, infeasible, lost = [], [], []
        for key in all_keys:
            if key in done or key in holders:
                continue
            if key not in known_alive:
                lost.append(key)
            elif any(a.robot.can_do(tasks_by_key[key].requires) for a in alive):
                unassigned.append(key)
            else:
                infeasible.append(key)
        last_change = max((a.last_change_s for a in self.agents.values()), default=0.0)
        cycle = self.channel.params.tdma_slot_s * len(self.order)
        rejected: Counter = Counter()
        for a in self.agents.values():
            rejected.update(a.stats.rejected)
        return AuctionReport(
            converged=converged,
            sim_time_s=last_change,
            end_time_s=self.time_s,
            rounds=math.ceil(last_change / cycle - 1e-9) if cycle > 0 else 0,
            messages=len(self.transmissions),
            bytes=sum(n for _, _, n in self.transmissions),
            conflicts=conflicts,
            disagreements=disagreements,
            unassigned=unassigned,
            infeasible=infeasible,
            lost=lost,
            done=sorted(done),
            paths={a.index: a.path_keys() for a in alive},
            lengths={a.index: a.path_length() for a in alive},
            names=dict(self.names),
            alive=[a.index for a in alive],
            rejected=rejected,
            transmissions=list(self.transmissions),
            channel=vars(self.channel.stats).copy(),
        )
