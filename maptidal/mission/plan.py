"""What the mission's team is given before it starts: a baseline's viewpoints planned from the tank
model (:func:`plan_tasks`, brought into the heights a robot can hold by :func:`into_reach` and checked by
:func:`reachable`), and the box a map-aware team is sent to inspect (:func:`inspection_box`). Map-aware
Map-TIDAL reads no tank model for its tasks: only the box."""

from __future__ import annotations

import numpy as np

from maptidal.allocation.tasks import Task, task_key
from maptidal.envs.scenario import inside_tank
from maptidal.evaluation.baselines import boustrophedon_viewpoints, voronoi_viewpoints
from maptidal.evaluation.free_space import free_space_mask
from maptidal.mission.params import MissionParams

# a task closer than this to a wall, the floor or the surface is out of the robot's reach
REACH_MARGIN_M = 0.35
PLANNER_VIEWPOINTS = {"voronoi": voronoi_viewpoints, "boustrophedon": boustrophedon_viewpoints}
# the origin byte of a mission plan's task keys (maptidal.allocation.tasks.task_key): robots mint theirs
# from their own index, at most 255 robots below it
PLAN_ORIGIN = 255


def inspection_box(params: MissionParams, tank) -> np.ndarray | None:
    """The box ``(2, 3)`` (lowest and highest corners) a map-aware team is sent to inspect
    (``inspect_box``, or for ``inspect_region = "walls"`` the box of the tank's evaluated walls), or
    None for the exploration radius alone."""
    if params.inspect_box is not None:
        return np.asarray(params.inspect_box, float)
    if params.inspect_region == "launch":
        return None
    return np.asarray(tank.evaluated_surface().bounds, float)


def box_corners(box: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """A box's two corners as plain tuples of floats (the form the frozen parameter classes hold)."""
    return tuple(tuple(float(v) for v in corner) for corner in np.asarray(box, float))  # type: ignore[return-value]


def reachable(tank, rows: np.ndarray, standoff_m: float) -> np.ndarray:
    """Which viewpoint rows ``(N, 6)`` a robot can fly: in the tank's free water (``standoff_m`` before
    the surface it looks at) and ``REACH_MARGIN_M`` from walls, floor and surface."""
    keep = free_space_mask(tank, rows, standoff_m) if len(rows) else np.zeros(0, bool)
    inside = np.array([inside_tank(tank, row[:3], REACH_MARGIN_M) for row in rows], bool)
    return keep & inside


def into_reach(tank, rows: np.ndarray, merge_m: float = 0.01) -> tuple[np.ndarray, int, int]:
    """A baseline's viewpoint rows ``(N, 6)`` flown as a pilot would fly its plan: a level-looking
    viewpoint above or below the band of heights a robot can hold (``REACH_MARGIN_M`` from the floor and
    the surface) is moved straight up or down to the band's nearest edge, which keeps its distance to the
    wall it looks at; viewpoints that then lie within ``merge_m`` of an earlier one looking the same way
    are merged into it. The rows, how many were moved and how many merged. A tank shallower than twice the
    margin has no band: nothing is moved."""
    low, high = REACH_MARGIN_M, tank.height - REACH_MARGIN_M
    rows = np.array(rows, dtype=float).reshape(-1, 6)
    if len(rows) == 0 or low > high:
        return rows, 0, 0
    level = np.abs(rows[:, 5]) < 1e-6  # the baselines look level at vertical walls
    outside = level & ((rows[:, 2] < low) | (rows[:, 2] > high))
    rows[outside, 2] = np.clip(rows[outside, 2], low, high)
    kept: list[int] = []
    for k in range(len(rows)):
        duplicate = any(
            np.linalg.norm(rows[k, :3] - rows[j, :3]) < merge_m and rows[k, 3:] @ rows[j, 3:] > 0.999
            for j in kept
        )
        if not duplicate:
            kept.append(k)
    return rows[kept], int(outside.sum()), len(rows) - len(kept)


def plan_tasks(planner: str, tank, standoff_m: float) -> tuple[list[Task], dict]:
    """A baseline's viewpoints from the tank model, as the tasks every robot knows from the start, and
    the plan's summary. Viewpoints above or below the heights a robot can hold are moved into them
    (:func:`into_reach`; the paper's boustrophedon puts its top and bottom lanes 8 cm from the surface
    and the floor); those still out of reach are left out, as discovery leaves out its own
    (:func:`reachable`). ValueError when the tank leaves the baseline no reachable viewpoint."""
    try:
        rows = PLANNER_VIEWPOINTS[planner](tank)
    except ValueError as error:
        raise ValueError(f"the {planner} baseline cannot plan this tank: {error}") from None
    viewpoints = len(rows)
    rows, moved, merged = into_reach(tank, rows)
    ok = reachable(tank, rows, standoff_m)
    tasks = [Task.create(task_key(PLAN_ORIGIN, k), row[:3], row[3:]) for k, row in enumerate(rows) if ok[k]]
    if not tasks:
        raise ValueError(
            f"the {planner} baseline has no viewpoint the robots can reach in this tank: all {viewpoints} "
            f"lie within {REACH_MARGIN_M:g} m of a wall, the floor or the surface, or behind a wall"
        )
    summary = {"viewpoints": viewpoints, "moved_into_reach": moved, "merged": merged}
    return tasks, {**summary, "unreachable": int((~ok).sum())}
