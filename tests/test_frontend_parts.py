"""The front end's pure parts (issue [perception]), each against a reference that shares no code with it:
recordings (round trip, quaternions against scipy, bad folders through the CLI), stereo covariances
(against Monte Carlo through triangulation), landmark fusion (against a stacked, whitened least-squares
solve), keyframe selection (hand-made cases) and PnP odometry (a known motion)."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from cli_helpers import assert_one_line_error, maptidal_here, run_maptidal
from scipy.spatial.transform import Rotation

from maptidal.perception.keyframing import KeyframeParams, KeyframeSelector
from maptidal.perception.landmarks import FusionParams, LandmarkMap, stereo_covariances
from maptidal.perception.odometry import OdometryParams, VisualOdometry, relative_motion
from maptidal.perception.recording import (
    CameraIntrinsics,
    CameraPose,
    RecordingError,
    RecordingWriter,
    load_recording,
    quaternion_from_rotation,
    rotation_from_quaternion,
)
from maptidal.perception.stereo import triangulate

INTRINSICS = CameraIntrinsics(96, 64, 50.0, 50.0, 48.0, 32.0, 0.075)


def _texture(seed: int, shape=(64, 96)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (shape[0] // 4, shape[1] // 4)).astype(np.float32)
    return (
        cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
    )


def _pose(x: float = 0.0, yaw_deg: float = 0.0) -> CameraPose:
    return CameraPose(np.array([x, 0.0, 1.0]), Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix())


def _write(root, frames: int = 3) -> None:
    writer = RecordingWriter(root, INTRINSICS, {"path": "sweep"})
    for k in range(frames):
        image = _texture(k)
        writer.add(
            0.2 * k, image, np.roll(image, -4, axis=1), {"truth": _pose(0.1 * k), "dr": _pose(0.1 * k + 0.01)}
        )


# ----- recordings ----------------------------------------------------------------------------------
def test_quaternions_agree_with_scipy_and_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        expected = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()  # scipy is scalar-last
        np.testing.assert_allclose(rotation_from_quaternion(q), expected, atol=1e-12)
        back = quaternion_from_rotation(expected)
        np.testing.assert_allclose(back, q if q[0] >= 0 else -q, atol=1e-9)


def test_a_recording_reads_back_what_was_written(tmp_path):
    _write(tmp_path)
    recording = load_recording(tmp_path)
    assert len(recording.frames) == 3 and recording.pose_sources() == {"truth", "dr"}
    assert recording.intrinsics == INTRINSICS and recording.metadata == {"path": "sweep"}
    left, right = recording.images(recording.frames[1])
    np.testing.assert_array_equal(left, _texture(1))
    np.testing.assert_array_equal(right, np.roll(_texture(1), -4, axis=1))
    pose = recording.frames[2].poses["truth"]
    np.testing.assert_allclose(pose.position, [0.2, 0.0, 1.0])
    np.testing.assert_allclose(pose.rotation, np.eye(3), atol=1e-12)


def _break(root, how: str) -> None:
    poses = json.loads((root / "poses.json").read_text())
    if how == "missing right":
        (root / "right" / "000001.png").unlink()
    elif how == "mismatched sizes":
        cv2.imwrite(str(root / "right" / "000000.png"), np.zeros((32, 48), np.uint8) + _texture(5, (32, 48)))
    elif how == "black frame":
        cv2.imwrite(str(root / "left" / "000002.png"), np.zeros((64, 96), np.uint8))
    elif how == "pose file does not match":
        poses["frames"] = poses["frames"][:2]
        (root / "poses.json").write_text(json.dumps(poses))
    elif how == "NaN pose":
        poses["frames"][1]["poses"]["truth"]["position"][0] = float("nan")
        (root / "poses.json").write_text(json.dumps(poses).replace("NaN", "NaN"))
    elif how == "textureless":
        for side in ("left", "right"):
            for k in range(3):
                ramp = np.tile(np.linspace(60, 200, 96).astype(np.uint8), (64, 1))
                cv2.imwrite(str(root / side / f"{k:06d}.png"), ramp)


@pytest.mark.parametrize(
    ("how", "message"),
    [
        ("missing right", "right image"),
        ("mismatched sizes", "intrinsics say"),
        ("black frame", "blank"),
        ("pose file does not match", "does not match the frames"),
        ("NaN pose", "NaN"),
        ("textureless", "no keypoints"),
    ],
)
def test_bad_recordings_give_one_line_and_status_2(tmp_path, how, message):
    root = tmp_path / "rec"
    _write(root)
    _break(root, how)
    assert_one_line_error(
        maptidal_here("discover-frames", root, "--out", tmp_path / "out", "--json"), message
    )


def test_a_recording_without_ground_truth_is_told_to_use_its_own_poses(tmp_path):
    # a real vehicle's recording: the robot's estimate only, no truth
    root = tmp_path / "real"
    writer = RecordingWriter(root, INTRINSICS, {"path": "field"})
    for k in range(3):
        image = _texture(k)
        writer.add(0.2 * k, image, np.roll(image, -4, axis=1), {"estimate": _pose(0.1 * k)})
    done = run_maptidal("discover-frames", root, "--out", tmp_path / "out", "--json")
    assert_one_line_error(done, "use --pose dr or --pose vo")


def test_a_missing_folder_and_bad_intrinsics_are_refused(tmp_path):
    with pytest.raises(RecordingError, match="no such recording"):
        load_recording(tmp_path / "nowhere")
    _write(tmp_path)
    (tmp_path / "intrinsics.json").write_text(json.dumps({**INTRINSICS.to_dict(), "fx": -1}))
    with pytest.raises(RecordingError, match="fx"):
        load_recording(tmp_path)


# ----- stereo covariance and fusion ------------------------------------------------------------------
def test_stereo_covariance_matches_monte_carlo_triangulation():
    f, b, cx, cy = 392.0, 0.075, 320.0, 200.0
    pixel = np.array([[420.0, 150.0]])
    disparity = 14.7  # about 2 m
    params = FusionParams(disparity_sigma_px=0.25, pixel_sigma_px=0.5)
    point, _ = triangulate(pixel, np.array([disparity]), f, f, cx, cy, b)
    predicted = stereo_covariances(point, np.array([disparity]), f, params)[0]
    rng = np.random.default_rng(0)
    n = 200_000
    noisy_pixels = pixel + rng.normal(scale=0.5, size=(n, 2))
    noisy_disparity = disparity + rng.normal(scale=0.25, size=n)
    samples, kept = triangulate(noisy_pixels, noisy_disparity, f, f, cx, cy, b)
    assert len(kept) == n
    sampled = np.cov(samples.T)
    # first-order propagation: within a few per cent of the sampled covariance at 0.25 / 14.7 px
    np.testing.assert_allclose(predicted, sampled, rtol=0.06, atol=2e-7)


def _brute_force_fusion(points, covariances):
    """Weighted least squares by stacking the whitened equations L^T x = L^T p_i (Sigma_i^-1 = L L^T)."""
    rows, rhs = [], []
    for p, c in zip(points, covariances, strict=True):
        whitening = np.linalg.cholesky(np.linalg.inv(c)).T
        rows.append(whitening)
        rhs.append(whitening @ p)
    solution, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return solution


def _random_covariance(rng, scale=0.01):
    a = rng.normal(size=(3, 3)) * scale
    return a @ a.T + np.eye(3) * scale**2 * 0.1


def test_fusion_is_the_weighted_least_squares_point():
    rng = np.random.default_rng(1)
    truth = np.array([0.3, -0.2, 1.5])
    covariances = [_random_covariance(rng) for _ in range(6)]
    points = [rng.multivariate_normal(truth, c) for c in covariances]
    landmarks = LandmarkMap(FusionParams(gate=0.0))  # no gate: every observation counts
    for p, c in zip(points, covariances, strict=True):
        landmarks.add([7], p[None], c[None])
    np.testing.assert_allclose(
        landmarks.positions([7])[0], _brute_force_fusion(points, covariances), atol=1e-10
    )
    assert landmarks.observations([7, 8]).tolist() == [6, 0]
    assert np.all(np.isnan(landmarks.positions([8])))


def test_fusion_rejects_a_gross_outlier_and_keeps_the_rest():
    rng = np.random.default_rng(2)
    truth = np.array([0.0, 0.0, 1.0])
    covariances = [np.eye(3) * 1e-4 for _ in range(5)]
    points = [rng.multivariate_normal(truth, c) for c in covariances]
    landmarks = LandmarkMap()
    for k, (p, c) in enumerate(zip(points, covariances, strict=True)):
        landmarks.add([1], p[None], c[None])
        if k == 2:
            accepted = landmarks.add([1], (truth + [0.5, 0, 0])[None], c[None])  # a slipped track
            assert not accepted[0]
    assert landmarks.rejected == 1 and landmarks.observations([1])[0] == 5
    np.testing.assert_allclose(
        landmarks.positions([1])[0], _brute_force_fusion(points, covariances), atol=1e-10
    )


def _reference_fusion(observations, gate):
    """The fusion rule one observation at a time, written out: information-form sums per id, and a
    chi-square gate on the residual against the current estimate."""
    information, vector, count, accepted, rejected = {}, {}, {}, [], 0
    for landmark, point, covariance in observations:
        if not (np.isfinite(point).all() and np.isfinite(covariance).all()):
            accepted.append(False)
            continue
        if landmark in count:
            estimate_cov = np.linalg.inv(information[landmark])
            residual = point - estimate_cov @ vector[landmark]
            if residual @ np.linalg.inv(covariance + estimate_cov) @ residual > gate**2:
                rejected += 1
                accepted.append(False)
                continue
            information[landmark] = information[landmark] + np.linalg.inv(covariance)
            vector[landmark] = vector[landmark] + np.linalg.inv(covariance) @ point
            count[landmark] += 1
        else:
            information[landmark] = np.linalg.inv(covariance)
            vector[landmark] = information[landmark] @ point
            count[landmark] = 1
        accepted.append(True)
    positions = {k: np.linalg.solve(information[k], vector[k]) for k in count}
    return accepted, rejected, positions, count


def test_a_frame_of_many_observations_folds_in_as_the_rule_one_at_a_time():
    rng = np.random.default_rng(4)
    truths = rng.uniform(-2, 2, (40, 3))
    landmarks, seen, expected_accepted = LandmarkMap(), [], []
    for _ in range(5):
        ids = rng.choice(40, 25, replace=False)
        ids[:3] = ids[3]  # an id seen more than once in one call
        covariances = np.stack([_random_covariance(rng, 0.01) for _ in ids])
        points = np.stack(
            [rng.multivariate_normal(truths[k], c) for k, c in zip(ids, covariances, strict=True)]
        )
        points[5] += [1.0, 0.0, 0.0]  # a slipped track, for the gate
        points[6, 1] = np.nan  # a bad row
        expected_accepted += landmarks.add(ids, points, covariances).tolist()
        seen += list(zip(ids.tolist(), points, covariances, strict=True))
    accepted, rejected, positions, count = _reference_fusion(seen, FusionParams().gate)
    assert expected_accepted == accepted and landmarks.rejected == rejected > 0
    ids = np.array(sorted(count))
    np.testing.assert_allclose(landmarks.positions(ids), [positions[k] for k in ids], atol=1e-9)
    assert landmarks.observations(ids).tolist() == [count[k] for k in ids]


# ----- keyframes --------------------------------------------------------------------------------------
def test_keyframes_follow_the_time_translation_and_rotation_thresholds():
    selector = KeyframeSelector(
        KeyframeParams(min_interval_s=0.2, max_interval_s=2.0, min_translation_m=0.08, min_rotation_deg=10)
    )
    decisions = [
        selector.is_keyframe(0.0, _pose(0.0)),  # the first frame
        selector.is_keyframe(0.1, _pose(0.5)),  # moved, but too soon
        selector.is_keyframe(0.3, _pose(0.05)),  # not far enough, not turned
        selector.is_keyframe(0.4, _pose(0.09)),  # 9 cm from the last keyframe
        selector.is_keyframe(0.7, _pose(0.09, 9.0)),  # 9 deg: not yet
        selector.is_keyframe(0.8, _pose(0.09, 11.0)),  # 11 deg
        selector.is_keyframe(2.7, _pose(0.09, 11.0)),  # hovering, 1.9 s
        selector.is_keyframe(2.81, _pose(0.09, 11.0)),  # hovering, 2.01 s: past the time limit
    ]
    assert decisions == [True, False, False, True, False, True, False, True]
    with pytest.raises(ValueError, match="max_interval_s"):
        KeyframeParams(min_interval_s=1.0, max_interval_s=0.5)


# ----- odometry ---------------------------------------------------------------------------------------
def _scene_points(rng, n=80):
    return np.column_stack([rng.uniform(-0.8, 0.8, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0.8, 2.0, n)])


def test_pnp_recovers_a_known_camera_motion():
    rng = np.random.default_rng(3)
    k = np.array([[392.0, 0, 320], [0, 392.0, 200], [0, 0, 1]])
    points_previous = _scene_points(rng)
    rotation = Rotation.from_euler("xyz", [2.0, -4.0, 3.0], degrees=True).as_matrix()
    translation = np.array([0.03, -0.01, 0.05])
    current = points_previous @ rotation.T + translation
    pixels = current[:, :2] / current[:, 2:] * 392.0 + [320, 200]
    pixels[:8] += 40.0  # outliers: RANSAC must drop them
    found = relative_motion(points_previous, pixels, k, OdometryParams())
    assert found is not None
    r, t, inliers = found
    np.testing.assert_allclose(r, rotation, atol=1e-6)
    np.testing.assert_allclose(t, translation, atol=1e-6)
    assert inliers == 72
    assert relative_motion(points_previous[:10], pixels[:10], k, OdometryParams()) is None  # too few


def test_visual_odometry_moves_by_the_visual_step_and_falls_back_on_dead_reckoning():
    # no gate here: this checks the fusion (tests/test_model_aided.py checks the gate)
    odometry = VisualOdometry(
        OdometryParams(visual_weight=1.0, visual_weight_depth=1.0, max_disagreement_m=math.inf)
    )
    start = _pose(0.0, 30.0)
    odometry.update(start, None)
    # the camera moves 0.1 m along its own forward axis (optical z): x_cur = x_prev - (0, 0, 0.1)
    motion = (np.eye(3), np.array([0.0, 0.0, -0.1]), 50)
    dead_reckoning = CameraPose(start.position + [0.5, 0, 0], start.rotation)  # a bad dead reckoning
    fused = odometry.update(dead_reckoning, motion)
    np.testing.assert_allclose(fused.position, start.position + 0.1 * start.forward, atol=1e-12)
    fallback = odometry.update(CameraPose(dead_reckoning.position + [0.0, 0.2, 0], start.rotation), None)
    np.testing.assert_allclose(fallback.position, fused.position + [0.0, 0.2, 0.0], atol=1e-12)
    assert math.isclose(odometry.visual_updates, 1)


def test_without_a_dvl_or_a_motion_model_vision_carries_the_horizontal_motion_alone():
    params = OdometryParams(visual_weight=0.5, visual_weight_depth=0.25, has_dvl=False, model_aided=False)
    odometry = VisualOdometry(params)
    start = _pose(0.0)
    odometry.update(start, None)
    # the camera (optical z = world x here) moves 0.1 m forward and, in the world, 0.2 m up (optical -y)
    motion = (np.eye(3), np.array([0.0, 0.2, -0.1]), 50)
    dead_reckoning = CameraPose(start.position + [0.0, 0.0, 0.1], start.rotation)  # no horizontal motion
    fused = odometry.update(dead_reckoning, motion)
    visual = start.rotation @ np.array([0.0, -0.2, 0.1])
    expected = start.position + [visual[0], visual[1], 0.25 * visual[2] + 0.75 * 0.1]
    np.testing.assert_allclose(fused.position, expected, atol=1e-12)


def test_a_frame_a_whole_interval_on_is_a_keyframe_though_its_time_is_a_sum_of_steps():
    selector = KeyframeSelector(KeyframeParams(min_interval_s=1.0, max_interval_s=1.0))
    pose = _pose(0.0)
    time_s, chosen = 0.0, []
    for step in range(1, 501):  # 10 s of 20 ms physics steps, a frame every 50 of them
        time_s += 0.02  # summed as a simulation does: the frame times fall a hair off whole seconds
        if step % 50 == 0:
            chosen.append(selector.is_keyframe(time_s, pose))
    assert chosen == [True] * 10
