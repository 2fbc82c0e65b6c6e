"""A literal, loop-by-loop CBBA: the test oracle for the conflict table and the speed baseline.

Synchronous rounds on a fully connected, lossless network; every robot broadcasts its full (y, z, s)
every round, as in Choi, Brunet & How (2009). Scores are the same path-insertion rewards with bid
warping as maptidal.allocation, and the same bundle re-check (a robot releases its bundle from the first
entry that is no longer its best choice), but every quantity is computed with plain Python loops over
tasks and insertion positions, and the conflict table is written out case by case from
docs/references.md, independently of maptidal.allocation.consensus.
"""

from __future__ import annotations

import math

import numpy as np

NONE = None  # "no winner" is None here, never 0 (agent 0 exists)


def literal_action(i, k, z_i, y_i, z_k, y_k, s_i: dict, s_k: dict) -> str:
    """The table of docs/references.md for one task: 'update', 'reset' or 'leave'."""

    def newer(m):
        return s_k.get(m, -1) > s_i.get(m, -1)

    def higher(bid_a, robot_a, bid_b, robot_b):
        return bid_a > bid_b or (bid_a == bid_b and robot_a < robot_b)

    sender_bid_higher = higher(y_k, z_k, y_i, z_i) if z_k is not NONE and z_i is not NONE else y_k > y_i
    if z_k == k:
        if z_i == i:
            return "update" if sender_bid_higher else "leave"
        if z_i == k:
            return "update"
        if z_i is NONE:
            return "update"
        m = z_i
        return "update" if newer(m) or sender_bid_higher else "leave"
    if z_k == i:
        if z_i == i:
            return "leave"
        if z_i == k:
            return "reset"
        if z_i is NONE:
            return "leave"
        m = z_i
        return "reset" if newer(m) else "leave"
    if z_k is not NONE:
        m = z_k
        if z_i == i:
            return "update" if newer(m) and sender_bid_higher else "leave"
        if z_i == k:
            return "update" if newer(m) else "reset"
        if z_i == m:
            return "update" if newer(m) else "leave"
        if z_i is NONE:
            return "update" if newer(m) else "leave"
        n = z_i
        if newer(m) and newer(n):
            return "update"
        if newer(m) and sender_bid_higher:
            return "update"
        if newer(n) and s_i.get(m, -1) > s_k.get(m, -1):
            return "reset"
        return "leave"
    # sender thinks nobody
    if z_i == i:
        return "leave"
    if z_i == k:
        return "update"
    if z_i is NONE:
        return "leave"
    m = z_i
    return "update" if newer(m) else "leave"


def _distance(a, b) -> float:
    return math.sqrt(sum((a[d] - b[d]) ** 2 for d in range(3)))


def _f32(value: float) -> float:
    return float(np.float32(value))


class LiteralRobot:
    """One robot of the literal CBBA."""

    def __init__(self, index, start, cost_per_m, capabilities, tasks, task_value, bundle_limit):
        self.i = index
        self.start = [float(v) for v in start]
        self.cost_per_m = cost_per_m
        self.capabilities = capabilities
        self.tasks = tasks  # list of (key, position, requires)
        self.value = task_value
        self.limit = bundle_limit or math.inf
        self.y = {t[0]: 0.0 for t in tasks}
        self.z = {t[0]: NONE for t in tasks}
        self.s = {}
        self.bundle, self.bids, self.path = [], [], []

    def _pos(self, key):
        return next(t[1] for t in self.tasks if t[0] == key)

    def _best_insertion(self, path, key):
        p = self._pos(key)
        best, best_at = math.inf, 0
        for n in range(len(path) + 1):
            before = self.start if n == 0 else self._pos(path[n - 1])
            if n < len(path):
                after = self._pos(path[n])
                extra = _distance(before, p) + _distance(p, after) - _distance(before, after)
            else:
                extra = _distance(before, p)
            if extra < best:
                best, best_at = extra, n
        return best, best_at

    def _choice(self, path, bids, exclude, own):
        cap = bids[-1] if bids else math.inf
        best = None
        for key, _, requires in self.tasks:
            if key in exclude or requires & ~self.capabilities or self.z[key] == "done":
                continue
            extra, at = self._best_insertion(path, key)
            raw = self.value - self.cost_per_m * extra
            bid = _f32(min(raw, cap))
            holder = self.z[key]
            beats = bid > self.y[key] or (bid == self.y[key] and holder is not NONE and self.i < holder)
            if raw <= 0 or bid <= 0 or not (beats or key in own):
                continue
            rank = (bid, raw, -key)
            if best is None or rank > best[0]:
                best = (rank, key, at, bid)
        return best

    def bundle_phase(self):
        own = set(self.bundle)
        path, bids = [], []
        for n, held in enumerate(self.bundle):  # re-check the bundle against the current bids
            best = self._choice(path, bids, set(self.bundle[:n]), own)
            if best is None or best[1] != held:
                for key in self.bundle[n:]:
                    self.y[key], self.z[key] = 0.0, NONE
                self.bundle, self.bids = self.bundle[:n], self.bids[:n]
                self.path = [key for key in self.path if key in self.bundle]
                break
            path.insert(best[2], held)
            bids.append(best[3])
        while len(self.bundle) < self.limit:
            best = self._choice(self.path, self.bids, set(self.bundle), set())
            if best is None:
                break
            _, key, at, bid = best
            self.bundle.append(key)
            self.bids.append(bid)
            self.path.insert(at, key)
            self.y[key], self.z[key] = bid, self.i

    def receive(self, k, y_k, z_k, s_k, now):
        for key in self.y:
            if z_k[key] == "done" or self.z[key] == "done":
                continue
            action = literal_action(self.i, k, self.z[key], self.y[key], z_k[key], y_k[key], self.s, s_k)
            if action == "update":
                self.y[key], self.z[key] = y_k[key], z_k[key]
            elif action == "reset":
                self.y[key], self.z[key] = 0.0, NONE
        for m, t in s_k.items():
            if m != self.i:
                self.s[m] = max(self.s.get(m, -1), t)
        self.s[k] = now
        for n, key in enumerate(self.bundle):  # outbid: release this entry and every later one
            if self.z[key] != self.i:
                for later in self.bundle[n + 1 :]:
                    if self.z[later] == self.i:
                        self.y[later], self.z[later] = 0.0, NONE
                self.bundle, self.bids = self.bundle[:n], self.bids[:n]
                self.path = [p for p in self.path if p in self.bundle]
                break


def literal_cbba(robots, tasks, task_value=1000.0, bundle_limit=0, max_rounds=1000):
    """Run synchronous CBBA; returns ({robot index: path keys}, rounds). robots/tasks are
    maptidal RobotProfile and Task objects (only their numbers are used)."""
    plain = [(t.key, [float(v) for v in t.position], t.requires) for t in tasks]
    team = [
        LiteralRobot(r.index, r.position, r.cost_per_m, r.capabilities, plain, task_value, bundle_limit)
        for r in robots
    ]
    for rounds in range(1, max_rounds + 1):
        before = [(dict(r.y), dict(r.z), list(r.bundle)) for r in team]
        for robot in team:
            robot.bundle_phase()
        sent = [(r.i, dict(r.y), dict(r.z), {**r.s, r.i: rounds}) for r in team]
        for robot in team:
            for k, y_k, z_k, s_k in sent:
                if k != robot.i:
                    robot.receive(k, y_k, z_k, s_k, rounds)
        after = [(dict(r.y), dict(r.z), list(r.bundle)) for r in team]
        if after == before:
            return {r.i: list(r.path) for r in team}, rounds
    raise RuntimeError("literal CBBA did not converge")
