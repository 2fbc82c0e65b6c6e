"""A robot's task manager: CBBA state, bundle building, and its side of the message exchange.

Each robot keeps (paper Sec. III.A): its known-task inventory; the CBBA state y (winning bids), z
(winners), clocks (s, the time it last heard of each robot: real milliseconds, not iteration counts),
bundle and path; what each neighbour is known to hold (from acknowledgements and from what it sent);
and when it last heard from each robot. It acts only on what it has received.

Deltas: a robot sends an entry only to neighbours not known to hold its current value. Knowledge comes
from acknowledgements (a neighbour acks a message sequence number, and the robot remembers what that
message carried) and from the neighbour's own messages: an entry it sent that the receiver agrees with
after conflict resolution is held by both. When the two still disagree after resolution, the receiver
marks the entry as not held, so its view goes back. An entry sent but not yet acknowledged is not
held either (the peer may have either value), so a value that changes and changes back is still sent.
That replaces CBBA's every-round full broadcast.
"""

from __future__ import annotations

import functools
import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from maptidal.allocation.consensus import RESET, UPDATE, outbids, resolve
from maptidal.allocation.messages import (
    DONE,
    ENTRY_DTYPE,
    NEVER,
    NO_WINNER,
    Message,
    MessageError,
    decode,
    encode,
    size_of,
    task_runs,
)
from maptidal.allocation.scoring import (
    AuctionParams,
    PathGeometry,
    RobotProfile,
    best_candidate,
    task_positions,
    warped_bids,
)
from maptidal.allocation.tasks import Task, task_key

MAX_ROBOTS = 250
_SENT_MEMORY = 256  # sequence numbers whose contents are remembered for late acknowledgements


@dataclass(frozen=True)
class AgentParams:
    """Timing of one robot's task manager.

    failure_timeout_s: a robot not heard of (directly or relayed) for this long is declared failed and
    its tasks are released; heartbeat_s: a robot with nothing to say still transmits this often so that
    the others know it is alive; goal_news_m: a robot whose goal has moved farther than this since its
    last message (or that became bound, or stopped being) transmits in its next slot, so that teammates
    keeping clear of its way hear of the new one (half the mission's 1 m clearance)."""

    failure_timeout_s: float = 120.0
    heartbeat_s: float = 30.0
    goal_news_m: float = 0.5

    def __post_init__(self) -> None:
        if not (self.failure_timeout_s > 0 and self.heartbeat_s > 0):
            raise ValueError("failure_timeout_s and heartbeat_s must be > 0")
        if not self.goal_news_m > 0:
            raise ValueError(f"goal_news_m must be > 0, got {self.goal_news_m!r}")
        if self.failure_timeout_s <= self.heartbeat_s:
            raise ValueError("failure_timeout_s must exceed heartbeat_s, or live robots are declared failed")


@dataclass
class AgentStats:
    """Counters of one robot's traffic."""

    messages_sent: int = 0
    bytes_sent: int = 0
    messages_accepted: int = 0
    rejected: Counter = field(default_factory=Counter)
    unknown_task_entries: int = 0


# A broadcast reaches every robot as the same bytes; decoding them once per simulation is a speed-up
# of the simulator, not of a robot (the Message is never modified by its readers).
_decode = functools.lru_cache(maxsize=256)(decode)


_UNKNOWN = -3  # a peer's view of an entry that must be sent again
_HISTORY = np.dtype([("winner", np.int64), ("bid", np.float64), ("heard_ms", np.int64)])


def _empty_history(n: int) -> np.ndarray:
    history = np.zeros(n, dtype=_HISTORY)
    history["heard_ms"] = -1
    return history


def _moved(before: np.ndarray | None, now: np.ndarray | None, distance_m: float) -> bool:
    """Whether a goal became or stopped being, or moved farther than ``distance_m``."""
    if before is None or now is None:
        return (before is None) != (now is None)
    return float(np.linalg.norm(np.asarray(now, float) - before)) > distance_m


def _ms(time_s: float) -> int:
    return round(time_s * 1000.0)


class CBBAAgent:
    """One robot's CBBA task manager (see the module docstring)."""

    def __init__(
        self,
        robot: RobotProfile,
        auction: AuctionParams | None = None,
        params: AgentParams | None = None,
    ) -> None:
        self.robot = robot
        self.index = robot.index
        self.auction = auction or AuctionParams()
        self.params = params or AgentParams()
        self.stats = AgentStats()
        # robot index -> (where it last said it was, m; when that was heard, s)
        self.peer_positions: dict[int, tuple[np.ndarray, float]] = {}
        # robot index -> whether its last message said it was giving way to a teammate; and whether this
        # robot gives way now (set by whoever flies it, sent in its messages)
        self.peer_giving_way: dict[int, bool] = {}
        # where each teammate's last message said it was bound (None: nowhere, it holds where it is)
        self.peer_goals: dict[int, np.ndarray | None] = {}
        self.goal: np.ndarray | None = None  # where this robot is bound, for its messages (set by its owner)
        self._sent_goal: np.ndarray | None = None
        self.giving_way = False
        self._sent_giving_way = False
        # nothing left to do (the mission sets it): such a robot gives way to every teammate
        self.peer_idle: dict[int, bool] = {}
        self.idle = False
        self._sent_idle = False
        self.tasks: list[Task] = []
        self._slot_of: dict[int, int] = {}
        self._keys = np.zeros(0, dtype=np.int64)  # task keys in slot order
        self._sorted_keys = np.zeros(0, dtype=np.int64)
        self._sort_order = np.zeros(0, dtype=np.int64)
        self.y = np.zeros(0)
        self.z = np.zeros(0, dtype=np.int64)
        self._version = np.zeros(0, dtype=np.int64)
        self._tick = 0
        self.bundle: list[int] = []
        self.bundle_bids: list[float] = []
        self.path: list[int] = []
        self.clocks = np.full(MAX_ROBOTS, NEVER, dtype=np.int64)
        self.failed: set[int] = set()
        # my (winner, bid) each peer is known to hold; UNKNOWN when it must hear my view again
        self._peer_z: dict[int, np.ndarray] = {}
        self._peer_y: dict[int, np.ndarray] = {}
        self._peer_task: dict[int, np.ndarray] = {}  # whether each peer knows each task record
        self.bid_history: dict[int, np.ndarray] = {}  # per neighbour: what it last said per task
        self._seq = 0
        self._sent: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._last_seq_from: dict[int, int] = {}
        # (sender, seq) -> the task keys that message carried, so that a third robot's ack of it says
        # that robot holds those records too (without it, every robot relays every teammate's discoveries
        # to the others, who heard them already, and a team that all hears each other wastes its channel)
        self._heard: dict[tuple[int, int], np.ndarray] = {}
        self._ack_owed: dict[int, int] = {}
        # task key -> when this robot learned it (discovered, or first heard), for tasks given a time
        self.learned_s: dict[int, float] = {}
        self._last_sent_ms: int | None = None
        self._geometry: PathGeometry | None = None
        self._feasible = np.zeros(0, dtype=bool)
        self._task_counter = 0
        self.last_change_s = 0.0
        self.alive = True
        # standing down (the mission sets it, ``stand_down``): it bids on nothing and holds nothing, for
        # now, while it cannot fly to any task (a robot that has lost its position for good)
        self.standing_down = False
        self.last_message_had_content = False
        self._bids_lowered = False  # some bid fell or was withdrawn since the last bundle check

    # ------------------------------------------------------------------ tasks
    @property
    def n_tasks(self) -> int:
        """Number of tasks this robot knows."""
        return len(self.tasks)

    @property
    def keys(self) -> np.ndarray:
        """Keys of the known tasks, in local slot order."""
        return self._keys

    def add_tasks(
        self,
        tasks: list[Task],
        from_robot: int | None = None,
        known_to: tuple[int, ...] = (),
        now_s: float | None = None,
    ) -> int:
        """Learn tasks (duplicates ignored); returns how many were new.

        from_robot: the neighbour the records came from (it knows them); known_to: robots known to hold
        the records already (for a mission plan every robot was given); now_s: when, kept in
        :attr:`learned_s` (how fast a robot's discoveries reach its team)."""
        fresh = [t for t in tasks if t.key not in self._slot_of]
        fresh = list({t.key: t for t in fresh}.values())
        if from_robot is not None:
            for t in tasks:
                if t.key in self._slot_of:
                    self._peer_task_array(from_robot)[self._slot_of[t.key]] = True
        if not fresh:
            return 0
        start = len(self.tasks)
        for offset, task in enumerate(fresh):
            self._slot_of[task.key] = start + offset
            if now_s is not None:
                self.learned_s[task.key] = now_s
        self.tasks.extend(fresh)
        n_new = len(fresh)
        self.y = np.concatenate([self.y, np.zeros(n_new)])
        self.z = np.concatenate([self.z, np.full(n_new, NO_WINNER, dtype=np.int64)])
        self._version = np.concatenate([self._version, np.zeros(n_new, dtype=np.int64)])
        self._feasible = np.concatenate(
            [self._feasible, np.array([self.robot.can_do(t.requires) for t in fresh], dtype=bool)]
        )
        for peer in list(self._peer_z):
            # a peer that learns a task starts it at "nobody wins"
            self._peer_z[peer] = np.concatenate(
                [self._peer_z[peer], np.full(n_new, NO_WINNER, dtype=np.int64)]
            )
            self._peer_y[peer] = np.concatenate([self._peer_y[peer], np.zeros(n_new)])
            self._peer_task[peer] = np.concatenate([self._peer_task[peer], np.zeros(n_new, dtype=bool)])
            self.bid_history[peer] = np.concatenate([self.bid_history[peer], _empty_history(n_new)])
        for peer in (*known_to, *(() if from_robot is None else (from_robot,))):
            if peer != self.index:
                self._peer_task_array(peer)[start:] = True
        self._keys = np.array([t.key for t in self.tasks], dtype=np.int64)
        self._sort_order = np.argsort(self._keys, kind="stable")
        self._sorted_keys = self._keys[self._sort_order]
        self._geometry = None
        return n_new

    def discover_task(
        self, position, direction=(1.0, 0.0, 0.0), requires: int | tuple[str, ...] = (), now_s: float = 0.0
    ) -> Task:
        """Mint a task this robot discovered (key = this robot's index and its own counter) and learn it."""
        task = Task.create(task_key(self.index, self._task_counter), position, direction, requires)
        self._task_counter += 1
        self.add_tasks([task], now_s=now_s)
        self.last_change_s = max(self.last_change_s, now_s)
        return task

    def slots_of(self, keys: np.ndarray) -> np.ndarray:
        """Local slots of task keys; -1 for keys this robot does not know."""
        keys = np.asarray(keys, dtype=np.int64)
        if not len(self._sorted_keys):
            return np.full(len(keys), -1, dtype=np.int64)
        at = np.searchsorted(self._sorted_keys, keys).clip(0, len(self._sorted_keys) - 1)
        found = self._sorted_keys[at] == keys
        return np.where(found, self._sort_order[at], -1)

    def is_open(self, key: int) -> bool:
        """True when this robot knows the task ``key`` and does not believe it done."""
        slot = self._slot_of.get(key)
        return slot is not None and self.z[slot] != DONE

    def mark_done(self, key: int, now_s: float) -> bool:
        """Record a completed task: it leaves the auction everywhere once the news spreads."""
        slot = self._slot_of.get(key)
        if slot is None or self.z[slot] == DONE:
            return False
        self._set(slot, DONE, 0.0)
        self._drop_from_bundle({slot})
        self.last_change_s = now_s
        return True

    def give_up(self, key: int, now_s: float) -> bool:
        """Stop bidding on task ``key`` for good: this robot found it cannot do it (it tried, and timed
        out). If it holds the task it releases it, with every later bundle entry (their marginal bids
        assumed it, as when a robot is outbid), and the release spreads like any lost bid, so another
        robot can win it. Returns False when the task is unknown or already given up."""
        slot = self._slot_of.get(key)
        if slot is None or not self._feasible[slot]:
            return False
        self._feasible[slot] = False
        if slot in self.bundle:
            released = self.bundle[self.bundle.index(slot) :]
            mine = [j for j in released if self.z[j] == self.index]  # not those another robot holds now
            if mine:
                self._set(np.array(mine), NO_WINNER, 0.0)
            self._drop_from_bundle(set(released))
            self._bids_lowered = True
        self.last_change_s = now_s
        return True

    def stand_down(self, now_s: float) -> bool:
        """Stop bidding for now and release every task held: the robot cannot fly to any task (it does not
        know where it is). The release spreads like any lost bid, so teammates win the tasks. Unlike
        ``give_up``, not for good: ``resume`` bids again. Returns False when already standing down."""
        if self.standing_down:
            return False
        self.standing_down = True
        mine = [j for j in self.bundle if self.z[j] == self.index]
        if mine:
            self._set(np.array(mine), NO_WINNER, 0.0)
        self._drop_from_bundle(set(self.bundle))
        self.last_change_s = now_s
        return True

    def resume(self, now_s: float) -> bool:
        """Bid again after ``stand_down``. Returns False when not standing down."""
        if not self.standing_down:
            return False
        self.standing_down = False
        self.last_change_s = now_s
        return True

    def set_position(self, position) -> None:
        """Move the start of the path (the robot's current position) for future bids."""
        self.robot.position = np.asarray(position, dtype=float)
        self._geometry = None

    # ------------------------------------------------------------------ state changes
    def _peer_task_array(self, peer: int) -> np.ndarray:
        if peer not in self._peer_task:
            self._peer_z[peer] = np.full(self.n_tasks, NO_WINNER, dtype=np.int64)
            self._peer_y[peer] = np.zeros(self.n_tasks)
            self._peer_task[peer] = np.zeros(self.n_tasks, dtype=bool)
            self.bid_history[peer] = _empty_history(self.n_tasks)
        return self._peer_task[peer]

    def neighbour_bids(self, peer: int) -> dict[int, tuple[int, float, float]]:
        """What `peer` last told this robot about each task: key -> (winner, bid, time heard in s)."""
        history = self.bid_history.get(peer)
        if history is None:
            return {}
        said = np.flatnonzero(history["heard_ms"] >= 0)
        return {
            self.tasks[j].key: (
                int(history["winner"][j]),
                float(history["bid"][j]),
                history["heard_ms"][j] / 1000,
            )
            for j in said
        }

    def _set(self, slots, winner, bid) -> None:
        self._tick += 1
        self.z[slots] = winner
        self.y[slots] = bid
        self._version[slots] = self._tick

    def _drop_from_bundle(self, slots: set[int]) -> None:
        keep = [n for n, j in enumerate(self.bundle) if j not in slots]
        self.bundle = [self.bundle[n] for n in keep]
        self.bundle_bids = [self.bundle_bids[n] for n in keep]
        self.path = [j for j in self.path if j not in slots]

    def _release_outbid(self) -> None:
        """Drop the first bundle entry this robot no longer wins and every entry after it (CBBA)."""
        lost = next((n for n, j in enumerate(self.bundle) if self.z[j] != self.index), None)
        if lost is None:
            return
        later = [j for j in self.bundle[lost + 1 :] if self.z[j] == self.index]
        if later:
            self._set(np.array(later), NO_WINNER, 0.0)
        self._drop_from_bundle(set(self.bundle[lost:]))

    def live_peers(self) -> list[int]:
        """Robots heard of and not declared failed."""
        heard = np.flatnonzero(self.clocks != NEVER)
        return [int(p) for p in heard if p != self.index and p not in self.failed]

    # ------------------------------------------------------------------ bundle phase
    def _bids(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._geometry is None:
            self._geometry = PathGeometry(self.robot.position, task_positions(self.tasks))
        return warped_bids(
            self._geometry, self.path, self.bundle_bids, self.robot.cost_per_m, self.auction.task_value
        )

    def _biddable(self, raw: np.ndarray, bid: np.ndarray, in_bundle: np.ndarray | None = None) -> np.ndarray:
        if in_bundle is None:
            in_bundle = np.zeros(self.n_tasks, dtype=bool)
            in_bundle[self.bundle] = True
        holder = np.where(self.z >= 0, self.z, np.iinfo(np.int64).max)
        beats = outbids(bid, self.index, self.y, holder)
        return self._feasible & ~in_bundle & (self.z != DONE) & (raw > 0) & (bid > 0) & beats

    def _recheck_bundle(self) -> bool:
        """Replay the bundle's construction against the current bids; release from the first entry that
        is no longer this robot's best choice. Returns True when it released something.

        A robot blocked from a task by a bid that is later withdrawn (the holder lost an earlier entry)
        has meanwhile bid on worse tasks, and under bid warping those lower its cap for good. Releasing
        them when the better task comes free keeps every bundle what a greedy construction against the
        current bids would build, which is what makes the converged assignment the sequential greedy one.
        """
        if not self.bundle:
            return False
        own = np.zeros(self.n_tasks, dtype=bool)
        own[self.bundle] = True
        path: list[int] = []
        bids: list[float] = []
        in_prefix = np.zeros(self.n_tasks, dtype=bool)
        for n, held in enumerate(self.bundle):
            raw, bid, position = warped_bids(
                self._geometry, path, bids, self.robot.cost_per_m, self.auction.task_value
            )
            candidates = np.flatnonzero(((self._biddable(raw, bid, in_prefix)) | own) & ~in_prefix)
            if best_candidate(candidates, self._keys, raw, bid) != held:
                released = self.bundle[n:]
                self._set(np.array(released), NO_WINNER, 0.0)
                self._drop_from_bundle(set(released))
                return True
            path.insert(int(position[held]), held)
            bids.append(float(bid[held]))
            in_prefix[held] = True
        return False

    def build_bundle(self, now_s: float = 0.0) -> bool:
        """CBBA's bundle phase: add the best outbidding task until none is left or the bundle is full.

        Returns True when the bundle changed."""
        if not self.alive or self.standing_down or not self.n_tasks:
            return False
        limit = self.auction.bundle_limit or math.inf
        if self._geometry is None:
            self._geometry = PathGeometry(self.robot.position, task_positions(self.tasks))
        changed = False
        if self._bids_lowered:
            changed = self._recheck_bundle()
            self._bids_lowered = False
        while len(self.bundle) < limit:
            raw, bid, position = self._bids()
            candidates = np.flatnonzero(self._biddable(raw, bid))
            if not len(candidates):
                break
            best = best_candidate(candidates, self._keys, raw, bid)
            self.path.insert(int(position[best]), int(best))
            self.bundle.append(int(best))
            self.bundle_bids.append(float(bid[best]))
            self._set(best, self.index, float(bid[best]))
            changed = True
        if changed:
            self.last_change_s = now_s
        return changed

    def would_bid(self) -> bool:
        """True when a bundle phase now would add a task (a dry run for convergence checks)."""
        if not self.alive or self.standing_down or not self.n_tasks:
            return False
        if self.auction.bundle_limit and len(self.bundle) >= self.auction.bundle_limit:
            return False
        raw, bid, _ = self._bids()
        return bool(self._biddable(raw, bid).any())

    # ------------------------------------------------------------------ receiving
    def check_failures(self, now_s: float) -> list[int]:
        """Declare robots not heard of for failure_timeout_s failed and release their tasks."""
        now = _ms(now_s)
        newly = [
            p for p in self.live_peers() if now - self.clocks[p] > self.params.failure_timeout_s * 1000.0
        ]
        for peer in newly:
            self.failed.add(peer)
            held = np.flatnonzero(self.z == peer)
            if len(held):
                self._set(held, NO_WINNER, 0.0)
                self.last_change_s = now_s
                self._bids_lowered = True
        return newly

    def receive(self, data: bytes, now_s: float) -> bool:
        """Process one received message; returns False (and counts why) when it is rejected."""
        try:
            message = _decode(data)
        except MessageError as error:
            self.stats.rejected[error.reason] += 1
            return False
        sender = message.sender
        if (
            sender == self.index
            or sender >= MAX_ROBOTS
            or len(message.clocks_ms) > MAX_ROBOTS
            or (message.winners >= MAX_ROBOTS).any()
        ):
            self.stats.rejected["malformed"] += 1
            return False
        if message.seq <= self._last_seq_from.get(sender, 0):
            self.stats.rejected["replayed"] += 1  # a replay, or older than one already processed
            return False
        self._last_seq_from[sender] = message.seq
        self.stats.messages_accepted += 1
        if message.position is not None:
            self.peer_positions[sender] = (np.asarray(message.position, float), now_s)
        self.peer_goals[sender] = None if message.goal is None else np.asarray(message.goal, float)
        self.peer_giving_way[sender] = message.giving_way
        self.peer_idle[sender] = message.idle
        self._peer_task_array(sender)
        self._apply_acks(sender, message.acks)
        if message.tasks:
            self.add_tasks(message.tasks, from_robot=sender, now_s=now_s)
            self._heard[(sender, message.seq)] = np.array([t.key for t in message.tasks], np.int64)
            self._heard.pop((sender, message.seq - _SENT_MEMORY), None)
        # an ack tells the sender that every entry landed; an entry on a task this robot has no record of
        # is dropped, so the message goes unacknowledged and the sender repeats the entry (a robot that
        # joined after a task was done had otherwise been counted as knowing it done, and flew to it)
        if message.has_content and not (len(message.keys) and (self.slots_of(message.keys) < 0).any()):
            self._ack_owed[sender] = message.seq
        clocks_sender = np.full(MAX_ROBOTS, NEVER, dtype=np.int64)
        clocks_sender[: len(message.clocks_ms)] = message.clocks_ms
        # a robot heard of more recently than when this robot gave up on it is alive after all
        self.failed = {p for p in self.failed if p != sender and clocks_sender[p] <= self.clocks[p]}
        if len(message.keys):
            self._resolve(message, clocks_sender, now_s)
        now = _ms(now_s)
        self.clocks = np.maximum(self.clocks, clocks_sender)
        self.clocks[sender] = max(now, self.clocks[sender])
        self.clocks[self.index] = max(self.clocks[self.index], now)
        return True

    def _apply_acks(self, sender: int, acks: list[tuple[int, int]]) -> None:
        for robot, seq in acks:
            overheard = self._heard.get((robot, seq))
            if robot != self.index and overheard is not None:
                # the sender acknowledges a message this robot heard too: it holds the records in it
                slots = self.slots_of(overheard)
                self._peer_task[sender][slots[slots >= 0]] = True
            if robot != self.index or seq not in self._sent:
                continue
            slots, winners, bids, task_slots = self._sent[seq]
            self._peer_z[sender][slots], self._peer_y[sender][slots] = winners, bids
            self._peer_task[sender][task_slots] = True

    def _resolve(self, message: Message, clocks_sender: np.ndarray, now_s: float) -> None:
        sender = message.sender
        slots = self.slots_of(message.keys)
        known = slots >= 0
        z_k, y_k = message.winners, message.bids
        if not known.all():
            self.stats.unknown_task_entries += int((~known).sum())
            slots, z_k, y_k = slots[known], z_k[known], y_k[known]
        self._peer_task[sender][slots] = True
        history = self.bid_history[sender]
        history["winner"][slots], history["bid"][slots], history["heard_ms"][slots] = z_k, y_k, _ms(now_s)
        if (z_k == DONE).any():
            news = (z_k == DONE) & (self.z[slots] != DONE)
            if news.any():
                self._set(slots[news], DONE, 0.0)
                self._drop_from_bundle(set(slots[news].tolist()))
                self.last_change_s = now_s
        # done is final: a peer that has not heard yet (its bid on a task done here) changes nothing
        live = (z_k != DONE) & (self.z[slots] != DONE)
        slots, z_k, y_k = slots[live], z_k[live], y_k[live]
        if self.failed:
            gone = np.isin(z_k, list(self.failed))
            z_k, y_k = np.where(gone, NO_WINNER, z_k), np.where(gone, 0.0, y_k)
        held_z, held_y = self._peer_z[sender], self._peer_y[sender]
        # identical entries resolve to no change in every row of the table; only differences need it
        differ = (self.z[slots] != z_k) | (self.y[slots] != y_k)
        same = slots[~differ]
        held_z[same], held_y[same] = self.z[same], self.y[same]
        if not differ.any():
            return
        slots, z_k, y_k = slots[differ], z_k[differ], y_k[differ]
        action = resolve(
            self.index, sender, self.z[slots], self.y[slots], z_k, y_k, self.clocks, clocks_sender
        )
        update = action == UPDATE
        reset = (action == RESET) & (self.z[slots] != NO_WINNER)
        if update.any():
            self._set(slots[update], z_k[update], y_k[update])
        if reset.any():
            self._set(slots[reset], NO_WINNER, 0.0)
        if update.any() or reset.any():
            self.last_change_s = now_s
            self._bids_lowered = True
            self._release_outbid()
        # what the sender holds: my value where we agree now; otherwise it must hear my view
        agree = (self.z[slots] == z_k) & (self.y[slots] == y_k)
        held_z[slots] = np.where(agree, self.z[slots], _UNKNOWN)
        held_y[slots] = self.y[slots]

    # ------------------------------------------------------------------ sending
    def _pending(self, peers: list[int]) -> tuple[np.ndarray, np.ndarray]:
        entries = np.zeros(self.n_tasks, dtype=bool)
        records = np.zeros(self.n_tasks, dtype=bool)
        for peer in peers:
            self._peer_task_array(peer)
            entries |= (self.z != self._peer_z[peer]) | (self.y != self._peer_y[peer])
            records |= ~self._peer_task[peer]
        return entries, records

    def has_pending(self, peers: list[int] | None = None) -> bool:
        """True when a peer lacks an entry, a task record or an ack from this robot.

        peers: whom to ask about (default: the live peers). A simulator that knows who is really
        reachable passes those, including robots this one has wrongly declared failed."""
        peers = self.live_peers() if peers is None else [p for p in peers if p != self.index]
        entries, records = self._pending(peers)
        return bool(entries.any() or records.any() or any(p in self._ack_owed for p in peers))

    def make_message(self, now_s: float, capacity_bytes: int | None = None) -> bytes | None:
        """The message for this robot's transmit slot, or None when it has nothing to say (no acks owed, no
        news of tasks, bids or of its giving way, and no heartbeat due).

        It carries the acks owed, then task records and bid entries some live peer lacks (newest
        entries first, each with its task record when needed) as far as capacity_bytes allows."""
        if not self.alive:
            return None
        now = _ms(now_s)
        self.clocks[self.index] = max(self.clocks[self.index], now)
        peers = self.live_peers()
        entries, records = self._pending(peers)
        heartbeat_due = (
            self._last_sent_ms is None or now - self._last_sent_ms >= self.params.heartbeat_s * 1000
        )
        # a teammate may be waiting to hear it
        news = (
            self.giving_way != self._sent_giving_way
            or self.idle != self._sent_idle
            or _moved(self._sent_goal, self.goal, self.params.goal_news_m)
        )
        if not (entries.any() or records.any() or self._ack_owed or heartbeat_due or news):
            return None
        n_clocks = int(np.flatnonzero(self.clocks != NEVER).max()) + 1
        acks = sorted(self._ack_owed.items())
        budget = math.inf if capacity_bytes is None else capacity_bytes
        while acks and size_of(n_clocks, len(acks), 0, 0) > budget:
            acks.pop()  # the rest stay owed for the next slot
        entry_slots = np.flatnonzero(entries)
        entry_slots = self._by_urgency(entry_slots)
        record_slots = np.flatnonzero(records)
        runs = len(task_runs([self.tasks[j] for j in record_slots]))
        if size_of(n_clocks, len(acks), len(record_slots), len(entry_slots), runs) > budget:
            record_slots, entry_slots = self._fit(budget, n_clocks, len(acks), records, entry_slots)
        self._seq += 1
        message = Message(
            sender=self.index,
            seq=self._seq,
            clocks_ms=self.clocks[:n_clocks].copy(),
            acks=acks,
            tasks=[self.tasks[s] for s in record_slots],
            keys=self._keys[entry_slots],
            winners=self.z[entry_slots],
            bids=self.y[entry_slots],
            position=tuple(float(v) for v in self.robot.position),  # type: ignore[arg-type]
            goal=None if self.goal is None else tuple(float(v) for v in self.goal),  # type: ignore[arg-type]
            giving_way=self.giving_way,
            idle=self.idle,
        )
        data = encode(message)
        self._sent[self._seq] = (entry_slots, self.z[entry_slots], self.y[entry_slots], record_slots)
        # until acknowledged, a peer may hold either its old value or this one: it must not be assumed
        # to hold the old one should this robot's value return to it
        for peer in peers:
            differs = (self._peer_z[peer][entry_slots] != message.winners) | (
                self._peer_y[peer][entry_slots] != message.bids
            )
            self._peer_z[peer][entry_slots[differs]] = _UNKNOWN
        self._sent.pop(self._seq - _SENT_MEMORY, None)
        for robot, _ in acks:
            del self._ack_owed[robot]
        self._last_sent_ms = now
        self._sent_giving_way = self.giving_way
        self._sent_idle = self.idle
        self._sent_goal = None if self.goal is None else np.array(self.goal, float)
        self.last_message_had_content = bool(len(entry_slots) or len(record_slots))
        self.stats.messages_sent += 1
        self.stats.bytes_sent += len(data)
        return data

    def _by_urgency(self, entry_slots: np.ndarray) -> np.ndarray:
        """The entries to send in the order they should go when a message cannot hold them all: tasks done
        first (news that keeps a teammate from inspecting one again), then this robot's path in the order
        it will fly it (a claim its teammates should hear before they set out too), then the rest newest
        first."""
        rank = np.full(len(entry_slots), len(self.path) + 1, np.int64)
        position = {slot: n for n, slot in enumerate(self.path)}
        for row, slot in enumerate(entry_slots.tolist()):
            if self.z[slot] == DONE:
                rank[row] = -1
            elif slot in position:
                rank[row] = position[slot]
        return entry_slots[np.lexsort((-self._version[entry_slots], rank))]

    def _fit(self, budget: float, n_clocks: int, n_acks: int, records: np.ndarray, entry_slots: np.ndarray):
        """What a full message carries, within budget, in this order:

        1. the done entries and the entry of the task this robot flies to next (:meth:`_by_urgency`'s
           first ones), each with its task record where a peer lacks it;
        2. the records of this robot's own discoveries that a peer lacks, oldest first: they leave in the
           order it made them, so each waits only for those before it (a bounded delay while it finds tasks
           slower than the channel carries them; newest first let a burst's first tasks wait for ever, and
           die with a robot that failed: issue [truthful-loop]);
        3. the rest of this robot's path, in flying order;
        4. records of other robots' discoveries that a peer lacks (relays, for peers out of their finder's
           range), oldest first;
        5. the rest of the entries in :meth:`_by_urgency` order.

        An entry travels with its task's record, since a peer drops an entry on a task it has no record
        of. Sizes count the records' runs exactly (:func:`task_runs`)."""
        next_task = self.path[0] if self.path else None
        first = [int(slot) for slot in entry_slots if self.z[slot] == DONE or slot == next_task]
        first_set = set(first)
        items: list[tuple[int | None, int | None]] = [
            (slot, slot if records[slot] else None) for slot in first
        ]
        lacking = [int(slot) for slot in np.flatnonzero(records) if slot not in first_set]
        own = [slot for slot in lacking if self._keys[slot] >> 16 == self.index]
        on_path = set(self.path)
        rest = [int(slot) for slot in entry_slots if int(slot) not in first_set]
        items += [(None, slot) for slot in own]
        items += [(slot, slot if records[slot] else None) for slot in rest if slot in on_path]
        items += [(None, slot) for slot in lacking if self._keys[slot] >> 16 != self.index]
        items += [(slot, slot if records[slot] else None) for slot in rest if slot not in on_path]
        chosen_records: list[int] = []
        chosen_entries: list[int] = []
        in_records: set[int] = set()
        in_entries: set[int] = set()
        size = size_of(n_clocks, n_acks, 0, 0)
        for entry, record in items:
            if entry is not None and entry in in_entries:
                continue
            record = None if record is None or record in in_records else record
            if entry is None and record is None:
                continue
            trial = chosen_records + ([record] if record is not None else [])
            n_entries = len(chosen_entries) + (entry is not None)
            needed = size_of(
                n_clocks, n_acks, len(trial), n_entries, len(task_runs([self.tasks[j] for j in trial]))
            )
            if needed > budget:
                if budget - size < ENTRY_DTYPE.itemsize:
                    break
                continue  # a smaller item further on may still fit
            size = needed
            if record is not None:
                chosen_records.append(record)
                in_records.add(record)
            if entry is not None:
                chosen_entries.append(entry)
                in_entries.add(entry)
        order = {slot: n for n, slot in enumerate(entry_slots.tolist())}
        chosen_entries.sort(key=order.__getitem__)  # in urgency order on the wire, as when all fit
        return np.array(chosen_records, dtype=np.int64), np.array(chosen_entries, dtype=np.int64)

    # ------------------------------------------------------------------ views
    def winners(self) -> dict[int, int]:
        """Task key -> winner index (NO_WINNER, DONE or a robot index) as this robot believes."""
        return {t.key: int(self.z[s]) for s, t in enumerate(self.tasks)}

    def path_keys(self) -> list[int]:
        """This robot's path as task keys, in execution order."""
        return [self.tasks[j].key for j in self.path]

    def path_length(self) -> float:
        """Length of this robot's path from its position, in metres."""
        if self._geometry is None:
            self._geometry = PathGeometry(self.robot.position, task_positions(self.tasks))
        return self._geometry.path_length(self.path)
