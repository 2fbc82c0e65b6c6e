"""Fixed policies for probing the Gymnasium environments' rewards (issue [rl], part 1): doing nothing,
three ways of trying to end an episode at once, and a scripted controller. Used by
``tests/test_reward_exploits.py`` and ``tests/bench/reward_exploits.py``."""

from __future__ import annotations

import gymnasium
import numpy as np

import maptidal.envs  # noqa: F401  (registers the environments)
from maptidal.envs.gym.scripted import scripted_pose

ENDINGS = ("surface", "dive", "ram")
POLICIES = ("nothing", *ENDINGS, "scripted")
# pilot commands (surge, sway, heave, roll, pitch, yaw): full heave up, full heave down, full surge
_FIXED = {"nothing": np.zeros(6), "surface": np.eye(6)[2], "dive": -np.eye(6)[2], "ram": np.eye(6)[0]}


def scripted_look_around(observation, depth_m: float) -> np.ndarray:
    """Turn slowly in place, holding the depth of the start (``depth_m``) on the depth sensor."""
    error = float(observation["depth"][0]) - depth_m  # deeper than the start: go up
    return np.clip([0.0, 0.0, 2.0 * error - 0.5 * float(observation["velocity"][2]), 0.0, 0.0, 0.15], -1, 1)


def episode_return(env: gymnasium.Env, policy: str, seed: int) -> tuple[float, int, bool]:
    """One episode of ``policy`` (one of POLICIES; in the team environment every robot flies it) in
    ``env``: its return, length in steps and whether it was terminated."""
    observation, _ = env.reset(seed=seed)
    robots = sorted(observation) if "rov0" in observation else None
    first = observation[robots[0]] if robots else observation
    start_depth = {name: float(observation[name]["depth"][0]) for name in robots or []}
    start_depth[None] = float(first["depth"][0])
    total, steps = 0.0, 0
    while True:
        action = {}
        for name in robots or [None]:
            own = observation[name] if name is not None else observation
            if policy != "scripted":
                command = _FIXED[policy]
            elif "target" in own:
                command = scripted_pose(own)
            else:
                command = scripted_look_around(own, start_depth[name])
            action[name] = np.asarray(command, np.float32)
        observation, reward, terminated, truncated, _ = env.step(action if robots else action[None])
        total, steps = total + float(reward), steps + 1
        if terminated or truncated:
            return total, steps, bool(terminated)


def returns(env_id: str, seeds, **options) -> dict[str, list[tuple[float, int, bool]]]:
    """Every policy's episodes over ``seeds`` in one environment made with ``options``."""
    env = gymnasium.make(env_id, **options)
    try:
        return {policy: [episode_return(env, policy, seed) for seed in seeds] for policy in POLICIES}
    finally:
        env.close()
