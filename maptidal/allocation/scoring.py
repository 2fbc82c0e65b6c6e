"""Bids for the auction: path-insertion rewards with bid warping.

Following the paper (Sec. III.A), a robot's reward for a task is what the task is worth minus the extra
travel it costs when inserted at the best position of the robot's current path (the path starts at the
robot's position). Travel is priced per robot: time at the robot's speed plus an optional energy term
per metre. That marginal score is NOT diminishing in the bundle (a task next to one already won gets
cheaper), and CBBA's convergence proof needs diminishing marginal gain (Choi, Brunet & How 2009,
docs/references.md). Bid warping restores it: each new bid is capped at the smallest bid already
in the bundle, so the bids along a bundle never increase and the auction converges to the same
assignment as a centralised sequential greedy allocation on the same (warped) bids.

Bids are rounded to float32 when they are made, because that is how they travel; every robot compares
exactly the numbers that were sent.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from maptidal.allocation.tasks import Task


@dataclass(frozen=True)
class AuctionParams:
    """Parameters every robot of one auction shares.

    task_value: what one inspection task is worth, in seconds of travel; bids are task_value minus the
    marginal travel cost, so a task further than task_value seconds of extra travel is not bid on.
    bundle_limit: most tasks one robot may hold (0 = no limit)."""

    task_value: float = 1000.0
    bundle_limit: int = 0

    def __post_init__(self) -> None:
        if not math.isfinite(self.task_value) or self.task_value <= 0:
            raise ValueError(f"task_value must be a positive number, got {self.task_value}")
        if self.bundle_limit < 0:
            raise ValueError(f"bundle_limit must be >= 0 (0 = no limit), got {self.bundle_limit}")


@dataclass
class RobotProfile:
    """What a robot brings to the auction.

    speed: m/s over ground; energy_per_m: extra cost in seconds per metre (robot-specific energy price);
    capabilities: bit mask (see maptidal.allocation.tasks.capability_mask)."""

    name: str
    index: int
    position: np.ndarray
    speed: float = 0.5
    capabilities: int = 1
    energy_per_m: float = 0.0

    def __post_init__(self) -> None:
        self.position = np.asarray(self.position, dtype=float)
        if self.position.shape != (3,) or not np.isfinite(self.position).all():
            raise ValueError(f"robot {self.name}: position must be 3 finite numbers")
        if not math.isfinite(self.speed) or self.speed <= 0:
            raise ValueError(f"robot {self.name}: speed must be > 0 m/s, got {self.speed}")
        if not math.isfinite(self.energy_per_m) or self.energy_per_m < 0:
            raise ValueError(f"robot {self.name}: energy_per_m must be >= 0, got {self.energy_per_m}")
        if not 0 <= self.index < 250:
            raise ValueError(f"robot {self.name}: index must be in [0, 250), got {self.index}")

    @property
    def cost_per_m(self) -> float:
        """Cost of one metre of travel, in seconds."""
        return 1.0 / self.speed + self.energy_per_m

    def can_do(self, requires: int) -> bool:
        """True when the robot has every capability the mask requires."""
        return requires & ~self.capabilities == 0


def to_bid(value: float | np.ndarray) -> np.ndarray:
    """Round bids to float32, the precision they travel in (kept as float64 arrays)."""
    return np.asarray(value, dtype=np.float32).astype(np.float64)


def task_positions(tasks: list[Task]) -> np.ndarray:
    """N x 3 positions of tasks (quantised metres)."""
    if not tasks:
        return np.zeros((0, 3))
    return np.asarray([t.position_cm for t in tasks], dtype=float) * 0.01


class PathGeometry:
    """Distances among one robot's known tasks and from its position, for insertion costs."""

    def __init__(self, start: np.ndarray, positions: np.ndarray) -> None:
        self.start = np.asarray(start, dtype=float)
        self.positions = np.asarray(positions, dtype=float)
        diff = self.positions[:, None, :] - self.positions[None, :, :]
        self.between = np.sqrt((diff**2).sum(-1))
        self.from_start = np.linalg.norm(self.positions - self.start, axis=1)

    def path_length(self, path: list[int]) -> float:
        """Length of the open path from the start through the tasks in order."""
        if not path:
            return 0.0
        idx = np.asarray(path)
        return float(self.from_start[idx[0]] + self.between[idx[:-1], idx[1:]].sum())

    def insertion(self, path: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """Extra length and best position of inserting every task into `path`.

        Returns (delta, position), each of length N: inserting task j before path[position[j]] (or at
        the end when position[j] == len(path)) lengthens the path by delta[j], the least over all
        positions; ties go to the earliest position."""
        n = len(self.positions)
        if not path:
            return self.from_start.copy(), np.zeros(n, dtype=int)
        idx = np.asarray(path)
        rows = self.between[idx]  # (m, n)
        prev = np.vstack([self.from_start[None, :], rows])  # legs from the node before the slot
        nxt = np.vstack([rows, np.zeros((1, n))])  # legs to the node after the slot (none at the end)
        old = np.empty(len(idx) + 1)
        old[0] = self.from_start[idx[0]]
        old[1:-1] = self.between[idx[:-1], idx[1:]]
        old[-1] = 0.0
        delta = prev + nxt - old[:, None]
        position = delta.argmin(axis=0)
        return delta[position, np.arange(n)], position


def warped_bids(
    geometry: PathGeometry, path: list[int], bundle_bids: list[float], cost_per_m: float, task_value: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Raw scores, warped float32 bids and best insertion positions of every task for one robot.

    raw = task_value - cost_per_m * (extra path length at the best insertion); the bid is raw capped at
    the last (smallest) bid of the bundle, so bids along a bundle never increase (bid warping)."""
    delta, position = geometry.insertion(path)
    raw = task_value - cost_per_m * delta
    cap = bundle_bids[-1] if bundle_bids else math.inf
    return raw, to_bid(np.minimum(raw, cap)), position


def best_candidate(candidates: np.ndarray, keys: np.ndarray, raw: np.ndarray, bid: np.ndarray) -> int:
    """The task a robot bids on among candidates: highest bid, then higher raw score, then lower key."""
    return int(candidates[np.lexsort((keys[candidates], -raw[candidates], -bid[candidates]))[0]])
