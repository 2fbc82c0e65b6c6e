"""The robots' perception beside the mission's loop (maptidal.mission.perception): the worker process
gives the answers the inline path gives, frame for frame; its errors and its death reach the mission as
clear errors; and a robot has one frame in flight at a time."""

from __future__ import annotations

import os
import signal

import cv2
import numpy as np
import pytest

from maptidal.discovery import DiscoveryParams
from maptidal.exploration import FrontierParams
from maptidal.map_discovery import MapAwareParams, RobotMap, gap_views
from maptidal.mission.perception import (
    ExploreRequest,
    FrameJob,
    InlinePerception,
    PerceptionProcess,
    perceive,
    start_perception,
)
from maptidal.perception.frontend import FrontEnd, FrontEndParams
from maptidal.perception.keyframing import KeyframeParams
from maptidal.perception.recording import CameraIntrinsics, CameraPose

WIDTH, HEIGHT = 160, 100
INTRINSICS = CameraIntrinsics(WIDTH, HEIGHT, 120.0, 120.0, 80.0, 50.0, 0.075)
DISPARITY_PX = 9  # a wall 1 m ahead: fx * baseline / depth


def _wall_pair(shift_px: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A textured wall square to the camera: the right image is the left one moved by the disparity."""
    rng = np.random.default_rng(seed)
    wide = cv2.GaussianBlur(rng.integers(0, 256, (HEIGHT, WIDTH + 64), np.uint8), (5, 5), 1.5)
    texture = np.repeat(wide[:, :, None], 3, axis=2)
    left = np.ascontiguousarray(texture[:, 32 - shift_px : 32 - shift_px + WIDTH])
    right = np.ascontiguousarray(
        texture[:, 32 - shift_px + DISPARITY_PX : 32 - shift_px + DISPARITY_PX + WIDTH]
    )
    return left, right


def _pose(x: float) -> CameraPose:
    # optical axes: right = world -y, down = world -z, forward = world +x
    rotation = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return CameraPose(np.array([0.0, -x, 0.0]), rotation)


def _fronts(names=("rov0", "rov1")) -> dict[str, FrontEnd]:
    keyframes = KeyframeParams(min_interval_s=0.0, max_interval_s=1.0, min_translation_m=0.0)
    return {name: FrontEnd(INTRINSICS, "vo", FrontEndParams(keyframes=keyframes)) for name in names}


def _job(robot: str, k: int, pose: CameraPose | None = None) -> FrameJob:
    left, right = _wall_pair(shift_px=2 * k, seed=0)
    dead_reckoned = _pose(0.01 * k)
    return FrameJob(robot, float(k), left, right, pose or dead_reckoned, dead_reckoned, np.zeros((0, 6)))


def _answers(perception, frames: int = 4) -> list:
    answers = []
    for k in range(frames):
        for robot in ("rov0", "rov1"):
            if perception.pending(robot):
                answers.append(perception.result(robot))
            perception.submit(_job(robot, k))
    answers += [perception.result(robot) for robot in ("rov0", "rov1")]
    return answers


def test_the_worker_process_gives_the_inline_answers_frame_for_frame():
    inline = InlinePerception()
    inline.configure(_fronts(), DiscoveryParams())
    apart = PerceptionProcess(["rov0", "rov1"], (HEIGHT, WIDTH, 3))
    try:
        apart.configure(_fronts(), DiscoveryParams())
        expected, got = _answers(inline), _answers(apart)
    finally:
        apart.close()
    assert [a.robot for a in got] == [a.robot for a in expected]
    assert any(a.faces > 0 for a in expected), "the synthetic wall made no keyframe mesh"
    assert any(len(a.new_tasks) for a in expected), "discovery found nothing on the wall"
    for mine, theirs in zip(got, expected, strict=True):
        assert (mine.robot, mine.time_s, mine.faces, mine.visual_updates) == (
            theirs.robot,
            theirs.time_s,
            theirs.faces,
            theirs.visual_updates,
        )
        np.testing.assert_array_equal(mine.xy_correction, theirs.xy_correction)
        np.testing.assert_array_equal(mine.new_tasks, theirs.new_tasks)
    assert apart.wait_s > 0.0 and inline.wait_s == 0.0


def test_an_error_in_the_worker_is_raised_in_the_mission_with_its_frame():
    perception = PerceptionProcess(["rov0"], (HEIGHT, WIDTH, 3))
    try:
        perception.configure(_fronts(["rov0"]), DiscoveryParams())
        perception.submit(_job("rov0", 0, pose=CameraPose(np.array([np.nan, 0, 0]), None)))
        with pytest.raises(RuntimeError, match=r"perception of rov0's frame at 0.00 s failed"):
            perception.result("rov0")
    finally:
        perception.close()


def test_a_worker_that_dies_is_a_clear_error_not_a_hang():
    perception = PerceptionProcess(["rov0"], (HEIGHT, WIDTH, 3))
    try:
        perception.configure(_fronts(["rov0"]), DiscoveryParams())
        os.kill(perception.pid, signal.SIGKILL)
        # the send may find the pipe broken already, or the wait for the answer finds it closed
        with pytest.raises(RuntimeError, match="the perception worker exited"):
            perception.submit(_job("rov0", 0))
            perception.result("rov0")
    finally:
        perception.close()


@pytest.mark.parametrize("in_process", [True, False])
def test_a_robot_has_one_frame_in_flight_and_images_of_the_mission_size(in_process):
    perception = start_perception(["rov0"], (HEIGHT, WIDTH, 3), in_process=in_process)
    try:
        perception.configure(_fronts(["rov0"]), DiscoveryParams())
        perception.submit(_job("rov0", 0))
        with pytest.raises(RuntimeError, match="already has a frame"):
            perception.submit(_job("rov0", 1))
        perception.result("rov0")
        if not in_process:
            small = FrameJob(
                "rov0", 2.0, *(np.zeros((10, 10, 3), np.uint8),) * 2, _pose(0), _pose(0), np.zeros((0, 6))
            )
            with pytest.raises(ValueError, match="expected"):
                perception.submit(small)
    finally:
        perception.close()


def test_the_worker_serves_only_the_robots_it_was_started_for():
    perception = PerceptionProcess(["rov0"], (HEIGHT, WIDTH, 3))
    try:
        with pytest.raises(ValueError, match="serves"):
            perception.configure(_fronts(["rov0", "rov1"]), DiscoveryParams())
    finally:
        perception.close()


def test_a_robot_with_no_look_left_gets_views_of_its_maps_gaps_unless_a_teammate_holds_its_looks():
    """A robot's map holds a wall at x = 3 by dense depth alone, and its exploration counts nothing
    (the box it counts lies far away): no look is left. Asking for looks then brings the views of the
    map's gaps (maptidal.map_discovery.gap_views); with a look left, or looks held only for a teammate
    near them, it brings none."""
    rng = np.random.default_rng(3)
    y, z = np.meshgrid(np.arange(0.0, 4.0, 0.05), np.arange(0.0, 2.0, 0.05))
    wall = np.column_stack([np.full(y.size, 3.0), y.ravel(), z.ravel()]) + rng.normal(0, 0.005, (y.size, 3))
    camera = np.array([1.0, 2.0, 1.0])
    rotation = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # looking along +x
    nothing = FrontierParams(gain_box=((50.0, 50.0, 50.0), (51.0, 51.0, 51.0)))
    everything = FrontierParams()
    blank = np.zeros((HEIGHT, WIDTH, 3), np.uint8)

    def answer(params: FrontierParams, teammates=None, holding=None):
        robot_map = RobotMap(MapAwareParams())
        robot_map.add_surface(camera, wall)
        job = FrameJob(
            "rov0",
            1.0,
            blank,
            blank,
            CameraPose(camera, rotation),
            CameraPose(camera, rotation),
            np.zeros((0, 6)),
            teammates,
            ExploreRequest(params, camera.copy(), np.zeros((0, 3)), holding),
        )
        front = FrontEnd(INTRINSICS, "truth", FrontEndParams())
        return perceive(front, job, DiscoveryParams(), robot_map)

    explored = answer(nothing)
    assert len(explored.frontier) == 0 and len(explored.gap_tasks) >= 1
    assert np.all(explored.gap_tasks[:, 3] > 0.95)  # looking at the wall
    exploring = answer(everything)
    assert len(exploring.frontier) > 0 and len(exploring.gap_tasks) == 0
    # teammates all about the water the looks stand in, none near the wall or its views
    grid = np.stack(np.meshgrid([0.3, 0.9, 1.5], np.arange(-1.0, 5.01, 0.6), [0.3, 0.9, 1.5]), -1)
    teammates = np.column_stack([grid.reshape(-1, 3), np.zeros(grid.size // 3)])
    held = answer(everything, teammates)
    assert len(held.frontier) == 0 and held.held_for_teammates > 0 and len(held.gap_tasks) == 0
    # the same teammates, none of them holding looks (each said it had nothing left to do): looks again
    free = answer(everything, teammates, holding=np.zeros((0, 4)))
    assert len(free.frontier) > 0 and free.held_for_teammates == 0
    robot_map = RobotMap(MapAwareParams())
    robot_map.add_surface(camera, wall)
    assert len(gap_views(robot_map, camera, np.zeros((0, 6)), DiscoveryParams(), teammates).final) >= 1
