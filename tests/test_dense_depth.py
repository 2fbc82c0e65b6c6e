"""Dense stereo depth (maptidal.perception.dense) and its place in a robot's map: on pairs built by hand
(a textured image and its copy shifted by a written disparity, so that the depth is f B / d by
construction), on the simulator's own rendered walls against the renderer's depth buffer, and folded into
a RobotMap."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maptidal.map_discovery import MapAwareParams, RobotMap, near_teammates
from maptidal.perception.dense import (
    DenseDepthParams,
    dense_points,
    disparity_map,
    gray_noise_sigma,
    texture_threshold,
    textured_pixels,
)
from maptidal.perception.recording import CameraIntrinsics


def mission_camera(**changes) -> CameraIntrinsics:
    """The mission's 320 x 200 camera (f = 196 px, 7.5 cm baseline), with ``changes``."""
    values = {
        "width": 320,
        "height": 200,
        "fx": 196.0,
        "fy": 196.0,
        "cx": 160.0,
        "cy": 100.0,
        "baseline_m": 0.075,
    }
    return CameraIntrinsics(**{**values, **changes})


def textured(rng, shape=(200, 400)) -> np.ndarray:
    """A blotchy texture, as the tank's concrete: noise blurred at two scales."""
    import cv2

    fine = rng.uniform(0, 255, shape).astype(np.float32)
    coarse = cv2.GaussianBlur(fine, (0, 0), 4.0)
    image = 0.5 * cv2.GaussianBlur(fine, (0, 0), 1.0) + 2.0 * (coarse - coarse.mean()) + 128
    return np.clip(image, 0, 255).astype(np.uint8)


def shifted_pair(rng, disparity_of_column) -> tuple[np.ndarray, np.ndarray]:
    """A left image and its right partner: each column x of the left image at disparity d(x) shows what
    the right image holds at x - d (a whole-pixel shift, so no resampling blurs it)."""
    scene = textured(rng)
    width = 320
    left = scene[:, 40 : 40 + width]
    right = np.empty_like(left)
    for x in range(width):
        right[:, x] = scene[:, 40 + x + disparity_of_column(x)]
    return left, right


def test_a_fronto_parallel_plane_is_at_f_b_over_d():
    rng = np.random.default_rng(0)
    d = 12  # px: z = 196 x 0.075 / 12 = 1.225 m
    left, right = shifted_pair(rng, lambda x: d)
    k = mission_camera()
    points = dense_points(left, right, k, np.zeros(3), np.eye(3))
    assert len(points) > 0.7 * (320 // 8) * (200 // 8)
    expected = k.fx * k.baseline_m / d
    assert np.median(np.abs(points[:, 2] - expected)) < 0.01
    # each point lies on its pixel's ray: x / z = (u - cx) / fx at a cell centre (u = 4, 12, ...)
    u = points[:, 0] / points[:, 2] * k.fx + k.cx
    assert np.allclose((u - 4) / 8, np.round((u - 4) / 8), atol=1e-6)


def test_two_depths_side_by_side_are_told_apart():
    rng = np.random.default_rng(1)
    left, right = shifted_pair(rng, lambda x: 10 if x < 160 else 20)
    k = mission_camera()
    points = dense_points(left, right, k, np.zeros(3), np.eye(3))
    u = points[:, 0] / points[:, 2] * k.fx + k.cx
    near = points[(u > 180) & (u < 300), 2]
    far = points[(u > 40) & (u < 140), 2]
    assert np.median(far) == pytest.approx(k.fx * k.baseline_m / 10, abs=0.02)
    assert np.median(near) == pytest.approx(k.fx * k.baseline_m / 20, abs=0.01)


def test_the_pose_places_the_points_in_the_world():
    rng = np.random.default_rng(2)
    left, right = shifted_pair(rng, lambda x: 12)
    k = mission_camera()
    local = dense_points(left, right, k, np.zeros(3), np.eye(3))
    # a camera at (1, 2, 3) looking along world +x (optical frame columns: right, down, forward)
    rotation = np.column_stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]]).astype(float)
    position = np.array([1.0, 2.0, 3.0])
    world = dense_points(left, right, k, position, rotation)
    assert world.shape == local.shape
    assert np.allclose(world, position + local @ rotation.T)
    assert np.median(world[:, 0]) == pytest.approx(1.0 + k.fx * k.baseline_m / 12, abs=0.01)


def test_a_bare_pair_and_far_points_give_nothing_and_a_lost_pose_gives_nothing():
    k = mission_camera()
    flat = np.full((200, 320), 128, np.uint8)
    assert len(dense_points(flat, flat, k, np.zeros(3), np.eye(3))) == 0  # nothing to match
    rng = np.random.default_rng(3)
    left, right = shifted_pair(rng, lambda x: 4)  # 3.7 m: beyond max_depth_m
    assert len(dense_points(left, right, k, np.zeros(3), np.eye(3))) == 0
    near_left, near_right = shifted_pair(rng, lambda x: 12)
    assert len(dense_points(near_left, near_right, k, np.full(3, np.nan), np.eye(3))) == 0


def test_the_grey_images_noise_is_the_models():
    """Against a Monte-Carlo draw: an RGB patch of a fixed colour with independent Gaussian noise in each
    channel, rounded to 8 bits and turned grey by OpenCV, as the simulator's camera images are."""
    import cv2

    rng = np.random.default_rng(6)
    for sigma in (0.8, 2.0, 5.0):
        colour = np.array([70.3, 121.6, 95.45])
        rgb = colour + rng.normal(0.0, sigma, (400, 400, 3))
        gray = cv2.cvtColor(np.clip(np.round(rgb), 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
        assert gray.std() == pytest.approx(gray_noise_sigma(sigma), rel=0.03)
        single = np.clip(np.round(100.2 + rng.normal(0.0, sigma, (400, 400))), 0, 255).astype(np.uint8)
        assert single.std() == pytest.approx(gray_noise_sigma(sigma, channels=1), rel=0.03)


def test_the_texture_test_is_each_blocks_sample_std_against_the_threshold():
    """Against the literal construction: each pixel's block, reflected at the border, and numpy's sample
    standard deviation of it."""
    rng = np.random.default_rng(7)
    image = np.clip(np.round(100 + rng.normal(0, 2.0, (23, 31)) + np.arange(31) * 0.15), 0, 255)
    image = image.astype(np.uint8)
    for block in (3, 5, 7):
        half = block // 2
        padded = np.pad(image.astype(float), half, mode="reflect")
        stds = np.array(
            [
                [padded[v : v + block, u : u + block].std(ddof=1) for u in range(image.shape[1])]
                for v in range(image.shape[0])
            ]
        )
        threshold = float(np.median(stds))
        mask = textured_pixels(image, block, threshold)
        clear = np.abs(stds - threshold) > 1e-6  # a tie is no test of the arithmetic
        assert np.array_equal(mask[clear], (stds > threshold)[clear])
        assert 0.3 < mask.mean() < 0.7


def test_noise_alone_passes_the_texture_test_at_one_minus_the_confidence():
    """A flat patch under noise of the given std: the share of its blocks that pass is the false-alarm
    rate the chi-square bound promises (drawn here, not computed)."""
    rng = np.random.default_rng(8)
    sigma = 1.5
    flat = 110.5 + rng.normal(0.0, sigma, (400, 400))
    for confidence in (0.9, 0.99):
        passed = textured_pixels(flat, 5, texture_threshold(sigma, 5, confidence))
        assert passed.mean() == pytest.approx(1.0 - confidence, rel=0.15)
    assert texture_threshold(sigma, 5, 0.0) == 0.0


def test_a_bare_patch_under_noise_gets_no_depth_and_the_texture_keeps_its_own():
    """The upper half of the pair is a flat grey under independent noise in each image (as the water
    surface seen from below), the lower half a textured plane at 12 px. Without the texture test the
    matcher fits the noise in the upper half; with it the upper half gives (nearly) nothing, and the plane
    keeps every point."""
    rng = np.random.default_rng(9)
    left, right = (image.astype(float) for image in shifted_pair(rng, lambda x: 12))
    left[:100], right[:100] = 90.3, 90.3
    noisy = [
        np.clip(np.round(i + rng.normal(0, 2.0, i.shape)), 0, 255).astype(np.uint8) for i in (left, right)
    ]
    k = mission_camera()
    counts = {}
    for confidence in (0.0, 0.99):
        params = DenseDepthParams(pixel_noise_sigma=2.0, texture_confidence=confidence)
        points = dense_points(*noisy, k, np.zeros(3), np.eye(3), params)
        v = points[:, 1] / points[:, 2] * k.fy + k.cy
        plane = points[v > 104, 2]
        assert np.median(np.abs(plane - k.fx * k.baseline_m / 12)) < 0.01
        counts[confidence] = ((v < 96).sum(), len(plane))
    cells_above = 12 * 40  # rows of cells wholly in the upper half, times columns
    assert counts[0.0][0] > 0.1 * cells_above  # the matcher does fit the noise
    assert counts[0.99][0] <= 0.02 * cells_above
    assert counts[0.99][1] >= 0.98 * counts[0.0][1]


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="num_disparities"):
        DenseDepthParams(num_disparities=20)
    with pytest.raises(ValueError, match="block_size"):
        DenseDepthParams(block_size=4)
    with pytest.raises(ValueError, match="max_depth_m"):
        DenseDepthParams(max_depth_m=math.nan)
    with pytest.raises(ValueError, match="pixel_noise_sigma"):
        DenseDepthParams(pixel_noise_sigma=-1.0)
    with pytest.raises(ValueError, match="texture_confidence"):
        DenseDepthParams(texture_confidence=1.0)
    with pytest.raises(ValueError, match="sizes differ"):
        disparity_map(np.zeros((200, 320), np.uint8), np.zeros((200, 300), np.uint8), DenseDepthParams())


def test_the_simulators_bare_wall_is_at_the_rendered_depth():
    """A robot 1 m from the tank's plain side wall and looking at it: the dense depth against the
    renderer's own depth buffer, which shares nothing with the matching."""
    from maptidal.camera import StereoCameraParams
    from maptidal.envs.simulation import Simulation

    sim = Simulation("assets/scenarios/mission.toml", camera=StereoCameraParams(width=320, height=200))
    sim.reset(seed=0)
    sim.place("rov0", [-1.0, 0.7, 1.0], yaw_rad=math.radians(90.0))
    left, right, depth, _ = sim.render_stereo("rov0", depth=True)
    calibration = sim.intrinsics()
    matrix = calibration["K"]
    k = mission_camera(fx=matrix[0][0], fy=matrix[1][1], cx=matrix[0][2], cy=matrix[1][2])
    points = dense_points(left, right, k, np.zeros(3), np.eye(3))
    assert len(points) > 0.6 * (320 // 8) * (200 // 8)  # the bare wall gives depth almost everywhere
    u = np.round(points[:, 0] / points[:, 2] * k.fx + k.cx).astype(int)
    v = np.round(points[:, 1] / points[:, 2] * k.fy + k.cy).astype(int)
    error = np.abs(points[:, 2] - depth[v, u])
    assert np.median(error) < 0.02 and np.percentile(error, 90) < 0.05
    sim.close()


def test_the_simulators_water_surface_seen_from_below_gives_no_depth():
    """A robot half a metre under the surface, looking at the side wall: above the wall's top edge the
    camera sees the surface from below, where the renderer's depth is its far clip. The matcher fits the
    noise there (the texture test off); with the test set from the scenario's camera noise, next to none
    of those points remain, and the wall keeps nearly all its accurate ones."""
    from maptidal.camera import StereoCameraParams
    from maptidal.envs.simulation import Simulation

    sim = Simulation("assets/scenarios/mission.toml", camera=StereoCameraParams(width=320, height=200))
    sim.reset(seed=0)
    sim.place("rov1", [-5.0, 0.0, 0.4])  # out of view
    sim.place("rov0", [-1.0, 0.0, 1.5], yaw_rad=math.radians(90.0))
    left, right, depth, _ = sim.render_stereo("rov0", depth=True)
    noise = sim.scenario.water.noise_sigma
    assert noise > 0
    matrix = sim.intrinsics()["K"]
    k = mission_camera(fx=matrix[0][0], fy=matrix[1][1], cx=matrix[0][2], cy=matrix[1][2])
    sim.close()
    found = {}
    for confidence in (0.0, 0.99):
        params = DenseDepthParams(pixel_noise_sigma=noise, texture_confidence=confidence)
        points = dense_points(left, right, k, np.zeros(3), np.eye(3), params)
        u = np.round(points[:, 0] / points[:, 2] * k.fx + k.cx).astype(int)
        v = np.round(points[:, 1] / points[:, 2] * k.fy + k.cy).astype(int)
        truth = depth[v, u]
        found[confidence] = ((truth > 40.0).sum(), (np.abs(points[:, 2] - truth) < 0.05).sum())
    assert found[0.0][0] >= 30  # open water put at 0.5 to 3 m
    assert found[0.99][0] <= 0.15 * found[0.0][0]
    assert found[0.99][1] >= 0.9 * found[0.0][1]


def test_a_map_folds_in_dense_depth_one_point_a_cell_and_carves_to_it():
    params = MapAwareParams()
    rng = np.random.default_rng(4)
    # a wall at x = 2, points 3 cm apart (several to a 10 cm cell), seen from the origin
    y, z = np.meshgrid(np.arange(-0.5, 0.5, 0.03), np.arange(0.5, 1.5, 0.03))
    wall = np.column_stack([np.full(y.size, 2.0), y.ravel(), z.ravel()]) + rng.normal(0, 0.002, (y.size, 3))
    camera = np.array([0.0, 0.0, 1.0])
    dense = RobotMap(params)
    dense.add_surface(camera, wall)
    cells = np.unique(np.floor(wall / params.coverage_voxel_m), axis=0)
    assert len(dense.surface) == len(cells) == len(dense.points())
    # the rays carved are those a keyframe's landmarks at the same places carve
    keyed = RobotMap(params)
    keyed.add_keyframe(camera, np.arange(len(wall)), wall)
    assert dense.free_voxels == keyed.free_voxels and len(dense.free_voxels) > 0
    # landmarks and dense points together are the map's surface
    keyed.add_surface(camera, wall)
    assert len(keyed.points()) == len(wall) + len(cells)


def test_dense_points_on_a_teammate_or_with_nans_are_not_kept():
    params = MapAwareParams()
    robot_map = RobotMap(params)
    points = np.array([[2.0, 0.0, 1.0], [2.0, 1.0, 1.0], [np.nan, 0.0, 0.0]])
    teammate = np.array([[2.0, 1.0, 1.0, 0.0]])
    robot_map.add_surface(np.array([0.0, 0.0, 1.0]), points, teammates=teammate)
    kept = robot_map.points()
    assert len(kept) == 1 and np.allclose(kept[0], points[0])
    assert not near_teammates(kept, teammate, params).any()
    robot_map.add_surface(np.full(3, np.nan), points)  # a lost pose adds nothing
    assert len(robot_map.points()) == 1


def test_the_maps_points_follow_every_change():
    """points() is stacked once per change of the map: asked between changes it must still show each."""
    robot_map = RobotMap(MapAwareParams())
    camera = np.array([0.0, 0.0, 1.0])
    assert robot_map.points().shape == (0, 3)
    robot_map.add_keyframe(camera, np.array([7]), np.array([[2.0, 0.0, 1.0]]))
    assert len(robot_map.points()) == 1
    robot_map.add_surface(camera, np.array([[2.0, 0.5, 1.0]]))
    assert len(robot_map.points()) == 2
    robot_map.add_keyframe(camera, np.array([7]), np.array([[2.0, 0.1, 1.0]]))  # landmark 7 moves
    assert np.allclose(robot_map.points()[0], [2.0, 0.1, 1.0])


def test_the_maps_points_are_its_dicts_values_in_order_however_many():
    """points() lists the landmarks then the dense points, each in its dict's order (a key keeps its
    first place), past the tables' first growth, and for a map built with points already in it."""
    rng = np.random.default_rng(5)
    robot_map = RobotMap(MapAwareParams())
    camera = np.array([0.0, 0.0, 1.0])
    for _ in range(3):
        ids = rng.choice(400, 300, replace=False)
        robot_map.add_keyframe(camera, ids, rng.uniform(1.0, 2.0, (300, 3)))
        robot_map.add_surface(camera, rng.uniform(1.0, 3.0, (500, 3)))
    expected = np.stack(list(robot_map.landmarks.values()) + list(robot_map.surface.values()))
    assert len(expected) > 600 and np.array_equal(robot_map.points(), expected)
    given = RobotMap(MapAwareParams(), landmarks={3: np.array([1.0, 2.0, 3.0])})
    assert np.array_equal(given.points(), [[1.0, 2.0, 3.0]])
