"""Tracking started where the camera's motion puts each keypoint (issue [truthful-loop], part 2):
``track_points(..., predicted=...)`` and the front end's predictor, against images shifted by hand and
points projected by hand in the world frame."""

import math

import cv2
import numpy as np
import pytest

from maptidal.perception.frontend import FrontEnd, FrontEndParams
from maptidal.perception.recording import CameraIntrinsics, CameraPose
from maptidal.perception.tracking import TrackerParams, track_points


def texture(height: int = 200, width: int = 320, seed: int = 0) -> np.ndarray:
    """A blotchy grey texture: random noise blurred, so KLT has gradients at every scale."""
    noise = np.random.default_rng(seed).uniform(0, 255, (height, width)).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), 3.0)
    blurred = (blurred - blurred.min()) / (blurred.max() - blurred.min()) * 255
    return blurred.astype(np.uint8)


def corners(image: np.ndarray) -> np.ndarray:
    """Good features in the middle band of ``image``, away from where the shift brings in new pixels."""
    found = cv2.goodFeaturesToTrack(image, 200, 0.01, 8).reshape(-1, 2)
    return found[(found[:, 0] > 100) & (found[:, 0] < 220) & (found[:, 1] > 30) & (found[:, 1] < 170)]


@pytest.mark.parametrize("shift_px", [90, -110])
def test_a_prediction_carries_klt_past_a_shift_it_cannot_reach_alone(shift_px):
    big = texture(200, 600)
    previous = big[:, 140:460].copy()
    current = big[:, 140 - shift_px : 460 - shift_px].copy()  # the scene moved shift_px to the right
    points = corners(previous)
    assert len(points) >= 20
    truth = points + [shift_px, 0.0]
    params = TrackerParams()
    _, ok_alone = track_points(previous, current, points, params)
    # a prediction 3 px off, as the dead reckoning's few centimetres are at a metre
    guess = truth + np.random.default_rng(1).normal(0, 3.0, truth.shape)
    found, ok = track_points(previous, current, points, params, predicted=guess)
    inside = (truth[:, 0] >= 0) & (truth[:, 0] < 320)
    assert ok[inside].mean() > 0.8
    assert np.abs(found[ok] - truth[ok]).max() < 1.0
    assert ok_alone.mean() < 0.5 * ok[inside].mean()  # unaided, the same shift loses most of them


def test_a_wrong_prediction_finds_the_right_place_or_nothing():
    image = texture()
    points = cv2.goodFeaturesToTrack(image, 300, 0.01, 8).reshape(-1, 2)
    points = points[(points[:, 0] > 20) & (points[:, 0] < 260)]
    # nothing moved, but the prediction says 40 px: from there KLT either finds its way back or settles
    # on a patch that looks alike; the backward check starts at the old pixel and cannot tell the second,
    # the patches' correlation must
    wrong_guess = points + [40.0, 0.0]
    found, ok = track_points(image, image, points, TrackerParams(), predicted=wrong_guess)
    wrong = ok & (np.abs(found - points).max(axis=1) > 1.0)
    assert ok.sum() >= 0.2 * len(points)
    assert wrong.sum() <= 0.01 * len(points)
    found, ok = track_points(image, image, points, TrackerParams(min_correlation=-1.0), predicted=wrong_guess)
    assert (ok & (np.abs(found - points).max(axis=1) > 1.0)).sum() >= 2  # what the correlation refuses


def test_bad_predictions_are_refused():
    image = texture()
    points = corners(image)
    with pytest.raises(ValueError, match="finite"):
        track_points(image, image, points, TrackerParams(), predicted=np.full_like(points, np.nan))
    with pytest.raises(ValueError, match="one per point"):
        track_points(image, image, points, TrackerParams(), predicted=points[:-1])


def look(yaw: float, position) -> CameraPose:
    """A camera looking horizontally along ``yaw`` (world z up; optical x right, y down, z forward)."""
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    return CameraPose(np.asarray(position, float), np.column_stack([right, down, forward]))


def project(intrinsics: CameraIntrinsics, pose: CameraPose, world: np.ndarray) -> np.ndarray:
    """Pixels of world points, written out per axis (no shared code with the front end)."""
    out = []
    for point in world:
        d = point - pose.position
        x, y, z = (float(pose.rotation[:, k] @ d) for k in range(3))
        out.append([intrinsics.fx * x / z + intrinsics.cx, intrinsics.fy * y / z + intrinsics.cy])
    return np.array(out)


def test_the_front_ends_prediction_is_the_rigid_motion_of_its_stereo_points():
    intrinsics = CameraIntrinsics(320, 200, 200.0, 200.0, 160.0, 100.0, 0.075)
    front = FrontEnd(intrinsics, "dr", FrontEndParams())
    before = look(0.3, [0.0, 0.0, 1.0])
    after = look(0.3 + math.radians(12.0), [0.1, 0.25, 1.02])
    rng = np.random.default_rng(3)
    world = np.column_stack([rng.uniform(1.5, 2.5, 12), rng.uniform(0.0, 1.5, 12), rng.uniform(0.5, 1.5, 12)])
    pixels_before = project(intrinsics, before, world)
    camera_before = (world - before.position) @ before.rotation  # optical-frame points of the last frame
    ids = np.arange(12)
    front._previous_pose = before
    front._previous_points = {int(i): camera_before[i] for i in ids[:10]}  # two without a stereo point
    predicted = front._predictor(after)(ids, pixels_before)
    expected = project(intrinsics, after, world)
    assert np.abs(predicted[:10] - expected[:10]).max() < 1e-6
    # the two without depth: placed at the others' median depth, so near but not exact
    assert np.all(np.isfinite(predicted[10:]))
    assert FrontEnd(intrinsics, "dr", FrontEndParams())._predictor(after) is None  # no last frame
    off = FrontEnd(intrinsics, "dr", FrontEndParams(predict_tracks=False))
    off._previous_pose = before
    assert off._predictor(after) is None
