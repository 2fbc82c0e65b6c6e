"""``MapTidal/TeamInspection-v1``: N robots share the inspection of the tank; and a PettingZoo
``ParallelEnv`` adapter of it (:func:`parallel_env`), the multi-agent convention."""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import ClassVar

import gymnasium
import mujoco
import numpy as np
from gymnasium import spaces

from maptidal.controllers.pose import PoseController
from maptidal.controllers.task import TaskExecutor, TaskParams
from maptidal.envs.gym.core import (
    CONTACT_COST_PER_S,
    SAFE_BOX,
    EnvOptions,
    EpisodeLength,
    EpisodeState,
    Restorable,
    gust_step,
)
from maptidal.envs.gym.tank_inspection import REWARD_PER_VOXEL, SECTORS, WallCoverage, camera_viewpoint
from maptidal.envs.randomization import apply as apply_randomization
from maptidal.envs.randomization import restore_sensor_noise
from maptidal.envs.scenario import Scenario, load_scenario, with_frame
from maptidal.envs.views import third_person_frame
from maptidal.evaluation.baselines import voronoi_viewpoints

MAX_ROBOTS = 4
MIN_SEPARATION_M = 0.9  # start poses at least this far apart (a Heavy is 0.58 m wide)


class TeamInspectionEnv(Restorable, EpisodeLength, gymnasium.Env):
    """N BlueROV2s (default 2) inspect the tank's evaluated walls together and share the reward.

    ## Action space

    ``Dict`` keyed by robot name (``rov0``, ``rov1``, ...), each ``Box(-1, 1, (6,), float32)``: the pilot
    command of ``controllers/convention.py`` through STABILIZE (or per-thruster commands with
    ``action="thrusters"``).

    ``action="tasks"``: each robot's entry is ``Discrete(N)``, the inspection task to fly next (the
    Voronoi baseline's 20 viewpoints, :func:`task_poses`). One step flies every robot to its task with
    ``maptidal.controllers.task.TaskExecutor`` (go-to-pose on its own estimate, hold 0.1 m and 5 deg for a 1 s
    dwell; ``task_timeout_s``, 30 s, if it cannot), and the observation adds ``tasks`` (the N poses x,
    y, z, yaw) and ``tasks_done`` (1 for each task captured). The reward is then 0.01 per wall voxel
    newly seen from where the robots end, minus 0.01 per second spent and 10 per second any robot is in
    contact; the episode ends when every task is done (a collision stops that step's flight, and the
    robots choose again).

    ## Observation space

    ``Dict`` keyed by robot name; each robot's entry is the Dict of ``MapTidal/TankInspection-v1``
    (pose, velocity, depth, imu, from that robot's own sensors) with ``coverage`` the team's share seen,
    overall and per sector, and ``others``: the other robots' true positions relative to this robot's
    estimate (m, world axes, ``3 x (N - 1)``; what an acoustic position exchange would give). With
    ``flat_obs=True`` each robot's entry is one Box.

    ## Rewards

    Shared by all robots, per step:

    | term | value |
    |---|---|
    | coverage | ``0.01 x`` the wall voxels newly seen by any robot's camera (with occlusion) |
    | energy | ``- 0.05 x`` the robots' mean squared thruster command |
    | contact | ``- 10 x`` the seconds of the step any robot is in contact (the tank or each other) |

    ## Starting state

    Random positions in the tank's safe box, at least 0.9 m apart, facing the end wall within +-60 deg.

    ## Episode end

    Terminated: with ``action="tasks"``, when every task is done. Collisions and surfacing end nothing
    (in v0 they did, and ramming a wall saw more before the end than doing nothing, which floated up
    and ended too). Truncated: after ``episode_s`` (60 s) when constructed directly; made by
    ``gymnasium.make``, after ``max_episode_steps`` steps (TimeLimit; registered 600, 60 s), except with
    ``action="tasks"``, whose steps last a task each: there the episode ends after ``episode_s`` of
    simulated time, however made (``maptidal.envs.gym.core.EpisodeLength``).

    ## Rendering

    ``render_mode="rgb_array"``: a view from behind the first robot with every robot's camera inset.

    ## Arguments

    ``n_robots=2`` (1 to 4), ``action`` ("pilot", "thrusters" or "tasks"), ``task_timeout_s=30``, and
    those of ``MapTidal/GoToPose-v1`` (``max_episode_steps`` 600 and ``episode_s`` 60 s; ``randomize``
    draws each robot its own vehicle and sensors, and one water).

    ## Version history

    - v1: contacts cost per second and end nothing; surfacing ends nothing.
    - v0: first version (maptidal 0.1).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}  # noqa: RUF012 (Gymnasium's convention)
    # what a saved state carries besides the simulation's (Restorable): the step count, the tasks done,
    # the episode's start, the go-to-pose controllers' integrators of the tasks mode
    _STATE_ATTRIBUTES: ClassVar[tuple[str, ...]] = (
        "_steps",
        "tasks_done",
        "_episode_start",
        "_controllers",
        "randomization_draw",
        "_mean_current",
        "_gust",
        "_turbulence_m_s",
    )

    def __init__(
        self,
        n_robots: int = 2,
        scenario: Scenario | str | None = None,
        episode_s: float = 60.0,
        task_timeout_s: float = 30.0,
        render_mode: str | None = None,
        **options,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self._renderer = None
        self.tasks_mode = options.get("action") == "tasks"
        self.randomization_draw: dict = {}
        # one water for the team: the drawn turbulence blows one gust about the one current (gust_step)
        self._mean_current, self._gust, self._turbulence_m_s = np.zeros(3), np.zeros(3), 0.0
        self._steps_are_periods = not self.tasks_mode  # a task step lasts as long as its task (EpisodeLength)
        if self.tasks_mode:
            options = {**options, "action": "pilot"}
        if not (math.isfinite(task_timeout_s) and task_timeout_s > 0):
            raise ValueError(f"task_timeout_s must be a positive number of seconds, got {task_timeout_s!r}")
        self.task_timeout_s = float(task_timeout_s)
        if not (isinstance(n_robots, int) and 1 <= n_robots <= MAX_ROBOTS):
            raise ValueError(f"n_robots must be an integer from 1 to {MAX_ROBOTS}, got {n_robots!r}")
        self.options = EnvOptions.checked(
            {**options, "episode_s": episode_s}, also=("n_robots", "task_timeout_s")
        )
        if self.options.obs_images is not None:
            raise ValueError("the team environment has no image observations yet")
        self.episode = EpisodeState()
        base = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        base = with_frame(base, self.options.frame)
        template = base.robots[0]
        robots = tuple(
            dataclasses.replace(template, name=f"rov{k}", position=(-1.5 - 0.9 * k, 0.0, 1.0))
            for k in range(n_robots)
        )
        self.scenario = dataclasses.replace(base, robots=robots)
        self.sim = self.options.simulation(self.scenario)
        self.agents = list(self.sim.robots)
        self.vehicle = template.vehicle
        self.substeps = max(1, round(self.options.control_period_s / self.scenario.control_period_s))
        self.max_steps = max(
            1, round(self.options.episode_s / (self.substeps * self.scenario.control_period_s))
        )
        self.tasks = task_poses(self.scenario.tank, self.vehicle.sensors.camera_position)
        if self.tasks_mode:
            self.action_space = spaces.Dict({name: spaces.Discrete(len(self.tasks)) for name in self.agents})
        else:
            n_actions = self.vehicle.n_thrusters if self.options.action == "thrusters" else 6
            self.action_space = spaces.Dict(
                {name: spaces.Box(-1.0, 1.0, (n_actions,), np.float32) for name in self.agents}
            )
        box = lambda n: spaces.Box(-np.inf, np.inf, (n,), np.float32)  # noqa: E731
        self._entry_spaces = {
            "pose": box(6),
            "velocity": box(6),
            "depth": box(1),
            "imu": box(6),
            "coverage": spaces.Box(0.0, 1.0, (SECTORS + 1,), np.float32),
            "others": box(3 * (n_robots - 1)),
        }
        if self.tasks_mode:
            self._entry_spaces["tasks"] = box(4 * len(self.tasks))
            self._entry_spaces["tasks_done"] = spaces.Box(0.0, 1.0, (len(self.tasks),), np.float32)
        self.tasks_done = np.zeros(len(self.tasks), bool)
        if self.options.flat_obs:
            size = sum(space.shape[0] for space in self._entry_spaces.values())
            per_robot = box(size)
        else:
            per_robot = spaces.Dict(self._entry_spaces)
        self.observation_space = spaces.Dict({name: per_robot for name in self.agents})
        self.walls = WallCoverage(self.scenario.tank)
        self.coverage = self.walls.model
        for name in self.agents:
            self.sim.track_estimate(name)  # the observations' estimates, in MANUAL too
        # STABILIZE holds roll and pitch, so the pose controllers of the tasks mode leave them alone
        self._controllers = {
            name: PoseController(self.vehicle.controller_model(), hold_roll_pitch=False)
            for name in self.agents
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode (``seed`` seeds poses and all noise). This task takes no ``options`` yet,
        and says so rather than ignore them."""
        if options:
            raise ValueError(f"MapTidal/TeamInspection takes no reset options yet, got {sorted(options)}")
        super().reset(seed=seed)
        randomization = self.options.randomization
        if randomization is not None:
            restore_sensor_noise(self.sim)  # the biases a reset draws: at the scenario's levels
        self.sim.reset(seed=int(self.np_random.integers(2**31 - 1)))
        self._steps = 0
        info = {}
        if randomization is not None:  # each robot its own vehicle and sensors; one water, one current
            self.randomization_draw = {
                name: randomization.sample(self.np_random, self.vehicle.n_thrusters) for name in self.agents
            }
            for draw in list(self.randomization_draw.values())[1:]:
                for shared in ("current_m_s", "current_heading_rad", "turbidity", "turbulence_m_s"):
                    draw.pop(shared, None)
            for name, draw in self.randomization_draw.items():
                apply_randomization(self.sim, name, draw)
            info = {"randomization": copy.deepcopy(self.randomization_draw)}
        first = self.randomization_draw.get(self.agents[0], {}) if randomization is not None else {}
        self._mean_current, self._gust = self.sim.current, np.zeros(3)
        self._turbulence_m_s = float(first.get("turbulence_m_s", 0.0))
        low, high = SAFE_BOX
        placed: list[np.ndarray] = []
        for name in self.agents:
            for _ in range(200):
                position = self.np_random.uniform(low, high)
                if all(np.linalg.norm(position - other) >= MIN_SEPARATION_M for other in placed):
                    break
            placed.append(position)
            self.sim.place(name, position, float(self.np_random.uniform(-math.pi / 3, math.pi / 3)))
        self.walls.reset()
        self.tasks_done = np.zeros(len(self.tasks), bool)
        self._episode_start = self.sim.time
        for controller in self._controllers.values():
            controller.reset()  # no integral carried over from the last episode
        self._look()
        self.episode.started()
        return self._observation(), info

    def step(self, action):
        """Hold each robot's action for one control period (with ``action="tasks"``: fly each robot to
        its chosen task and hold it for the dwell); one shared reward. Raises
        ``gymnasium.error.ResetNeeded`` before ``reset()`` and after the episode ended."""
        self.episode.check_step()
        return self.episode.record(self._step(action))

    def _step(self, action):
        if not isinstance(action, dict) or set(action) != set(self.agents):
            raise ValueError(f"action must be a dict with one entry per robot {self.agents}")
        if self.tasks_mode:
            return self._fly_tasks(action)
        commands = {}
        for name in self.agents:
            value = np.asarray(action[name], float)
            if value.shape != self.action_space[name].shape or not np.all(np.isfinite(value)):
                raise ValueError(f"{name}: action must be {self.action_space[name].shape} finite values")
            commands[name] = np.clip(value, -1.0, 1.0)
        mode = "thrusters" if self.options.action == "thrusters" else "pilot"
        currents = None
        if self._turbulence_m_s > 0:
            currents = np.array([self._next_current() for _ in range(self.substeps)])
        # every control period of the step in one call (the compiled flight stack where it runs)
        per_period = self.sim.step_periods(commands, self.substeps, mode, currents)
        mine = [self.sim.robots.index(name) for name in self.agents]
        energy = float(per_period[:, mine, 0].sum())  # mean squared commands, summed over periods and robots
        touching = int((per_period[:, :, 1].max(axis=1) > 0).sum())  # periods with any robot in contact
        self._steps += 1
        new = self._look()
        contact_s = touching * self.scenario.control_period_s
        reward = REWARD_PER_VOXEL * new - 0.05 * energy / (self.substeps * len(self.agents))
        reward -= CONTACT_COST_PER_S * contact_s
        truncated = self._out_of_steps(self._steps)
        info = {"new_voxels": new, "coverage": float(self.seen.mean()), "contact_s": contact_s}
        return self._observation(), float(reward), False, bool(truncated), info

    def _blow(self) -> None:
        """One control period of the drawn turbulence, about the episode's current."""
        if self._turbulence_m_s > 0:
            self.sim.set_current(self._next_current())

    def _next_current(self) -> np.ndarray:
        """Blow the drawn turbulence one control period on; the current it gives."""
        period = self.scenario.control_period_s
        self._gust = gust_step(self._gust, self._turbulence_m_s, period, self.np_random)
        return self._mean_current + self._gust

    def _fly_tasks(self, action):
        chosen = {}
        for name in self.agents:
            index = action[name]
            if not (isinstance(index, int | np.integer) and 0 <= int(index) < len(self.tasks)):
                raise ValueError(f"{name}: a task index from 0 to {len(self.tasks) - 1}, got {index!r}")
            chosen[name] = int(index)
        params = TaskParams(dwell_s=1.0, timeout_s=self.task_timeout_s)
        executors = {
            name: TaskExecutor(
                self._controllers[name],
                self.sim.estimate(name),
                self.tasks[k, :3],
                float(self.tasks[k, 3]),
                params,
            )
            for name, k in chosen.items()
        }
        status = dict.fromkeys(self.agents, "approach")
        period = self.scenario.control_period_s
        start = self.sim.time
        collided, contact_s = False, 0.0
        while any(s not in ("capture", "timeout") for s in status.values()):
            commands = {}
            for name in self.agents:
                commands[name], now = executors[name].update(self.sim.estimate(name), period)
                if status[name] not in ("capture", "timeout"):
                    status[name] = now
            self._blow()
            self.sim.step(commands)
            if self.sim.contacts():
                collided, contact_s = True, contact_s + period
                break
            if self.sim.time - self._episode_start >= self.options.episode_s:
                break
        for name, k in chosen.items():
            if status[name] == "capture":
                self.tasks_done[k] = True
        new = self._look()
        elapsed = self.sim.time - start
        reward = REWARD_PER_VOXEL * new - 0.01 * elapsed - CONTACT_COST_PER_S * contact_s
        terminated = bool(self.tasks_done.all())
        truncated = not terminated and self.sim.time - self._episode_start >= self.options.episode_s
        info = {
            "new_voxels": new,
            "coverage": float(self.seen.mean()),
            "status": status,
            "elapsed_s": elapsed,
            "collided": collided,
        }
        return self._observation(), float(reward), bool(terminated), bool(truncated), info

    @property
    def seen(self) -> np.ndarray:
        """Which wall voxels any robot's camera has seen this episode."""
        return self.walls.seen

    def _task_state(self) -> dict:
        return {"seen": self.walls.seen.copy()}

    def _set_task_state(self, state: dict) -> None:
        self.walls.restore(state["seen"])

    def _look(self) -> int:
        camera = self.vehicle.sensors.camera_position
        viewpoints = [camera_viewpoint(self.sim.ground_truth(name), camera) for name in self.agents]
        return self.walls.look(np.array(viewpoints))

    def _observation(self) -> dict:
        coverage = self.walls.summary()
        positions = {name: np.asarray(self.sim.ground_truth(name)["position"]) for name in self.agents}
        out = {}
        for name in self.agents:
            e, readings = self.sim.estimate(name), self.sim.latest_readings(name)
            others = [positions[other] - e.position for other in self.agents if other != name]
            entry = {
                "pose": np.r_[e.position, e.rpy],
                "velocity": np.r_[e.velocity_body, e.angular_velocity_body],
                "depth": np.array([readings.get("depth", {}).get("depth_m", 0.0)]),
                "imu": np.r_[readings["imu"]["accel"], readings["imu"]["gyro"]],
                "coverage": coverage,
                "others": np.concatenate(others) if others else np.zeros(0),
            }
            if self.tasks_mode:
                entry["tasks"] = self.tasks.ravel()
                entry["tasks_done"] = self.tasks_done.astype(float)
            entry = {key: np.asarray(value, np.float32) for key, value in entry.items()}
            out[name] = (
                np.concatenate([entry[k] for k in self._entry_spaces]) if self.options.flat_obs else entry
            )
        return out

    def render(self):
        """``rgb_array``: a view from behind the first robot, every robot's left camera inset."""
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.sim.model, 240, 320)
        return third_person_frame(self.sim, self._renderer, self.agents)

    def close(self) -> None:
        """Free the renderers."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.sim.close()


def task_poses(tank, camera_position) -> np.ndarray:
    """The inspection tasks of the ``action="tasks"`` mode, ``(N, 4)`` robot poses x, y, z, yaw: the
    Voronoi baseline's viewpoints (``maptidal.evaluation.baselines``, 1 m from the walls), each with the robot
    placed so that its camera sits at the viewpoint looking along it."""
    viewpoints = voronoi_viewpoints(tank)
    poses = []
    for viewpoint in viewpoints:
        direction = viewpoint[3:] / np.linalg.norm(viewpoint[3:])
        yaw = math.atan2(direction[1], direction[0])
        forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        position = viewpoint[:3] - forward * float(camera_position[0]) - np.array([0, 0, camera_position[2]])
        poses.append([*position, yaw])
    return np.array(poses)


def parallel_env(**kwargs):
    """TeamInspection as a PettingZoo ``ParallelEnv`` (needs the optional ``pettingzoo`` package): each
    robot is an agent with its own observation and action spaces; every agent gets the shared reward."""
    from pettingzoo import ParallelEnv

    class TeamInspectionParallel(ParallelEnv):
        """PettingZoo view of :class:`TeamInspectionEnv` (same arguments). ``render()`` is the team
        environment's (``render_mode="rgb_array"``); ``state()`` is the global state a centralised
        critic may use: each robot's true pose (x, y, z, roll, pitch, yaw) and body velocity (u, v, w,
        p, q, r), in agent order, then the team's share of the walls seen, overall and per sector."""

        metadata = {"name": "maptidal_team_inspection_v1", "render_modes": ["rgb_array"]}  # noqa: RUF012

        def __init__(self, render_mode: str | None = None, **options) -> None:
            self.env = TeamInspectionEnv(render_mode=render_mode, **options)
            self.render_mode = render_mode
            self.possible_agents = list(self.env.agents)
            self.agents: list[str] = []
            size = 12 * len(self.possible_agents) + SECTORS + 1
            self.state_space = spaces.Box(-np.inf, np.inf, (size,), np.float32)

        def render(self):
            return self.env.render()

        def state(self) -> np.ndarray:
            parts = []
            for agent in self.possible_agents:
                truth = self.env.sim.ground_truth(agent)
                parts += [
                    truth["position"],
                    truth["rpy"],
                    truth["velocity_body"],
                    truth["angular_velocity_body"],
                ]
            parts.append(self.env.walls.summary())
            return np.concatenate([np.asarray(p, float) for p in parts]).astype(np.float32)

        def observation_space(self, agent: str):
            return self.env.observation_space[agent]

        def action_space(self, agent: str):
            return self.env.action_space[agent]

        def reset(self, seed: int | None = None, options: dict | None = None):
            # PettingZoo's API test passes options no task knows and expects them taken: the team task
            # takes none yet, so they are left out, with a warning, rather than refused
            if options:
                gymnasium.logger.warn(f"TeamInspection takes no reset options yet; ignored {sorted(options)}")
            observations, _ = self.env.reset(seed=seed)
            self.agents = list(self.possible_agents)
            return observations, {agent: {} for agent in self.agents}

        def step(self, actions: dict):
            full = {
                agent: actions.get(agent, np.zeros(self.env.action_space[agent].shape))
                for agent in self.possible_agents
            }
            observations, reward, terminated, truncated, info = self.env.step(full)
            agents = list(self.agents)
            if terminated or truncated:
                self.agents = []
            return (
                {agent: observations[agent] for agent in agents},
                dict.fromkeys(agents, reward),
                dict.fromkeys(agents, terminated),
                dict.fromkeys(agents, truncated),
                {agent: dict(info) for agent in agents},
            )

        def close(self) -> None:
            self.env.close()

    return TeamInspectionParallel(**kwargs)
