"""Who ends an episode on time (``maptidal.envs.gym.core.EpisodeLength``): the registration's
``max_episode_steps`` through ``gymnasium.make``, ``episode_s`` when a class is built directly, and the
two never disagree."""

from __future__ import annotations

import pickle

import gymnasium
import numpy as np
import pytest
from gymnasium.wrappers import TimeAwareObservation

import maptidal.envs  # noqa: F401  (registers the MapTidal/ environments)
from maptidal.envs.gym import ENVIRONMENTS
from maptidal.envs.gym.go_to_pose import GoToPoseEnv


def _steps_until_truncated(env, limit: int) -> int:
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    for step in range(1, limit + 1):
        *_, terminated, truncated, _ = env.step(action)
        assert not terminated
        if truncated:
            return step
    return limit + 1


@pytest.mark.parametrize("env_id", sorted(ENVIRONMENTS))
def test_the_registration_sets_the_default_episode_in_steps(env_id):
    # the class built directly, with its own defaults, counts its episode in the same steps
    module, name = ENVIRONMENTS[env_id].split(":")
    env_class = getattr(__import__(module, fromlist=[name]), name)
    env = env_class()
    try:
        assert gymnasium.spec(env_id).max_episode_steps == env.max_steps
    finally:
        env.close()


def test_make_ends_the_episode_at_max_episode_steps_even_past_the_default_length():
    env = gymnasium.make("MapTidal/GoToPose-v1", flat_obs=True, max_episode_steps=230)  # default 200
    try:
        assert env.spec.max_episode_steps == 230
        assert _steps_until_truncated(env, 260) == 230
    finally:
        env.close()


def test_make_ends_the_episode_at_the_registered_steps_by_default():
    env = gymnasium.make("MapTidal/GoToPose-v1", flat_obs=True)
    try:
        assert _steps_until_truncated(env, 220) == gymnasium.spec("MapTidal/GoToPose-v1").max_episode_steps
    finally:
        env.close()


def test_a_class_built_directly_ends_after_episode_s():
    env = GoToPoseEnv(flat_obs=True, episode_s=3.0)
    try:
        assert env.spec is None
        assert _steps_until_truncated(env, 50) == 30
    finally:
        env.close()


def test_time_aware_observation_takes_the_environment():
    env = TimeAwareObservation(
        gymnasium.make("MapTidal/GoToPose-v1", max_episode_steps=25), flatten=False, normalize_time=True
    )
    try:
        observation, _ = env.reset(seed=1)
        assert observation["time"][0] == 0.0
        for _ in range(25):
            observation, _, _, truncated, _ = env.step(np.zeros(6, np.float32))
        assert truncated and observation["time"][0] == pytest.approx(1.0)
    finally:
        env.close()


def test_episode_s_through_make_names_max_episode_steps():
    with pytest.raises(ValueError, match="max_episode_steps"):
        gymnasium.make("MapTidal/GoToPose-v1", episode_s=8.0)


def test_the_team_tasks_mode_keeps_episode_s_through_make():
    # a task step lasts a whole task, so its episode is counted in simulated time
    env = gymnasium.make("MapTidal/TeamInspection-v1", action="tasks", episode_s=5.0)
    try:
        assert env.unwrapped.options.episode_s == 5.0
    finally:
        env.close()


def test_a_pickled_made_environment_keeps_its_time_limit_to_the_registration():
    env = gymnasium.make("MapTidal/GoToPose-v1", flat_obs=True, max_episode_steps=230)
    try:
        copy = pickle.loads(pickle.dumps(env.unwrapped))
        assert copy.spec is not None and copy.spec.id == "MapTidal/GoToPose-v1"
        copy.reset(seed=0)
        for _ in range(205):  # past the class's own 200: the TimeLimit outside it decides
            *_, truncated, _ = copy.step(np.zeros(6, np.float32))
            assert not truncated
        copy.close()
    finally:
        env.close()
