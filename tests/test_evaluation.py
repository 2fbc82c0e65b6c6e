"""The comparison and the sweep, from Python and from the command line."""

import json

import numpy as np
import pytest

from maptidal.cli import main
from maptidal.discovery import DiscoveryParams, discover
from maptidal.evaluation.comparison import (
    EvaluationConfig,
    discover_over_keyframes,
    expected_ordering,
    parse_grid,
    run_compare,
    run_sweep,
    surface_aligned_count,
)
from maptidal.evaluation.coverage import CoverageParams
from maptidal.files import load_tasks, save_tasks
from maptidal.keyframes import ExplorationParams, exploration_keyframes
from maptidal.tank import TankModel

FAST = EvaluationConfig(
    coverage=CoverageParams(voxel_m=0.1),
    exploration=ExplorationParams(heights_m=(1.0,), yaw_step_deg=45.0),
)


def test_discovery_over_keyframes_chains_existing_tasks():
    tank = TankModel()
    keyframes = exploration_keyframes(tank, ExplorationParams(heights_m=(1.0,), yaw_step_deg=45.0))
    run = discover_over_keyframes(keyframes, DiscoveryParams())
    existing = np.empty((0, 6))
    for keyframe in keyframes:
        result = discover(keyframe.mesh.vertices, keyframe.mesh.faces, existing=existing)
        existing = np.vstack([existing, result.final])
    np.testing.assert_array_equal(run.tasks, existing)
    assert run.frames[-1]["total_tasks"] == len(existing)


def test_compare_writes_everything_and_scores_every_method(tmp_path):
    document = run_compare(tmp_path, FAST, plots=True, progress=False)
    assert set(document["methods"]) == {"maptidal", "voronoi", "voronoi_generator", "boustrophedon"}
    for row in document["methods"].values():
        assert set(row) == {"tasks", "pct_uninspected", "mean_views", "mad"}
        assert 0.0 <= row["pct_uninspected"] <= 100.0 and row["mad"] >= 0.0
    for name in ("compare.json", "report.md", "histogram.png", "voxels_maptidal.png", "tasks_voronoi.json"):
        assert (tmp_path / name).stat().st_size > 0
    assert len(load_tasks(tmp_path / "tasks_maptidal.json")) == document["methods"]["maptidal"]["tasks"]
    assert "| maptidal |" in (tmp_path / "report.md").read_text()
    again = run_compare(None, FAST, progress=False)
    assert again["methods"] == document["methods"]  # deterministic for a seed


def test_expected_ordering():
    rows = {
        "maptidal": {"pct_uninspected": 3.8, "mad": 0.03, "tasks": 20},
        "voronoi": {"pct_uninspected": 17.3, "mad": 0.1, "tasks": 20},
        "boustrophedon": {"pct_uninspected": 8.9, "mad": 0.08, "tasks": 30},
    }
    assert all(expected_ordering(rows).values())
    rows["maptidal"]["tasks"] = 31
    assert expected_ordering(rows)["no_more_tasks"] is False


def test_parse_grid():
    grid = parse_grid(["t=0.7,0.8", "theta_ex=0.3"])
    assert grid["t"] == (0.7, 0.8) and grid["theta_ex"] == (0.3,) and len(grid["r_ex"]) == 4
    for bad in (["x=1"], ["t"], ["t=a,b"], ["t="]):
        with pytest.raises(ValueError):
            parse_grid(bad)


def test_sweep_in_parallel_equals_serial(tmp_path):
    grid = {"t": (0.75,), "r_ex": (1.5, 1.8), "theta_ex": (0.25, 0.3)}
    serial = run_sweep(None, grid, FAST, jobs=1, progress=False)
    parallel = run_sweep(tmp_path, grid, FAST, jobs=2, plots=True, progress=False)
    assert serial == parallel and len(parallel) == 4
    assert (tmp_path / "sweep.csv").read_text().count("\n") == 5
    assert "| 0.75 | 1.5 |" in (tmp_path / "sweep.md").read_text()
    assert (tmp_path / "sweep.png").stat().st_size > 0
    # Larger r_ex excludes more: never more tasks at the same t and theta_ex.
    by_key = {(r["r_ex"], r["theta_ex"]): r["tasks"] for r in parallel}
    assert by_key[(1.8, 0.25)] <= by_key[(1.5, 0.25)]


def test_sweep_rejects_bad_values_before_running():
    with pytest.raises(ValueError):
        run_sweep(None, {"t": (1.5,), "r_ex": (1.7,), "theta_ex": (0.25,)}, FAST, progress=False)


def test_cli_compare_json(capsys):
    assert main(["compare", "--json", "--no-write", "--voxel", "0.1"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert set(document) == {"methods"}
    assert set(document["methods"]["voronoi"]) == {"tasks", "pct_uninspected", "mean_views", "mad"}
    assert document["methods"]["voronoi"]["tasks"] == 20


def test_cli_coverage(tmp_path, capsys):
    tasks = tmp_path / "tasks.json"
    save_tasks(tasks, np.array([[-1.0, 0.0, 1.0, 1.0, 0.0, 0.0]]))
    assert (
        main(["coverage", str(tasks), "--json", "--voxel", "0.1", "--plot-dir", str(tmp_path / "plots")]) == 0
    )
    report = json.loads(capsys.readouterr().out)
    assert report["n_viewpoints"] == 1 and 50.0 < report["pct_uninspected"] < 100.0
    assert (tmp_path / "plots" / "voxels.png").stat().st_size > 0


def test_cli_bad_input_exits_2(tmp_path, capsys):
    bad_tank = tmp_path / "tank.toml"
    bad_tank.write_text("water_depth = 2.0\n[end_wall]\nwidth = 2.4\n[window]\nwidth = 5.0\n")
    tasks = tmp_path / "tasks.json"
    save_tasks(tasks, np.array([[-1.0, 0.0, 1.0, 1.0, 0.0, 0.0]]))
    assert main(["coverage", str(tasks), "--tank", str(bad_tank)]) == 2
    assert "does not fit" in capsys.readouterr().err
    assert main(["coverage", str(tmp_path / "missing.json")]) == 2
    assert main(["sweep", "--grid", "t=abc", "--out", str(tmp_path / "s")]) == 2
    assert main(["compare", "--voxel", "-0.1", "--no-write"]) == 2
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("command", ["coverage", "compare", "sweep"])
def test_every_command_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage: maptidal " + command in capsys.readouterr().out


def test_tasks_looking_straight_at_a_surface_are_told_from_tilted_ones():
    tank = TankModel()
    end_wall = tank.segments[len(tank.segments) // 2]
    look = -end_wall.inward_normal
    standing = end_wall.start + 0.5 * (end_wall.end - end_wall.start) + end_wall.inward_normal[:2]
    tilt = np.radians(10.0)  # within theta_ex = 0.25 rad; 20 degrees is not
    rotate = np.array([[np.cos(tilt), -np.sin(tilt), 0], [np.sin(tilt), np.cos(tilt), 0], [0, 0, 1]])
    rows = np.array(
        [
            np.r_[standing, 1.0, look],
            np.r_[standing, 1.0, rotate @ look],
            np.r_[standing, 1.0, rotate @ rotate @ look],
            np.r_[standing, 1.0, 0.0, 0.0, -2.0],  # straight down at the floor (any length)
            np.r_[standing, 1.0, 0.0, 0.0, 1.0],  # up at the surface, which is not evaluated
        ]
    )
    assert surface_aligned_count(tank, rows, 0.25) == 3
    assert surface_aligned_count(tank, rows[:0], 0.25) == 0


def test_kimeras_code_default_thresholds_reject_more_keyframe_triangles():
    from maptidal.perception.mesher import MesherParams

    assert MesherParams.preset("configs") == MesherParams()
    strict = MesherParams.preset("code-defaults")
    assert (
        strict.min_ratio_largest_smallest_side,
        strict.min_elongation_ratio,
        strict.max_triangle_side_m,
    ) == (
        0.5,
        0.5,
        0.5,
    )
    with pytest.raises(ValueError, match="unknown mesher preset"):
        MesherParams.preset("euroc")
    loose = run_compare(None, EvaluationConfig(), plots=False, progress=False)
    tight = run_compare(None, EvaluationConfig(mesher=strict), plots=False, progress=False)
    assert tight["mesher"]["max_triangle_side_m"] == 0.5
    faces = [sum(f["faces"] for f in document["keyframes"]) for document in (loose, tight)]
    assert faces[1] < faces[0]
    assert tight["methods"]["maptidal"]["tasks"] < loose["methods"]["maptidal"]["tasks"]
