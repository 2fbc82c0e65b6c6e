"""The stereo front end's first stages (maptidal/perception/stereo.py): keypoints, row matching,
triangulation, on rendered frames and on images with a known disparity."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from literal_stereo import literal_match_stereo

from maptidal.perception.stereo import (
    FrontEndInputError,
    StereoParams,
    detect_keypoints,
    match_stereo,
    triangulate,
)


def _texture(seed: int = 0, shape=(200, 320)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (shape[0] // 4, shape[1] // 4)).astype(np.float32)
    return (
        cv2.resize(noise, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC).clip(0, 255).astype(np.uint8)
    )


def test_a_known_sub_pixel_disparity_is_recovered():
    left = _texture()
    disparity = 12.3
    shift = np.float32([[1, 0, -disparity], [0, 1, 0]])  # right image: content moved left by d
    right = cv2.warpAffine(left, shift, (left.shape[1], left.shape[0]), flags=cv2.INTER_CUBIC)
    params = StereoParams(detector="gftt", max_disparity_px=40)
    keypoints = detect_keypoints(left, params)
    keypoints = keypoints[keypoints[:, 0] > 60]  # their matches lie inside the right image
    found = match_stereo(left, right, keypoints, params)
    assert np.isfinite(found).mean() > 0.8
    assert np.nanmedian(np.abs(found - disparity)) < 0.15


@pytest.mark.parametrize("seed", range(6))
def test_the_vectorised_matcher_is_the_literal_one(seed):
    """Every keypoint at once gives what one matchTemplate per keypoint gives: the same matches, the
    same rejections (ratio, left-right, edges) and the same sub-pixel disparities, on shifted noisy
    texture with keypoints near and past the edges and random matcher settings."""
    rng = np.random.default_rng(seed)
    left = _texture(seed)
    shift = np.float32([[1, 0, -rng.uniform(2, 60)], [0, 1, 0]])
    right = cv2.warpAffine(left, shift, (left.shape[1], left.shape[0]), flags=cv2.INTER_CUBIC)
    right = (right.astype(int) + rng.integers(-8, 9, right.shape)).clip(0, 255).astype(np.uint8)
    params = StereoParams(
        min_disparity_px=int(rng.integers(0, 4)),
        max_disparity_px=int(rng.integers(20, 100)),
        patch=(5, 9, 11, 17, 9, 11)[seed],  # 17 px sums in float64
    )
    keypoints = np.vstack([detect_keypoints(left, params), rng.uniform(-5, 330, (40, 2))])
    literal = literal_match_stereo(left, right, keypoints, params)
    found = match_stereo(left, right, keypoints, params)
    assert np.array_equal(np.isnan(found), np.isnan(literal))
    assert 0.2 < np.isfinite(found).mean() < 1.0  # both matches and rejections are compared
    # OpenCV's float TM_SQDIFF rounds (ours is exact): it moves a near-flat parabola's vertex a little
    np.testing.assert_allclose(found, literal, atol=1e-3)


@pytest.mark.parametrize("patch", [9, 17])
def test_the_matching_costs_are_exact_sums_of_squared_differences(patch):
    # the costs decide ties and the ratio test, so they are summed without rounding, also where a
    # large patch's sums pass float32's 2^24 (17 px: up to 289 x 255^2)
    from maptidal.perception.stereo import _ssd_along

    rng = np.random.default_rng(patch)
    templates = rng.integers(0, 3, (5, patch, patch))
    strips = rng.integers(250, 256, (5, patch, patch + 6))  # far from the templates: sums near the top
    pairs = zip(templates, strips, strict=True)
    exact = np.array([[((strip[:, k : k + patch] - t) ** 2).sum() for k in range(7)] for t, strip in pairs])
    if patch > 15:
        assert exact.min() > 2**24 and (exact % 2).any()  # odd sums there are not float32 numbers
    np.testing.assert_array_equal(_ssd_along(templates, strips), exact)


def test_textureless_images_give_no_matches():
    flat = np.full((200, 320), 128, np.uint8)
    keypoints = np.array([[160.0, 100.0], [200.0, 120.0]])
    assert np.all(np.isnan(match_stereo(flat, flat, keypoints)))  # every disparity ties: ambiguous


def test_keypoints_are_spread_over_the_grid_and_capped():
    image = _texture(1, (400, 640))
    for detector in ("orb", "fast", "gftt", "sift"):
        params = StereoParams(detector=detector, max_keypoints=240)
        points = detect_keypoints(image, params)
        assert 0 < len(points) <= 240, detector
        cells = {(int(v * 4 / 400), int(u * 6 / 640)) for u, v in points}
        assert len(cells) >= 20, detector  # of the 24 cells


def test_triangulation_follows_the_pinhole_and_the_depth_band():
    keypoints = np.array([[320.0, 200.0], [420.0, 150.0], [100.0, 100.0]])
    disparity = np.array([29.4, 14.7, 2.0])  # Z = 392 x 0.075 / d: 1.0 m, 2.0 m, 14.7 m
    points, kept = triangulate(keypoints, disparity, 392.0, 392.0, 320.0, 200.0, 0.075)
    assert kept.tolist() == [0, 1]  # 14.7 m is outside the 0.3 to 4 m band
    np.testing.assert_allclose(points[0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(points[1], [100 * 2.0 / 392, -50 * 2.0 / 392, 2.0])


@pytest.mark.parametrize("detector", ["orb", "gftt", "fast", "sift"])
def test_depth_on_rendered_frames_matches_the_renderers(detector):
    from maptidal.envs.simulation import Simulation

    sim = Simulation()
    sim.reset(seed=0)
    K = np.array(sim.intrinsics()["K"])
    left, right, depth, _ = sim.render_stereo("rov0", depth=True)
    params = StereoParams(detector=detector)
    keypoints = detect_keypoints(left, params)
    points, kept = triangulate(
        keypoints,
        match_stereo(left, right, keypoints, params),
        K[0, 0],
        K[1, 1],
        K[0, 2],
        K[1, 2],
        sim.intrinsics()["baseline_m"],
        params,
    )
    truth = depth[keypoints[kept, 1].round().astype(int), keypoints[kept, 0].round().astype(int)]
    relative = np.abs(points[:, 2] - truth) / truth
    assert len(kept) >= 40  # the smooth painted walls give few; the ladder, window and seams the rest
    assert np.median(relative) < 0.02


def test_bad_images_get_a_clear_error():
    image = _texture()
    with pytest.raises(FrontEndInputError, match="differ in size"):
        match_stereo(image, image[:100], np.array([[50.0, 50.0]]))
    with pytest.raises(FrontEndInputError, match="8-bit"):
        detect_keypoints(image.astype(np.float32))
    with pytest.raises(FrontEndInputError, match="image"):
        detect_keypoints(np.zeros((0, 0), np.uint8))
    with pytest.raises(ValueError, match="detector"):
        StereoParams(detector="surf")
    assert len(detect_keypoints(np.zeros((100, 100), np.uint8))) == 0  # a black frame: no keypoints


# ----- tracking ---------------------------------------------------------------------------------------
def test_klt_tracks_a_known_shift_and_keeps_the_landmark_ids():
    from maptidal.perception.tracking import LandmarkTracker, track_points

    first = _texture(2, (400, 640))
    shift = np.float32([[1, 0, 6.0], [0, 1, -3.0]])  # the scene moves 6 px right and 3 px up
    second = cv2.warpAffine(first, shift, (640, 400), flags=cv2.INTER_CUBIC)
    points = detect_keypoints(first, StereoParams(detector="gftt"))
    moved, ok = track_points(first, second, points)
    assert ok.mean() > 0.8  # those near the edge that fills with black are lost
    np.testing.assert_allclose(np.median(moved[ok] - points[ok], axis=0), [6.0, -3.0], atol=0.1)
    tracker = LandmarkTracker()
    ids_1, pixels_1, tracked_1 = tracker.update(first)
    assert len(ids_1) > 100 and not tracked_1.any()  # all new in the first frame
    ids_2, pixels_2, tracked_2 = tracker.update(second)
    kept = np.isin(ids_1, ids_2[tracked_2])
    assert kept.mean() > 0.8  # most landmarks keep their id
    index = {landmark: k for k, landmark in enumerate(ids_2)}
    for landmark, pixel in zip(ids_1[kept][:20], pixels_1[kept][:20], strict=True):
        np.testing.assert_allclose(pixels_2[index[landmark]] - pixel, [6.0, -3.0], atol=0.3)
    assert len(set(ids_2.tolist())) == len(ids_2)  # new keypoints get new ids
    blank = np.zeros_like(first)
    ids_3, _, tracked_3 = tracker.update(blank)  # the view is lost: nothing tracks, nothing new
    assert not tracked_3.any() and len(ids_3) == 0
