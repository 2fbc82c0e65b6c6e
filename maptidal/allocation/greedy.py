"""Centralised sequential greedy allocation: the yardstick for CBBA.

With bids that diminish along a bundle (which bid warping guarantees), CBBA on a connected network
converges to exactly this assignment (Choi, Brunet & How 2009, docs/references.md): repeatedly
give the single best (robot, task) pair, by the same warped bids, to that robot. It shares the bid and
tie rules with the agents (maptidal.allocation.scoring), so the comparison is exact.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from maptidal.allocation.scoring import (
    AuctionParams,
    PathGeometry,
    RobotProfile,
    best_candidate,
    task_positions,
    warped_bids,
)
from maptidal.allocation.tasks import Task


@dataclass
class Allocation:
    """Paths (task keys in execution order), bundles (in the order won) and bids per robot index."""

    paths: dict[int, list[int]]
    bundles: dict[int, list[int]]
    bids: dict[int, list[float]]
    lengths: dict[int, float]

    def winners(self) -> dict[int, int]:
        """Task key -> robot index for every assigned task."""
        return {key: robot for robot, keys in self.bundles.items() for key in keys}

    def travel_cost(self, robots: list[RobotProfile]) -> float:
        """Sum over robots of path length times the robot's cost per metre (seconds)."""
        return sum(r.cost_per_m * self.lengths.get(r.index, 0.0) for r in robots)


def sequential_greedy(robots: list[RobotProfile], tasks: list[Task], auction: AuctionParams) -> Allocation:
    """Assign tasks one at a time to the robot with the globally highest warped bid (ties: lower index)."""
    positions = task_positions(tasks)
    keys = np.array([t.key for t in tasks], dtype=np.int64)
    limit = auction.bundle_limit or math.inf
    geometry = {r.index: PathGeometry(r.position, positions) for r in robots}
    feasible = {r.index: np.array([r.can_do(t.requires) for t in tasks], dtype=bool) for r in robots}
    paths: dict[int, list[int]] = {r.index: [] for r in robots}
    bundles: dict[int, list[int]] = {r.index: [] for r in robots}
    bids: dict[int, list[float]] = {r.index: [] for r in robots}
    free = np.ones(len(tasks), dtype=bool)
    while free.any():
        best: tuple[float, int, int, int] | None = None  # (bid, -robot, task, insertion position)
        for robot in sorted(robots, key=lambda r: r.index):
            if len(bundles[robot.index]) >= limit:
                continue
            raw, bid, position = warped_bids(
                geometry[robot.index],
                paths[robot.index],
                bids[robot.index],
                robot.cost_per_m,
                auction.task_value,
            )
            candidates = np.flatnonzero(free & feasible[robot.index] & (raw > 0) & (bid > 0))
            if not len(candidates):
                continue
            j = best_candidate(candidates, keys, raw, bid)
            if best is None or bid[j] > best[0]:
                best = (float(bid[j]), robot.index, j, int(position[j]))
        if best is None:
            break
        value, index, j, at = best
        paths[index].insert(at, j)
        bundles[index].append(j)
        bids[index].append(value)
        free[j] = False
    return Allocation(
        paths={i: [int(keys[j]) for j in p] for i, p in paths.items()},
        bundles={i: [int(keys[j]) for j in b] for i, b in bundles.items()},
        bids=bids,
        lengths={i: geometry[i].path_length(p) for i, p in paths.items()},
    )
