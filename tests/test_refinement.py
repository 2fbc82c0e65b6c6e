"""Kimera-like landmark refinement in the synthetic keyframes, and the noise curve."""

from __future__ import annotations

import json

import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.cli import main
from maptidal.keyframes import FeatureParams, RefinementParams, keyframes_at, tank_landmarks
from maptidal.tank import TankModel

TANK = TankModel()


def _median_error(keyframe) -> float:
    truth = tank_landmarks(TANK, FeatureParams(seed=0))[keyframe.landmark_ids]
    return float(np.median(np.linalg.norm(keyframe.landmarks - truth, axis=1)))


def test_a_tracked_landmarks_error_falls_as_one_over_the_root_of_its_observations():
    poses = [(np.array([-1.5, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))] * 9  # the same view, tracked
    refined = keyframes_at(TANK, poses, refinement=RefinementParams(enabled=True, frames_per_keyframe=1))
    ratio = _median_error(refined[0]) / _median_error(refined[8])
    assert 2.4 < ratio < 3.6  # sqrt(9) = 3
    single = keyframes_at(TANK, poses)  # no fusion: every keyframe as noisy as the first
    assert 0.8 < _median_error(single[0]) / _median_error(single[8]) < 1.25
    # a keyframe of 5 frames starts sqrt(5) better than a single observation
    five = keyframes_at(TANK, poses[:1], refinement=RefinementParams(enabled=True, frames_per_keyframe=5))
    assert 1.8 < _median_error(single[0]) / _median_error(five[0]) < 2.7
    exact = keyframes_at(TANK, poses[:1], camera=StereoCameraParams(disparity_sigma_px=0.0))
    assert _median_error(exact[0]) < 1e-9


def test_the_noise_curve_shows_refinement_cutting_the_task_count(tmp_path, capsys):
    assert main(["noise-curve", "--levels", "0,0.25", "--json", "--out", str(tmp_path)]) == 0
    rows = {(r["disparity_sigma_px"], r["refined"]): r for r in json.loads(capsys.readouterr().out)["rows"]}
    assert rows[(0.0, False)]["tasks"] == rows[(0.0, True)]["tasks"]  # no noise: nothing to refine
    assert rows[(0.25, True)]["tasks"] < rows[(0.25, False)]["tasks"]
    assert rows[(0.25, True)]["faces_within_theta_ex"] > rows[(0.25, False)]["faces_within_theta_ex"]
    assert (tmp_path / "noise_curve.png").stat().st_size > 1000
    assert main(["noise-curve", "--levels", "-1", "--out", str(tmp_path)]) == 2
