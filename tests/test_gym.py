"""The Gymnasium environments: Gymnasium's own checker, vectorisation, seeding, rewards on hand-made
cases, bad arguments, and learnability by a numpy-only cross-entropy method."""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
from absl.testing import absltest
from dm_env import test_utils
from gymnasium.utils.env_checker import check_env

import maptidal.envs  # noqa: F401  (registers the MapTidal/ environments)
from maptidal.envs.gym.tank_inspection import camera_viewpoint

ENV_IDS = ("MapTidal/GoToPose-v1", "MapTidal/StationKeeping-v1", "MapTidal/TankInspection-v1")


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize(
    "options", [{}, {"flat_obs": True}, {"action": "thrusters"}, {"obs_images": "stereo"}]
)
def test_gymnasium_check_env_passes(env_id, options):
    env = gymnasium.make(env_id, **options)
    try:
        check_env(env.unwrapped)
    finally:
        env.close()


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_environments_vectorise(mode):
    envs_ = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=2, vectorization_mode=mode, flat_obs=True)
    try:
        observations, _ = envs_.reset(seed=3)
        assert observations.shape == (2, envs_.single_observation_space.shape[0])
        assert not np.allclose(observations[0], observations[1])  # each copy its own episode
        for _ in range(3):
            observations, rewards, *_ = envs_.step(envs_.action_space.sample())
        assert rewards.shape == (2,) and np.all(np.isfinite(observations))
    finally:
        envs_.close()


def _trajectory(env, seed: int, steps: int = 15) -> np.ndarray:
    observation, _ = env.reset(seed=seed)
    actions = np.random.default_rng(0).uniform(-0.5, 0.5, (steps, 6)).astype(np.float32)
    rows = [observation]
    for action in actions:
        observation, *_ = env.step(action)
        rows.append(observation)
    return np.array(rows)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_the_same_seed_and_actions_give_the_same_trajectory(env_id):
    env = gymnasium.make(env_id, flat_obs=True)
    try:
        first, again, other = _trajectory(env, 11), _trajectory(env, 11), _trajectory(env, 12)
    finally:
        env.close()
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, other)


def _toward(observation, sign: float = 1.0) -> np.ndarray:
    forward, left, up, yaw_error = observation["target"]
    command = np.array([forward, -left, up, 0.0, 0.0, -yaw_error]) * sign
    return np.clip(2.0 * command, -1, 1).astype(np.float32)


def test_moving_towards_the_target_earns_more_than_moving_away():
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        totals = []
        for sign in (1.0, -1.0):
            observation, _ = env.reset(seed=5)
            total = 0.0
            for _ in range(15):
                observation, reward, terminated, *_ = env.step(_toward(observation, sign))
                total += reward
                if terminated:
                    break
            totals.append(total)
    finally:
        env.close()
    assert totals[0] > 0 > totals[1]


def test_a_collision_costs_per_second_in_contact_and_ends_nothing():
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        env.reset(seed=2)
        inner = env.unwrapped
        inner.sim.place(inner.robot, [-0.45, 0.0, 1.0], 0.0)  # nose 0.2 m from the end wall, facing it
        touching = []
        for _ in range(30):
            _, reward, terminated, truncated, info = env.step(np.array([1, 0, 0, 0, 0, 0], np.float32))
            assert not terminated and not truncated
            if info["contact_s"] > 0:
                touching.append((reward, info["contact_s"]))
        assert inner.sim.contacts() and len(touching) >= 10  # pressed on the wall, the episode goes on
        for reward, contact_s in touching:
            assert contact_s <= inner.dt + 1e-9
            assert reward < 0.5 - 10.0 * contact_s  # pressed on a wall the other terms pay little; the cost
    finally:
        env.close()


def test_station_keeping_currents_vary_per_episode_and_push_an_idle_robot():
    env = gymnasium.make("MapTidal/StationKeeping-v1", turbulence_m_s=0.0)
    try:
        currents = []
        for seed in (1, 2):
            env.reset(seed=seed)
            currents.append(np.array(env.unwrapped.mean_current))
        assert not np.allclose(currents[0], currents[1])
        env.reset(seed=4)
        current = env.unwrapped.mean_current
        start = np.array(env.unwrapped.target)
        for _ in range(30):
            *_, info = env.step(np.zeros(6, np.float32))
        drift = np.array(env.unwrapped.sim.ground_truth(env.unwrapped.robot)["position"]) - start
        assert np.linalg.norm(current) > 0.05
        assert drift[:2] @ current[:2] > 0  # carried along with the water
        assert info["distance_m"] > 0.05
    finally:
        env.close()


def test_inspection_pays_for_new_views_and_nothing_for_looking_again():
    env = gymnasium.make("MapTidal/TankInspection-v1")
    try:
        observation, _ = env.reset(seed=1)
        start = observation["coverage"][0]
        assert start > 0  # what the camera sees at the start is seen
        still = [env.step(np.zeros(6, np.float32))[1] for _ in range(3)]
        assert max(still) < 0.05  # the same view again: (almost) nothing new
        turning = [env.step(np.array([0, 0, 0, 0, 0, 0.6], np.float32)) for _ in range(10)]
        assert sum(step[1] for step in turning) > 1.0  # new wall comes into view
        observation, info = turning[-1][0], turning[-1][4]
        assert observation["coverage"][0] == pytest.approx(info["coverage"]) and info["coverage"] > start
        inner = env.unwrapped
        seen = inner.seen.copy()
        assert inner._look(inner.sim.ground_truth(inner.robot)) == 0  # looking again adds nothing
        np.testing.assert_array_equal(inner.seen, seen)
    finally:
        env.close()


def test_the_incremental_count_sees_what_the_whole_trajectory_sees():
    """The reward counts rays only to voxels not yet seen; the set seen must equal a full count of every
    viewpoint flown (CoverageModel.views over all voxels, the coverage evaluation's own path)."""
    env = gymnasium.make("MapTidal/TankInspection-v1")
    try:
        env.reset(seed=4)
        inner = env.unwrapped
        camera = inner.vehicle.sensors.camera_position
        viewpoints = [camera_viewpoint(inner.sim.ground_truth(inner.robot), camera)]
        rng = np.random.default_rng(4)
        for _ in range(25):
            action = np.r_[rng.uniform(-0.5, 0.5, 2), 0.0, 0.0, 0.0, rng.uniform(-1, 1)].astype(np.float32)
            *_, terminated, truncated, _ = env.step(action)
            viewpoints.append(camera_viewpoint(inner.sim.ground_truth(inner.robot), camera))
            assert not (terminated or truncated)
        full = inner.coverage.views(np.array(viewpoints)) > 0
        assert full.sum() > 200
        np.testing.assert_array_equal(inner.seen, full)
    finally:
        env.close()


def test_rgb_array_rendering_shows_the_robot_with_its_camera_inset():
    env = gymnasium.make("MapTidal/GoToPose-v1", render_mode="rgb_array")
    try:
        env.reset(seed=0)
        frame = env.render()
    finally:
        env.close()
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8
    inset, rest = frame[4:84, 216:316], frame[120:, :200]
    assert inset.std() > 1 and rest.std() > 1 and not np.allclose(inset.mean(), rest.mean(), atol=0.5)


class _FakeViewer:
    """Stands in for mujoco.viewer's passive handle where no display exists: records what it is given."""

    launched: list = []  # noqa: RUF012

    def __init__(self, model, data):
        self.model, self.data, self.synced_times, self.closed = model, data, [], False
        _FakeViewer.launched.append(self)

    def sync(self):
        self.synced_times.append(float(self.data.time))

    def close(self):
        self.closed = True


def test_human_rendering_drives_mujocos_passive_viewer(monkeypatch):
    import mujoco.viewer

    import maptidal.envs.gym.core as core

    monkeypatch.setattr(core, "_has_display", lambda: True)
    monkeypatch.setattr(
        core.MapTidalEnv, "metadata", {"render_modes": ["rgb_array", "human"], "render_fps": 10}
    )
    monkeypatch.setattr(mujoco.viewer, "launch_passive", _FakeViewer)
    _FakeViewer.launched.clear()
    env = gymnasium.make("MapTidal/GoToPose-v1", render_mode="human")
    env.reset(seed=0)
    assert env.render() is None
    env.step(np.zeros(6, np.float32))
    env.render()
    sim = env.unwrapped.sim
    env.close()
    (viewer,) = _FakeViewer.launched  # one window for the episode, synced after each render
    assert viewer.model is sim.model and viewer.data is sim.data
    assert len(viewer.synced_times) == 2 and viewer.synced_times[1] > viewer.synced_times[0]
    assert viewer.closed


def test_human_rendering_without_a_display_says_so(monkeypatch):
    import maptidal.envs.gym.core as core
    from maptidal.envs.gym.go_to_pose import GoToPoseEnv

    monkeypatch.setattr(core, "_has_display", lambda: False)
    # (gymnasium.make would instead wrap rgb_array in its own pygame window, HumanRendering)
    with pytest.raises(ValueError, match="needs a display"):
        GoToPoseEnv(render_mode="human")


def test_dm_viewer_is_handed_a_working_environment_factory(monkeypatch):
    from dm_control import viewer

    import maptidal.envs.gym.core as core
    from maptidal.envs.gym.dm_tasks import view

    handed = {}
    monkeypatch.setattr(core, "_has_display", lambda: True)
    monkeypatch.setattr(viewer, "launch", lambda factory, policy=None: handed.update(factory=factory))
    view("go_to_pose", seed=3)
    env = handed["factory"]()  # the viewer builds the environment itself, as dm_control's launch does
    first = env.reset()
    step = env.step(np.zeros(6))
    assert first.first() and step.mid() and set(step.observation) >= {"pose", "target"}
    monkeypatch.setattr(core, "_has_display", lambda: False)
    with pytest.raises(ValueError, match="needs a display"):
        view("go_to_pose")


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"warp_drive": True}, "unknown option"),
        ({"image_size": (0, 64), "obs_images": "left"}, "image_size"),
        ({"action": "joystick"}, "action must be"),
        ({"obs_images": "left", "flat_obs": True}, "flat_obs cannot carry images"),
        ({"render_mode": "vr"}, "render_mode"),
        ({"frame": "bluerov3"}, "frame"),
    ],
)
def test_bad_arguments_give_a_clear_error(options, message):
    with pytest.raises(ValueError, match=message):
        gymnasium.make("MapTidal/GoToPose-v1", **options)
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        env.reset(seed=0)
        with pytest.raises(ValueError, match="finite"):
            env.step(np.array([math.nan, 0, 0, 0, 0, 0], np.float32))
    finally:
        env.close()


# ----- learnability, numpy only -----------------------------------------------------------------
def _linear_policy(theta: np.ndarray, observation) -> np.ndarray:
    """One gain per axis on the target offset (forward, left, up, yaw error) and one on the matching
    velocity (u, v, w, r): a linear policy of the observation with few enough parameters for CEM."""
    target = observation["target"]
    velocity = observation["velocity"][[0, 1, 2, 5]]
    axes = theta[:4] * target + theta[4:] * velocity
    return np.clip([axes[0], axes[1], axes[2], 0.0, 0.0, axes[3]], -1, 1).astype(np.float32)


def _episode(env, theta, seed) -> tuple[float, bool]:
    observation, _ = env.reset(seed=seed)
    total, reached = 0.0, False
    while True:
        observation, reward, terminated, truncated, info = env.step(_linear_policy(theta, observation))
        total += reward
        reached |= info["is_success"]
        if terminated or truncated:
            return total, reached


def _batch_returns(batch, thetas: np.ndarray, seeds: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """One episode per robot of the batched environment, robot k flying the linear policy ``thetas[k]``
    (:func:`_linear_policy`, row by row) from seed ``seeds[k]``: the returns and who reached the pose."""
    observation, _ = batch.reset(seed=seeds)
    totals, reached = np.zeros(batch.num_envs), np.zeros(batch.num_envs, bool)
    while True:
        axes = (
            thetas[:, :4] * observation["target"] + thetas[:, 4:] * observation["velocity"][:, [0, 1, 2, 5]]
        )
        actions = np.zeros((batch.num_envs, 6), np.float32)
        actions[:, :3], actions[:, 5] = axes[:, :3], axes[:, 3]
        observation, reward, terminated, truncated, info = batch.step(actions.clip(-1, 1))
        totals += reward
        reached |= info["is_success"]
        if (terminated | truncated).all():
            return totals, reached


def test_a_linear_policy_trained_by_the_cross_entropy_method_reaches_the_target():
    """The reward and the observations carry the signal: from zero gains, six CEM generations of 16
    (one common episode each) find a policy that reaches the pose in most new episodes. The population
    flies as one batched environment (make_vec), which gives what 16 one-robot environments give."""
    batch = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=16, max_episode_steps=80)
    rng = np.random.default_rng(0)
    mean, std = np.zeros(8), np.ones(8)
    try:
        for generation in range(6):
            population = mean + std * rng.normal(size=(16, 8))
            scores, _ = _batch_returns(batch, population, [1000 + generation] * 16)
            elite = population[np.argsort(scores)[-4:]]
            mean, std = elite.mean(axis=0), elite.std(axis=0) + 0.05
        _, reached = _batch_returns(batch, np.tile(mean, (16, 1)), [5000 + k for k in range(16)])
    finally:
        batch.close()
    assert reached[:10].sum() >= 7, reached[:10]


def test_the_batched_episode_is_the_one_robot_episode():
    # what the CEM test relies on: a linear policy's return in the batch is its return alone
    theta = np.array([1.5, 1.5, 1.5, 1.0, -0.5, -0.5, -0.5, -0.3])
    env = gymnasium.make("MapTidal/GoToPose-v1", max_episode_steps=30)
    batch = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=2, max_episode_steps=30)
    try:
        alone = [_episode(env, theta, seed) for seed in (7, 8)]
        together, reached = _batch_returns(batch, np.tile(theta, (2, 1)), [7, 8])
    finally:
        env.close()
        batch.close()
    np.testing.assert_allclose(together, [total for total, _ in alone], atol=1e-6)
    assert list(reached) == [hit for _, hit in alone]


# ----- the team task and PettingZoo -----------------------------------------------------------------
def test_team_inspection_passes_the_checkers_of_gymnasium_and_pettingzoo():
    from pettingzoo.test import parallel_api_test

    from maptidal.envs.gym.team_inspection import parallel_env

    env = gymnasium.make("MapTidal/TeamInspection-v1")
    try:
        check_env(env.unwrapped)
    finally:
        env.close()
    parallel = parallel_env(n_robots=3, flat_obs=True)
    try:
        parallel_api_test(parallel, num_cycles=20)
    finally:
        parallel.close()


def test_the_team_shares_one_reward_for_what_any_robot_sees():
    env = gymnasium.make("MapTidal/TeamInspection-v1", n_robots=2)
    try:
        observations, _ = env.reset(seed=7)
        assert set(observations) == {"rov0", "rov1"}
        np.testing.assert_array_equal(observations["rov0"]["coverage"], observations["rov1"]["coverage"])
        inner = env.unwrapped
        one = inner.coverage.views(np.array([_viewpoint(inner, "rov0")])) > 0
        two = inner.coverage.views(np.array([_viewpoint(inner, "rov1")])) > 0
        assert inner.seen.sum() == (one | two).sum() > one.sum()  # the team sees the union
        idle = {name: np.zeros(6, np.float32) for name in inner.agents}
        turn = {"rov0": np.array([0, 0, 0, 0, 0, 0.6], np.float32), "rov1": np.zeros(6, np.float32)}
        still = env.step(idle)[1]
        turning = sum(env.step(turn)[1] for _ in range(8))
        assert still < 0.05 < turning
    finally:
        env.close()


def _viewpoint(inner, name):
    from maptidal.envs.gym.tank_inspection import camera_viewpoint

    return camera_viewpoint(inner.sim.ground_truth(name), inner.vehicle.sensors.camera_position)


def test_the_team_renders_with_every_robots_camera_inset():
    env = gymnasium.make("MapTidal/TeamInspection-v1", render_mode="rgb_array")
    try:
        env.reset(seed=0)
        frame = env.render()
    finally:
        env.close()
    assert frame.shape == (240, 320, 3)
    first, second = frame[4:64, 236:316], frame[4:64, 152:232]  # two insets of 80 x 60
    assert first.std() > 1 and second.std() > 1 and not np.array_equal(first, second)


@pytest.mark.parametrize("bad", [0, 5, 1.5, "two"])
def test_a_bad_robot_count_is_refused(bad):
    with pytest.raises(ValueError, match="n_robots"):
        gymnasium.make("MapTidal/TeamInspection-v1", n_robots=bad)


# ----- dm_control ---------------------------------------------------------------------------------
class GoToPoseDmEnvTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's own conformance tests on the dm_control version of GoToPose."""

    def make_object_under_test(self):
        from maptidal.envs.gym.dm_tasks import load

        return load("go_to_pose", seed=3, episode_s=2.0)


class TankInspectionDmEnvTest(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """The same on TankInspection."""

    def make_object_under_test(self):
        from maptidal.envs.gym.dm_tasks import load

        return load("tank_inspection", seed=3, episode_s=2.0)


def test_the_dm_control_task_shares_the_gymnasium_tasks_world_and_rewards():
    from maptidal.envs.gym.dm_tasks import load

    env = load("go_to_pose", seed=5)
    task_env = env.task.task_env
    assert env.physics.data.ptr is task_env.sim.data  # one MjData, not a second world
    first = env.reset()
    towards = []
    observation = first.observation
    for _ in range(10):
        forward, left, up, yaw_error = observation["target"]
        step = env.step(np.clip(2.0 * np.array([forward, -left, up, 0, 0, -yaw_error]), -1, 1))
        towards.append(step.reward)
        observation = step.observation
    assert sum(towards) > 0
    assert env.physics.data.time == pytest.approx(10 * task_env.dt)
    with pytest.raises(ValueError, match="unknown task"):
        load("backflip")


def test_the_team_can_pick_tasks_that_go_to_pose_flies():
    env = gymnasium.make("MapTidal/TeamInspection-v1", action="tasks")
    try:
        assert env.action_space["rov0"] == gymnasium.spaces.Discrete(20)
        observations, _ = env.reset(seed=0)
        before = env.unwrapped.seen.mean()
        observations, reward, terminated, _, info = env.step({"rov0": 3, "rov1": 7})  # far apart
        assert info["status"] == {"rov0": "capture", "rov1": "capture"} and not terminated
        assert observations["rov0"]["tasks_done"][[3, 7]].tolist() == [1.0, 1.0]
        assert info["coverage"] > before and reward > 0
        truth = env.unwrapped.sim.ground_truth("rov0")["position"]
        assert np.linalg.norm(np.asarray(truth) - env.unwrapped.tasks[3, :3]) < 0.2  # really flown there
        first, first_voxels = reward, info["new_voxels"]
        # the same views again: the few voxels at the edge of a view taken a few cm away pay little
        _, again, _, _, info = env.step({"rov0": 3, "rov1": 7})
        assert again < 0.05 * first and info["new_voxels"] < 0.05 * first_voxels
        with pytest.raises(ValueError, match="task index"):
            env.step({"rov0": 20, "rov1": 0})
    finally:
        env.close()
    quick = gymnasium.make("MapTidal/TeamInspection-v1", action="tasks", task_timeout_s=3.0)
    try:
        check_env(quick.unwrapped)
    finally:
        quick.close()


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"image_size": (100000, 128)}, "at most"),  # a raw MemoryError before
        ({"image_size": (80.5, 128)}, "two whole numbers"),
        ({"image_size": (True, 128)}, "two whole numbers"),
        ({"image_size": 80}, "two whole numbers"),
        ({"flat_obs": "yes"}, "flat_obs must be True or False"),
        ({"episode_s": math.inf}, "episode_s must be"),  # an OverflowError before
        ({"episode_s": 1e9}, "a day"),
        ({"episode_s": math.nan}, "episode_s must be"),
    ],
)
def test_bad_options_are_refused_before_anything_is_built(options, message):
    from maptidal.envs.gym.core import EnvOptions

    with pytest.raises(ValueError, match=message):
        EnvOptions.checked(options)


def test_a_step_before_reset_or_after_the_episode_ended_raises():
    from maptidal.envs.gym.station_keeping import StationKeepingEnv

    env = StationKeepingEnv(episode_s=1.0)  # unwrapped: Gymnasium's OrderEnforcing is not there to catch it
    try:
        with pytest.raises(gymnasium.error.ResetNeeded, match="before step"):
            env.step(np.zeros(6, np.float32))
        env.reset(seed=0)
        up = np.array([0, 0, 1, 0, 0, 0], np.float32)
        for _ in range(env.max_steps):
            _, _, terminated, truncated, _ = env.step(up)
            if terminated or truncated:
                break
        assert truncated and not terminated
        with pytest.raises(gymnasium.error.ResetNeeded, match="truncated"):
            env.step(up)
        env.reset(seed=1)
        env.step(np.zeros(6, np.float32))  # a new episode steps again
    finally:
        env.close()


# ----- reset options ------------------------------------------------------------------------------
def test_reset_options_fix_the_start_the_target_and_the_current():
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        fixed = {"pose": (-2.0, 0.2, 1.0, 0.0), "target": (-1.0, 0.2, 1.3, 0.5)}
        observation, _ = env.reset(seed=3, options=fixed)
        truth = env.unwrapped.sim.ground_truth(env.unwrapped.robot)
        np.testing.assert_allclose(truth["position"], [-2.0, 0.2, 1.0], atol=1e-6)
        # facing +x at the start: the target is 1 m ahead and 0.3 m up, 0.5 rad to the left
        np.testing.assert_allclose(observation["target"], [1.0, 0.0, 0.3, 0.5], atol=0.02)
    finally:
        env.close()
    env = gymnasium.make("MapTidal/StationKeeping-v1", turbulence_m_s=0.0)
    try:
        env.reset(seed=4, options={"pose": (-2.0, 0.0, 1.0, 0.0), "current": (0.0, 0.15, 0.0)})
        for _ in range(30):
            *_, info = env.step(np.zeros(6, np.float32))
        assert info["current_m_s"] == [0.0, 0.15, 0.0]
        drift = np.asarray(env.unwrapped.sim.ground_truth(env.unwrapped.robot)["position"]) - [-2.0, 0.0, 1.0]
        assert drift[1] > 0.1 and abs(drift[0]) < 0.5 * drift[1]  # carried along +y, the current's way
    finally:
        env.close()


@pytest.mark.parametrize(
    ("env_id", "options", "message"),
    [
        ("MapTidal/TankInspection-v1", {"target": (-1.0, 0.0, 1.0, 0.0)}, "unknown reset option"),
        ("MapTidal/GoToPose-v1", {"pose": (-1.0, 0.0, 1.0)}, "four finite numbers"),
        ("MapTidal/GoToPose-v1", {"pose": (-1.0, 0.0, math.nan, 0.0)}, "four finite numbers"),
        ("MapTidal/GoToPose-v1", {"pose": ("a", 0.0, 1.0, 0.0)}, "four finite numbers"),
        ("MapTidal/GoToPose-v1", {"target": (-1.0, 0.0, 5.0, 0.0)}, "in the tank's water"),
        ("MapTidal/GoToPose-v1", {"pose": (3.0, 0.0, 1.0, 0.0)}, "in the tank's water"),
        ("MapTidal/StationKeeping-v1", {"current": (10.0, 0.0, 0.0)}, "beyond"),
        ("MapTidal/StationKeeping-v1", {"current": "fast"}, "three finite numbers"),
        ("MapTidal/TeamInspection-v1", {"pose": (-1.0, 0.0, 1.0, 0.0)}, "no reset options"),
    ],
)
def test_bad_reset_options_are_refused_and_the_episode_goes_on(env_id, options, message):
    env = gymnasium.make(env_id)
    try:
        env.reset(seed=0)
        env.step(env.action_space.sample())
        with pytest.raises(ValueError, match=message):
            env.reset(seed=1, options=options)
        env.step(env.action_space.sample())  # the episode under way was left as it was
    finally:
        env.close()


# ----- state -------------------------------------------------------------------------------------
def _replay(env, actions) -> np.ndarray:
    rows = []
    for action in actions:
        observation, reward, *_ = env.step(action)
        rows.append(np.r_[np.concatenate([np.ravel(v) for v in observation.values()]), reward])
    return np.array(rows)


@pytest.mark.parametrize(
    "env_id", ["MapTidal/GoToPose-v1", "MapTidal/StationKeeping-v1", "MapTidal/TankInspection-v1"]
)
def test_a_saved_state_replays_the_trajectory_bit_for_bit_here_in_a_pickle_and_in_a_copy(env_id):
    import copy
    import pickle

    actions = np.random.default_rng(1).uniform(-1, 1, (40, 6)).astype(np.float32)
    env = gymnasium.make(env_id)
    try:
        env.reset(seed=5)
        _replay(env, actions[:10])
        state = env.unwrapped.get_state()
        pickled, copied = pickle.loads(pickle.dumps(env)), copy.deepcopy(env)
        first = _replay(env, actions[10:])
        env.unwrapped.set_state(state)
        np.testing.assert_array_equal(_replay(env, actions[10:]), first)  # the estimator and autopilot too
        np.testing.assert_array_equal(_replay(pickled, actions[10:]), first)
        np.testing.assert_array_equal(_replay(copied, actions[10:]), first)
        pickled.close()
        copied.close()
    finally:
        env.close()


def test_a_state_of_another_task_or_version_is_refused():
    go, hold = gymnasium.make("MapTidal/GoToPose-v1"), gymnasium.make("MapTidal/StationKeeping-v1")
    try:
        go.reset(seed=0)
        hold.reset(seed=0)
        state = go.unwrapped.get_state()
        with pytest.raises(ValueError, match="GoToPoseEnv"):
            hold.unwrapped.set_state(state)
        with pytest.raises(ValueError, match="version"):
            go.unwrapped.set_state({**state, "version": 0})
        with pytest.raises(ValueError, match="version"):
            go.unwrapped.sim.set_state({**state["sim"], "version": 99})
    finally:
        go.close()
        hold.close()


def test_the_pettingzoo_adapter_renders_and_gives_the_global_state():
    from maptidal.envs.gym.team_inspection import parallel_env

    env = parallel_env(n_robots=2, render_mode="rgb_array")
    try:
        env.reset(seed=3)
        state = env.state()
        assert state.shape == env.state_space.shape == (2 * 12 + 9,) and state.dtype == np.float32
        for k, agent in enumerate(env.possible_agents):
            truth = env.env.sim.ground_truth(agent)
            np.testing.assert_allclose(state[12 * k : 12 * k + 3], truth["position"], atol=1e-5)
            np.testing.assert_allclose(state[12 * k + 3 : 12 * k + 6], truth["rpy"], atol=1e-5)
        np.testing.assert_allclose(state[24:], env.env.walls.summary(), atol=1e-6)
        surge = np.array([1, 0, 0, 0, 0, 0], np.float32)
        for _ in range(10):
            env.step(dict.fromkeys(env.agents, surge))
        assert not np.allclose(env.state()[:3], state[:3])  # the robots moved, and the state with them
        image = env.render()
        assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8 and image.std() > 0
    finally:
        env.close()


def _flat(value) -> np.ndarray:
    if isinstance(value, dict):
        return np.concatenate([_flat(value[key]) for key in sorted(value)])
    return np.ravel(np.asarray(value, float))


@pytest.mark.parametrize("action_kind", ["pilot", "tasks"])
def test_the_team_replays_from_a_saved_state_bit_for_bit_here_in_a_pickle_and_in_a_copy(action_kind):
    import copy
    import pickle

    options = {"action": "tasks"} if action_kind == "tasks" else {}
    env = gymnasium.make("MapTidal/TeamInspection-v1", **options)
    rng = np.random.default_rng(2)
    names = env.unwrapped.agents
    if action_kind == "tasks":
        actions = [{name: int(rng.integers(len(env.unwrapped.tasks))) for name in names} for _ in range(4)]
    else:
        actions = [{name: rng.uniform(-1, 1, 6).astype(np.float32) for name in names} for _ in range(30)]

    def rollout(target, steps):
        rows = []
        for action in steps:
            observation, reward, *_ = target.step(action)
            rows.append(np.r_[_flat(observation), reward])
        return np.array(rows)

    try:
        env.reset(seed=6)
        rollout(env, actions[:1] if action_kind == "tasks" else actions[:10])
        state = env.unwrapped.get_state()
        pickled, copied = pickle.loads(pickle.dumps(env)), copy.deepcopy(env)
        rest = actions[1:3] if action_kind == "tasks" else actions[10:]
        first = rollout(env, rest)
        env.unwrapped.set_state(state)
        np.testing.assert_array_equal(rollout(env, rest), first)
        np.testing.assert_array_equal(rollout(pickled, rest), first)
        np.testing.assert_array_equal(rollout(copied, rest), first)
        pickled.close()
        copied.close()
    finally:
        env.close()


def test_the_ppo_summary_averages_seeds_and_tabulates_evaluations(tmp_path):
    # examples/ppo_summary.py on made-up runs: the table's means and spreads over seeds, the curves' bins
    import importlib.util
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / "ppo_summary.py"
    spec = importlib.util.spec_from_file_location("ppo_summary", path)
    summary = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(summary)
    for seed, (ppo, scripted) in enumerate([(10.0, 5.0), (20.0, 5.0)]):
        run = tmp_path / f"run{seed}"
        run.mkdir()
        evaluations = {
            "nominal": {
                "ppo": {"return_mean": ppo, "success": 0.5},
                "scripted": {"return_mean": scripted, "success": 1.0},
            }
        }
        curve = [{"step": 100 * k, "return": float(k + seed), "success": False} for k in range(1, 11)]
        result = {
            "env": "MapTidal/StationKeeping-v1",
            "randomized_training": False,
            "seed": seed,
            "timesteps": 1000,
            "evaluations": evaluations,
            "curve": curve,
        }
        (run / "result.json").write_text(json.dumps(result))
    groups = summary.load([tmp_path / "run0", tmp_path / "run1", tmp_path / "missing"])
    text = summary.table(groups)
    assert "15.0 +- 5.0, 50% reached" in text and "5.0 +- 0.0, 100% reached" in text
    edges = np.linspace(0, 1000, 11)
    np.testing.assert_allclose(
        summary.binned_curve(groups[("MapTidal/StationKeeping-v1", False)][1], edges)[:9], np.arange(2, 11)
    )
    summary.plot(groups, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 10_000


def test_the_batched_environment_trains_stable_baselines3_with_its_autoreset():
    # examples/train_ppo.py --batched: SB3's VecEnv over make_vec's batch (the rl extra; skipped without)
    pytest.importorskip("stable_baselines3")
    import importlib.util
    from pathlib import Path

    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    path = Path(__file__).resolve().parents[1] / "examples" / "train_ppo.py"
    spec = importlib.util.spec_from_file_location("train_ppo", path)
    train_ppo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(train_ppo)
    vec = train_ppo.batched_vec_env("MapTidal/GoToPose-v1", 2, seed=3, randomize=False)
    try:
        assert isinstance(vec, VecEnv) and vec.num_envs == 2
        observations = vec.reset()
        assert observations.shape == (2, vec.observation_space.shape[0])
        hold = np.zeros((2, 6), np.float32)
        for step in range(1, train_ppo.EPISODE_STEPS + 1):
            observations, _, dones, infos = vec.step(hold)
            assert dones.tolist() == [step == train_ppo.EPISODE_STEPS] * 2
        for info, observation in zip(infos, observations, strict=True):
            assert info["TimeLimit.truncated"] and "episode" in info
            assert info["episode"]["l"] == train_ppo.EPISODE_STEPS
            assert not np.allclose(info["terminal_observation"], observation)  # a new episode began
        observations, *_ = vec.step(hold)  # the next episode runs on; no step is lost to the reset
        assert vec.venv.batch.steps.tolist() == [1, 1]
    finally:
        vec.close()
