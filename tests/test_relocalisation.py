"""Relocalisation against the robot's own map (maptidal.perception.relocalisation), checked against
constructions that share nothing with it: a brute-force search of the camera centre, synthetic views of
a textured wall drawn by a homography, and the Kalman update written out by hand."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np
import pytest

from maptidal.perception.odometry import OdometryParams, VisualOdometry
from maptidal.perception.recording import CameraIntrinsics, CameraPose
from maptidal.perception.relocalisation import (
    AnchorMap,
    RelocalisationParams,
    bearings,
    centre_from_rays,
    describe,
    locate,
    project,
)

INTRINSICS = CameraIntrinsics(320, 200, 196.0, 196.0, 160.0, 100.0, 0.075)


def facing_wall(yaw_deg: float = 0.0) -> np.ndarray:
    """Optical-to-world rotation of a camera looking along +x (towards a wall at x = 0), turned by yaw."""
    yaw = math.radians(yaw_deg)
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])  # image right: world -y when facing +x
    down = np.array([0.0, 0.0, -1.0])
    return np.column_stack([right, down, forward])


def test_the_centre_from_rays_is_the_brute_force_minimum():
    rng = np.random.default_rng(3)
    centre = np.array([-1.2, 0.3, 1.0])
    points = np.column_stack([np.zeros(20), rng.uniform(-1, 1, 20), rng.uniform(0.2, 1.8, 20)])
    rays = points - centre + rng.normal(0, 0.01, (20, 3))  # a little noise: the minimum is not the truth
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    solved = centre_from_rays(points, rays)

    def cost(c):
        offsets = points - c
        along = np.einsum("ni,ni->n", offsets, rays)
        return float(np.sum(np.linalg.norm(offsets - along[:, None] * rays, axis=1) ** 2))

    # brute force: a grid 1 mm fine around the truth, then 0.1 mm around its best point
    best = centre
    for step in (1e-3, 1e-4):
        axis = np.arange(-20, 21) * step
        grid = best + np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
        best = grid[np.argmin([cost(c) for c in grid])]
    assert np.linalg.norm(solved - best) < 2e-4
    assert cost(solved) <= cost(best) + 1e-12


def test_parallel_rays_fix_nothing():
    points = np.array([[0.0, 0.0, 1.0], [0.0, 0.5, 1.0], [0.0, 1.0, 1.0]])
    rays = np.tile([1.0, 0.0, 0.0], (3, 1))
    assert centre_from_rays(points, rays) is None


def test_locate_finds_the_centre_among_outliers():
    rng = np.random.default_rng(7)
    rotation = facing_wall(15.0)
    centre = np.array([-1.1, -0.2, 0.9])
    # points on the end wall (x = 0) and an angled wall, in view
    wall = np.column_stack([np.zeros(40), rng.uniform(-0.6, 0.3, 40), rng.uniform(0.5, 1.3, 40)])
    angled = np.column_stack([rng.uniform(-0.6, 0, 20), np.zeros(20), rng.uniform(0.5, 1.3, 20)])
    angled[:, 1] = -0.8 - angled[:, 0]
    points = np.vstack([wall, angled])
    pixels, depth = project(points, centre, rotation, INTRINSICS)
    assert (depth > 0).all()
    pixels = pixels + rng.normal(0, 0.5, pixels.shape)
    wrong = rng.choice(len(points), 18, replace=False)  # 30 % of the matches are wrong
    pixels[wrong] = rng.uniform([0, 0], [320, 200], (len(wrong), 2))
    found = locate(points, pixels, rotation, INTRINSICS, RelocalisationParams(), np.random.default_rng(0))
    assert found is not None
    solved, inliers = found
    assert np.linalg.norm(solved - centre) < 0.01
    assert not inliers[wrong].any() or inliers[wrong].sum() <= 2  # a wrong match may land near its pixel
    assert inliers.sum() >= len(points) - len(wrong) - 2


def test_too_few_matches_give_no_fix():
    rotation = facing_wall()
    points = np.array([[0.0, 0.1 * k, 1.0] for k in range(5)])
    pixels, _ = project(points, np.array([-1.0, 0.0, 1.0]), rotation, INTRINSICS)
    params = RelocalisationParams(min_inliers=8)
    assert locate(points, pixels, rotation, INTRINSICS, params, np.random.default_rng(0)) is None


# ----- views of a textured wall ----------------------------------------------------------------------
TEXTURE_M = 4.0  # the texture spans the wall y in [-2, 2] m, z in [0, 4] m
TEXTURE_PX = 1600


def _texture() -> np.ndarray:
    rng = np.random.default_rng(11)
    noise = rng.uniform(0, 255, (TEXTURE_PX // 8, TEXTURE_PX // 8)).astype(np.float32)
    image = cv2.resize(noise, (TEXTURE_PX, TEXTURE_PX), interpolation=cv2.INTER_CUBIC)
    blobs = np.zeros_like(image)
    for _ in range(900):
        u, v = rng.integers(0, TEXTURE_PX, 2)
        cv2.circle(blobs, (int(u), int(v)), int(rng.integers(3, 12)), float(rng.uniform(60, 255)), -1)
    return np.clip(0.5 * image + blobs, 0, 255).astype(np.uint8)


def wall_view(texture: np.ndarray, centre: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The wall x = 0 seen by the camera, drawn by the plane's homography, and each pixel's depth (m)."""
    # texture pixel (a, b) is the wall point y = 2 - a * s, z = 4 - b * s
    s = TEXTURE_M / TEXTURE_PX
    to_wall = np.array([[0.0, 0.0, 0.0], [-s, 0.0, 2.0], [0.0, -s, 4.0]])  # (x, y, z) = M (a, b, 1)
    k = np.array([[INTRINSICS.fx, 0, INTRINSICS.cx], [0, INTRINSICS.fy, INTRINSICS.cy], [0, 0, 1]])
    offset = np.array([[0.0, 0.0, -centre[0]], [0.0, 0.0, -centre[1]], [0.0, 0.0, -centre[2]]])
    homography = k @ rotation.T @ (to_wall + offset)
    image = cv2.warpPerspective(
        texture, homography, (INTRINSICS.width, INTRINSICS.height), flags=cv2.INTER_AREA
    )
    u, v = np.meshgrid(np.arange(INTRINSICS.width) + 0.0, np.arange(INTRINSICS.height) + 0.0)
    rays = bearings(np.column_stack([u.ravel(), v.ravel()]), rotation, INTRINSICS)
    distance = -centre[0] / rays[:, 0]  # along each ray to x = 0
    depth = distance * (rays @ rotation[:, 2])
    return image, depth.reshape(u.shape)


def corners(image: np.ndarray) -> np.ndarray:
    found = cv2.goodFeaturesToTrack(image, 300, 0.01, 6, blockSize=7)
    return found.reshape(-1, 2).astype(float)


def _frame(texture, centre, rotation):
    image, depth = wall_view(texture, centre, rotation)
    pixels = corners(image)
    z = depth[pixels[:, 1].astype(int), pixels[:, 0].astype(int)]
    rays = np.column_stack(
        [
            (pixels[:, 0] - INTRINSICS.cx) / INTRINSICS.fx,
            (pixels[:, 1] - INTRINSICS.cy) / INTRINSICS.fy,
            np.ones(len(pixels)),
        ]
    )
    return image, pixels, rays * z[:, None]


@pytest.mark.parametrize("offset", [(0.0, 0.15, 0.0), (0.12, -0.1, 0.05)])
def test_a_second_view_nearer_and_turned_is_relocalised_on_the_map_of_the_first(offset):
    """Anchors made at 1.6 m; the robot then comes to 1.0 m, 20 cm aside and turned 12 deg, believing
    itself ``offset`` away from where it is: the fix lands within 3 cm of the truth."""
    texture = _texture()
    params = RelocalisationParams()
    anchors = AnchorMap(INTRINSICS, params)
    first_centre, first_rotation = np.array([-1.6, 0.0, 1.8]), facing_wall()
    image, pixels, points = _frame(texture, first_centre, first_rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    made = anchors.add(CameraPose(first_centre, first_rotation), pixels, points, descriptors, valid, 0.01)
    assert made > 100

    centre, rotation = np.array([-1.0, -0.2, 1.75]), facing_wall(12.0)
    image, pixels, points = _frame(texture, centre, rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    believed = CameraPose(centre + np.array(offset), rotation)
    fix, matched = anchors.relocalise(believed, pixels, descriptors, valid, sigma_m=0.1)
    assert fix is not None, dict(anchors.refused)
    assert np.linalg.norm(fix.centre - centre) < 0.03
    assert fix.inliers >= params.min_inliers and len(matched) == fix.inliers
    assert fix.sigma_m == pytest.approx(math.hypot(0.01, params.fix_sigma_m))


def test_a_fix_beyond_the_innovation_gate_is_refused():
    """The same second view, believed 15 cm off by a robot sure of itself to 2 cm: the fix is too far
    from the prediction for both to be right (3.03 standard deviations of their difference, 9 cm). The
    search is widened, so that the anchors are found at all."""
    texture = _texture()
    params = RelocalisationParams(min_search_radius_px=60.0)
    anchors = AnchorMap(INTRINSICS, params)
    first_centre, first_rotation = np.array([-1.6, 0.0, 1.8]), facing_wall()
    image, pixels, points = _frame(texture, first_centre, first_rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    anchors.add(CameraPose(first_centre, first_rotation), pixels, points, descriptors, valid, 0.01)
    centre, rotation = np.array([-1.0, -0.2, 1.75]), facing_wall(12.0)
    image, pixels, points = _frame(texture, centre, rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    believed = CameraPose(centre + np.array([0.0, 0.15, 0.0]), rotation)
    fix, _ = anchors.relocalise(believed, pixels, descriptors, valid, sigma_m=0.02)
    assert fix is None and anchors.refused["gate"] == 1
    fix, _ = anchors.relocalise(believed, pixels, descriptors, valid, sigma_m=0.1)  # unsure: let through
    assert fix is not None and np.linalg.norm(fix.centre - centre) < 0.03


def _anchored_and_second_view(params: RelocalisationParams):
    """The wall seen from 1.6 m (its anchors, made by ``fresh_anchors(params)``), and a second view from
    1.0 m, 20 cm aside and turned 12 deg: (fresh_anchors, second view's centre, rotation, pixels,
    descriptors, valid)."""
    texture = _texture()
    first_centre, first_rotation = np.array([-1.6, 0.0, 1.8]), facing_wall()
    image, pixels, points = _frame(texture, first_centre, first_rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    centre, rotation = np.array([-1.0, -0.2, 1.75]), facing_wall(12.0)
    second = _frame(texture, centre, rotation)
    second_descriptors, second_valid = describe(
        second[0], second[1], second[2][:, 2], INTRINSICS, params.support_m
    )

    def fresh_anchors(chosen: RelocalisationParams) -> AnchorMap:
        anchors = AnchorMap(INTRINSICS, chosen)
        anchors.add(CameraPose(first_centre, first_rotation), pixels, points, descriptors, valid, 0.01)
        return anchors

    return fresh_anchors, centre, rotation, second[1], second_descriptors, second_valid


def test_a_robot_far_off_is_relocalised_against_the_whole_map():
    """Believed 1 m from where it is, beyond any search near the prediction: a robot that knows itself
    lost (0.5 m unsure) is found again by matching against every anchor; one that believes itself
    surer is not (it would take a wrong fix for a right one)."""
    params = RelocalisationParams()
    fresh_anchors, centre, rotation, pixels, descriptors, valid = _anchored_and_second_view(params)
    believed = CameraPose(centre + np.array([-0.8, 0.6, 0.0]), rotation)
    for sigma, found in ((0.5, True), (0.2, False)):
        anchors = fresh_anchors(params)
        fix, _ = anchors.relocalise(believed, pixels, descriptors, valid, sigma_m=sigma)
        assert (fix is not None) == found, (sigma, dict(anchors.refused))
        if found:
            assert anchors.global_fixes == 1 and np.linalg.norm(fix.centre - centre) < 0.03
            assert fix.inliers >= params.global_min_inliers


def test_a_robot_lost_farther_than_the_first_search_is_found_by_the_widening_rings():
    """Believed 2.1 m from where it is (a robot without a DVL pushed while in contact): the first search,
    out to 1.2 m, misses it; each further search tries one more ring of 0.3 m (a guided match reaches
    some 0.4 m about its grid point), so a later search finds it (searching one frame in three: the 7th
    or the 10th frame). A robot that believes itself surer than global_sigma_m does not search and is
    not found; nor is one whose rings stop at 1.5 m."""
    params = RelocalisationParams()
    fresh_anchors, centre, rotation, pixels, descriptors, valid = _anchored_and_second_view(params)
    believed = CameraPose(centre + np.array([-0.3, 2.1, 0.0]), rotation)
    for sigma, reach, found_at in ((0.5, 2.4, (7, 10)), (0.25, 2.4, None), (0.5, 1.5, None)):
        anchors = fresh_anchors(dataclasses.replace(params, max_lost_search_m=reach))
        frames = []
        for frame in range(1, 14):
            fix, _ = anchors.relocalise(believed, pixels, descriptors, valid, sigma_m=sigma)
            if fix is not None:
                frames.append(frame)
                assert np.linalg.norm(fix.centre - centre) < 0.03
                break
        if found_at is None:
            assert not frames, (sigma, reach, frames)
        else:
            assert frames and frames[0] in found_at, (sigma, reach, frames, dict(anchors.refused))
            assert anchors.global_fixes == 1


def test_the_searchs_offsets_are_the_whole_grid_then_one_ring_at_a_time():
    """The offsets each search tries, against the grid written out point by point: first every point of
    the 0.3 m grid out to 1.2 m but the prediction, then the points at exactly 1.5, 1.8, 2.1 and 2.4 m
    (the largest coordinate), then the whole grid again."""
    params = RelocalisationParams()
    anchors = AnchorMap(INTRINSICS, params)
    grid = [(i * 0.3, j * 0.3) for i in range(-8, 9) for j in range(-8, 9)]

    def chebyshev(offset) -> float:
        return round(max(abs(offset[0]), abs(offset[1])), 6)

    expected = [
        sorted(o for o in grid if 0 < chebyshev(o) <= 1.2 + 1e-9),
        *[sorted(o for o in grid if abs(chebyshev(o) - r) < 1e-9) for r in (1.5, 1.8, 2.1, 2.4)],
        sorted(o for o in grid if 0 < chebyshev(o) <= 1.2 + 1e-9),
    ]
    for ring, want in enumerate(expected):
        offsets, bound = anchors._next_search()
        got = sorted((round(dx, 6), round(dy, 6)) for dx, dy in offsets.tolist())
        assert got == [(round(a, 6), round(b, 6)) for a, b in want]
        if ring in (0, 5):  # the first search keeps its bound of max_global_correction_m
            assert bound == params.max_global_correction_m
        else:  # a ring's fix may lie out to its corners and a step
            assert bound >= max(math.hypot(*o) for o in want) + params.global_step_m - 1e-9
    # with no rings beyond the first search, every search is the whole grid
    anchors = AnchorMap(INTRINSICS, dataclasses.replace(params, max_lost_search_m=1.2))
    for _ in range(3):
        offsets, bound = anchors._next_search()
        assert len(offsets) == 80 and bound == params.max_global_correction_m


def test_a_view_of_another_wall_gives_no_fix():
    """Anchors from one texture, then a view of a wall with another: nothing to relocalise on."""
    params = RelocalisationParams()
    anchors = AnchorMap(INTRINSICS, params)
    centre, rotation = np.array([-1.2, 0.0, 1.8]), facing_wall()
    image, pixels, points = _frame(_texture(), centre, rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    anchors.add(CameraPose(centre, rotation), pixels, points, descriptors, valid, 0.01)
    other = np.flipud(np.fliplr(_texture())).copy()
    image, pixels, points = _frame(other, centre, rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    fix, _ = anchors.relocalise(CameraPose(centre + [0, 0.1, 0], rotation), pixels, descriptors, valid, 0.1)
    assert fix is None
    fix, _ = anchors.relocalise(CameraPose(centre + [0, 0.1, 0], rotation), pixels, descriptors, valid, 1.0)
    assert fix is None  # nor against the whole map


def test_anchors_are_not_doubled_but_surer_ones_take_the_place_of_unsure_ones():
    texture = _texture()
    params = RelocalisationParams()
    centre, rotation = np.array([-1.4, 0.0, 1.8]), facing_wall()
    image, pixels, points = _frame(texture, centre, rotation)
    descriptors, valid = describe(image, pixels, points[:, 2], INTRINSICS, params.support_m)
    pose = CameraPose(centre, rotation)
    anchors = AnchorMap(INTRINSICS, params)
    first = anchors.add(pose, pixels, points, descriptors, valid, 0.2)
    assert anchors.add(pose, pixels, points, descriptors, valid, 0.15) == 0  # not sure enough to replace
    assert len(anchors) == first
    replaced = anchors.add(pose, pixels, points, descriptors, valid, 0.02)  # 0.2 > 2 x 0.02 + 0.01
    assert replaced == first and len(anchors) == first
    assert np.allclose(anchors.sigmas, 0.02)


def test_a_fix_is_weighed_as_a_kalman_filter_does():
    odometry = VisualOdometry(OdometryParams(has_dvl=False, start_sigma_m=0.0))
    rotation = facing_wall()
    odometry.update(CameraPose(np.array([-1.0, 0.0, 1.0]), rotation), None)
    odometry.update(CameraPose(np.array([-1.0, 0.0, 1.0]), rotation), None, dt_s=20.0)
    drift = OdometryParams().drift_m2_s_no_dvl
    assert odometry.drift_scale == 1.0
    assert odometry.sigma_m == pytest.approx(math.sqrt(drift * 20.0))
    prior = odometry.sigma_m**2
    pose = odometry.correct(np.array([-0.8, 0.4, 5.0]), sigma_m=0.05)
    gain = prior / (prior + 0.05**2)
    assert pose.position == pytest.approx([-1.0 + 0.2 * gain, 0.4 * gain, 1.0])  # depth: the pressure's
    assert odometry.sigma_m == pytest.approx(math.sqrt(prior * 0.05**2 / (prior + 0.05**2)))


def test_fixes_farther_off_than_the_uncertainty_allowed_speed_the_drift_up():
    """A motion model that is off drifts faster than the estimator's parameter says: each fix that lands
    farther off than the uncertainty allows scales the drift rate by 1.5, up to its cap; fixes that land
    close bring it back down to its own."""
    params = OdometryParams(has_dvl=False)
    odometry = VisualOdometry(params)
    rotation = facing_wall()
    here = np.array([-1.0, 0.0, 1.0])
    odometry.update(CameraPose(here, rotation), None)
    for _ in range(12):
        odometry.update(CameraPose(here, rotation), None, dt_s=1.0)
        odometry.correct(odometry.pose.position + np.array([0.5, 0.0, 0.0]), sigma_m=0.02)
    assert odometry.drift_scale == params.max_drift_scale
    before = odometry.sigma_m**2
    odometry.update(CameraPose(here, rotation), None, dt_s=1.0)
    assert odometry.sigma_m**2 - before == pytest.approx(params.drift_m2_s_no_dvl * params.max_drift_scale)
    for _ in range(60):
        odometry.update(CameraPose(here, rotation), None, dt_s=1.0)
        odometry.correct(odometry.pose.position, sigma_m=0.02)  # right where it believed it was
    assert odometry.drift_scale == 1.0
    dvl = VisualOdometry(OdometryParams(has_dvl=True))  # a DVL's drift does not adapt: the fix is wrong
    dvl.update(CameraPose(here, rotation), None)
    dvl.correct(here + np.array([0.5, 0.0, 0.0]), sigma_m=0.02)
    assert dvl.drift_scale == 1.0


def test_with_a_dvl_a_fix_moves_the_estimate_little():
    """The DVL keeps the say: its estimate's variance grows 500 times slower, so 60 s after the start a
    fix 2 cm sure moves it less than a third of the way, where it moves a robot without one nearly all."""
    rotation = facing_wall()
    moved = {}
    for has_dvl in (True, False):
        odometry = VisualOdometry(OdometryParams(has_dvl=has_dvl))
        odometry.update(CameraPose(np.zeros(3), rotation), None)
        odometry.update(CameraPose(np.zeros(3), rotation), None, dt_s=60.0)
        moved[has_dvl] = odometry.correct(np.array([0.1, 0.0, 0.0]), sigma_m=0.02).position[0] / 0.1
    assert 0.0 < moved[True] < 1 / 3
    assert moved[False] > 0.95


def test_a_dvl_that_drops_out_leaves_the_robot_as_unsure_as_one_without_until_its_next_fix():
    """The variance written out by hand: with its DVL a robot's grows at drift_m2_s_dvl; from a frame in
    which its DVL dropped out until its next fix, at drift_m2_s_no_dvl (adapting to refused fixes as a
    robot without a DVL does), and its visual steps weigh as that robot's; after the fix, as before."""
    params = OdometryParams(has_dvl=True, start_sigma_m=0.01)
    odometry = VisualOdometry(params)
    rotation = facing_wall()
    here = np.array([-1.0, 0.0, 1.0])
    # a visual step of 10 cm along +x, the dead reckoning standing still: within the 12 cm gate
    step = (np.eye(3), -(rotation.T @ np.array([0.1, 0.0, 0.0])), 50)
    odometry.update(CameraPose(here, rotation), None)
    expected = 0.01**2
    odometry.update(CameraPose(here, rotation), None, dt_s=10.0)
    expected += params.drift_m2_s_dvl * 10.0
    assert odometry.sigma_m**2 == pytest.approx(expected)
    moved = odometry.update(CameraPose(here, rotation), step, dt_s=1.0).position[0] - here[0]
    expected += params.drift_m2_s_dvl
    assert moved == pytest.approx(0.1 * params.visual_weight)
    start = odometry.pose.position[0]
    odometry.update(CameraPose(here, rotation), step, dt_s=1.0, unaided_s=0.4)  # its DVL out for 0.4 s
    expected += params.drift_m2_s_no_dvl
    assert odometry.unaided and not odometry.dvl_aided
    assert odometry.pose.position[0] - start == pytest.approx(0.1 * params.visual_weight_model_aided)
    assert odometry.sigma_m**2 == pytest.approx(expected)
    odometry.update(CameraPose(here, rotation), None, dt_s=5.0)  # the DVL back, but no fix yet
    expected += params.drift_m2_s_no_dvl * 5.0
    assert odometry.sigma_m**2 == pytest.approx(expected)
    odometry.surprised()  # a fix refused: the drift adapts, as without a DVL
    assert odometry.drift_scale == 1.5
    odometry.update(CameraPose(here, rotation), None, dt_s=2.0)
    expected += params.drift_m2_s_no_dvl * 1.5 * 2.0
    assert odometry.sigma_m**2 == pytest.approx(expected)
    odometry.correct(odometry.pose.position, sigma_m=0.02)  # found again
    assert not odometry.unaided and odometry.drift_scale == 1.0
    expected = expected * 0.02**2 / (expected + 0.02**2)
    assert odometry.sigma_m**2 == pytest.approx(expected)
    odometry.update(CameraPose(here, rotation), None, dt_s=10.0)
    expected += params.drift_m2_s_dvl * 10.0
    assert odometry.sigma_m**2 == pytest.approx(expected)
    odometry.surprised()  # with its DVL keeping the say, a refused fix is the fix's error
    assert odometry.drift_scale == 1.0
    without = VisualOdometry(OdometryParams(has_dvl=False))  # a robot without a DVL has nothing to lose
    without.update(CameraPose(here, rotation), None, unaided_s=1.0)
    assert not without.unaided


def test_a_robot_pushed_while_its_dvl_was_out_is_found_again_by_its_map():
    """A robot with a DVL maps a wall, then is pushed 22 cm while its DVL is out (a teammate beneath it),
    as in variant B's seed 6: its dead reckoning does not see the push. Told of the dropout, it grows
    unsure until a fix on its anchors gets through and brings it back within 3 cm; not told, it holds
    itself sure to a few mm, finds no fix, and stays 22 cm off."""
    params = RelocalisationParams()
    fresh_anchors, centre, rotation, pixels, descriptors, valid = _anchored_and_second_view(params)
    push = np.array([0.06, 0.21, 0.0])
    for told in (True, False):
        anchors = fresh_anchors(params)
        odometry = VisualOdometry(OdometryParams(has_dvl=True, start_sigma_m=0.005))
        believed = CameraPose(centre + push, rotation)  # the dead reckoning, carried on from before
        odometry.update(believed, None)
        found_at = None
        for frame in range(1, 31):
            unaided = 1.0 if told and frame == 1 else 0.0
            pose = odometry.update(believed, None, dt_s=1.0, unaided_s=unaided)
            gated = anchors.refused["gate"]
            fix, _ = anchors.relocalise(pose, pixels, descriptors, valid, odometry.sigma_m)
            if anchors.refused["gate"] > gated:
                odometry.surprised()
            if fix is not None:
                odometry.correct(fix.centre, fix.sigma_m)
                found_at = frame
                break
        error = np.linalg.norm((odometry.pose.position - centre)[:2])
        if told:
            assert found_at is not None and error < 0.03, (found_at, error, dict(anchors.refused))
        else:
            assert found_at is None and error > 0.2  # its search, a few mm wide, misses its anchors


def test_a_keypoint_between_two_look_alike_anchors_matches_neither():
    """Lowe's ratio test: two anchors whose descriptors are near twins, both in the search window of a
    keypoint, give no match (the repeated rungs of a ladder); make one distinct and the other is taken."""
    anchors = AnchorMap(INTRINSICS, RelocalisationParams())
    rotation, centre = facing_wall(), np.array([-1.0, 0.0, 1.0])
    pose = CameraPose(centre, rotation)
    points = np.array([[0.0, 0.02, 1.0], [0.0, -0.02, 1.0]])  # 8 px apart at 1 m
    rng = np.random.default_rng(5)
    descriptor = rng.uniform(0, 60, 128).astype(np.float32)
    twin = descriptor + rng.normal(0, 0.2, 128).astype(np.float32)
    pixels, _ = project(points, centre, rotation, INTRINSICS)
    camera = (points - centre) @ rotation
    anchors.add(pose, pixels, camera, np.stack([descriptor, twin]), np.ones(2, bool), 0.01)
    assert len(anchors) == 2  # one frame's keypoints are not spaced against each other
    query = (descriptor + rng.normal(0, 1.0, 128)).astype(np.float32)[None]  # a new look at the place
    keypoints, matched = anchors.match(pose, pixels[:1], query, np.ones(1, bool), 0.05)
    assert len(keypoints) == 0
    anchors.descriptors[1] = rng.uniform(0, 60, 128).astype(np.float32)  # no longer a twin
    keypoints, matched = anchors.match(pose, pixels[:1], query, np.ones(1, bool), 0.05)
    assert keypoints.tolist() == [0] and matched.tolist() == [0]


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="min_inliers"):
        RelocalisationParams(min_inliers=1)
    with pytest.raises(ValueError, match="depth band"):
        RelocalisationParams(min_depth_m=2.0, max_depth_m=1.0)


def _random_map_and_frame(rng: np.random.Generator, levels: int | None):
    """An anchor map of points 0.5 to 3 m before a camera facing +x, and a frame of keypoints near some of
    their pixels. Descriptors are continuous (``levels`` None) or drawn from a few values, so that equal
    distances (ties) are common."""

    def draw(count: int) -> np.ndarray:
        if levels is None:
            return rng.uniform(0, 60, (count, 128)).astype(np.float32)
        return (rng.integers(0, levels, (count, 128)) * 7.0).astype(np.float32)

    pose = CameraPose(np.array([-2.0, 0.0, 1.0]), facing_wall(float(rng.uniform(-20, 20))))
    count = int(rng.integers(5, 120))
    depth = rng.uniform(0.5, 3.0, count)
    pixel = np.column_stack([rng.uniform(0, 320, count), rng.uniform(0, 200, count)])
    camera = (
        np.column_stack(
            [
                (pixel[:, 0] - INTRINSICS.cx) / INTRINSICS.fx,
                (pixel[:, 1] - INTRINSICS.cy) / INTRINSICS.fy,
                np.ones(count),
            ]
        )
        * depth[:, None]
    )
    anchors = AnchorMap(INTRINSICS, RelocalisationParams(ratio=float(rng.uniform(0.6, 1.0))))
    anchors.points = pose.position + camera @ pose.rotation.T
    anchors.descriptors = draw(count)
    anchors.sigmas = np.full(count, 0.01)
    keys = int(rng.integers(1, 60))
    near = rng.integers(0, count, keys)
    pixels = np.clip(pixel[near] + rng.normal(0, 15, (keys, 2)), 0, [319, 199])
    descriptors = draw(keys)
    copied = rng.random(keys) < 0.5  # half of them a new look at an anchor's place
    noise = rng.normal(0, 3, (int(copied.sum()), 128)) if levels is None else 0.0
    descriptors[copied] = (anchors.descriptors[near[copied]] + noise).astype(np.float32)
    valid = rng.random(keys) < 0.9
    return anchors, pose, pixels, descriptors, valid


def test_the_guided_match_is_the_literal_anchor_by_anchor_one():
    """Against a match written out anchor by anchor, keypoint by keypoint (tests/bench/
    literal_relocalisation.py), on random maps and frames: the same keypoints take the same anchors."""
    from literal_relocalisation import literal_match

    rng = np.random.default_rng(11)
    matched_any = 0
    for _ in range(150):
        anchors, pose, pixels, descriptors, valid = _random_map_and_frame(rng, levels=None)
        sigma = float(rng.uniform(0.0, 0.3))
        keypoints, matched = anchors.match(pose, pixels, descriptors, valid, sigma)
        assert (keypoints.tolist(), matched.tolist()) == literal_match(
            anchors, pose, pixels, descriptors, valid, sigma
        )
        matched_any += len(matched) > 0
    assert matched_any > 50  # the cases are not all empty


def test_a_search_with_the_distances_worked_out_once_matches_as_keypoint_by_keypoint():
    """The search's match from every keypoint's distances to every anchor (``all_distances``, worked out
    once for the grid of predictions) against the keypoint-by-keypoint match, on descriptors drawn
    from a few values so that ties are common: the same keypoints, the same anchors, every time."""
    rng = np.random.default_rng(12)
    ties = 0
    for _ in range(300):
        anchors, pose, pixels, descriptors, valid = _random_map_and_frame(rng, levels=int(rng.integers(1, 4)))
        distances = anchors.all_distances(descriptors, valid)
        for row in np.flatnonzero(valid):
            ties += len(np.unique(distances[row])) < len(anchors)
        sigma = float(rng.uniform(0.0, 0.3))
        one_by_one = anchors.match(pose, pixels, descriptors, valid, sigma)
        at_once = anchors.match(pose, pixels, descriptors, valid, sigma, distances)
        assert [a.tolist() for a in one_by_one] == [a.tolist() for a in at_once]
    assert ties > 1000  # ties are common


def test_locate_is_the_literal_ransac_hypothesis_by_hypothesis():
    """``locate`` weighs every hypothesis at once; against RANSAC written out one hypothesis at a time,
    each centre by its own least squares (tests/bench/literal_relocalisation.py), drawing the same pairs:
    the same inliers and, to rounding, the same centre, on random scenes with outliers, points seen from
    behind and points that share a ray."""
    from literal_relocalisation import literal_locate

    rng = np.random.default_rng(13)
    found = 0
    for _ in range(60):
        rotation = facing_wall(float(rng.uniform(-30, 30)))
        centre = np.array([-2.0, 0.0, 1.0]) + rng.normal(0, 0.3, 3)
        count = int(rng.integers(8, 60))
        points = centre + (rng.uniform([-1, -0.6, 1.0], [1, 0.6, 3.0], (count, 3)) @ rotation.T)
        pixels, _ = project(points, centre, rotation, INTRINSICS)
        pixels = pixels + rng.normal(0, 0.8, pixels.shape)
        wrong = rng.random(count) < rng.uniform(0.0, 0.6)  # outliers: matched to the wrong place
        pixels[wrong] += rng.uniform(-60, 60, (int(wrong.sum()), 2))
        # points behind the camera on their pixel's ray (seen at that pixel, but from behind) ...
        behind = rng.random(count) < 0.2
        points[behind] = 2 * centre - points[behind]
        # ... and pairs of points on one ray, whose two rays fix no centre
        twins = rng.random(count) < 0.3
        points[twins] = centre + 1.5 * (points[np.roll(twins, 1)][: int(twins.sum())] - centre)
        pixels[twins] = pixels[np.roll(twins, 1)][: int(twins.sum())]
        params = RelocalisationParams(ransac_iterations=int(rng.integers(1, 80)))
        seed = int(rng.integers(0, 1 << 30))
        ours = locate(points, pixels, rotation, INTRINSICS, params, np.random.default_rng(seed))
        literal = literal_locate(points, pixels, rotation, INTRINSICS, params, np.random.default_rng(seed))
        assert (ours is None) == (literal is None)
        if ours is not None:
            found += 1
            assert ours[1].tolist() == literal[1].tolist()
            np.testing.assert_allclose(ours[0], literal[0], atol=1e-9)
    assert found > 20


def test_locate_keeps_the_first_of_two_equally_good_hypotheses_as_the_literal_ransac_does():
    """Two groups of as many matches, each consistent with a centre of its own (a repeated structure):
    the hypotheses of each group have as many inliers. ``locate`` keeps the first drawn, as the literal
    RANSAC does, whichever group that is for the random stream."""
    from literal_relocalisation import literal_locate

    rotation = facing_wall()
    rng = np.random.default_rng(14)
    centres = [np.array([-2.0, 0.3, 1.0]), np.array([-2.0, -0.5, 1.2])]
    points, pixels = [], []
    for centre in centres:
        group = centre + rng.uniform([-1, -0.6, 1.0], [1, 0.6, 3.0], (12, 3)) @ rotation.T
        points.append(group)
        pixels.append(project(group, centre, rotation, INTRINSICS)[0])
    points, pixels = np.vstack(points), np.vstack(pixels)
    params = RelocalisationParams()
    chosen = set()
    for seed in range(40):
        ours = locate(points, pixels, rotation, INTRINSICS, params, np.random.default_rng(seed))
        literal = literal_locate(points, pixels, rotation, INTRINSICS, params, np.random.default_rng(seed))
        assert ours is not None and literal is not None
        assert ours[1].tolist() == literal[1].tolist()
        chosen.add(int(np.argmin([np.linalg.norm(ours[0] - c) for c in centres])))
    assert chosen == {0, 1}  # the stream decides which group wins: the order matters
