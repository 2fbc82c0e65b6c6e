"""The front end on frames the simulator renders (issue [perception]): a robot flies the paper's capture
path with its own physics and controller; the mesh is checked against the true tank surface, the
keypoints against where the paper says they fall, the pose sources against ground truth, and rendered
discovery against the synthetic pipeline on the same path."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from cli_helpers import run_maptidal

from maptidal.envs.scenario import load_scenario
from maptidal.envs.water import WaterParams
from maptidal.evaluation.comparison import EvaluationConfig, config_keyframes, discover_over_keyframes
from maptidal.evaluation.coverage import CoverageModel
from maptidal.frame_discovery import discover_on_recording
from maptidal.keyframes import RefinementParams, tank_edges
from maptidal.mission.capture import CaptureParams, capture
from maptidal.perception.frontend import FrontEndParams
from maptidal.perception.landmarks import FusionParams
from maptidal.raycast import first_hit_distances_from
from maptidal.tank import TankModel, load_tank_config

FEATURE_MARGIN_M = 0.05


@pytest.fixture(scope="module")
def clear_recording(tmp_path_factory):
    """The paper's path (camera 1 m from the end wall, rising 0.5 m) in clear water: Jerlov I, no noise."""
    scenario = load_scenario()
    clear = dataclasses.replace(scenario, water=WaterParams(turbidity=0.0, noise_sigma=0.0, vignetting=0.0))
    return capture(tmp_path_factory.mktemp("clear"), clear, CaptureParams(path="paper"), seed=0)


@pytest.fixture(scope="module")
def truth_run(clear_recording):
    return discover_on_recording(clear_recording, "truth", FrontEndParams(max_keyframes=7))


def test_the_capture_rises_half_a_metre_facing_the_end_wall(clear_recording):
    truth = [frame.poses["truth"] for frame in clear_recording.frames]
    heights = np.array([pose.position[2] for pose in truth])
    assert 0.4 <= heights[-1] - heights[0] <= 0.6
    assert np.all(np.diff(heights) > -0.01)  # rising, not bobbing
    forwards = np.array([pose.forward for pose in truth])
    assert np.all(forwards[:, 0] > 0.99)  # facing +x, the end wall
    assert np.all(np.abs(np.array([p.position[0] for p in truth]) + 1.0) < 0.05)  # 1 m from it


def test_the_mesh_lies_within_3_cm_of_the_true_surface_in_clear_water(truth_run):
    assert len(truth_run.run.keyframes) == 7
    assert truth_run.mesh_error_median_m is not None and truth_run.mesh_error_median_m < 0.03
    # the tails are reported beside the median, and ordered
    assert truth_run.mesh_error_median_m <= truth_run.mesh_error_p90_m <= truth_run.mesh_error_max_m
    document = truth_run.to_json()
    assert document["mesh_error_p90_m"] == truth_run.mesh_error_p90_m
    assert all(len(k.keyframe.mesh.faces) > 50 for k in truth_run.run.keyframes)


def test_the_mesh_error_falls_with_the_fused_observations(clear_recording, truth_run):
    bins = {row["observations"]: row["median_error_m"] for row in truth_run.mesh_error_by_observations}
    assert bins["1"] > bins["16+"]
    # with an estimated pose (each observation placed by a slightly different pose), fusing every
    # observation beats keeping the last one (measured with the quaternion attitude estimator: 5.0 mm
    # against 5.6 mm; with the old Euler-rate one 8.1 against 9.7; with ground-truth poses 4.5 against
    # 6.2)
    fused = discover_on_recording(clear_recording, "dr", FrontEndParams(max_keyframes=7))
    last_only = discover_on_recording(
        clear_recording, "dr", FrontEndParams(max_keyframes=7, fusion=FusionParams(enabled=False))
    )
    assert fused.mesh_error_median_m < 0.95 * last_only.mesh_error_median_m


def _feature_distances(tank: TankModel, points: np.ndarray) -> np.ndarray:
    """Distance to the nearest feature the paper names: the wall corners and floor line, the window's
    frame, and the ladder."""
    best = np.full(len(points), np.inf)
    for a, b in tank_edges(tank):
        edge = b - a
        s = np.clip((points - a) @ edge / (edge @ edge), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + s[:, None] * edge), axis=1))
    for centre, half, axes in tank.ladder_boxes():
        local = (points - centre) @ np.asarray(axes).T
        outside = np.maximum(np.abs(local) - half, 0.0)
        best = np.minimum(best, np.linalg.norm(outside, axis=1))
    return best


def test_keypoints_concentrate_on_the_ladder_window_frame_and_corners(clear_recording, truth_run):
    tank = TankModel(load_tank_config(None))
    triangles = tank.scene_triangles()
    keypoint_share, area_share = [], []
    k = clear_recording.intrinsics
    for output in truth_run.run.keyframes:
        landmarks = output.keyframe.landmarks
        found = landmarks[np.isfinite(landmarks).all(axis=1)]
        keypoint_share.append(np.mean(_feature_distances(tank, found) < FEATURE_MARGIN_M))
        # the features' share of what the camera sees: a ray through every 8th pixel to the surface
        pose = clear_recording.frames[output.frame_index].poses["truth"]
        u, v = np.meshgrid(np.arange(4, k.width, 8), np.arange(4, k.height, 8))
        rays = np.column_stack([(u.ravel() - k.cx) / k.fx, (v.ravel() - k.cy) / k.fy, np.ones(u.size)])
        directions = rays @ pose.rotation.T
        hits = first_hit_distances_from(pose.position, directions, triangles)
        seen = pose.position + hits[np.isfinite(hits), None] * directions[np.isfinite(hits)]
        area_share.append(np.mean(_feature_distances(tank, seen) < FEATURE_MARGIN_M))
    # keypoints fall on the features half as often again as the features' share of the image (measured:
    # 53 % against 27 % for ORB's raw detections; envs/textures.py)
    assert np.mean(keypoint_share) > 1.5 * np.mean(area_share), (keypoint_share, area_share)


def test_each_pose_source_tracks_the_ground_truth(clear_recording, truth_run):
    assert truth_run.ate_m == 0.0
    for source in ("dr", "vo"):
        result = discover_on_recording(clear_recording, source, FrontEndParams(max_keyframes=7))
        assert 0.0 < result.ate_m < 0.05, source
        assert result.mesh_error_median_m < 0.03, source
        assert len(result.tasks) > 0
    vo = discover_on_recording(clear_recording, "vo", FrontEndParams(max_keyframes=2))
    inliers = [record.pnp_inliers for record in vo.run.frames[1:]]
    assert all(n is not None and n >= 20 for n in inliers)  # PnP held on every frame


def test_rendered_discovery_is_close_to_the_synthetic_pipeline_on_the_same_path(truth_run):
    tank = TankModel(load_tank_config(None))
    # against the synthetic keyframes without landmark refinement, the comparison the tolerance below was
    # set on (docs/perception.md, "Rendered against synthetic"); the refined ones give fewer tasks
    # (46 against 52-59)
    config = EvaluationConfig(capture="paper", refinement=RefinementParams(enabled=False))
    synthetic = discover_over_keyframes(config_keyframes(tank, config), config.discovery)
    model = CoverageModel.from_tank(tank, config.coverage)
    rendered_report, _ = model.evaluate(truth_run.tasks)
    synthetic_report, _ = model.evaluate(synthetic.tasks)
    # the tolerances docs/perception.md states: task count within 25 %; rendered keyframes see more of
    # the walls than the synthetic ones (every textured pixel can give a keypoint), so they leave no more
    # uninspected
    assert abs(len(truth_run.tasks) - len(synthetic.tasks)) <= 0.25 * len(synthetic.tasks)
    assert rendered_report.pct_uninspected <= synthetic_report.pct_uninspected + 5.0


def test_discover_frames_prints_the_documented_json(clear_recording, tmp_path):
    done = run_maptidal(
        "discover-frames", clear_recording.root, "--pose", "dr", "--keyframes", 3, "--json", "--out", tmp_path
    )
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    assert document["keyframes"] == 3 and len(document["keypoints_per_keyframe"]) == 3
    assert isinstance(document["mesh_faces"], int) and document["mesh_faces"] > 0
    assert 0 < document["mesh_error_median_m"] < 0.03 and 0 < document["ate_m"] < 0.05
    assert set(document["counts"]) == {"cips", "after_prune", "confirmed", "final"}
    assert len(document["tasks"]) == document["counts"]["final"] > 0
    for name in ("tasks.json", "frames.json", "keyframe_00.ply", "keyframe_02.png"):
        assert (tmp_path / name).is_file(), name
    saved = json.loads((tmp_path / "tasks.json").read_text())
    assert len(saved["tasks"]) == len(document["tasks"])


def test_compare_reports_rendered_keyframes_beside_the_synthetic_ones(tmp_path):
    done = run_maptidal(
        "compare", "--capture", "paper", "--keyframes", "rendered", "--out", tmp_path, "--json"
    )
    assert done.returncode == 0, done.stderr
    methods = json.loads(done.stdout)["methods"]
    assert {"maptidal", "maptidal_rendered", "voronoi", "boustrophedon"} <= set(methods)
    assert methods["maptidal_rendered"]["tasks"] > 0
    document = json.loads((tmp_path / "compare.json").read_text())
    assert len(document["keyframes_rendered"]) == 7  # the paper's first 7 keyframes
    for name in (
        "histogram.png",
        "voxels_maptidal_rendered.png",
        "report.md",
        "tasks_maptidal_rendered.json",
    ):
        assert (tmp_path / name).is_file(), name
    assert (tmp_path / "recording" / "poses.json").is_file()
