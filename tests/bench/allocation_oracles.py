"""Brute-force optimum of small allocation instances: the yardstick for CBBA's path quality.

For every way of splitting the tasks among the robots, each robot flies the shortest open path from its
start through its tasks (Held-Karp over subsets); the optimum is the split with the least total travel
cost (metres times the robot's cost per metre). Exponential: meant for about 3 robots and 7 tasks.
"""

from __future__ import annotations

import itertools
import math

import numpy as np


def shortest_open_paths(start: np.ndarray, points: np.ndarray) -> dict[int, float]:
    """Least length of an open path from start through every point of each subset (bit mask -> m)."""
    n = len(points)
    between = np.linalg.norm(points[:, None] - points[None], axis=-1)
    first = np.linalg.norm(points - start, axis=1)
    # best[mask][j]: shortest path from start visiting mask, ending at j
    best = {(1 << j, j): float(first[j]) for j in range(n)}
    for size in range(2, n + 1):
        for subset in itertools.combinations(range(n), size):
            mask = sum(1 << j for j in subset)
            for j in subset:
                rest = mask & ~(1 << j)
                best[(mask, j)] = min(best[(rest, p)] + float(between[p, j]) for p in subset if p != j)
    shortest = {0: 0.0}
    for (mask, _), length in best.items():
        shortest[mask] = min(shortest.get(mask, math.inf), length)
    return shortest


def brute_force_cost(robots, tasks) -> float:
    """Least total travel cost over all assignments of tasks to capable robots (every task assigned)."""
    points = np.array([t.position for t in tasks])
    tables = [shortest_open_paths(r.position, points) for r in robots]
    best = math.inf
    for owners in itertools.product(range(len(robots)), repeat=len(tasks)):
        if any(not robots[o].can_do(t.requires) for o, t in zip(owners, tasks, strict=True)):
            continue
        masks = [0] * len(robots)
        for j, o in enumerate(owners):
            masks[o] |= 1 << j
        cost = sum(r.cost_per_m * tables[n][masks[n]] for n, r in enumerate(robots))
        best = min(best, cost)
    return best


def random_instance(n_robots: int, n_tasks: int, seed: int, heterogeneous: bool = False):
    """Robots and mission tasks scattered in a 20 x 10 x 3 m volume (the size of the OSB tank).

    heterogeneous: speeds 0.3-0.8 m/s, energy prices, and some tasks needing a tool only some robots carry."""
    from maptidal.allocation.scoring import RobotProfile
    from maptidal.allocation.tasks import MISSION_ORIGIN, Task, capability_mask, task_key

    rng = np.random.default_rng(seed)
    low, high = [0.0, 0.0, -3.0], [20.0, 10.0, 0.0]
    robots = []
    for i in range(n_robots):
        kit = ["camera", "tool"] if heterogeneous and i % 2 == 0 else ["camera"]
        robots.append(
            RobotProfile(
                f"r{i}",
                i,
                rng.uniform(low, high),
                speed=float(rng.uniform(0.3, 0.8)) if heterogeneous else 0.5,
                capabilities=capability_mask(kit),
                energy_per_m=float(rng.uniform(0, 1)) if heterogeneous else 0.0,
            )
        )
    tasks = []
    for j in range(n_tasks):
        needs = ("camera", "tool") if heterogeneous and rng.random() < 0.3 else ("camera",)
        tasks.append(
            Task.create(task_key(MISSION_ORIGIN, j), rng.uniform(low, high), rng.normal(size=3), needs)
        )
    return robots, tasks
