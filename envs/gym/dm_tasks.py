"""The same tasks as dm_control ``control.Environment``s (``dm_env.Environment``), for DeepMind-stack
users (Acme, dm_env).

Each environment is a :class:`MapTidalPhysics`, a ``dm_control.mujoco.Physics`` around the *same*
``MjData`` (and so the same compiled model and hydrodynamics callback) as the Gymnasium task's
:class:`maptidal.envs.simulation.Simulation`, and a :class:`GymTask` that asks the Gymnasium task for its
start state, observations, reward and termination. No second world is built.

    from maptidal.envs.gym.dm_tasks import load
    env = load("go_to_pose")                 # or "station_keeping", "tank_inspection"
    timestep = env.reset()
    timestep = env.step(numpy.zeros(6))

One ``env.step`` is one control period of the Gymnasium task (0.1 s by default); the physics steps
underneath it run through the Simulation (mixer, thrust curve, flight mode, sensors), as in the
Gymnasium task. Where a display exists, :func:`view` (``dm_control.viewer.launch``) shows a task.
"""

from __future__ import annotations

import collections

import numpy as np
from dm_control import mujoco
from dm_control.mujoco import wrapper
from dm_control.rl import control
from dm_control.suite import base
from dm_env import specs

from maptidal.envs.gym.core import MapTidalEnv
from maptidal.envs.gym.go_to_pose import GoToPoseEnv
from maptidal.envs.gym.station_keeping import StationKeepingEnv
from maptidal.envs.gym.tank_inspection import TankInspectionEnv

TASKS: dict[str, type[MapTidalEnv]] = {
    "go_to_pose": GoToPoseEnv,
    "station_keeping": StationKeepingEnv,
    "tank_inspection": TankInspectionEnv,
}


class MapTidalPhysics(mujoco.Physics):
    """dm_control's Physics over a Gymnasium task's own MjData; ``step`` flies the pending action for
    one of the task's control periods through its Simulation."""

    def bind(self, task_env: MapTidalEnv) -> MapTidalPhysics:
        """Attach the Gymnasium task whose Simulation owns this MjData."""
        self.task_env = task_env
        self.pending_action = np.zeros(task_env.action_space.shape)
        return self

    def step(self, nstep: int = 1) -> None:
        """One control period of the task (``nstep`` is the Environment's, always 1 here)."""
        for _ in range(nstep):
            self.task_env._act(self.pending_action)

    def timestep(self) -> float:
        """The task's control period (s): what one ``step`` advances."""
        return self.task_env.dt


class GymTask(base.Task):
    """A dm_control Task that defers to a Gymnasium task for everything but the stepping."""

    def __init__(self, task_env: MapTidalEnv, seed: int | None = None) -> None:
        super().__init__(random=seed)
        self.task_env = task_env
        self._last: tuple[float, bool] = (0.0, False)

    def initialize_episode(self, physics: MapTidalPhysics) -> None:
        """A new episode of the Gymnasium task, seeded from this task's random state."""
        self.task_env.reset(seed=int(self.random.randint(2**31 - 1)))
        self._last = (0.0, False)

    def before_step(self, action, physics: MapTidalPhysics) -> None:
        """Hand the action to the physics, which flies it."""
        physics.pending_action = np.asarray(action, float)

    def after_step(self, physics: MapTidalPhysics) -> None:
        """Score the step."""
        reward, terminated, _ = self.task_env._reward(self.task_env.sim.ground_truth(self.task_env.robot))
        self._last = (float(reward), bool(terminated))

    def action_spec(self, physics: MapTidalPhysics) -> specs.BoundedArray:
        """The Gymnasium task's Box(-1, 1) action as a dm_env spec."""
        space = self.task_env.action_space
        return specs.BoundedArray(space.shape, np.float64, -1.0, 1.0, name="action")

    def get_observation(self, physics: MapTidalPhysics) -> collections.OrderedDict:
        """The Gymnasium task's Dict observation, as float64 arrays (images as uint8)."""
        observation = self.task_env._observation()
        return collections.OrderedDict(
            (key, value if value.dtype == np.uint8 else value.astype(np.float64))
            for key, value in observation.items()
        )

    def get_reward(self, physics: MapTidalPhysics) -> float:
        """The Gymnasium task's reward for the last step."""
        return self._last[0]

    def get_termination(self, physics: MapTidalPhysics):
        """0.0 (no future) when the Gymnasium task terminated, else None (the time limit is the
        Environment's)."""
        return 0.0 if self._last[1] else None


def load(task: str, seed: int | None = None, **options) -> control.Environment:
    """A dm_control Environment of ``task`` ("go_to_pose", "station_keeping", "tank_inspection");
    ``options`` are the Gymnasium task's (``flat_obs`` is not: dm_env observations stay a dict)."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; choose one of {sorted(TASKS)}")
    if options.get("flat_obs"):
        raise ValueError("use dm_control's own flat_observation, not flat_obs")
    task_env = TASKS[task](**options)
    physics = MapTidalPhysics(wrapper.MjData(task_env.sim.data)).bind(task_env)
    return control.Environment(
        physics, GymTask(task_env, seed), time_limit=task_env.options.episode_s, n_sub_steps=1
    )


def view(task: str, policy=None, seed: int | None = None, **options) -> None:
    """Show ``task`` in ``dm_control.viewer`` (needs a display), flown by ``policy`` (a function of the
    ``TimeStep`` that returns a 6-vector; none: the viewer's zero action)."""
    from maptidal.envs.gym.core import _has_display

    if not _has_display():
        raise ValueError("dm_control.viewer needs a display (DISPLAY or WAYLAND_DISPLAY is unset)")
    from dm_control import viewer

    viewer.launch(lambda: load(task, seed=seed, **options), policy=policy)
