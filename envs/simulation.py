"""The simulation API: load a scenario, step robots with pilot or thruster commands, read sensors.

Example::

    from maptidal.envs.simulation import Simulation
    sim = Simulation("assets/scenarios/default.toml")
    sim.reset(seed=1)
    for _ in range(100):
        sim.step({"rov0": {"surge": 0.5}})
    print(sim.ground_truth("rov0")["position"], sim.sensors("rov0")["depth"])
    left, right = sim.render_stereo("rov0")

Commands are the normalised 6-DOF pilot command of :mod:`maptidal.controllers.convention`,
mixed into thruster commands by ArduSub's mixer for the robot's frame; pass
``mode="thrusters"`` to command each thruster directly (M1 first, in [-1, 1]).

``Simulation(..., flight_mode="stabilize")`` or :meth:`Simulation.set_flight_mode` flies a robot in an
ArduSub flight mode (:mod:`maptidal.controllers.flight_modes`: manual, stabilize, alt_hold, poshold) on the
state estimated from its own sensors; the API's default is "manual", so that a pilot command is exactly the
mixer's input, while ``maptidal sim`` flies STABILIZE, as ArduSub pilots do.
"""

from __future__ import annotations

import copy
import functools
import math
import queue
import time
import weakref
from collections.abc import Mapping
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import mujoco
import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.controllers.convention import pilot_command
from maptidal.controllers.estimation import (
    DeadReckoning,
    EstimatorParams,
    MotionModel,
    StateEstimate,
    rpy_from_rotation,
)
from maptidal.controllers.flight_modes import FLIGHT_MODES, FlightController, ModeParams
from maptidal.controllers.mixing import MixerParams, mix
from maptidal.controllers.pose import VehicleModel
from maptidal.controllers.thrusters import linearise_thrusters
from maptidal.envs import hydrodynamics
from maptidal.envs.gl_water import CameraGeometry
from maptidal.envs.native_flight import NativeFlight, check_flight_backend, native_available
from maptidal.envs.rendering import (
    check_render_samples,
    depth_coefficients,
    geoms_behind_camera,
    gl_water_available,
    release,
    render_camera,
    render_camera_underwater,
    renders_on_gpu,
    update_camera_scene,
)
from maptidal.envs.scenario import MAX_CURRENT_M_S, Scenario, check_current, load_scenario
from maptidal.envs.sensors import RobotSensors, SensorNoise
from maptidal.envs.vehicle import VehicleParams
from maptidal.envs.water import WaterModel, WaterParams, depth_to_range, worker_thread
from maptidal.envs.world import DEPTH_SENSOR_POSITION, RobotPlacement, camera_offsets, compose

WATER_BACKENDS = ("auto", "gl", "cpu", "prefer-gl")


def check_water_backend(backend: object) -> str:
    """``backend`` if it names a water backend (:attr:`Simulation.water_backend`), else ValueError."""
    if backend not in WATER_BACKENDS:
        raise ValueError(f"water_backend must be one of {WATER_BACKENDS}, got {backend!r}")
    return backend


# the warnings MuJoCo counts when it resets a bad state itself
_BAD_STATE_WARNINGS = [
    int(mujoco.mjtWarning.mjWARN_BADQPOS),
    int(mujoco.mjtWarning.mjWARN_BADQVEL),
    int(mujoco.mjtWarning.mjWARN_BADQACC),
]


def step_physics(model: mujoco.MjModel, data: mujoco.MjData, n_steps: int) -> None:
    """``n_steps`` MuJoCo steps, the sensors computed in the last only.

    Nothing reads the sensors between the steps of one call, and they do not feed the dynamics, so the
    state is bit for bit that of ``mj_step(model, data, nstep=n_steps)`` and so is ``data.sensordata``
    afterwards (mj_step computes the sensors of the state it starts from, so those of the last step are
    those the full loop ends with). It spares the IMU's accelerometer (which asks MuJoCo for the
    constraint forces) and the DVL's four rangefinder rays at every step but one: about a fifth of
    the BlueROV2's physics step. The model's other disable flags are kept and restored."""
    n_steps = int(n_steps)
    if n_steps > 1:
        flags = model.opt.disableflags
        model.opt.disableflags = flags | mujoco.mjtDisableBit.mjDSBL_SENSOR
        try:
            mujoco.mj_step(model, data, nstep=n_steps - 1)
        finally:
            model.opt.disableflags = flags
    if n_steps > 0:
        mujoco.mj_step(model, data)


class SimulationError(RuntimeError):
    """The physics went bad (NaN or diverging state); the message says when and for whom."""


@dataclass(frozen=True)
class Contact:
    """A contact involving a robot: which robot, what it touches, where, and the normal force (N)."""

    robot: str
    other: str
    position: tuple[float, float, float]
    normal_force_n: float


# a snapshot's scene holds as many geoms as mujoco.Renderer's own does by default
SNAPSHOT_MAX_GEOM = 10000


@dataclass(frozen=True)
class StereoSnapshot:
    """A robot's stereo pair, or one of its cameras, as it is at one moment, to draw later
    (:meth:`Simulation.stereo_snapshot`): each camera's scene, and each frame's noise seed (None without
    the water model), in the order of ``sides``."""

    robot: str
    scenes: tuple[mujoco.MjvScene, ...]
    seeds: tuple[int | None, ...]
    water: bool
    on_gl: bool
    depth: bool
    sides: tuple[str, ...] = ("left", "right")


# the path is counted in steps of at least this (m): station keeping bobs the body by a few mm every
# control period (the depth loop's limit cycle), which would add metres of "travel" over a mission
PATH_STEP_M = 0.05


@dataclass
class Odometry:
    """What one robot has done since the reset, measured on the simulated truth: the distance its body
    travelled (m: a polyline through its positions, a vertex whenever it is :data:`PATH_STEP_M` from the
    last, so a few mm of bobbing adds nothing; a teleport by :meth:`Simulation.place` adds nothing) and
    the electrical energy its thrusters drew (J: each thruster's power at its lagged thrust,
    :class:`maptidal.controllers.thrusters.ThrusterPower`, times the time stepped), and the time it
    spent touching the tank or a teammate (s, counted a control period at a time)."""

    path_m: float = 0.0
    thruster_energy_j: float = 0.0
    # the time its hull touched the tank or a teammate (s): what a collision costs, seen
    contact_s: float = 0.0
    # the path's last vertex (None: the next position starts the path)
    last_vertex: tuple[float, float, float] | None = field(default=None, repr=False, compare=False)

    def move_to(self, position) -> None:
        """Add the body's new position (x, y, z) to the path: a vertex if it is a path step from the
        last."""
        position = tuple(float(v) for v in position)
        if self.last_vertex is None:
            self.last_vertex = position
            return
        step = math.dist(position, self.last_vertex)
        if step >= PATH_STEP_M:
            self.path_m += step
            self.last_vertex = position


class Simulation:
    """A scenario running in MuJoCo with Fossen hydrodynamics, thrusters, sensors and cameras.

    ``render_samples`` is the multisample anti-aliasing of the camera images (MuJoCo's
    ``visual/quality/offsamples``; 0 turns it off)."""

    def __init__(
        self,
        scenario: Scenario | str | Path | None = None,
        camera: StereoCameraParams | None = None,
        hydrodynamics_backend: str = "native",
        water_backend: str = "auto",
        flight_mode: str = "manual",
        mode_params: ModeParams | None = None,
        render_samples: int = 4,
        motion_model_error: float = 0.0,
        flight_backend: str = "native",
    ) -> None:
        check_render_samples(render_samples)
        check_flight_backend(flight_backend)
        if not (math.isfinite(motion_model_error) and 0.0 <= motion_model_error < 1.0):
            raise ValueError(f"motion_model_error must be in [0, 1), got {motion_model_error!r}")
        # how far off the coefficients of the estimators' motion models are (MotionModel.perturbed): 0,
        # the simulator's own, is the best a vehicle's owner can hope for
        self.motion_model_error = motion_model_error
        self.mode_params = mode_params or ModeParams()
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        self.camera = camera or StereoCameraParams()
        self.backend = hydrodynamics.install_callback(prefer_native=hydrodynamics_backend == "native")
        placements = [
            RobotPlacement(r.name, r.vehicle, r.position, math.radians(r.yaw_deg))
            for r in self.scenario.robots
        ]
        spec = compose(self.scenario.tank, placements, self.scenario.timestep_s, camera=self.camera)
        self.model = spec.compile()
        # multisample anti-aliasing of the off-screen images: 4 (MuJoCo's default) stands for a lens's
        # blur; 0 halves the render time on a CPU rasteriser, with jagged edges (docs/mission.md, "Speed")
        self.model.vis.quality.offsamples = render_samples
        self.data = mujoco.MjData(self.model)
        self.robots = [r.name for r in self.scenario.robots]
        self._specs = {r.name: r for r in self.scenario.robots}
        self._slots: dict[str, hydrodynamics.RobotSlot] = {}
        self._sensors: dict[str, RobotSensors] = {}
        self._mixers: dict[str, MixerParams] = {}
        self._vehicle_models: dict[str, VehicleModel] = {}  # what the robots know of themselves
        self._ctrl_adr: dict[str, int] = {}
        for robot in self.scenario.robots:
            body = self.model.body(f"{robot.name}/base")
            joint = self.model.joint(f"{robot.name}/root")
            actuator = self.model.actuator(f"{robot.name}/thruster1")
            self._ctrl_adr[robot.name] = int(actuator.id)
            self._slots[robot.name] = hydrodynamics.RobotSlot(
                int(body.id), int(joint.dofadr[0]), int(self.model.actuator_actadr[actuator.id])
            )
            mounts = robot.vehicle.sensors
            self._sensors[robot.name] = RobotSensors(
                self.model,
                f"{robot.name}/",
                robot.sensors,
                self.scenario.noise,
                (mounts.dvl_min_range_m, mounts.dvl_max_range_m),
                self.scenario.tank.height,
            )
            self._mixers[robot.name] = MixerParams(frame=robot.vehicle.ardusub_frame)
            self._vehicle_models[robot.name] = robot.vehicle.controller_model()
        # the vehicles the physics flies (set_plant): the scenario's, unless randomised; the robots'
        # controllers, estimators and autopilots keep the scenario's, what a robot believes of itself
        self._plants: dict[str, VehicleParams] = {r.name: r.vehicle for r in self.scenario.robots}
        self._thruster_gains: dict[str, np.ndarray] = {
            r.name: np.ones(r.vehicle.n_thrusters) for r in self.scenario.robots
        }
        check_water_backend(water_backend)
        self.water = WaterModel(self.scenario.water)
        self._requested_water_backend = water_backend
        self._resolved_water_backend: str | None = None
        depth_shift, depth_scale = (float(v) for v in depth_coefficients(self.model))
        cam = self.camera
        self._geometry = CameraGeometry(cam.fx, cam.fy, cam.cx, cam.cy, depth_shift, depth_scale)
        self.rng = np.random.default_rng()
        self.wall_time_s = 0.0
        # the process-wide renderer of this model (and its GL context) goes when the simulation does
        self._release_renderer = weakref.finalize(self, release, self.model)
        self._release_renderer.atexit = False  # at exit, maptidal.envs.rendering frees every renderer itself
        self._flight_modes = dict.fromkeys(self.robots, flight_mode)
        self._autopilots: dict[str, _Autopilot] = {}
        self._thruster_outputs: dict[str, np.ndarray] = {}
        # one dead-reckoning estimator per robot that flies a flight mode or was asked to track one;
        # updated once per control period, after the physics, from the period's one sensor reading
        self._tracked: set[str] = set()
        self._estimators: dict[str, DeadReckoning] = {}
        self._readings: dict[str, dict] = {}
        self._odometry: dict[str, Odometry] = {}
        self._robot_of_body = {slot.body_id: name for name, slot in self._slots.items()}
        # where each robot's position lies in qpos (its free joint's), read for the odometry: xpos lags
        # qpos by a physics step after mj_step, and set_state recomputes it
        self._position_adr = {
            name: int(self.model.jnt_qposadr[self.model.body_jntadr[slot.body_id]])
            for name, slot in self._slots.items()
        }
        # scenes for stereo snapshots, reused: allocating one costs about 20 ms
        self._free_scenes: queue.SimpleQueue[mujoco.MjvScene] = queue.SimpleQueue()
        # each camera's own-body geoms behind its near plane, left out of its scenes (no pixel changes)
        self._hidden_geoms: dict[str, np.ndarray] = {}
        # the compiled flight stack (maptidal.envs.native_flight), where it builds and the hydrodynamics
        # are the C callback; the Python below is its reference and the fallback
        use_native = flight_backend == "native" and native_available(self.backend)
        self._native = NativeFlight(self, PATH_STEP_M) if use_native else None
        self.reset()

    def close(self) -> None:
        """Free this simulation's renderer and GL context now (also done when it is garbage collected)."""
        self._release_renderer()

    def __enter__(self) -> Simulation:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

    # ----- state ------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time (s) since reset."""
        return float(self.data.time)

    def reset(self, seed: int | None = None) -> None:
        """Put every robot back at its start pose, at rest, thrusters idle; reseed the noise."""
        mujoco.mj_resetData(self.model, self.data)
        self.rng = np.random.default_rng(seed)
        hydrodynamics.pack_userdata(
            self.data.userdata,
            [self._slots[name] for name in self.robots],
            [self._plants[name] for name in self.robots],
            np.asarray(self.scenario.current),
            water_surface_z=self.scenario.tank.height,
        )
        for sensors in self._sensors.values():
            sensors.reset(self.rng)
        mujoco.mj_forward(self.model, self.data)
        self.wall_time_s = 0.0
        self._odometry = {robot: Odometry() for robot in self.robots}
        for robot, mode in self._flight_modes.items():
            self.set_flight_mode(robot, mode)

    # what get_state copies besides MuJoCo's integration state: the noise generator and sensor biases,
    # the flight modes and autopilots, the estimators, the last readings and thruster outputs
    _STATE_ATTRIBUTES = (
        "rng",
        "_sensors",
        "_flight_modes",
        "_autopilots",
        "_estimators",
        "_readings",
        "_thruster_outputs",
        "_tracked",
        "_plants",
        "_thruster_gains",
        "water",
        "_odometry",
    )
    STATE_VERSION = 2  # 2: with the odometry

    def get_state(self) -> dict:
        """Everything the simulation's future depends on, copied: MuJoCo's integration state
        (``mj_getState``: time, positions, velocities, warm start, controls, applied forces and the
        userdata that holds the water current and the thrusters' states) and the Python side (the noise
        generator, sensor biases, flight modes with their autopilots' integrators, the estimators, the
        last readings). :meth:`set_state` puts it back, on this simulation or another of the same
        scenario, and the same commands then give the same trajectory, bit for bit."""
        physics = np.empty(mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_INTEGRATION))
        mujoco.mj_getState(self.model, self.data, physics, mujoco.mjtState.mjSTATE_INTEGRATION)
        return {
            "version": self.STATE_VERSION,
            "layout": self._state_layout(),
            "physics": physics,
            "python": copy.deepcopy({name: getattr(self, name) for name in self._STATE_ATTRIBUTES}),
        }

    def set_state(self, state: dict) -> None:
        """Restore a :meth:`get_state`; a state from another version or another world (other robots,
        another model size) raises ValueError and changes nothing."""
        if not isinstance(state, dict) or state.get("version") != self.STATE_VERSION:
            got = state.get("version") if isinstance(state, dict) else type(state).__name__
            raise ValueError(f"a simulation state of version {self.STATE_VERSION} is needed, got {got!r}")
        here = self._state_layout()
        if state.get("layout") != here:
            raise ValueError(f"the state is of another world: {state.get('layout')!r}, this one is {here!r}")
        physics = np.asarray(state["physics"], float)
        mujoco.mj_setState(self.model, self.data, physics, mujoco.mjtState.mjSTATE_INTEGRATION)
        mujoco.mj_forward(self.model, self.data)  # positions and sensors derived from the state
        for name, value in copy.deepcopy(state["python"]).items():
            setattr(self, name, value)
        for robot in self.robots:  # the plants' numbers that live in the model, not in its state
            self._apply_plant_to_model(robot)

    def _state_layout(self) -> tuple:
        """What a state must match to be put back here: the robots and the model's sizes."""
        m = self.model
        return (tuple(self.robots), m.nq, m.nv, m.na, m.nu, m.nuserdata)

    def place(self, robot: str, position, yaw_rad: float = 0.0, quaternion=None) -> None:
        """Put ``robot`` at ``position`` (m, world) with heading ``yaw_rad`` (counter-clockwise from +x),
        level, or with the attitude ``quaternion`` (w, x, y, z) when given; at rest, thrusters idle; its
        flight mode's estimator restarts there."""
        slot = self._slots[self._check(robot)]
        values = np.asarray(position, float)
        if values.shape != (3,) or not np.all(np.isfinite(values)) or not math.isfinite(yaw_rad):
            raise ValueError(
                f"{robot}: a placement needs a finite (x, y, z) and yaw, got {position}, {yaw_rad}"
            )
        joint = self.model.body_jntadr[slot.body_id]
        qpos = self.model.jnt_qposadr[joint]
        attitude = np.array([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])
        if quaternion is not None:
            attitude = np.asarray(quaternion, float)
            if attitude.shape != (4,) or not np.all(np.isfinite(attitude)) or np.linalg.norm(attitude) < 1e-9:
                raise ValueError(
                    f"{robot}: a quaternion is four finite numbers, not all zero; got {quaternion}"
                )
            attitude = attitude / np.linalg.norm(attitude)
        self.data.qpos[qpos : qpos + 3] = values
        self.data.qpos[qpos + 3 : qpos + 7] = attitude
        self._odometry[robot].last_vertex = None  # a teleport is no travel: the path restarts here
        self.data.qvel[slot.dof_adr : slot.dof_adr + 6] = 0.0
        self._sensors[robot].mean_specific_force = None  # no period flown from here yet
        n = self._specs[robot].vehicle.n_thrusters
        self.data.act[slot.act_adr : slot.act_adr + n] = 0.0
        self.data.ctrl[self._ctrl_adr[robot] : self._ctrl_adr[robot] + n] = 0.0
        mujoco.mj_forward(self.model, self.data)
        self.set_flight_mode(robot, self._flight_modes[robot])

    def set_plant(self, robot: str, vehicle: VehicleParams, thruster_gains=None) -> None:
        """Fly ``robot``'s physics as ``vehicle`` from now on (its mass and inertia, buoyancy and centre
        of buoyancy, added mass, damping, thrust curve and lag), each thruster's thrust times
        ``thruster_gains`` (default 1; above 1 a thruster can push harder than the curve's maximum).
        Its controllers, estimator and autopilot keep the scenario's vehicle: what a robot believes of
        itself, so a plant that differs is the gap between a model and a real vehicle (domain
        randomisation, :mod:`maptidal.envs.randomization`). :meth:`reset` keeps the plant; the
        scenario's vehicle puts it back. Set it between :meth:`reset` and the first step: it rewrites
        every robot's hydrodynamics parameters, the water current included."""
        believed = self._specs[self._check(robot)].vehicle
        if vehicle.n_thrusters != believed.n_thrusters or vehicle.ardusub_frame != believed.ardusub_frame:
            raise ValueError(
                f"{robot}: a plant must have the robot's frame ({believed.ardusub_frame}, "
                f"{believed.n_thrusters} thrusters), got {vehicle.ardusub_frame} with {vehicle.n_thrusters}"
            )
        gains = np.ones(vehicle.n_thrusters) if thruster_gains is None else np.asarray(thruster_gains, float)
        if gains.shape != (vehicle.n_thrusters,) or not (np.all(np.isfinite(gains)) and np.all(gains > 0)):
            raise ValueError(
                f"{robot}: thruster_gains must be {vehicle.n_thrusters} positive finite numbers, "
                f"got {np.asarray(thruster_gains).tolist()}"
            )
        self._plants[robot] = vehicle
        self._thruster_gains[robot] = gains.copy()
        self._apply_plant_to_model(robot)
        block = self.data.userdata
        current = block[hydrodynamics.HEADER + hydrodynamics.SLOT_CURRENT :][:3].copy()
        enabled = bool(block[2])
        hydrodynamics.pack_userdata(
            block,
            [self._slots[name] for name in self.robots],
            [self._plants[name] for name in self.robots],
            current,
            enabled=enabled,
            water_surface_z=self.scenario.tank.height,
        )

    def plant(self, robot: str) -> VehicleParams:
        """The vehicle ``robot``'s physics flies (:meth:`set_plant`; the scenario's by default)."""
        return self._plants[self._check(robot)]

    def _apply_plant_to_model(self, robot: str) -> None:
        """Write the plant's numbers that MuJoCo's model holds: the body's mass and inertia, the
        thrusters' lag and their control range (a gain above 1 needs room above full command)."""
        vehicle, gains = self._plants[robot], self._thruster_gains[robot]
        body = self._slots[robot].body_id
        mass_changed = self.model.body_mass[body] != vehicle.mass or not np.array_equal(
            self.model.body_inertia[body], vehicle.inertia
        )
        self.model.body_mass[body] = vehicle.mass
        self.model.body_inertia[body] = vehicle.inertia
        first = self._ctrl_adr[robot]
        actuators = slice(first, first + vehicle.n_thrusters)
        self.model.actuator_dynprm[actuators, 0] = vehicle.thruster.time_constant_s
        self.model.actuator_ctrlrange[actuators, 0] = -gains
        self.model.actuator_ctrlrange[actuators, 1] = gains
        if mass_changed:
            # the constants MuJoCo derives from masses when it compiles (body_subtreemass and the like):
            # without this its mass matrix kept the compiled mass while gravity took the new one. It
            # works in an MjData of its own, which it moves to qpos0: never the simulation's. Only on a
            # change: set_state puts every plant back, and a rollout may restore a state often
            mujoco.mj_setConst(self.model, mujoco.MjData(self.model))

    def set_sensor_noise(self, robot: str, noise: SensorNoise, rescale_biases: bool = False) -> None:
        """``robot``'s sensor noise levels from now on (:meth:`reset` keeps them). ``rescale_biases``:
        also scale the IMU biases drawn at the last reset by the new bias walk over the old one (where the
        old is above 0), so that they are what a reset at the new levels would have drawn."""
        sensors = self._sensors[self._check(robot)]
        if rescale_biases:
            old = sensors.noise
            if old.accel_bias_walk > 0:
                sensors.accel_bias = sensors.accel_bias * (noise.accel_bias_walk / old.accel_bias_walk)
            if old.gyro_bias_walk > 0:
                sensors.gyro_bias = sensors.gyro_bias * (noise.gyro_bias_walk / old.gyro_bias_walk)
        sensors.noise = noise

    def sensor_noise(self, robot: str) -> SensorNoise:
        """``robot``'s sensor noise levels."""
        return self._sensors[self._check(robot)].noise

    def set_water(self, params: WaterParams) -> None:
        """The water the cameras look through from now on (turbidity, noise, vignetting)."""
        self.water = WaterModel(params)

    @property
    def current(self) -> np.ndarray:
        """The water current now (m/s, world frame; a copy)."""
        slot = hydrodynamics.HEADER + hydrodynamics.SLOT_CURRENT
        return self.data.userdata[slot : slot + 3].copy()

    def set_current(self, current_world) -> None:
        """Change the water current (m/s, world frame) from now on; :meth:`reset` restores the
        scenario's."""
        current = check_current(current_world)
        for k in range(len(self.robots)):
            start = hydrodynamics.HEADER + k * hydrodynamics.BLOCK
            slot = start + hydrodynamics.SLOT_CURRENT
            self.data.userdata[slot : slot + 3] = current

    def set_flight_mode(self, robot: str, mode: str) -> None:
        """Fly ``robot`` in an ArduSub flight mode: "manual" (the pilot command goes to the mixer),
        "stabilize", "alt_hold" or "poshold" (:mod:`maptidal.controllers.flight_modes`), on the state
        estimated from the robot's own sensors, started at its current pose as a vehicle's estimator
        would be."""
        self._check(robot)
        if mode not in FLIGHT_MODES:
            raise ValueError(f"unknown flight mode {mode!r}; choose one of {', '.join(FLIGHT_MODES)}")
        spec = self._specs[robot]
        if mode != "manual":
            needed = {"imu", "compass", "depth"} | ({"dvl"} if mode == "poshold" else set())
            missing = needed - set(spec.sensors)
            if missing:
                raise ValueError(
                    f"{robot}: flight mode {mode} needs the sensors {', '.join(sorted(missing))}"
                )
        self._flight_modes[robot] = mode
        self._autopilots.pop(robot, None)
        if mode != "manual":
            self._autopilots[robot] = _Autopilot(
                FlightController(mode, self.scenario.tank.height, self.mode_params)
            )
        self._restart_estimator(robot)

    def track_estimate(self, robot: str) -> None:
        """Keep a dead-reckoning estimate of ``robot`` (:meth:`estimate`) in every flight mode, MANUAL
        included, through resets and placements. Robots in the other modes always have one."""
        self._tracked.add(self._check(robot))
        self._restart_estimator(robot)

    def _restart_estimator(self, robot: str) -> None:
        # an estimator starts at the true pose, as a vehicle's does when it is armed at a known spot
        self._estimators.pop(robot, None)
        self._readings.pop(robot, None)
        if robot not in self._autopilots and robot not in self._tracked:
            return
        spec = self._specs[robot]
        truth = self.ground_truth(robot)
        params = EstimatorParams(
            self.scenario.tank.height,
            DEPTH_SENSOR_POSITION,
            spec.vehicle.sensors.dvl_position,
            motion_model=self._vehicle_models[robot].motion_model().perturbed(self.motion_model_error),
        )
        self._estimators[robot] = DeadReckoning(params, truth["position"], truth["rpy"][2])
        self._update_estimate(robot)

    def _update_estimate(self, robot: str) -> None:
        readings = self.sensors(robot)
        dvl = readings.get("dvl")
        if dvl is None or not dvl["valid"]:
            # no DVL velocity: the estimator falls back on the force the robot's own thruster commands ask
            # for (what a real vehicle knows of its outputs), through its motion model
            outputs = self._thruster_outputs.get(robot)
            force = np.zeros(3) if outputs is None else self._vehicle_models[robot].body_force(outputs)
            readings["thrust"] = {"force_body": force.tolist()}
        self._readings[robot] = readings
        period = self.scenario.substeps * self.scenario.timestep_s
        self._estimators[robot].update(readings, period)

    def estimate(self, robot: str) -> StateEstimate:
        """``robot``'s dead-reckoned state from its own sensors, as of the end of the last control period
        (:class:`maptidal.controllers.estimation.DeadReckoning`): what its flight mode flies on. Robots in
        MANUAL have one after :meth:`track_estimate`."""
        return self._estimator(robot).state

    def _estimator(self, robot: str) -> DeadReckoning:
        """``robot``'s estimator; a robot in MANUAL keeps none until :meth:`track_estimate`."""
        if self._check(robot) not in self._estimators:
            raise ValueError(f"{robot} keeps no estimate in MANUAL: call track_estimate({robot!r}) first")
        return self._estimators[robot]

    def motion_model(self, robot: str) -> MotionModel | None:
        """The motion model ``robot``'s estimator dead-reckons on without a DVL (the vehicle's, put off by
        ``motion_model_error``): what the robot believes of its own dynamics."""
        return self._estimator(robot).params.motion_model

    def latest_readings(self, robot: str) -> dict:
        """The sensor readings :meth:`estimate` last folded in (as :meth:`sensors` returns them)."""
        if self._check(robot) not in self._readings:
            raise ValueError(f"{robot} keeps no estimate in MANUAL: call track_estimate({robot!r}) first")
        return self._readings[robot]

    def flight_mode(self, robot: str) -> str:
        """The robot's flight mode."""
        return self._flight_modes[self._check(robot)]

    def set_hydrodynamics(self, enabled: bool) -> None:
        """Switch hydrodynamics and thrust on or off (off: a bare rigid body, for baselines)."""
        hydrodynamics.set_enabled(self.data.userdata, enabled)

    # ----- acting -----------------------------------------------------------------------
    def thruster_commands(self, robot: str, command, mode: str = "pilot") -> np.ndarray:
        """The per-thruster commands in [-1, 1] that ``command`` gives for ``robot``."""
        n = self._specs[robot].vehicle.n_thrusters
        if mode == "pilot":  # MANUAL: the stick, after ArduSub's pilot gain, to the mixer
            return mix(self.mode_params.pilot_gain.apply(pilot_command(command)), self._mixers[robot])
        if mode == "thrusters":
            values = np.asarray(command, float)
            if values.shape != (n,) or not np.all(np.isfinite(values)):
                raise ValueError(f"{robot}: expected {n} finite thruster commands, got {values.tolist()}")
            return np.clip(values, -1.0, 1.0)
        raise ValueError(f"mode must be 'pilot' or 'thrusters', got {mode!r}")

    def _drive(self, robot: str, thrusters: np.ndarray) -> None:
        # the thrust curve is static, so it acts before the lag: the actuators filter the normalised
        # thrust the commands ask for (a command inside the deadband asks for none, at once)
        first = self._ctrl_adr[robot]
        self._thruster_outputs[robot] = np.asarray(thrusters, float).copy()
        normalised = self._plants[robot].thruster.normalised_thrust(thrusters)
        self.data.ctrl[first : first + len(thrusters)] = normalised * self._thruster_gains[robot]

    def thruster_outputs(self, robot: str) -> np.ndarray:
        """The thruster commands in [-1, 1] last sent to ``robot``'s thrusters (the mixer's output, after
        any thrust linearisation; what ArduSub maps to PWM), M1 first."""
        n = self._specs[self._check(robot)].vehicle.n_thrusters
        return self._thruster_outputs.get(robot, np.zeros(n)).copy()

    def step(self, commands: Mapping[str, object] | None = None, mode: str = "pilot") -> float:
        """Hold ``commands`` (robot name to command) for one control period; returns the new time.

        Robots without a command keep their last one. Raises :class:`SimulationError`
        if the state becomes NaN or MuJoCo reports a diverging acceleration.
        """
        self.step_periods(commands, 1, mode)
        return self.time

    @property
    def flight_backend(self) -> str:
        """Which flight stack runs the control periods: "native" (C) or "python"."""
        return "native" if self._native_ready() else "python"

    def _native_ready(self) -> bool:
        # the C loop calls mj_step, so the passive-force callback must be the C one too
        return (
            self._native is not None
            and hydrodynamics.installed_backend() in ("native", None)
            and self._native.supported()
        )

    def step_periods(
        self,
        commands: Mapping[str, object] | None = None,
        n_periods: int = 1,
        mode: str = "pilot",
        currents=None,
    ) -> np.ndarray:
        """Hold ``commands`` for ``n_periods`` control periods, as that many :meth:`step` calls do, in one
        call to the compiled flight stack where it runs (:attr:`flight_backend`).

        ``currents``: None, or the water current (m/s, world) to set at the start of each period,
        ``(n_periods, 3)``. Returns ``(n_periods, robots, 2)``: each robot's mean squared thruster
        command (:meth:`thruster_outputs`) and whether it touched anything (1.0) at each period's end.
        Raises :class:`SimulationError` if the state becomes NaN or diverges."""
        n_periods = int(n_periods)
        if n_periods < 1:
            raise ValueError(f"n_periods must be at least 1, got {n_periods}")
        if currents is not None:
            currents = np.asarray(currents, float)
            if currents.shape != (n_periods, 3):
                raise ValueError(f"currents must be ({n_periods}, 3) m/s, got shape {currents.shape}")
            speeds = np.sqrt((currents * currents).sum(axis=1))
            if not (np.isfinite(speeds).all() and speeds.max() <= MAX_CURRENT_M_S):
                for current in currents:  # the offending one, in check_current's words
                    check_current(current)
        self._take_commands(commands, mode)
        if self._native_ready():
            time_before = self.time
            per_period, ran = self._native.run(n_periods, currents)
            if ran < n_periods:
                period = self.scenario.substeps * self.scenario.timestep_s
                raise self._diverged(self.scenario.substeps, time_before + ran * period)
            return per_period
        per_period = np.zeros((n_periods, len(self.robots), 2))
        for t in range(n_periods):
            if currents is not None:
                self.set_current(currents[t])
            self._fly_period()
            touching = self._robots_touching() if self.data.ncon else set()
            for k, robot in enumerate(self.robots):
                outputs = self._thruster_outputs.get(robot)
                if outputs is not None:
                    per_period[t, k, 0] = sum(v * v for v in outputs.tolist()) / len(outputs)
                per_period[t, k, 1] = robot in touching
        return per_period

    def _take_commands(self, commands: Mapping[str, object] | None, mode: str) -> None:
        """The pilots' new commands to the autopilots, and direct commands to the thrusters."""
        for robot, command in (commands or {}).items():
            if robot not in self._slots:
                raise KeyError(f"unknown robot {robot!r}; robots: {', '.join(self.robots)}")
            if robot in self._autopilots and mode == "pilot":
                self._autopilots[robot].pilot = self.mode_params.pilot_gain.apply(pilot_command(command))
                continue
            self._drive(robot, self.thruster_commands(robot, command, mode))

    def _fly_period(self) -> None:
        """One control period in Python (the compiled stack's reference): the flight modes, the
        physics, the sensors and the estimates."""
        period = self.scenario.substeps * self.scenario.timestep_s
        for robot, autopilot in self._autopilots.items():
            # the flight mode runs every control period, on the estimate from this moment's readings
            estimate = self._estimators[robot].state
            mixer_input = autopilot.controller.update(autopilot.pilot, estimate, period)
            thrusters = mix(mixer_input, self._mixers[robot])
            if self.mode_params.linearise_thrust:
                thruster = self._specs[robot].vehicle.thruster
                thrusters = linearise_thrusters(thrusters, thruster.curve, thruster.pwm_range)
            self._drive(robot, thrusters)
        self.advance_physics(self.scenario.substeps)
        for robot in self._estimators:
            self._update_estimate(robot)

    def set_thrusters(self, robot: str, commands) -> None:
        """Set ``robot``'s thruster commands in [-1, 1] (M1 first) directly, for drivers that step the
        physics themselves (:meth:`advance_physics`), such as ArduPilot's JSON backend."""
        self._drive(self._check(robot), self.thruster_commands(robot, commands, mode="thrusters"))

    def advance_physics(self, n_steps: int) -> float:
        """Advance ``n_steps`` physics time steps with the controls as they are; the new time.

        Raises :class:`SimulationError` if the state becomes NaN or diverges."""
        bad_before = self._instability_warnings()
        time_before = self.time  # MuJoCo restarts a diverged state at t = 0: say when it went
        velocities = {
            robot: self.data.qvel[slot.dof_adr : slot.dof_adr + 3].tolist()
            for robot, slot in self._slots.items()
        }
        start = time.perf_counter()
        step_physics(self.model, self.data, n_steps)
        self.wall_time_s += time.perf_counter() - start
        self._period_specific_force(velocities, n_steps * self.scenario.timestep_s)
        self._count_odometry(n_steps * self.scenario.timestep_s)
        for sensors in self._sensors.values():
            sensors.advance(n_steps * self.scenario.timestep_s, self.rng)
        diverged = self._instability_warnings() > bad_before
        if diverged or not (np.isfinite(self.data.qpos).all() and np.isfinite(self.data.qvel).all()):
            raise self._diverged(n_steps, time_before)
        return self.time

    def _period_specific_force(self, velocities: dict[str, list[float]], seconds: float) -> None:
        """Each robot's specific force (m/s^2, body axes at the end) averaged over the ``seconds`` just
        stepped, from its velocity change: what an IMU's delta velocity over the period gives, however
        short an impact within it (:attr:`RobotSensors.mean_specific_force`). Written out axis by axis,
        as the compiled flight stack computes it."""
        g = self.model.opt.gravity.tolist()
        for robot, slot in self._slots.items():
            v = self.data.qvel[slot.dof_adr : slot.dof_adr + 3].tolist()
            x = self.data.xmat[slot.body_id].tolist()
            w = [(v[k] - velocities[robot][k]) / seconds - g[k] for k in range(3)]
            self._sensors[robot].mean_specific_force = np.array(
                [x[j] * w[0] + x[3 + j] * w[1] + x[6 + j] * w[2] for j in range(3)]
            )

    def _diverged(self, n_steps: int, time_before: float) -> SimulationError:
        """The error for a state that went bad in the ``n_steps`` physics steps after ``time_before``."""
        return SimulationError(
            f"the physics state became NaN or diverged in the {n_steps} steps after "
            f"t = {time_before:.3f} s; "
            f"last thruster commands {self.data.ctrl.round(3).tolist()}. Reset the simulation."
        )

    def _count_odometry(self, seconds: float) -> None:
        # the thrust at the period's end stands for the period: it lags its command by 0.1 s, five
        # control periods, so it barely moves within one; so does a contact
        for robot in self._robots_touching() if self.data.ncon else ():
            self._odometry[robot].contact_s += seconds
        for robot, slot in self._slots.items():
            odometry = self._odometry[robot]
            adr = self._position_adr[robot]
            odometry.move_to(self.data.qpos[adr : adr + 3].tolist())
            n = len(self._thruster_gains[robot])
            act = self.data.act[slot.act_adr : slot.act_adr + n].tolist()
            odometry.thruster_energy_j += self._plants[robot].thruster.power_w(act) * seconds

    def _robots_touching(self) -> set[str]:
        """The robots whose hull touches anything now (both robots of a robot-robot contact)."""
        touching = set()
        for k in range(self.data.ncon):
            contact = self.data.contact[k]
            for geom in (contact.geom1, contact.geom2):
                robot = self._robot_of_body.get(int(self.model.geom_bodyid[geom]))
                if robot is not None:
                    touching.add(robot)
        return touching

    def odometry(self, robot: str) -> Odometry:
        """``robot``'s distance travelled, thruster energy and time in contact since the reset (a copy)."""
        return copy.copy(self._odometry[self._check(robot)])

    def _instability_warnings(self) -> int:
        # MuJoCo resets the state itself on a bad qpos/qvel/qacc and counts a warning
        return int(self.data.warning.number[_BAD_STATE_WARNINGS].sum())

    # ----- reading ----------------------------------------------------------------------
    def sensors(self, robot: str) -> dict:
        """Noisy readings of the robot's enabled sensors (imu, depth, dvl, compass)."""
        return self._sensors[self._check(robot)].read(self.data, self.rng)

    def ground_truth(self, robot: str) -> dict:
        """The true state, flagged as such: position, quaternion (w, x, y, z), roll-pitch-yaw,
        body-frame linear and angular velocity, the specific force (m/s^2, body), and the lagged
        thruster states."""
        slot = self._slots[self._check(robot)]
        rotation = self.data.xmat[slot.body_id].reshape(3, 3)
        quat = self.data.xquat[slot.body_id]
        n = self._specs[robot].vehicle.n_thrusters
        return {
            "ground_truth": True,
            "position": self.data.xpos[slot.body_id].tolist(),
            "quaternion": quat.tolist(),
            "rpy": list(rpy_from_matrix(rotation)),
            "velocity_body": (rotation.T @ self.data.qvel[slot.dof_adr : slot.dof_adr + 3]).tolist(),
            "angular_velocity_body": self.data.qvel[slot.dof_adr + 3 : slot.dof_adr + 6].tolist(),
            # what an ideal accelerometer reads: (a - g) in the body frame, +9.81 up at rest
            "specific_force_body": (
                rotation.T @ (self.data.qacc[slot.dof_adr : slot.dof_adr + 3] - self.model.opt.gravity)
            ).tolist(),
            "thrusters": self.data.act[slot.act_adr : slot.act_adr + n].tolist(),
            "time_s": self.time,
        }

    def contacts(self) -> list[Contact]:
        """Current contacts that involve a robot, with the normal force."""
        found = []
        bodies = self._robot_of_body
        force = np.zeros(6)
        for k in range(self.data.ncon):
            contact = self.data.contact[k]
            b1, b2 = self.model.geom_bodyid[contact.geom1], self.model.geom_bodyid[contact.geom2]
            for mine, other in ((b1, b2), (b2, b1)):
                if mine in bodies:
                    mujoco.mj_contactForce(self.model, self.data, k, force)
                    other_name = bodies.get(other, "tank" if other == 0 else self.model.body(other).name)
                    found.append(
                        Contact(bodies[mine], other_name, tuple(contact.pos.tolist()), float(force[0]))
                    )
                    break
        return found

    def render_stereo(self, robot: str, depth: bool = False, water: bool = True):
        """The robot's stereo pair as uint8 RGB images ``(H, W, 3)``: ``(left, right)``.

        With ``depth=True`` returns ``(left, right, left_depth, right_depth)``, the
        planar depth in metres. ``water`` applies the underwater image model, on the GL side
        where it can (see :attr:`water_backend`).
        """
        return self.render_snapshot(self.stereo_snapshot(robot, depth=depth, water=water))

    def render_left(self, robot: str, depth: bool = False, water: bool = True):
        """The robot's left camera image alone, uint8 RGB ``(H, W, 3)``, drawn without the right camera:
        half the drawing of :meth:`render_stereo`. With ``depth=True`` returns ``(left, left_depth)``."""
        drawn = self.render_snapshot(self.stereo_snapshot(robot, depth=depth, water=water, sides=("left",)))
        return drawn if depth else drawn[0]

    def stereo_snapshot(
        self, robot: str, depth: bool = False, water: bool = True, sides: tuple[str, ...] = ("left", "right")
    ) -> StereoSnapshot:
        """What :meth:`render_stereo` (or, with ``sides=("left",)``, :meth:`render_left`) would render
        now, taken now and drawn later by :meth:`render_snapshot`: each camera's scene and its frame's
        noise seed (drawn from the simulation's generator in the order rendering at once draws them).
        Drawing it on another thread, while the physics steps on, gives the images of this moment, and
        the generator's stream is the same as rendering at once."""
        spec = self._specs[self._check(robot)]
        if "stereo" not in spec.sensors:
            raise ValueError(f"{robot} has no stereo camera in this scenario")
        if not sides or any(side not in ("left", "right") for side in sides):
            raise ValueError(f"sides must be a sequence of 'left' and 'right', got {sides!r}")
        water = water and self.water.params.enabled
        on_gl = water and self.water_backend == "gl"
        scenes, seeds = [], []
        for side in sides:
            try:
                scene = self._free_scenes.get_nowait()
            except queue.Empty:
                scene = mujoco.MjvScene(self.model, maxgeom=SNAPSHOT_MAX_GEOM)
            camera = f"{robot}/{side}"
            hidden = self._hidden_geoms.get(camera)
            if hidden is None:
                hidden = self._hidden_geoms[camera] = geoms_behind_camera(self.model, camera)
            scenes.append(update_camera_scene(self.model, self.data, camera, scene, hidden))
            if on_gl:
                noisy = self.water.params.noise_sigma > 0
                seeds.append(int(self.rng.integers(1 << 32)) if noisy else 0)
            elif water:
                seeds.append(int(self.rng.integers(1 << 63)))  # the frame's own noise generator
            else:
                seeds.append(None)
        return StereoSnapshot(robot, tuple(scenes), tuple(seeds), water, on_gl, depth, tuple(sides))

    def render_snapshot(self, snapshot: StereoSnapshot):
        """Draw a :meth:`stereo_snapshot`: the images :meth:`render_stereo` returns. Call it on the thread
        that renders for this simulation: the renderer's GL context is current on the thread that first
        drew (or read :attr:`water_backend`), and may not be made current on another while it is. The
        snapshot's scenes are reused after."""
        cam = self.camera
        images: list = []  # arrays, or futures of the CPU water model's results
        depths = []
        try:
            for scene, seed in zip(snapshot.scenes, snapshot.seeds, strict=True):
                if snapshot.on_gl:
                    rgb, buffer = render_camera_underwater(
                        self.model,
                        scene,
                        self._geometry,
                        self.water.params,
                        cam.height,
                        cam.width,
                        seed=seed,
                        with_depth=snapshot.depth,
                    )
                else:
                    rgb, buffer = render_camera(
                        self.model,
                        scene,
                        cam.height,
                        cam.width,
                        with_depth=snapshot.water or snapshot.depth,
                        raw_depth=True,
                    )
                if buffer is not None:
                    buffer = cv2.add(cv2.flip(buffer, 0), self._geometry.depth_shift)
                if snapshot.water and not snapshot.on_gl:
                    # range along each ray = (ray length per unit depth x d) / (buffer + c), in one division
                    ranges = cv2.divide(self._range_numerator, buffer)
                    # the left frame's water model runs on a worker thread while the right camera renders
                    # (OpenCV releases the GIL)
                    frame_rng = np.random.default_rng(seed)
                    rgb = worker_thread("maptidal-water").submit(self.water.apply, rgb, ranges, frame_rng)
                images.append(rgb)
                if snapshot.depth:
                    depths.append(cv2.divide(self._geometry.depth_scale, buffer))
            images = [image.result() if isinstance(image, Future) else image for image in images]
        finally:
            for scene in snapshot.scenes:
                self._free_scenes.put(scene)
        return (*images, *depths) if snapshot.depth else tuple(images)

    @property
    def water_backend(self) -> str:
        """Where the water model runs: ``"gl"`` (a shader in the renderer's context) or ``"cpu"``
        (:class:`maptidal.envs.water.WaterModel`). ``"gl"`` at construction raises RuntimeError where the
        shader cannot run. ``"auto"`` picks GL on a GPU and the CPU model on a CPU rasteriser
        (Mesa llvmpipe), where the shader is no faster when drawing is all the process does
        (docs/simulation.md, its bench). ``"prefer-gl"`` takes the shader wherever it runs, else the CPU
        model: the mission's choice, since with its cameras drawn beside the physics on a busy CPU the shader,
        which spares the depth read-back and the CPU's water model, is the faster (docs/mission.md)."""
        if self._resolved_water_backend is None:
            requested = self._requested_water_backend
            height, width = self.camera.height, self.camera.width
            if requested == "cpu" or (requested == "auto" and not renders_on_gpu(self.model, height, width)):
                self._resolved_water_backend = "cpu"
            elif gl_water_available(self.model, height, width, self._geometry):
                self._resolved_water_backend = "gl"
            elif requested == "gl":
                raise RuntimeError("water_backend='gl' asked for, but the water shader cannot run here")
            else:
                self._resolved_water_backend = "cpu"
        return self._resolved_water_backend

    @functools.cached_property
    def _range_numerator(self) -> np.ndarray:
        """Per pixel, ray length per unit planar depth times the depth-buffer scale: dividing it by
        (buffer + shift) gives range along the ray."""
        g = self._geometry
        ones = np.ones((self.camera.height, self.camera.width), np.float32)
        return (depth_to_range(ones, g.fx, g.fy, g.cx, g.cy) * g.depth_scale).astype(np.float32)

    def intrinsics(self) -> dict:
        """Calibration of each stereo camera: K matrix (pixels), image size, baseline (m), field of
        view (deg), and the extrinsics: camera-to-body rotation and position (x forward, y left, z up).

        The numbers are those of :class:`maptidal.camera.StereoCameraParams` (the OAK-D's stereo pair by
        default), the same camera the renderer draws with."""
        cam = self.camera
        # optical frame (x right, y down, z forward) in body axes
        optical_to_body = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]
        vehicle = self._specs[self.robots[0]].vehicle
        return {
            "width": cam.width,
            "height": cam.height,
            "K": cam.matrix().tolist(),
            "baseline_m": cam.baseline_m,
            "hfov_deg": cam.hfov_deg,
            "vfov_deg": cam.vfov_deg,
            "optical_to_body": optical_to_body,
            "positions_body": {side: pos.tolist() for side, pos in camera_offsets(vehicle, cam).items()},
        }

    def _check(self, robot: str) -> str:
        if robot not in self._slots:
            raise KeyError(f"unknown robot {robot!r}; robots: {', '.join(self.robots)}")
        return robot


@dataclass
class _Autopilot:
    """A robot's flight-mode state: its flight controller and the pilot's last command (the estimate it
    flies on is the simulation's, :meth:`Simulation.estimate`)."""

    controller: FlightController
    pilot: np.ndarray = field(default_factory=lambda: np.zeros(6))


def rpy_from_matrix(rotation: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad; ZYX about the world axes, z up) from a body-to-world rotation (the
    estimator's own conversion, :func:`maptidal.controllers.estimation.rpy_from_rotation`)."""
    return rpy_from_rotation(np.asarray(rotation))
