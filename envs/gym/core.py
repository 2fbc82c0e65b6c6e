"""The shared machinery of maptidal's Gymnasium environments: one robot of a scenario, its estimated
state from its own sensors, the action conventions, observations, rendering and episode bookkeeping.

Each task (``go_to_pose.py``, ``station_keeping.py``, ...) subclasses :class:`MapTidalEnv` and says what
its target, reward and termination are.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import sys
from dataclasses import dataclass
from typing import ClassVar

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from maptidal.camera import StereoCameraParams
from maptidal.controllers.convention import PilotGain
from maptidal.controllers.estimation import rotation_from_rpy, wrap_angle
from maptidal.controllers.flight_modes import FLIGHT_MODES, ModeParams
from maptidal.envs import randomization
from maptidal.envs.randomization import Randomization
from maptidal.envs.scenario import Scenario, check_current, inside_tank, load_scenario, with_frame
from maptidal.envs.simulation import Simulation
from maptidal.envs.views import third_person_frame

ACTIONS = ("pilot", "thrusters")
IMAGES = (None, "left", "stereo")
# height, width: the tank model's offscreen buffer (maptidal.envs.world.build_tank_spec)
MAX_IMAGE = (800, 1280)
MAX_EPISODE_S = 86400.0  # a day, as for a mission (maptidal run)
# where a robot may be put or sent in the OSB tank (tank frame: end wall at x = 0, floor at z = 0):
# 0.8 m clear of the end wall, 0.8 m of the 2.4 m wall's centre line, 0.5 m above the floor and below
# the 2.0 m surface
SAFE_BOX = (np.array([-3.0, -0.8, 0.5]), np.array([-0.8, 0.8, 1.5]))
# what a second in contact with the tank or a teammate costs, in every task. A contact, like surfacing,
# does not end an episode (v1): where one did, ending it was a policy's cheapest way out of negative
# per-step rewards (a PPO policy on StationKeeping-v0 learned to surface at once, -13 against -91 for
# doing nothing). At 0.1 s a step that is 1 per step in contact, the most any task's reward pays a step
CONTACT_COST_PER_S = 10.0


@dataclass(frozen=True)
class EnvOptions:
    """Checked arguments shared by every task (see the task classes' docstrings)."""

    action: str = "pilot"
    flat_obs: bool = False
    obs_images: str | None = None
    image_size: tuple[int, int] = (80, 128)
    control_period_s: float = 0.1
    episode_s: float = 20.0
    frame: str = "heavy"
    # ArduSub's pilot gain (JS_GAIN; maptidal.controllers.convention.PilotGain): 1 makes an action of 1
    # full authority, as on a vehicle whose gain the bridge has set to 1; 0.5 matches ArduSub's default
    pilot_gain: float = 1.0
    # the ArduSub flight mode a pilot action is flown in (maptidal.controllers.flight_modes): "stabilize"
    # (None: the default), "manual", "alt_hold" (the heave stick a climb rate) or "poshold" (needs a
    # DVL); with action="thrusters" there is none: the commands go straight to the thrusters
    flight_mode: str | None = None
    # domain randomisation per episode (maptidal.envs.randomization): None, True (every key at its
    # default range) or a dict of key to (low, high) or one number
    randomize: object = None

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"action must be one of {ACTIONS}, got {self.action!r}")
        if self.obs_images not in IMAGES:
            raise ValueError(f"obs_images must be one of {IMAGES}, got {self.obs_images!r}")
        if not isinstance(self.flat_obs, bool):
            raise ValueError(f"flat_obs must be True or False, got {self.flat_obs!r}")
        size = tuple(self.image_size) if isinstance(self.image_size, tuple | list) else ()
        whole = all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in size)
        if not (len(size) == 2 and whole and 0 < size[0] <= MAX_IMAGE[0] and 0 < size[1] <= MAX_IMAGE[1]):
            raise ValueError(
                f"image_size must be two whole numbers (height, width) of at most {MAX_IMAGE} pixels (the "
                f"model's offscreen buffer), got {self.image_size!r}"
            )
        if self.flat_obs and self.obs_images is not None:
            raise ValueError("flat_obs cannot carry images: use the Dict observation with obs_images")
        if not (0 < self.control_period_s <= 1.0):
            raise ValueError(f"control_period_s must be in (0, 1] s, got {self.control_period_s}")
        if not (self.control_period_s <= self.episode_s <= MAX_EPISODE_S):
            raise ValueError(
                f"episode_s must be from one control period to {MAX_EPISODE_S:g} s (a day), "
                f"got {self.episode_s}"
            )
        if self.frame not in ("heavy", "standard"):
            raise ValueError(f"frame must be 'heavy' or 'standard', got {self.frame!r}")
        if self.flight_mode is not None and self.flight_mode not in FLIGHT_MODES:
            raise ValueError(f"flight_mode must be one of {FLIGHT_MODES}, got {self.flight_mode!r}")
        if self.action == "thrusters" and self.flight_mode is not None:
            raise ValueError('action="thrusters" drives the thrusters directly: it takes no flight_mode')
        try:
            PilotGain(self.pilot_gain)
        except ValueError as error:
            raise ValueError(f"pilot_gain: {error}") from None
        Randomization.from_option(self.randomize)  # raises on an unknown key or a range outside physics

    @property
    def randomization(self) -> Randomization | None:
        """What ``randomize`` asks for, checked (None: nothing is randomised)."""
        return Randomization.from_option(self.randomize)

    def simulation(self, scenario: Scenario) -> Simulation:
        """The simulation these options fly: the pilot action through ``flight_mode`` (STABILIZE unless
        given) at ``pilot_gain``, or the thrusters directly (MANUAL). With image observations its cameras
        draw at ``image_size`` itself (:meth:`camera`), not at the OAK-D's 640 x 400 and then shrunk."""
        mode = (self.flight_mode or "stabilize") if self.action == "pilot" else "manual"
        modes = ModeParams(pilot_gain=PilotGain(float(self.pilot_gain)))
        return Simulation(scenario, camera=self.camera(), flight_mode=mode, mode_params=modes)

    def camera(self) -> StereoCameraParams | None:
        """The stereo pair the observation's images come from: the OAK-D binned to ``image_size``, so
        its field of view is the sensor's (78.5 x 54.1 deg) at every size, and a size of another aspect
        than the sensor's 1.6 has non-square pixels, as a resized 640 x 400 image had. None (the
        OAK-D's 640 x 400 mode) without image observations."""
        if self.obs_images is None:
            return None
        height, width = (int(v) for v in self.image_size)
        return StereoCameraParams(width=width, height=height)

    @classmethod
    def checked(cls, options: dict, also: tuple[str, ...] = ()) -> EnvOptions:
        """The options from keyword arguments, or a ValueError naming the unknown ones (``also``: the
        caller's own arguments, listed in the message)."""
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; the options are {sorted(known | set(also))}")
        return cls(**options)


_ZERO3 = np.zeros(3)


class EpisodeState:
    """Where an environment's episode stands, so that a step before ``reset()`` or after the episode
    ended raises ``gymnasium.error.ResetNeeded`` (Gymnasium leaves both undefined; a step there used to
    go on, with ``terminated=False`` after a termination)."""

    def __init__(self) -> None:
        self.ended: str | None = "never started"

    def started(self) -> None:
        """A new episode began (``reset``)."""
        self.ended = None

    def check_step(self) -> None:
        """Raise unless an episode is under way."""
        if self.ended == "never started":
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        if self.ended is not None:
            raise gymnasium.error.ResetNeeded(
                f"the episode has ended ({self.ended}); call reset() before step()"
            )

    def record(self, result: tuple) -> tuple:
        """Note a step's ``(obs, reward, terminated, truncated, info)``; returns it unchanged."""
        terminated, truncated = result[2], result[3]
        self.ended = "terminated" if terminated else "truncated" if truncated else None
        return result


def _numbers(value) -> bool:
    """Whether ``value`` is a sequence of plain numbers (not strings, not booleans)."""
    try:
        return all(isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in value)
    except TypeError:
        return False


def _has_display() -> bool:
    # MuJoCo's viewer needs a window system; without one GLFW would abort the process
    return sys.platform != "linux" or bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class Restorable:
    """What makes an environment's episode savable (``get_state`` / ``set_state``) and the environment
    picklable and deep-copyable: a copy is built anew from the constructor's arguments and given the
    state. The environment has ``sim`` (a :class:`Simulation`), ``episode`` (an :class:`EpisodeState`)
    and ``np_random``; it names the rest of its episode's bookkeeping in ``_STATE_ATTRIBUTES`` and
    copies anything else in ``_task_state``."""

    def __new__(cls, *args, **kwargs):
        # the constructor's arguments, kept so that a pickled or deep-copied environment is built anew
        # and then given the state (__getstate__)
        env = super().__new__(cls)
        env._init_args = (args, kwargs)
        return env

    STATE_VERSION = 1
    # the episode's bookkeeping a state carries besides the simulation's, copied as it is; those an
    # environment does not have are skipped
    _STATE_ATTRIBUTES: ClassVar[tuple[str, ...]] = ()

    def get_state(self) -> dict:
        """The whole state of the episode, copied: the simulation's (:meth:`Simulation.get_state`: the
        physics, sensor noise, flight mode, autopilot and estimator), the task's (target, current, what
        has been seen, the step count) and the environment's random generator. :meth:`set_state` on
        this environment or another made with the same arguments then replays the same actions to the
        same observations and rewards, bit for bit."""
        return {
            "version": self.STATE_VERSION,
            "task": type(self).__name__,
            "sim": self.sim.get_state(),
            "episode": copy.deepcopy(
                {name: getattr(self, name) for name in self._STATE_ATTRIBUTES if hasattr(self, name)}
            ),
            "task_state": self._task_state(),
            "ended": self.episode.ended,
            "np_random": copy.deepcopy(self.np_random.bit_generator.state),
        }

    def set_state(self, state: dict) -> None:
        """Restore a :meth:`get_state`; one from another version or task raises ValueError first."""
        if not isinstance(state, dict) or state.get("version") != self.STATE_VERSION:
            got = state.get("version") if isinstance(state, dict) else type(state).__name__
            raise ValueError(f"an environment state of version {self.STATE_VERSION} is needed, got {got!r}")
        if state.get("task") != type(self).__name__:
            raise ValueError(
                f"the state is of {state.get('task')!r}, this environment is {type(self).__name__}"
            )
        self.sim.set_state(state["sim"])
        for name, value in copy.deepcopy(state["episode"]).items():
            setattr(self, name, value)
        self._set_task_state(state["task_state"])
        self.episode.ended = state["ended"]
        self.np_random.bit_generator.state = copy.deepcopy(state["np_random"])

    def _task_state(self) -> dict:
        """The task's own state beyond ``_STATE_ATTRIBUTES``, copied."""
        return {}

    def _set_task_state(self, state: dict) -> None:
        """Restore :meth:`_task_state`."""

    def __getstate__(self) -> dict:
        started = self.episode.ended != "never started"
        made = getattr(self, "spec", None)  # what gymnasium.make gave it (EpisodeLength)
        return {"init": self._init_args, "state": self.get_state() if started else None, "spec": made}

    def __setstate__(self, saved: dict) -> None:
        args, kwargs = saved["init"]
        self.__init__(*args, **kwargs)
        self._init_args = (args, kwargs)
        if saved.get("spec") is not None:
            self.spec = saved["spec"]
        if saved["state"] is not None:
            self.set_state(saved["state"])


class EpisodeLength:
    """Who ends an episode on time. Constructed directly, the environment does, after ``episode_s``
    (its ``max_steps`` control periods). Made by ``gymnasium.make``, Gymnasium's TimeLimit does, after
    ``max_episode_steps`` steps, as in Gymnasium's own MuJoCo environments: the registration sets it to
    the task's default length (``maptidal.envs.gym.MAX_EPISODE_STEPS``), ``make(..., max_episode_steps=N)``
    changes it, and ``-1`` removes it. So the spec, ``TimeAwareObservation`` and the episodes agree.

    ``episode_s`` through ``make`` is refused with a ValueError naming ``max_episode_steps``: the
    registered TimeLimit is added after the environment is built, so the two could disagree. An
    environment whose steps last no fixed time (the team's tasks mode, a step a whole task) says so in
    ``_steps_are_periods``; its episodes end after ``episode_s`` of simulated time however made."""

    _own_time_limit = True
    _made_spec = None
    _steps_are_periods = True

    @property
    def spec(self):
        """The ``EnvSpec`` ``gymnasium.make`` gave this environment (None when constructed directly)."""
        return self._made_spec

    @spec.setter
    def spec(self, spec) -> None:
        if spec is not None and self._steps_are_periods and "episode_s" in (spec.kwargs or {}):
            registered = gymnasium.registry.get(spec.id)
            steps = registered.max_episode_steps if registered is not None else None
            raise ValueError(
                f"through gymnasium.make an episode's length is max_episode_steps (Gymnasium's TimeLimit; "
                f"{spec.id} registers {steps} steps of control_period_s), not episode_s: pass "
                f"max_episode_steps=round(episode_s / control_period_s) instead, or construct the class "
                f"with episode_s"
            )
        self._own_time_limit = spec is None
        self._made_spec = spec

    def _out_of_steps(self, steps: int) -> bool:
        """Whether ``steps`` control periods end the episode on time (never when TimeLimit does it)."""
        return self._own_time_limit and steps >= self.max_steps


# the turbulence's time constant (s): gusts of a few seconds, slow enough for a controller to fight
GUST_TIME_CONSTANT_S = 2.0


def gust_step(gust: np.ndarray, sigma_m_s: float, dt: float, rng: np.random.Generator) -> np.ndarray:
    """One control period of turbulence: the exact Ornstein-Uhlenbeck update of a gust (m/s, 3 axes),
    ``g exp(-dt / tau) + sigma sqrt(1 - exp(-2 dt / tau)) N(0, 1)`` per axis with tau =
    :data:`GUST_TIME_CONSTANT_S`, whose stationary standard deviation is ``sigma`` whatever ``dt``."""
    return gust_steps(gust, sigma_m_s, dt, rng, 1)[0]


def gust_steps(gust: np.ndarray, sigma_m_s: float, dt: float, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` control periods of :func:`gust_step`, ``(n, 3)``: the same gusts from the same generator as
    ``n`` calls of it (a generator's normals are one sequence however they are asked for)."""
    decay = math.exp(-dt / GUST_TIME_CONSTANT_S)
    kicks = rng.normal(size=(n, 3)) * sigma_m_s * math.sqrt(1 - decay * decay)
    out = np.empty((n, 3))
    previous = np.asarray(gust, float)
    for k in range(n):
        previous = out[k] = decay * previous + kicks[k]
    return out


class MapTidalEnv(Restorable, EpisodeLength, gymnasium.Env):
    """Base class: one robot, estimated state, Box(-1, 1) actions, Dict or flat observations.

    ``render_mode="human"`` is offered only where a display exists (Gymnasium's checker builds the
    environment in every mode the metadata lists); asked for without one, the constructor says why."""

    # a saved state's episode bookkeeping (Restorable): the step count, the last step's energy and
    # contact, and the pose tasks' target and water (GoToPose's progress, StationKeeping's current)
    _STATE_ATTRIBUTES: ClassVar[tuple[str, ...]] = (
        "_steps",
        "_energy",
        "_contact_s",
        "target",
        "target_yaw",
        "_previous",
        "mean_current",
        "gust",
        "episode_turbulence_m_s",
        "randomization_draw",
    )
    # the turbulence (m/s): an Ornstein-Uhlenbeck gust on each axis about the episode's current, with
    # this standard deviation (gust_step); none unless a task sets it or ``randomize`` draws it
    turbulence_m_s: float = 0.0

    metadata: ClassVar[dict] = {
        "render_modes": ["rgb_array", *(["human"] if _has_display() else [])],
        "render_fps": 10,
    }

    def __init__(
        self,
        scenario: Scenario | str | None = None,
        render_mode: str | None = None,
        **options,
    ) -> None:
        self.options = EnvOptions.checked(options)
        if render_mode == "human" and not _has_display():
            raise ValueError(
                "render_mode='human' opens MuJoCo's viewer, which needs a display (DISPLAY or "
                "WAYLAND_DISPLAY is unset); use render_mode='rgb_array' when headless"
            )
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(
                f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.render_mode = render_mode
        base = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        self.scenario = with_frame(base, self.options.frame)
        self.sim = self.options.simulation(self.scenario)
        self.robot = self.sim.robots[0]
        spec = self.scenario.robots[0]
        self.vehicle = spec.vehicle
        self.substeps = max(1, round(self.options.control_period_s / self.scenario.control_period_s))
        self.dt = self.substeps * self.scenario.control_period_s
        self.max_steps = max(1, round(self.options.episode_s / self.dt))
        n = self.vehicle.n_thrusters if self.options.action == "thrusters" else 6
        self.action_space = spaces.Box(-1.0, 1.0, (n,), np.float32)
        self._dict_space = spaces.Dict(self._observation_spaces())
        if self.options.flat_obs:
            size = sum(int(np.prod(space.shape)) for space in self._dict_space.spaces.values())
            self.observation_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)
        else:
            self.observation_space = self._dict_space
        self.sim.track_estimate(self.robot)  # the observation's estimate, in MANUAL too
        self.randomization = self.options.randomization
        self.randomization_draw: dict = {}
        self.mean_current = np.zeros(3)
        self.gust = np.zeros(3)
        self.episode_turbulence_m_s = self.turbulence_m_s
        self._steps = 0
        self._energy = self._contact_s = 0.0
        self.episode = EpisodeState()
        self._renderer: mujoco.Renderer | None = None
        self._viewer = None

    # ----- what a task says -------------------------------------------------------------------
    def _task_spaces(self) -> dict[str, spaces.Space]:
        """The task's own observation entries."""
        return {}

    def _task_observation(self) -> dict[str, np.ndarray]:
        return {}

    # the keys of reset(options=...) a task honours (MapTidalEnv.reset)
    reset_options: ClassVar[tuple[str, ...]] = ("pose", "current")

    def _start_episode(self, pose: tuple[np.ndarray, float] | None = None, **given) -> None:
        """Choose the start pose (``pose`` when given: position, yaw), targets and water for a new
        episode (uses self.np_random); ``given`` holds the task's other reset options."""

    def _set_episode_current(self, current: np.ndarray) -> None:
        """Hold the water current ``current`` (m/s, world frame) for the episode; the turbulence blows
        about it."""
        self.mean_current = np.asarray(current, float)
        self.sim.set_current(self.mean_current + self.gust)

    def _reward(self, truth: dict) -> tuple[float, bool, dict]:
        """(reward, terminated, info) after one step."""
        raise NotImplementedError

    # ----- gymnasium API ----------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; ``seed`` seeds the start pose, targets, currents and all sensor and
        camera noise. ``options`` may fix what would be drawn (the task's ``reset_options``):

        - ``"pose"``: the start, ``(x, y, z, yaw)`` in m and rad, in the tank's water at least half the
          hull's length from walls, floor and surface;
        - ``"target"`` (GoToPose, StationKeeping): the pose to reach or hold, the same way;
        - ``"current"``: the water current for the episode, ``(vx, vy, vz)`` m/s (StationKeeping's
          turbulence still blows about it).

        Anything else, or a value out of range, raises ValueError before the episode changes.

        With ``randomize``, the vehicle, sensors and water are drawn first
        (:mod:`maptidal.envs.randomization`), and the draw is ``info["randomization"]``; a current
        given here, or drawn by the task itself (StationKeeping), replaces a drawn one."""
        chosen = self._checked_reset_options(options)
        super().reset(seed=seed)
        if self.randomization is not None:
            randomization.restore_sensor_noise(self.sim)  # the biases a reset draws: the scenario's
        self.sim.reset(seed=int(self.np_random.integers(2**31 - 1)))
        self._steps = 0
        info = self._randomize_episode()
        self.gust = np.zeros(3)
        self.mean_current = np.asarray(self.sim.current, float)  # the scenario's, or the drawn one
        self.episode_turbulence_m_s = float(
            self.randomization_draw.get("turbulence_m_s", self.turbulence_m_s)
        )
        current = chosen.pop("current", None)
        self._start_episode(**chosen)  # placing the robot restarts the simulation's estimator there
        if current is not None:
            self._set_episode_current(current)
        self.episode.started()
        return self._observation(), info

    def _randomize_episode(self) -> dict:
        """Draw and apply this episode's randomisation (none without ``randomize``); reset's info."""
        if self.randomization is None:
            self.randomization_draw = {}
            return {}
        self.randomization_draw = self.randomization.sample(self.np_random, self.vehicle.n_thrusters)
        randomization.apply(self.sim, self.robot, self.randomization_draw)
        return {"randomization": copy.deepcopy(self.randomization_draw)}

    def _checked_reset_options(self, options: dict | None) -> dict:
        """``reset``'s options, checked (its docstring), as arrays: pose and target as (position, yaw)."""
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise ValueError(f"reset options must be a dict, got {type(options).__name__}")
        unknown = sorted(set(options) - set(self.reset_options))
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; this task takes {list(self.reset_options)}")
        chosen: dict = {}
        margin = max(self.vehicle.hull_size[:2]) / 2
        for key in ("pose", "target"):
            if key not in options:
                continue
            value = np.asarray(options[key], float) if _numbers(options[key]) else np.zeros(0)
            if value.shape != (4,) or not np.isfinite(value).all():
                raise ValueError(
                    f"reset option {key!r} must be four finite numbers (x, y, z, yaw), got {options[key]!r}"
                )
            if not inside_tank(self.scenario.tank, value[:3], margin):
                raise ValueError(
                    f"reset option {key!r} must lie in the tank's water at least {margin:.2f} m from walls, "
                    f"floor and surface, got {value[:3].tolist()}"
                )
            chosen[key] = (value[:3].copy(), float(value[3]))
        if "current" in options:
            if not _numbers(options["current"]):
                got = options["current"]
                raise ValueError(f"reset option 'current' is three finite numbers (m/s), got {got!r}")
            chosen["current"] = check_current(options["current"], "reset option 'current'")
        return chosen

    @property
    def _estimate(self):
        return self.sim.estimate(self.robot)

    @property
    def _readings(self) -> dict:
        return self.sim.latest_readings(self.robot)

    def step(self, action):
        """Hold ``action`` for one control period (``control_period_s``). Raises
        ``gymnasium.error.ResetNeeded`` before ``reset()`` and after the episode ended."""
        self.episode.check_step()
        self._act(action)
        truth = self.sim.ground_truth(self.robot)
        reward, terminated, info = self._reward(truth)
        truncated = not terminated and self._out_of_steps(self._steps)
        return self.episode.record(
            (self._observation(), float(reward), bool(terminated), bool(truncated), info)
        )

    def _act(self, action) -> None:
        """Check ``action`` and fly it for one control period (the physics, the sensors, the estimate)."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action must be finite, got {a.tolist()}")
        a = a.clip(-1.0, 1.0)
        mode = "thrusters" if self.options.action == "thrusters" else "pilot"
        # every control period of the step in one call (the compiled flight stack where it runs)
        per_period = self.sim.step_periods({self.robot: a}, self.substeps, mode, self._substep_currents())
        mine = per_period[:, 0, :].tolist()
        self._energy = sum(row[0] for row in mine) / self.substeps  # the mean squared command
        self._contact_s = sum(row[1] > 0 for row in mine) * self.scenario.control_period_s
        self._steps += 1

    def _substep_currents(self) -> np.ndarray | None:
        """The water current of each control period of the step: the turbulence (:func:`gust_step`)
        blown period by period about the episode's current; None without turbulence."""
        if self.episode_turbulence_m_s <= 0:
            return None
        period = self.scenario.control_period_s
        gusts = gust_steps(self.gust, self.episode_turbulence_m_s, period, self.np_random, self.substeps)
        self.gust = gusts[-1].copy()
        return self.mean_current + gusts

    def _next_current(self) -> np.ndarray:
        """Blow the turbulence one control period on (:func:`gust_step`); the current it gives."""
        self.gust = gust_step(
            self.gust, self.episode_turbulence_m_s, self.scenario.control_period_s, self.np_random
        )
        return self.mean_current + self.gust

    def _before_substep(self) -> None:
        """Blow the turbulence for one control period about the episode's current (the batched
        environment's period loop)."""
        if self.episode_turbulence_m_s > 0:
            self.sim.set_current(self._next_current())

    # ----- observations -------------------------------------------------------------------
    def _observation_spaces(self) -> dict[str, spaces.Space]:
        box = lambda n: spaces.Box(-np.inf, np.inf, (n,), np.float32)  # noqa: E731
        entries: dict[str, spaces.Space] = {
            "pose": box(6),
            "velocity": box(6),
            "depth": box(1),
            "imu": box(6),
        }
        entries.update(self._task_spaces())
        height, width = (int(v) for v in self.options.image_size)
        if self.options.obs_images == "left":
            entries["left"] = spaces.Box(0, 255, (height, width, 3), np.uint8)
        elif self.options.obs_images == "stereo":
            entries["stereo"] = spaces.Box(0, 255, (2, height, width, 3), np.uint8)
        return entries

    def _observation(self):
        e = self._estimate
        imu = self._readings.get("imu", {})
        depth = self._readings.get("depth", {})
        # np.concatenate, not np.r_: the observation is built every step, and np.r_ costs 15 us a call
        values = {
            "pose": np.concatenate((e.position, e.rpy)),
            "velocity": np.concatenate((e.velocity_body, e.angular_velocity_body)),
            "depth": np.array([depth.get("depth_m", 0.0)]),
            "imu": np.concatenate((imu.get("accel", _ZERO3), imu.get("gyro", _ZERO3))),
        }
        values.update(self._task_observation())
        observation = {key: np.asarray(value, np.float32) for key, value in values.items()}
        if self.options.obs_images is not None:
            observation.update(self._images())
        if self.options.flat_obs:
            return np.concatenate([observation[key].ravel() for key in self._dict_space.spaces])
        return observation

    def _images(self) -> dict[str, np.ndarray]:
        # the cameras draw at image_size (EnvOptions.camera); "left" draws the left camera alone
        if self.options.obs_images == "left":
            return {"left": self.sim.render_left(self.robot)}
        return {"stereo": np.stack(self.sim.render_stereo(self.robot))}

    # ----- helpers for tasks ----------------------------------------------------------------
    def _sample_pose(self) -> tuple[np.ndarray, float]:
        low, high = SAFE_BOX
        return self.np_random.uniform(low, high), float(self.np_random.uniform(-math.pi, math.pi))

    def _relative_target(self, target: np.ndarray, target_yaw: float) -> np.ndarray:
        """The target as the robot estimates it: offset in its heading frame (m) and yaw error (rad)."""
        e = self._estimate
        offset_world = np.asarray(target, float) - e.position
        heading = rotation_from_rpy(0.0, 0.0, e.yaw)
        return np.append(heading.T @ offset_world, wrap_angle(target_yaw - e.yaw))

    @property
    def _contact_cost(self) -> float:
        """What the last step's time in contact costs (``CONTACT_COST_PER_S``)."""
        return CONTACT_COST_PER_S * self._contact_s

    # ----- rendering ------------------------------------------------------------------------
    def render(self):
        """``rgb_array``: a third-person view following the robot, its left camera inset top right.
        ``human``: MuJoCo's passive viewer (needs a display)."""
        if self.render_mode == "rgb_array":
            return self._render_rgb()
        if self.render_mode == "human":
            if self._viewer is None:
                import mujoco.viewer

                self._viewer = mujoco.viewer.launch_passive(self.sim.model, self.sim.data)
            self._viewer.sync()
        return None

    def _render_rgb(self) -> np.ndarray:
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.sim.model, 240, 320)
        return third_person_frame(self.sim, self._renderer, [self.robot])

    def close(self) -> None:
        """Free the renderers and the viewer."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        self.sim.close()


POSITION_TOLERANCE_M = 0.1  # the task executor's defaults (controllers/task.py)
YAW_TOLERANCE_RAD = math.radians(5.0)


class PoseTargetEnv(MapTidalEnv):
    """A task with a pose to reach or hold (``self.target``, ``self.target_yaw``, set by
    ``_start_episode``): the observation adds ``target``, as the robot estimates it."""

    reset_options: ClassVar[tuple[str, ...]] = ("pose", "target", "current")

    def _task_spaces(self) -> dict[str, spaces.Space]:
        return {"target": spaces.Box(-np.inf, np.inf, (4,), np.float32)}

    def _task_observation(self) -> dict[str, np.ndarray]:
        return {"target": self._relative_target(self.target, self.target_yaw)}

    def _target_errors(self, truth: dict) -> tuple[float, float, bool]:
        """The true distance (m) and yaw error (rad) to the target, and whether both are within the
        tolerances (0.1 m, 5 deg)."""
        distance = float(np.linalg.norm(np.asarray(truth["position"]) - self.target))
        yaw_error = abs(wrap_angle(self.target_yaw - truth["rpy"][2]))
        return distance, yaw_error, distance <= POSITION_TOLERANCE_M and yaw_error <= YAW_TOLERANCE_RAD
