"""N pose-task robots in one process, stepped as numpy arrays: the vector environment that
``gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=N)`` (or StationKeeping-v1) returns.

Each sub-environment is a whole :class:`~maptidal.envs.gym.go_to_pose.GoToPoseEnv` (or
StationKeeping): its own MuJoCo model and data, its own random streams. Resets go through it, so the
start states, targets, currents and randomisation are the one-robot environment's own. Stepping does
not go through it, in one of two ways:

- **compiled** (where every robot's simulation has the compiled flight stack,
  :mod:`maptidal.envs.native_flight`): the batch keeps each robot's parameter and state blocks, packed
  from its simulation at each reset, and flies every robot's control periods in one call of the C
  (``maptidal_flight_batch``), with each robot's noise from its own generator; observations are read
  from the blocks. A step then costs about its physics.
- **numpy** (otherwise): the flight stack of all N robots runs once per control period on arrays
  (:mod:`maptidal.controllers.batched`: STABILIZE or MANUAL, the mixer, the thrust curve, the
  dead-reckoning estimator), the sensors are read and given their noise from each sub-environment's
  own generator in the one-robot order, and only MuJoCo's ``mj_step`` runs robot by robot.

Either way a batch of N gives the observations and rewards N one-robot environments give, to rounding
(``tests/test_batched.py`` holds both ways to 1e-6 over episodes, resets included).

What it does not do (``make_vec`` then falls back on a ``SyncVectorEnv`` of one-robot environments, with
a warning that says why): image observations, ``render_mode``, scenarios without every sensor (IMU,
depth, DVL, compass), frames other than the Heavy's vectored_6dof, and the ALT_HOLD and POSHOLD flight
modes where the compiled flight stack is not there (the numpy batch flies STABILIZE and MANUAL). The
sub-environments' own simulations are left behind by a batched step (their estimators, autopilots and
odometry are not updated; their physics is), so ``get_state`` of a sub-environment is not offered
here.

Autoreset: Gymnasium's ``NEXT_STEP`` mode, as ``SyncVectorEnv``'s default: the step after an episode
ended resets that sub-environment (its action is ignored) and returns its first observation with reward
0. ``reset(options={"reset_mask": mask})`` resets only the sub-environments the mask names.
"""

from __future__ import annotations

import math
import os
from typing import ClassVar

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from maptidal.controllers.batched import (
    BATCHED_MODES,
    BatchedDeadReckoning,
    BatchedStabilize,
    cross_rows,
    mix_batch,
)
from maptidal.controllers.thrusters import linearise_thrusters
from maptidal.envs import hydrodynamics, native_flight
from maptidal.envs.gym.core import CONTACT_COST_PER_S, MAX_EPISODE_S, POSITION_TOLERANCE_M, YAW_TOLERANCE_RAD
from maptidal.envs.sensors import SENSORS
from maptidal.envs.simulation import _BAD_STATE_WARNINGS, PATH_STEP_M, SimulationError, step_physics

TASKS = ("go_to_pose", "station_keeping")
NORMALS_PER_PERIOD = 17  # a robot's sensors' standard normals per control period (_draw_noise)


def unbatchable(options: dict) -> str | None:
    """Why these environment arguments cannot be batched (None: they can)."""
    if options.get("obs_images") is not None:
        return "image observations are drawn robot by robot"
    if options.get("render_mode") is not None:
        return "rendering is per robot"
    if (
        options.get("action", "pilot") == "pilot"
        and (options.get("flight_mode") or "stabilize") not in BATCHED_MODES
        and not native_flight.native_available(
            "numpy" if os.environ.get("MAPTIDAL_HYDRO") == "numpy" else "native"
        )
    ):
        return (
            f"flight mode {options.get('flight_mode')!r} is batched only by the compiled flight stack, "
            f"which is not there (the numpy batch flies {', '.join(BATCHED_MODES)})"
        )
    if options.get("frame", "heavy") != "heavy":
        return "only the Heavy's vectored_6dof mixer is batched"
    if options.get("scenario") is not None:
        return "a scenario of one's own is flown one robot at a time"
    return None


def make_vector(task: str, num_envs: int = 1, **kwargs) -> VectorEnv:
    """``make_vec``'s ``vector_entry_point`` for the pose tasks: a :class:`BatchedPoseEnv` when the
    arguments allow (:func:`unbatchable`), else a ``SyncVectorEnv`` of one-robot environments, with a
    warning that says why."""
    why = unbatchable(kwargs)
    if why is None:
        return BatchedPoseEnv(task, num_envs, **kwargs)
    gymnasium.logger.warn(f"MapTidal {task}: a SyncVectorEnv, not the batched environment: {why}")
    kwargs.pop("threads", None)  # a SyncVectorEnv steps its environments one after another
    env_class = _task_class(task)
    limit = kwargs.pop("max_episode_steps", None)

    def build():
        env = env_class(**kwargs)
        if limit is not None and limit > 0:
            env.episode_s = MAX_EPISODE_S
            return gymnasium.wrappers.TimeLimit(env, limit)
        return env

    return gymnasium.vector.SyncVectorEnv([build for _ in range(num_envs)])


def go_to_pose(num_envs: int = 1, **kwargs) -> VectorEnv:
    """``MapTidal/GoToPose-v1``'s vector entry point (:func:`make_vector`)."""
    return make_vector("go_to_pose", num_envs, **kwargs)


def station_keeping(num_envs: int = 1, **kwargs) -> VectorEnv:
    """``MapTidal/StationKeeping-v1``'s vector entry point (:func:`make_vector`)."""
    return make_vector("station_keeping", num_envs, **kwargs)


def _task_class(task: str):
    if task == "go_to_pose":
        from maptidal.envs.gym.go_to_pose import GoToPoseEnv

        return GoToPoseEnv
    if task == "station_keeping":
        from maptidal.envs.gym.station_keeping import StationKeepingEnv

        return StationKeepingEnv
    raise ValueError(f"task must be one of {TASKS}, got {task!r}")


class BatchedPoseEnv(VectorEnv):
    """N robots of GoToPose-v1 or StationKeeping-v1 stepped together (module docstring).

    ## Spaces, rewards, episode ends

    Those of the one-robot task, batched: ``single_action_space`` is its action space and
    ``action_space`` stacks N of them; the observation likewise (flat or Dict, without images). Rewards
    are the task's. Episodes end as ``gymnasium.make`` ends them: truncated after ``max_episode_steps``
    (the registration's 200; ``None`` or -1: never), never terminated. ``infos`` carry the task's keys per
    robot (``is_success``, ``distance_m``, ``contact_s``, and GoToPose's ``yaw_error_rad`` or
    StationKeeping's ``current_m_s``, an (N, 3) array), and reset's ``randomization`` when randomised.

    ## Arguments

    ``task`` ("go_to_pose" or "station_keeping"), ``num_envs``, ``max_episode_steps``, ``threads`` (how
    many threads the compiled batch shares its robots out over: by default one per CPU the process may
    use, at most one per robot; the results do not depend on it), and the one-robot
    task's keyword arguments (``action``, ``flat_obs``, ``control_period_s``, ``pilot_gain``,
    ``flight_mode`` "stabilize" or "manual", or "alt_hold" or "poshold" on the compiled stack,
    ``randomize``, StationKeeping's ``max_current_m_s`` and ``turbulence_m_s``). Actions outside [-1, 1]
    are clipped; a NaN or infinite action, or one of the wrong shape, raises ValueError before anything
    moves.
    """

    metadata: ClassVar[dict] = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        task: str,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        threads: int | None = None,
        **kwargs,
    ) -> None:
        if not (isinstance(num_envs, int) and num_envs >= 1):
            raise ValueError(f"num_envs must be a whole number >= 1, got {num_envs!r}")
        if threads is None:
            threads = min(num_envs, _usable_cpus())
        if not (isinstance(threads, int) and not isinstance(threads, bool) and threads >= 1):
            raise ValueError(f"threads must be a whole number >= 1, got {threads!r}")
        # the compiled batch shares its robots out over this many threads (the numpy batch runs on one)
        self.threads = min(threads, num_envs)
        why = unbatchable(kwargs)
        if why is not None:
            raise ValueError(f"these arguments cannot be batched: {why}")
        env_class = _task_class(task)
        self.task = task
        self.envs = [env_class(episode_s=MAX_EPISODE_S, **kwargs) for _ in range(num_envs)]
        first = self.envs[0]
        self.num_envs = num_envs
        self.max_episode_steps = max_episode_steps if max_episode_steps and max_episode_steps > 0 else None
        self.single_action_space = first.action_space
        self.single_observation_space = first.observation_space
        self.action_space = batch_space(first.action_space, num_envs)
        self.observation_space = batch_space(first.observation_space, num_envs)
        self.sims = [env.sim for env in self.envs]
        self.robot = first.robot
        self._check_sensors(first)
        self.thrusters_action = first.options.action == "thrusters"
        mode = first.sim.flight_mode(self.robot) if not self.thrusters_action else "manual"
        # STABILIZE flies on an autopilot whose outputs are linearised (ModeParams.linearise_thrust);
        # MANUAL and the thruster action send the mixer's or the policy's commands as they are. ALT_HOLD
        # and POSHOLD fly on an autopilot too, and only in the compiled stack (no numpy twin)
        self.mode = mode
        self.autopilot = mode != "manual"
        self.stabilized = mode == "stabilize"
        self.linearise = self.stabilized and first.sim.mode_params.linearise_thrust
        self.flight = (
            BatchedStabilize(mode, num_envs, first.sim.mode_params) if mode in BATCHED_MODES else None
        )
        self.estimator = BatchedDeadReckoning(first.sim._estimators[self.robot].params, num_envs)
        self.pilot_gain = first.sim.mode_params.pilot_gain
        spec = first.sim._specs[self.robot]
        self.vehicle_model = first.sim._vehicle_models[self.robot]
        self.controller_curve = spec.vehicle.thruster
        self.n_thrusters = spec.vehicle.n_thrusters
        self.substeps_per_period = first.scenario.substeps
        self.period_s = first.scenario.control_period_s
        self.periods_per_step = first.substeps
        sensors = first.sim._sensors[self.robot]
        self._slices = sensors._slices
        self._dvl_range = sensors.dvl_range
        self._water_depth = sensors.water_depth
        self._body = sensors.body_id
        self._ctrl = slice(
            first.sim._ctrl_adr[self.robot], first.sim._ctrl_adr[self.robot] + self.n_thrusters
        )
        n = num_envs
        self.outputs = np.zeros((n, self.n_thrusters))
        self.accel_bias, self.gyro_bias = np.zeros((n, 3)), np.zeros((n, 3))
        self.readings = {"accel": np.zeros((n, 3)), "gyro": np.zeros((n, 3)), "depth_m": np.zeros(n)}
        self.target, self.target_yaw = np.zeros((n, 3)), np.zeros(n)
        self.previous = np.zeros((n, 2))
        self.steps = np.zeros(n, int)
        self._autoreset = np.zeros(n, bool)
        self._started = False
        self._plant_groups: list[tuple[object, np.ndarray]] = []
        self._gains = np.ones((n, self.n_thrusters))
        self._bad_states = np.zeros(n, int)
        self._noise_scales = np.zeros((n, NORMALS_PER_PERIOD))
        self._beams = [self._slices[f"beam{k}"].start for k in range(4)]
        # views into each robot's MjData, made at each reset rather than N times per control period
        # (a microsecond or two each): numpy views of MuJoCo's buffers stay valid for the data's life
        self._models, self._datas = [None] * n, [None] * n
        self._ctrl_views, self._sensordata_views, self._up_views = [None] * n, [None] * n, [None] * n
        for row in range(n):
            self._refresh_views(row)
        # the compiled flight stack (maptidal.envs.native_flight), where every robot's simulation has it:
        # the batch keeps each robot's parameter and state blocks itself and flies them all in one call
        self.native = all(sim._native is not None for sim in self.sims)
        if self.native:
            params, state = native_flight.layout(0), native_flight.layout(1)
            self._offsets = {name: offset for name, (offset, _) in state.items()}
            self._params = np.zeros((n, params["__size__"][0]))
            self._state = np.zeros((n, state["__size__"][0]))
            self._noise = np.zeros((n, self.periods_per_step * NORMALS_PER_PERIOD))
            self._currents = np.zeros((n, self.periods_per_step, 3))
            self._per_period = np.zeros((n, self.periods_per_step, 2))
            self._ran = np.zeros(n, np.intc)
            self._wall = np.zeros(1)
            self._model_addresses = np.array([sim.model._address for sim in self.sims], np.uintp)
            self._data_addresses = np.array([sim.data._address for sim in self.sims], np.uintp)

    @staticmethod
    def _check_sensors(env) -> None:
        missing = set(SENSORS) - {"stereo"} - set(env.scenario.robots[0].sensors)
        if missing:
            raise ValueError(
                f"the batched environment needs every sensor; the scenario's robot lacks {sorted(missing)}"
            )

    # ----- reset ------------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset every sub-environment (or those ``options["reset_mask"]`` names): seeds ``seed``,
        ``seed + 1``, ... as ``SyncVectorEnv`` gives them, or one per sub-environment from a list. Other
        options go to each sub-environment's ``reset`` (``pose``, ``target``, ``current``)."""
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(self.num_envs, bool)), bool)
        if mask.shape != (self.num_envs,):
            raise ValueError(f"reset_mask must be {self.num_envs} booleans, got shape {mask.shape}")
        if not self._started and not mask.all():
            raise ValueError("the first reset must reset every sub-environment")
        if seed is None or isinstance(seed, int | np.integer):
            seeds = [None if seed is None else int(seed) + k for k in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} environments")
        infos: dict = {}
        for row in np.flatnonzero(mask):
            _, info = self.envs[row].reset(seed=seeds[row], options=options or None)
            self._load(row)
            infos = self._add_info(infos, info, row)
        self._started = True
        self._autoreset[mask] = False
        self._regroup_plants()
        return self._observation(), infos

    def _load(self, row: int) -> None:
        """Take row ``row``'s state from its sub-environment, just reset."""
        env, sim = self.envs[row], self.sims[row]
        robot = self.robot
        self.estimator.load(row, sim._estimators[robot])
        if self.stabilized:
            self.flight.load(row, sim._autopilots[robot].controller)
        elif self.flight is not None:
            self.flight.time_s[row] = 0.0
        sensors = sim._sensors[robot]
        self.accel_bias[row], self.gyro_bias[row] = sensors.accel_bias, sensors.gyro_bias
        readings = sim.latest_readings(robot)
        self.readings["accel"][row] = readings["imu"]["accel"]
        self.readings["gyro"][row] = readings["imu"]["gyro"]
        self.readings["depth_m"][row] = readings["depth"]["depth_m"]
        self.outputs[row] = sim.thruster_outputs(robot)
        self.target[row], self.target_yaw[row] = env.target, env.target_yaw
        self.previous[row] = env._previous if self.task == "go_to_pose" else (0.0, 0.0)
        self.steps[row] = 0
        self._refresh_views(row)
        self._gains[row] = sim._thruster_gains[robot]
        self._bad_states[row] = int(sim.data.warning.number[_BAD_STATE_WARNINGS].sum())
        # what each of a period's standard normals is scaled by (_draw_noise): this robot's noise levels
        n = sensors.noise
        walk = math.sqrt(self.period_s)
        self._noise_scales[row] = (
            [n.accel_bias_walk * walk] * 3
            + [n.gyro_bias_walk * walk] * 3
            + [n.accel_sigma] * 3
            + [n.gyro_sigma] * 3
            + [n.depth_sigma]
            + [n.dvl_sigma] * 3
            + [n.compass_sigma_deg]
        )
        if self.native:  # the robot's blocks, packed from its simulation's objects as one robot's are
            self._params[row], self._state[row] = sim._native.blocks(robot)

    def _refresh_views(self, row: int) -> None:
        sim = self.sims[row]
        self._models[row], self._datas[row] = sim.model, sim.data
        self._ctrl_views[row] = sim.data.ctrl[self._ctrl]
        self._sensordata_views[row] = sim.data.sensordata
        self._up_views[row] = sim.data.xmat[self._body, 6:9]

    def _regroup_plants(self) -> None:
        # the thrust curve of each robot's plant (randomised ones differ): robots that share one are
        # pushed through it together
        groups: dict[object, list[int]] = {}
        for row, sim in enumerate(self.sims):
            groups.setdefault(sim._plants[self.robot].thruster, []).append(row)
        self._plant_groups = [(plant, np.array(rows)) for plant, rows in groups.items()]

    # ----- step -------------------------------------------------------------------------------
    def step(self, actions):
        """Hold each robot's action for one control period; returns (observations, rewards,
        terminations, truncations, infos), arrays of N."""
        if not self._started:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"actions must have shape {self.action_space.shape}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("actions must be finite")
        a = a.clip(-1.0, 1.0)
        active = ~self._autoreset
        rows = np.flatnonzero(active)
        energy, touching = np.zeros(self.num_envs), np.zeros(self.num_envs)
        pilot = a if self.thrusters_action else self.pilot_gain.apply(a)
        if self._native_ready():
            energy, touching = self._fly_native(pilot, rows)
        elif self.flight is None:
            raise RuntimeError(
                f"{self.mode.upper()} is batched only by the compiled flight stack, which cannot run now "
                f"(hydrodynamics callback: {hydrodynamics.installed_backend()})"
            )
        else:
            noise = self._draw_noise(rows)
            blowing = [self.envs[row] for row in rows if self.envs[row].episode_turbulence_m_s > 0]
            for period in range(self.periods_per_step):
                for env in blowing:
                    env._before_substep()
                self._drive(pilot)
                energy += (self.outputs * self.outputs).sum(axis=1) / self.n_thrusters
                touching += self._advance(rows, noise[period])
                self._estimate(noise[period])
            self._check_physics(rows)
        self.steps += active
        rewards, infos = self._rewards(energy / self.periods_per_step, touching * self.period_s)
        terminated = np.zeros(self.num_envs, bool)
        truncated = (
            self.steps >= self.max_episode_steps
            if self.max_episode_steps is not None
            else np.zeros(self.num_envs, bool)
        )
        truncated &= active
        observations = self._observation()
        infos = _only_rows(infos, active)  # a row that resets reports its reset's info alone
        for row in np.flatnonzero(self._autoreset):
            _, info = self.envs[row].reset()
            self._load(row)
            rewards[row], truncated[row] = 0.0, False
            infos = self._add_info(infos, info, row)
        if self._autoreset.any():
            self._regroup_plants()
            observations = self._observation()
        self._autoreset = terminated | truncated
        return observations, rewards, terminated, truncated, infos

    def _native_ready(self) -> bool:
        # the C loop calls mj_step, so the passive-force callback must be the C one too
        return self.native and self.sims[0]._native_ready()

    def _fly_native(self, pilot: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The step's control periods for ``rows`` in one call of the compiled flight stack; each row's
        summed mean squared thruster command and periods in contact. STABILIZE runs in the C on each
        robot's pilot command (ALT_HOLD and POSHOLD too); MANUAL and the thruster action send their
        commands to the thrusters here, held for the step, as a one-robot simulation does."""
        o, state, periods = self._offsets, self._state, self.periods_per_step
        if self.autopilot:
            state[rows, o["PILOT"] : o["PILOT"] + 6] = pilot[rows]
        else:
            self._drive(pilot)
            state[rows, o["OUTPUTS"] : o["OUTPUTS"] + self.n_thrusters] = self.outputs[rows]
            state[rows, o["OUTPUTS_SET"]] = 1.0
        active = np.zeros(self.num_envs, np.intc)
        active[rows] = 1
        blowing = np.zeros(self.num_envs, np.intc)
        for row in rows.tolist():
            self.sims[row].rng.standard_normal(out=self._noise[row])  # the one-robot order (_draw_noise)
            currents = self.envs[row]._substep_currents()
            if currents is not None:
                self._currents[row], blowing[row] = currents, 1
        first = self.sims[0]
        period_s = first.scenario.substeps * first.scenario.timestep_s
        self._ran[:] = periods
        self._wall[0] = 0.0
        native_flight.library().maptidal_flight_batch(
            self.num_envs,
            self._model_addresses.ctypes.data,
            self._data_addresses.ctypes.data,
            self._params.ctypes.data,
            state.ctypes.data,
            active.ctypes.data,
            periods,
            self.substeps_per_period,
            period_s,
            PATH_STEP_M,
            self._noise.ctypes.data,
            self._noise.shape[1],
            self._currents.ctypes.data,
            blowing.ctypes.data,
            hydrodynamics.HEADER + hydrodynamics.SLOT_CURRENT,
            self._per_period.ctypes.data,
            self._ran.ctypes.data,
            self._wall.ctypes.data,
            self.threads,
        )
        failed = np.flatnonzero(self._ran < periods)
        if len(failed):
            raise SimulationError(
                f"sub-environment {int(failed[0])}: the physics state became NaN or diverged; reset it"
            )
        e = self.estimator
        e.position, e.rpy = state[:, o["POSITION"] : o["POSITION"] + 3], state[:, o["RPY"] : o["RPY"] + 3]
        e.velocity_body = state[:, o["VELOCITY"] : o["VELOCITY"] + 3]
        e.angular_velocity_body = state[:, o["RATES"] : o["RATES"] + 3]
        self.readings = {
            "accel": state[:, o["R_ACCEL"] : o["R_ACCEL"] + 3],
            "gyro": state[:, o["R_GYRO"] : o["R_GYRO"] + 3],
            "depth_m": state[:, o["R_DEPTH"]],
        }
        self.outputs = state[:, o["OUTPUTS"] : o["OUTPUTS"] + self.n_thrusters]
        per_period = self._per_period
        per_period[active == 0] = 0.0  # a row waiting on its reset flew nothing
        return per_period[:, :, 0].sum(axis=1), (per_period[:, :, 1] > 0).sum(axis=1).astype(float)

    def _drive(self, pilot: np.ndarray) -> None:
        """One control period's thruster commands, into each robot's actuators."""
        if self.thrusters_action:
            outputs = pilot
        else:
            mixer_input = self.flight.update(
                pilot, self.estimator.rpy, self.estimator.angular_velocity_body, self.period_s
            )
            outputs = mix_batch(mixer_input)
            if self.linearise:
                outputs = linearise_thrusters(
                    outputs, self.controller_curve.curve, self.controller_curve.pwm_range
                )
        self.outputs = np.asarray(outputs, float)
        if len(self._plant_groups) == 1:  # every robot on one thrust curve (no randomisation)
            normalised = self._plant_groups[0][0].normalised_thrust(self.outputs)
        else:
            normalised = np.empty_like(self.outputs)
            for plant, rows in self._plant_groups:
                normalised[rows] = plant.normalised_thrust(self.outputs[rows])
        controls = normalised * self._gains
        for ctrl, row_controls in zip(self._ctrl_views, controls, strict=True):
            ctrl[:] = row_controls

    def _draw_noise(self, rows: np.ndarray) -> np.ndarray:
        """Every standard normal this step's sensors need, (periods, N, 17) (zeros for rows not
        stepped), drawn from each sub-environment's own generator at once. Per control period a one-robot
        simulation draws 6 for the IMU biases' random walk (RobotSensors.advance), then 3 + 3 + 1 + 3 + 1
        for the accelerometer, gyro, depth, DVL and compass (RobotSensors.read), one at a time in that
        order; a generator's normals are one sequence however they are asked for, so one draw of
        periods x 17 is the same numbers."""
        periods = self.periods_per_step
        draws = np.zeros((periods, self.num_envs, NORMALS_PER_PERIOD))
        for row in rows:
            draws[:, row] = self.sims[row].rng.standard_normal((periods, NORMALS_PER_PERIOD))
        return draws * self._noise_scales

    def _advance(self, rows: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The physics of one control period for ``rows``, then the IMU biases' random walk (``noise``:
        this period's scaled normals); which rows touched something."""
        substeps = self.substeps_per_period
        models, datas = self._models, self._datas
        # one robot in the tank: every contact is the robot's
        if len(rows) == self.num_envs:  # the usual case, no row waiting on its reset: no indexing
            contacts = []
            for model, data in zip(models, datas, strict=True):
                step_physics(model, data, substeps)
                contacts.append(data.ncon)
            touching = (np.array(contacts) > 0).astype(float)
        else:
            touching = np.zeros(self.num_envs)
            for row in rows.tolist():
                data = datas[row]
                step_physics(models[row], data, substeps)
                touching[row] = data.ncon > 0
        self.accel_bias += noise[:, 0:3]
        self.gyro_bias += noise[:, 3:6]
        return touching

    def _check_physics(self, rows: np.ndarray) -> None:
        """Raise SimulationError if a row's physics diverged this step (MuJoCo reset a bad state, or
        NaN): once a step, not once a period, as MuJoCo's warning counters keep count."""
        for row in rows:
            data = self.sims[row].data
            bad = int(data.warning.number[_BAD_STATE_WARNINGS].sum())
            if bad > self._bad_states[row] or not np.isfinite(data.qvel).all():
                self._bad_states[row] = bad
                raise SimulationError(
                    f"sub-environment {row}: the physics state became NaN or diverged; reset it"
                )

    def _estimate(self, noise: np.ndarray) -> None:
        """Read every robot's sensors (RobotSensors.read, with this period's scaled normals ``noise``)
        and update the estimates."""
        raw = np.stack(self._sensordata_views)
        up_body = np.stack(self._up_views)
        s = self._slices
        accel = raw[:, s["accelerometer"]] + self.accel_bias + noise[:, 6:9]
        gyro = raw[:, s["gyro"]] + self.gyro_bias + noise[:, 9:12]
        depth = self._water_depth - raw[:, s["depth_pos"]][:, 2] + noise[:, 12]
        ranges = raw[:, self._beams]
        low, high = self._dvl_range
        valid = np.all((ranges >= low) & (ranges <= high), axis=1)
        velocity = raw[:, s["velocimeter"]] + noise[:, 13:16]
        heading = (headings_from_field(raw[:, s["magnetometer"]], up_body) + noise[:, 16]) % 360.0
        # the commanded force is read only where a DVL has no lock
        thrust = None if valid.all() else self.vehicle_model.body_force(self.outputs)
        self.estimator.update(accel, gyro, depth, heading, valid, velocity, thrust, self.period_s)
        self.readings = {"accel": accel, "gyro": gyro, "depth_m": depth}

    # ----- observations and rewards -----------------------------------------------------------
    def _observation(self):
        e = self.estimator
        heading = e.rpy[:, 2]
        offset = self.target - e.position
        c, s = np.cos(heading), np.sin(heading)
        relative = np.column_stack(
            (c * offset[:, 0] + s * offset[:, 1], -s * offset[:, 0] + c * offset[:, 1], offset[:, 2])
        )
        yaw_error = np.arctan2(np.sin(self.target_yaw - heading), np.cos(self.target_yaw - heading))
        values = {
            "pose": np.column_stack((e.position, e.rpy)),
            "velocity": np.column_stack((e.velocity_body, e.angular_velocity_body)),
            "depth": self.readings["depth_m"][:, None],
            "imu": np.column_stack((self.readings["accel"], self.readings["gyro"])),
            "target": np.column_stack((relative, yaw_error)),
        }
        observation = {key: value.astype(np.float32) for key, value in values.items()}
        if self.envs[0].options.flat_obs:
            return np.concatenate([observation[key] for key in self.envs[0]._dict_space.spaces], axis=1)
        return observation

    def _rewards(self, energy: np.ndarray, contact_s: np.ndarray) -> tuple[np.ndarray, dict]:
        position = np.stack([sim.data.xpos[self._body] for sim in self.sims])
        rotation = np.stack([sim.data.xmat[self._body] for sim in self.sims])
        true_yaw = np.arctan2(rotation[:, 3], rotation[:, 0])
        distance = np.linalg.norm(position - self.target, axis=1)
        yaw_error = np.abs(np.arctan2(np.sin(self.target_yaw - true_yaw), np.cos(self.target_yaw - true_yaw)))
        within = (distance <= POSITION_TOLERANCE_M) & (yaw_error <= YAW_TOLERANCE_RAD)
        contact_cost = CONTACT_COST_PER_S * contact_s
        if self.task == "go_to_pose":
            rewards = 10.0 * (self.previous[:, 0] - distance) + 2.0 * (self.previous[:, 1] - yaw_error)
            rewards = rewards - (0.05 * energy + contact_cost) + within
            self.previous = np.column_stack((distance, yaw_error))
        else:
            held = 0.5 * np.exp(-distance / 0.2) + 0.2 * np.exp(-yaw_error / 0.2) + np.where(within, 0.3, 0.0)
            rewards = held * (1.0 - 0.5 * energy) - contact_cost
        values = {"is_success": within, "distance_m": distance, "contact_s": contact_s}
        if self.task == "go_to_pose":
            values["yaw_error_rad"] = yaw_error
        else:
            values["current_m_s"] = np.stack([env.mean_current for env in self.envs])
        everyone = np.ones(self.num_envs, bool)
        infos = {}
        for key, value in values.items():
            infos[key], infos[f"_{key}"] = value, everyone
        return rewards.astype(np.float64), infos

    def close_extras(self, **kwargs) -> None:
        """Close every sub-environment."""
        for env in self.envs:
            env.close()


def _usable_cpus() -> int:
    """The CPUs this process may run on (its affinity, where the system tells it), at least 1."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def _only_rows(infos: dict, rows: np.ndarray) -> dict:
    """Vector infos kept for ``rows`` (a mask) only: the others' ``_key`` flags cleared, and a key no row
    keeps dropped, as ``SyncVectorEnv`` leaves it out."""
    kept = {}
    for key, value in infos.items():
        if key.startswith("_"):
            continue
        mask = infos[f"_{key}"] & rows
        if mask.any():
            kept[key], kept[f"_{key}"] = value, mask
    return kept


def headings_from_field(field_body: np.ndarray, up_body: np.ndarray) -> np.ndarray:
    """:func:`maptidal.envs.sensors.heading_from_field` row by row: tilt-compensated compass headings
    (deg clockwise from north) of (N, 3) body-frame fields, with (N, 3) world verticals in body axes."""
    up = up_body / np.sqrt(np.einsum("ij,ij->i", up_body, up_body))[:, None]
    horizontal = field_body - np.einsum("ij,ij->i", field_body, up)[:, None] * up  # the field's level part
    forward = _BODY_X - up[:, :1] * up  # body forward, made horizontal
    left = cross_rows(up, forward)
    angle = np.arctan2(np.einsum("ij,ij->i", horizontal, left), np.einsum("ij,ij->i", horizontal, forward))
    return np.degrees(angle) % 360.0


_BODY_X = np.array([1.0, 0.0, 0.0])
