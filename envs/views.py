"""Views of the world for people: a third-person frame with each robot's camera image inset (the gym
environments' ``rgb_array`` render, and the frames of a mission's video)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import mujoco
import numpy as np

from maptidal.envs.rendering import CAMERA_SCENE_OPTION
from maptidal.envs.simulation import Simulation


def follow_camera(sim: Simulation, robot: str, n_robots: int = 1) -> mujoco.MjvCamera:
    """A camera tracking ``robot`` from behind and above (further back with more robots inset)."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    camera.trackbodyid = sim.model.body(f"{robot}/base").id
    camera.distance, camera.elevation, camera.azimuth = 2.5 + 0.5 * (n_robots - 1), -20.0, 200.0
    return camera


def overview_camera(look_at: Sequence[float], distance_m: float = 4.5) -> mujoco.MjvCamera:
    """A free camera behind the team, looking down 30 degrees towards the end wall (+x) at ``look_at``."""
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:] = np.asarray(look_at, float)
    camera.distance, camera.elevation, camera.azimuth = distance_m, -30.0, 0.0  # looking along +x
    return camera


def third_person_frame(
    sim: Simulation,
    renderer: mujoco.Renderer,
    robots: list[str],
    camera: mujoco.MjvCamera | None = None,
    insets: Mapping[str, np.ndarray] | None = None,
    labels: bool = False,
) -> np.ndarray:
    """The ``camera``'s view (default: :func:`follow_camera` on the first robot), with each robot's left
    camera image inset along the top right: the images in ``insets`` where given, else rendered now;
    with ``labels``, each inset carries its robot's name."""
    camera = camera if camera is not None else follow_camera(sim, robots[0], len(robots))
    renderer.update_scene(sim.data, camera=camera, scene_option=CAMERA_SCENE_OPTION)  # no sonar rays
    frame = renderer.render().copy()
    height, width = frame.shape[:2]
    size = (width // (2 + len(robots)), height // (2 + len(robots)))
    right = width - 4
    for robot in robots:
        left = insets.get(robot) if insets is not None else None
        if left is None:
            left = sim.render_left(robot)
        frame[4 : 4 + size[1], right - size[0] : right] = cv2.resize(left, size, interpolation=cv2.INTER_AREA)
        if labels:  # the robot's name in the inset's corner, for a view with several robots
            corner = (right - size[0] + 3, 4 + size[1] - 4)
            cv2.putText(frame, robot, corner, cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
        right -= size[0] + 4
    return frame
