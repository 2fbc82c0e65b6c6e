"""The optional free-space check (maptidal/evaluation/free_space.py) and its use by compare."""

from __future__ import annotations

import numpy as np

from maptidal.evaluation.baselines import voronoi_viewpoints
from maptidal.evaluation.comparison import EvaluationConfig, run_compare
from maptidal.evaluation.free_space import classify_tasks, free_space_counts, free_space_mask
from maptidal.tank import TankModel

TANK = TankModel()


def _one(task) -> str:
    return str(classify_tasks(TANK, np.array([task]))[0])


def test_tasks_in_open_water_are_kept_and_the_others_named():
    viewpoint = voronoi_viewpoints(TANK)[0]  # 1 m off a wall, looking at it
    assert _one(viewpoint) == "free"
    assert _one([-1.5, 0.0, 1.0, 1.0, 0.0, 0.0]) == "free"  # mid-tank, facing the end wall
    below = viewpoint.copy()
    below[2] = -0.3
    assert _one(below) == "below_floor"
    above = viewpoint.copy()
    above[2] = TANK.height + 0.2
    assert _one(above) == "above_surface"
    behind = viewpoint.copy()
    behind[:3] = viewpoint[:3] + 1.5 * viewpoint[3:]  # through the wall it looks at, 0.5 m beyond
    assert _one(behind) == "behind_wall"
    assert _one([0.4, 0.0, 1.0, -1.0, 0.0, 0.0]) == "behind_wall"  # behind the end wall (x > 0)


def test_a_target_behind_a_wall_has_no_line_of_sight():
    viewpoint = voronoi_viewpoints(TANK)[0]
    assert classify_tasks(TANK, viewpoint[None], standoff_m=1.0)[0] == "free"
    assert classify_tasks(TANK, viewpoint[None], standoff_m=2.5)[0] == "no_line_of_sight"


def test_the_baselines_are_all_in_free_space_and_the_mask_matches_the_counts():
    viewpoints = voronoi_viewpoints(TANK)
    assert free_space_mask(TANK, viewpoints).all()
    mixed = np.vstack([viewpoints[:3], [[-1.0, 0.0, -0.5, 1, 0, 0], [0.5, 0.0, 1.0, 1, 0, 0]]])
    counts = free_space_counts(TANK, mixed)
    assert counts == {
        "free": 3,
        "below_floor": 1,
        "above_surface": 0,
        "behind_wall": 1,
        "no_line_of_sight": 0,
    }


def test_compare_reports_where_tasks_lie_and_the_check_keeps_only_free_ones():
    off = run_compare(None, EvaluationConfig(), plots=False, progress=False)
    on = run_compare(None, EvaluationConfig(free_space=True), plots=False, progress=False)
    assert not off["free_space"]["check"] and on["free_space"]["check"]
    outside = sum(v for k, v in off["free_space"]["maptidal"].items() if k != "free")
    assert outside > 0  # the paper's discovery has no such check: some tasks lie outside the water
    assert on["free_space"]["maptidal"]["free"] == on["methods"]["maptidal"]["tasks"]  # all free
    assert sum(f.get("dropped_by_free_space", 0) for f in on["keyframes"]) > 0
    assert off["methods"]["voronoi"] == on["methods"]["voronoi"]  # the baselines are unaffected


def test_sweep_takes_the_check_too(tmp_path):
    from maptidal.cli import main

    grid = ["--grid", "t=0.75", "r_ex=1.7", "theta_ex=0.25", "--no-plots"]
    assert main(["sweep", *grid, "--out", str(tmp_path / "off")]) == 0
    assert main(["sweep", *grid, "--free-space", "--out", str(tmp_path / "on")]) == 0
    tasks = [
        int((tmp_path / d / "sweep.csv").read_text().splitlines()[1].split(",")[3]) for d in ("off", "on")
    ]
    assert tasks[1] < tasks[0]  # tasks outside the water dropped
