"""Capture stereo recordings from the simulator (issue [perception]): a robot flies a scripted path with the
simulator's physics and [controllers]' go-to-pose on its own dead-reckoned state, and every
``1 / frame_rate_hz`` seconds its stereo pair is rendered and written with two poses of its left camera:
the ground truth (``truth``) and the robot's dead reckoning (``dr``).

Two paths:

- ``paper``: the paper's protocol (Ruediger & Banerjee, Sec. IV.B): facing the end wall, "the robot was
  allowed to rise slowly a distance of about 0.5 m, and the first 7 keyframes were analyzed". The
  start is :class:`maptidal.keyframes.PaperCaptureParams` (the camera 1 m from the end wall on the
  centre line, rising from 0.75 to 1.25 m), at ``rise_speed_m_s`` (5 cm/s: "slowly").
- ``sweep``: the exploration pass of the synthetic keyframes (:class:`maptidal.keyframes.ExplorationParams`):
  a yaw sweep from -90 to 90 deg at the first height, a climb, and the sweep back at the second.

The robot flies in STABILIZE (roll and pitch held level by the autopilot), after ``settle_s`` of holding
the start pose so that the thrusters' lag and the controller's integrators have settled.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.controllers.estimation import rotation_from_rpy
from maptidal.controllers.pose import PoseController
from maptidal.controllers.trajectory import Hold, MotionLimits, PoseTrajectory, Route
from maptidal.envs.scenario import Scenario, load_scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.world import camera_offsets
from maptidal.files import save_mesh
from maptidal.keyframes import ExplorationParams, PaperCaptureParams
from maptidal.perception.recording import (
    CameraIntrinsics,
    CameraPose,
    Recording,
    RecordingWriter,
    load_recording,
    quaternion_from_rotation,
    rotation_from_quaternion,
)

PATHS = ("paper", "sweep")
SURFACE_FILE = "surface.ply"  # the tank's true surfaces (walls, floor, ladder), written beside the frames
# optical frame (x right, y down, z forward) in body axes (x forward, y left, z up)
OPTICAL_TO_BODY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class CaptureParams:
    """The path, the frame rate, the settling time and the speeds of the scripted flight."""

    path: str = "paper"
    frame_rate_hz: float = 5.0
    settle_s: float = 3.0
    rise_speed_m_s: float = 0.05
    yaw_rate_deg_s: float = 10.0
    paper: PaperCaptureParams = field(default_factory=PaperCaptureParams)
    sweep: ExplorationParams = field(default_factory=ExplorationParams)
    max_frames: int | None = None

    def __post_init__(self) -> None:
        if self.path not in PATHS:
            raise ValueError(f"path must be one of {PATHS}, got {self.path!r}")
        for name in ("frame_rate_hz", "rise_speed_m_s", "yaw_rate_deg_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive, got {value!r}")
        if not (math.isfinite(self.settle_s) and self.settle_s >= 0):
            raise ValueError(f"settle_s must be >= 0, got {self.settle_s!r}")


def camera_waypoints(params: CaptureParams) -> list[tuple[np.ndarray, float]]:
    """The path's camera (position, yaw) waypoints, in the tank frame, first to last."""
    if params.path == "paper":
        p = params.paper
        low = np.array([-p.distance_from_end_wall_m, 0.0, p.start_height_m])
        return [(low, 0.0), (low + [0.0, 0.0, p.rise_m], 0.0)]
    s = params.sweep
    low, high = (math.radians(s.yaw_min_deg), math.radians(s.yaw_max_deg))
    points = []
    for sweep, height in enumerate(s.heights_m):
        position = np.array([-s.distance_from_end_wall_m, 0.0, height])
        ends = (low, high) if sweep % 2 == 0 else (high, low)
        points += [(position, ends[0]), (position, ends[1])]
    return points


def camera_pose_from_body(position, rotation_body: np.ndarray, left_offset: np.ndarray) -> CameraPose:
    """The left camera's pose from a body pose (position, body-to-world rotation) and its body offset."""
    rotation_body = np.asarray(rotation_body, float)
    return CameraPose(
        np.asarray(position, float) + rotation_body @ left_offset, rotation_body @ OPTICAL_TO_BODY
    )


def place_camera(sim: Simulation, robot: str, pose: CameraPose) -> None:
    """Put ``robot`` where its left camera has ``pose`` (the inverse of :func:`camera_pose_from_body`), at
    rest: to render a recorded frame again."""
    spec = next(r for r in sim.scenario.robots if r.name == robot)
    left_offset = camera_offsets(spec.vehicle, sim.camera)["left"]
    rotation_body = pose.rotation @ OPTICAL_TO_BODY.T
    sim.place(
        robot, pose.position - rotation_body @ left_offset, quaternion=quaternion_from_rotation(rotation_body)
    )


def capture(
    out_dir: str | Path,
    scenario: Scenario | str | Path | None = None,
    params: CaptureParams | None = None,
    seed: int = 0,
    robot: str | None = None,
    progress: Callable[[float, float], None] | None = None,
    water_backend: str = "auto",
    camera: StereoCameraParams | None = None,
) -> Recording:
    """Fly ``params.path`` in ``scenario`` and write the recording to ``out_dir``; returns it loaded.
    ``water_backend`` is :class:`maptidal.envs.simulation.Simulation`'s (``"cpu"`` gives the same pixels on
    every machine); ``camera`` the stereo pair (default: the OAK-D at 640x400; the mission draws 320x200)."""
    params = params or CaptureParams()
    scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    sim = Simulation(scenario, camera=camera, flight_mode="stabilize", water_backend=water_backend)
    try:
        return _fly(sim, Path(out_dir), params, seed, robot or sim.robots[0], progress)
    finally:
        sim.close()


def _fly(sim: Simulation, out_dir: Path, params: CaptureParams, seed: int, robot: str, progress) -> Recording:
    sim.reset(seed=seed)
    spec = next(r for r in sim.scenario.robots if r.name == robot)
    if "stereo" not in spec.sensors:
        raise ValueError(f"{robot} has no stereo camera in this scenario")
    offsets = camera_offsets(spec.vehicle, sim.camera)
    centre = np.asarray(spec.vehicle.sensors.camera_position, float)
    waypoints = camera_waypoints(params)

    def body_target(camera_position: np.ndarray, yaw: float) -> np.ndarray:
        # the waypoints place the camera pair's centre; the body sits behind it
        return camera_position - rotation_from_rpy(0.0, 0.0, yaw) @ centre

    start_position, start_yaw = waypoints[0]
    sim.place(robot, body_target(start_position, start_yaw), start_yaw)
    k = np.array(sim.intrinsics()["K"])
    intrinsics = CameraIntrinsics(
        sim.camera.width,
        sim.camera.height,
        float(k[0, 0]),
        float(k[1, 1]),
        float(k[0, 2]),
        float(k[1, 2]),
        sim.camera.baseline_m,
    )
    metadata = {
        "scenario": sim.scenario.name,
        "tank": sim.scenario.tank.config.name,
        "surface": SURFACE_FILE,
        "robot": robot,
        "sensors": list(spec.sensors),
        # the simulator's dead reckoning: without a DVL, its horizontal velocity comes from the thrust
        # commands through the vehicle's motion model (maptidal.controllers.estimation.MotionModel)
        "dead_reckoning": "model-aided",
        "path": params.path,
        "seed": seed,
        "water": dataclasses.asdict(sim.scenario.water),
    }
    writer = RecordingWriter(out_dir, intrinsics, metadata)
    # the true surface, for the mesh error (a real recording has none)
    triangles = sim.scenario.tank.scene_triangles()
    save_mesh(out_dir / SURFACE_FILE, triangles.reshape(-1, 3), np.arange(len(triangles) * 3).reshape(-1, 3))
    controller = PoseController(spec.vehicle.controller_model(), hold_roll_pitch=False)
    limits = MotionLimits(
        max_speed=params.rise_speed_m_s,
        max_accel=0.05,
        max_yaw_rate=math.radians(params.yaw_rate_deg_s),
        max_yaw_accel=math.radians(params.yaw_rate_deg_s),
    )
    start = body_target(start_position, start_yaw)
    route = Route(
        [
            Hold(start, start_yaw, params.settle_s),
            *(
                PoseTrajectory(body_target(a, yaw_a), yaw_a, body_target(b, yaw_b), yaw_b, limits)
                for (a, yaw_a), (b, yaw_b) in itertools.pairwise(waypoints)
            ),
        ]
    )
    period = sim.scenario.control_period_s
    if params.frame_rate_hz > (1 + 1e-9) / period:
        raise ValueError(
            f"a frame rate of {params.frame_rate_hz:g} Hz is faster than the control period allows "
            f"({1 / period:g} Hz): frames are drawn once a control period"
        )
    frame_every = 1.0 / params.frame_rate_hz
    elapsed, next_frame = 0.0, params.settle_s
    while elapsed < route.duration - 1e-9:
        command = controller.update(sim.estimate(robot), route.at(elapsed), period)
        sim.step({robot: command})
        elapsed += period
        if elapsed >= next_frame - 1e-9:  # frames from the end of the settling hold on
            next_frame += frame_every
            _write_frame(sim, writer, robot, offsets["left"])
            if params.max_frames is not None and len(writer.frames) >= params.max_frames:
                return load_recording(out_dir)
        if progress is not None:
            progress(elapsed, route.duration)
    if not writer.frames or sim.time > writer.frames[-1]["time_s"] + 1e-6:
        _write_frame(sim, writer, robot, offsets["left"])  # the end of the path
    return load_recording(out_dir)


def _write_frame(sim: Simulation, writer: RecordingWriter, robot: str, left_offset: np.ndarray) -> None:
    left, right = sim.render_stereo(robot)
    truth = sim.ground_truth(robot)
    estimate = sim.estimate(robot)
    poses = {
        "truth": camera_pose_from_body(
            truth["position"], rotation_from_quaternion(truth["quaternion"]), left_offset
        ),
        "dr": camera_pose_from_body(estimate.position, rotation_from_rpy(*estimate.rpy), left_offset),
    }
    writer.add(sim.time, left, right, poses)
