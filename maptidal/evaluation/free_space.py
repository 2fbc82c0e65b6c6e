"""Where a task may lie: in the water, with a clear line of sight to what it inspects.

Map-TIDAL's discovery (paper Algorithms 1-3) has no free-space check, so a task can lie below the floor,
above the surface or behind a wall (its direction points at a CIP, wherever the CIP's normal sends
it). This module classifies tasks, and offers the optional check that ``maptidal compare --free-space``
and ``sweep --free-space`` apply (off by default, as the paper has none):

- *in the water*: between the floor (z = 0) and the surface (z = water depth), on the water's side
  of every wall of the tank's evaluated region (the walls form a convex outline) and of the far end
  wall;
- *line of sight*: the segment from the task to its target, ``standoff`` (L_i) along its direction,
  meets no wall, floor or ladder more than ``tolerance`` before the target.

Pure numpy on :class:`maptidal.tank.TankModel`, so it runs on real maps as well as on the simulator's.
"""

from __future__ import annotations

import numpy as np

from maptidal.raycast import visible_from
from maptidal.tank import TankModel

CATEGORIES = ("free", "below_floor", "above_surface", "behind_wall", "no_line_of_sight")


def classify_tasks(
    tank: TankModel, tasks: np.ndarray, standoff_m: float = 1.0, tolerance_m: float = 0.05
) -> np.ndarray:
    """One of :data:`CATEGORIES` for each task row ``(x, y, z, dx, dy, dz)``; the first that applies."""
    tasks = np.asarray(tasks, float).reshape(-1, 6)
    labels = np.full(len(tasks), "free", dtype=object)
    if len(tasks) == 0:
        return labels
    positions = tasks[:, :3]
    labels[positions[:, 2] <= 0.0] = "below_floor"
    labels[(labels == "free") & (positions[:, 2] >= tank.height)] = "above_surface"
    water_side = positions[:, 0] > tank.far_x
    for segment in tank.segments:
        offset = positions[:, :2] - segment.start
        water_side &= offset @ segment.inward_normal[:2] > 0.0
    labels[(labels == "free") & ~water_side] = "behind_wall"
    directions = tasks[:, 3:] / np.linalg.norm(tasks[:, 3:], axis=1, keepdims=True)
    targets = positions + standoff_m * directions
    occluders = tank.scene_occluders  # prepared once per tank: a mission asks at every keyframe
    for k in np.flatnonzero(labels == "free"):
        if not visible_from(positions[k], targets[k : k + 1], occluders, tolerance_m)[0]:
            labels[k] = "no_line_of_sight"
    return labels


def free_space_mask(tank: TankModel, tasks: np.ndarray, standoff_m: float = 1.0) -> np.ndarray:
    """True for the tasks that pass the check (in the water, line of sight to the target)."""
    return classify_tasks(tank, tasks, standoff_m) == "free"


def free_space_counts(tank: TankModel, tasks: np.ndarray, standoff_m: float = 1.0) -> dict[str, int]:
    """How many tasks fall in each of :data:`CATEGORIES`."""
    labels = classify_tasks(tank, tasks, standoff_m)
    return {name: int(np.sum(labels == name)) for name in CATEGORIES}
