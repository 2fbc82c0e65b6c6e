"""``MapTidal/StationKeeping-v1``: hold a pose against a current and turbulence that vary per episode."""

from __future__ import annotations

import math

import numpy as np

from maptidal.envs.gym.core import PoseTargetEnv


class StationKeepingEnv(PoseTargetEnv):
    """One BlueROV2 holds the pose it starts at while a current and turbulence push it off.

    ## Action space

    As ``MapTidal/GoToPose-v1``: ``Box(-1, 1, (6,), float32)`` pilot commands through STABILIZE, or
    ``action="thrusters"``.

    ## Observation space

    As ``MapTidal/GoToPose-v1`` (pose, velocity, depth, imu, target; optional images); ``target`` is the
    pose to hold, as the robot estimates it (offset in its heading frame, m, and yaw error, rad).

    ## Rewards

    Per step, from the true pose, bounded to [-1, 1]:

    | term | value | range |
    |---|---|---|
    | position | ``0.5 exp(-distance / 0.2 m)`` | 0 to 0.5 |
    | heading | ``0.2 exp(-yaw error / 0.2 rad)`` | 0 to 0.2 |
    | held | ``0.3`` while within 0.1 m and 5 deg | 0 or 0.3 |
    | energy | the sum above times ``1 - 0.5 x`` the mean squared thruster command | x 0.5 to 1 |
    | contact | ``- 10 x`` the seconds of the step in contact with the tank | -1 to 0 at 0.1 s |

    Every step away from contact earns something, so no way of ending an episode pays (v0's negative
    per-step reward made surfacing at once the best a policy could learn).

    ## Starting state

    A random pose in the tank's safe box, at rest, which is also the pose to hold; ``reset(options=...)``
    may fix the ``pose``, a ``target`` elsewhere, and the ``current`` (MapTidalEnv.reset). The
    episode's current is horizontal, of a random direction and a speed drawn from
    [0, ``max_current_m_s``] (default 0.2 m/s); turbulence adds an Ornstein-Uhlenbeck gust on each
    axis with standard deviation ``turbulence_m_s`` (default 0.03 m/s) and a 2 s time constant.

    ## Episode end

    Never terminated: a collision costs per second in contact and the robot may surface, as a real one
    would. Truncated as in ``MapTidal/GoToPose-v1``: after 200 steps made by ``gymnasium.make``
    (``max_episode_steps``), after ``episode_s`` (default 20 s) constructed directly.
    ``info["is_success"]``: within tolerance.

    ## Arguments

    Those of ``MapTidal/GoToPose-v1``, and ``max_current_m_s=0.2``, ``turbulence_m_s=0.03`` (a
    ``turbulence_m_s`` drawn by ``randomize`` replaces it for its episode).

    ## Version history

    - v1: a bounded, non-negative per-step reward; contacts cost per second and end nothing.
    - v0: first version (maptidal 0.1).
    """

    def __init__(self, *args, max_current_m_s: float = 0.2, turbulence_m_s: float = 0.03, **kwargs) -> None:
        if not (0 <= max_current_m_s <= 1.0 and math.isfinite(max_current_m_s)):
            raise ValueError(f"max_current_m_s must be in [0, 1] m/s, got {max_current_m_s!r}")
        if not (0 <= turbulence_m_s <= 0.5 and math.isfinite(turbulence_m_s)):
            raise ValueError(f"turbulence_m_s must be in [0, 0.5] m/s, got {turbulence_m_s!r}")
        self.max_current_m_s, self.turbulence_m_s = max_current_m_s, turbulence_m_s
        super().__init__(*args, **kwargs)

    def _start_episode(self, pose=None, target=None) -> None:
        start, yaw = pose if pose is not None else self._sample_pose()
        self.sim.place(self.robot, start, yaw)
        self.target, self.target_yaw = target if target is not None else (start, yaw)
        heading = self.np_random.uniform(-math.pi, math.pi)
        speed = self.np_random.uniform(0.0, self.max_current_m_s)
        self._set_episode_current(speed * np.array([math.cos(heading), math.sin(heading), 0.0]))

    def _reward(self, truth: dict) -> tuple[float, bool, dict]:
        distance, yaw_error, within = self._target_errors(truth)
        held = 0.5 * math.exp(-distance / 0.2) + 0.2 * math.exp(-yaw_error / 0.2) + (0.3 if within else 0.0)
        reward = held * (1.0 - 0.5 * self._energy) - self._contact_cost
        info = {
            "is_success": within,
            "distance_m": distance,
            "current_m_s": self.mean_current.tolist(),
            "contact_s": self._contact_s,
        }
        return reward, False, info
