"""Image observations drawn at their size: the cameras render at ``image_size`` with the OAK-D's field of
view, and ``obs_images="left"`` draws the left camera alone.

The reference is independent of the small camera: the OAK-D's own 640 x 400 image, shrunk with OpenCV's
area filter, which is what the environments returned before they drew at the size asked for."""

from __future__ import annotations

import cv2
import gymnasium
import numpy as np
import pytest

import maptidal.envs  # noqa: F401  (registers the MapTidal/ environments)
from maptidal.camera import StereoCameraParams
from maptidal.envs.simulation import Simulation


def _shrunk_reference(size: tuple[int, int]) -> np.ndarray:
    """The default scenario's first robot's left image at 640 x 400, resized to ``size`` (h, w)."""
    with Simulation(None) as sim:
        sim.reset(seed=1)
        left, _ = sim.render_stereo(sim.robots[0], water=False)
    return cv2.resize(left, (size[1], size[0]), interpolation=cv2.INTER_AREA)


@pytest.mark.parametrize("size", [(80, 128), (84, 84)])
def test_a_small_camera_sees_what_the_full_camera_sees_shrunk(size):
    # (84, 84) is not the sensor's 1.6 aspect: its pixels are taller than wide, as the resized image's
    # were; a square-pixel camera of that size would see another field of view (correlation about 0.4)
    reference = _shrunk_reference(size)
    camera = StereoCameraParams(width=size[1], height=size[0])
    with Simulation(None, camera=camera) as sim:
        sim.reset(seed=1)
        drawn = sim.render_left(sim.robots[0], water=False)
    assert drawn.shape == (*size, 3) and drawn.dtype == np.uint8
    difference = np.abs(drawn.astype(int) - reference.astype(int)).mean()
    correlation = np.corrcoef(drawn.ravel(), reference.ravel())[0, 1]
    assert difference < 6.0 and correlation > 0.98, (difference, correlation)


def test_render_left_is_the_left_image_of_the_pair_with_the_same_noise():
    images = []
    for draw in ("left", "stereo"):
        with Simulation(None, camera=StereoCameraParams(width=128, height=80)) as sim:
            sim.reset(seed=4)
            robot = sim.robots[0]
            images.append(sim.render_left(robot) if draw == "left" else sim.render_stereo(robot)[0])
    np.testing.assert_array_equal(images[0], images[1])  # the water's noise seed is drawn first for both


def test_render_left_with_depth_gives_the_left_depth():
    with Simulation(None, camera=StereoCameraParams(width=128, height=80)) as sim:
        sim.reset(seed=2)
        robot = sim.robots[0]
        left, depth = sim.render_left(robot, depth=True, water=False)
        _, _, stereo_depth, right_depth = sim.render_stereo(robot, depth=True, water=False)
    assert left.shape == (80, 128, 3) and depth.shape == (80, 128)
    np.testing.assert_array_equal(depth, stereo_depth)
    assert not np.array_equal(depth, right_depth)


def test_a_snapshot_names_only_left_and_right():
    with Simulation(None) as sim, pytest.raises(ValueError, match="sides"):
        sim.stereo_snapshot(sim.robots[0], sides=("middle",))


@pytest.mark.parametrize("images", ["left", "stereo"])
def test_the_environment_draws_its_images_at_image_size(images):
    env = gymnasium.make("MapTidal/GoToPose-v1", obs_images=images, image_size=(84, 84))
    try:
        camera = env.unwrapped.sim.camera
        assert (camera.height, camera.width) == (84, 84)
        observation, _ = env.reset(seed=0)
        expected = (84, 84, 3) if images == "left" else (2, 84, 84, 3)
        assert observation[images].shape == expected
        assert env.observation_space.contains(observation)
        observation, *_ = env.step(np.zeros(6, np.float32))
        assert observation[images].shape == expected and observation[images].std() > 1.0  # not blank
    finally:
        env.close()


def test_without_images_the_camera_is_the_oakd_mode():
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        camera = env.unwrapped.sim.camera
        assert (camera.width, camera.height) == (640, 400)
    finally:
        env.close()
