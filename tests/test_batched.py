"""The batched flight stack and vector environment (issue [rl], part 6): each N-row twin against its
one-robot reference (``controllers/``' scalar classes, themselves checked against ArduPilot elsewhere),
and the batched environment against a ``SyncVectorEnv`` of one-robot environments, step for step."""

from __future__ import annotations

import dataclasses
import math

import gymnasium
import numpy as np
import pytest

import maptidal.envs  # noqa: F401  (registers MapTidal/)
from maptidal.controllers.batched import (
    BatchedACPID,
    BatchedDeadReckoning,
    BatchedStabilize,
    dead_zones,
    mix_batch,
    sqrt_controllers,
)
from maptidal.controllers.estimation import DeadReckoning, EstimatorParams, MotionModel, StateEstimate
from maptidal.controllers.flight_modes import ATC_RATE_ROLL_PITCH, ATC_RATE_YAW, FlightController, dead_zone
from maptidal.controllers.mixing import mix
from maptidal.controllers.pid import ACPID, sqrt_controller
from maptidal.envs.gym.batched import BatchedPoseEnv, headings_from_field
from maptidal.envs.sensors import heading_from_field

RNG = np.random.default_rng(2026)


@pytest.fixture(params=["native", "python"])
def flight_backend(request, monkeypatch) -> str:
    """Both ways a batch flies: the robots' blocks in one call of the compiled flight stack, and the
    numpy twins of the flight stack (where the compiled one is not there), each against a
    ``SyncVectorEnv`` flying the same stack."""
    if request.param == "python":
        monkeypatch.setenv("MAPTIDAL_FLIGHT", "python")
    return request.param


# ----- the twins, against their one-robot references ---------------------------------------------
def test_sqrt_controllers_and_dead_zones_are_the_scalar_functions_row_by_row():
    errors = np.concatenate([RNG.normal(0, 0.05, 50), RNG.normal(0, 2.0, 50), [0.0, 1e-9, -1e-9]])
    for dt in (0.02, 0.0):
        got = sqrt_controllers(errors, 6.0, math.radians(1100.0), dt)
        want = [sqrt_controller(float(e), 6.0, math.radians(1100.0), dt) for e in errors]
        np.testing.assert_allclose(got, want, rtol=1e-14, atol=1e-15)
    sticks = np.concatenate([RNG.uniform(-1, 1, 60), [0.0, 0.1, -0.1, 1.0, -1.0]])
    np.testing.assert_array_equal(dead_zones(sticks, 0.1), [dead_zone(float(s), 0.1) for s in sticks])


@pytest.mark.parametrize("without_integrator", [False, True])
def test_batched_acpid_follows_acpid_through_resets_limits_and_nan(without_integrator):
    gains = (ATC_RATE_ROLL_PITCH, ATC_RATE_ROLL_PITCH, ATC_RATE_YAW)
    if without_integrator:  # an axis with no integral term (ki 0), beside two with one
        gains = (gains[0], dataclasses.replace(gains[1], ki=0.0), gains[2])
    n = 4
    batch = BatchedACPID(gains, n)
    scalar = [[ACPID(g) for g in gains] for _ in range(n)]
    for step in range(80):
        target = RNG.normal(0, 1.0, (n, 3))
        measured = RNG.normal(0, 0.5, (n, 3))
        limit = RNG.uniform(size=(n, 3)) < 0.3
        if step == 30:
            target[1, 2] = np.nan  # a bad input: output 0, the loop left as it was
        if step == 50:
            scalar[2][0].reset()
            batch.load(2, scalar[2])
        got = batch.update(target, measured, 0.02, limit)
        want = [
            [scalar[i][k].update(target[i, k], measured[i, k], 0.02, bool(limit[i, k])) for k in range(3)]
            for i in range(n)
        ]
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(batch.integrator, [[p.integrator for p in row] for row in scalar], atol=1e-14)


def _estimate(rng) -> StateEstimate:
    return StateEstimate(
        position=rng.normal(0, 1, 3),
        rpy=np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), rng.uniform(-math.pi, math.pi)]),
        velocity_body=rng.normal(0, 0.2, 3),
        angular_velocity_body=rng.normal(0, 0.3, 3),
    )


@pytest.mark.parametrize("mode", ["stabilize", "manual"])
def test_batched_stabilize_gives_the_flight_controllers_mixer_inputs(mode):
    n = 5
    controllers = [FlightController(mode, 2.0) for _ in range(n)]
    batch = BatchedStabilize(mode, n)
    for row, controller in enumerate(controllers):
        batch.load(row, controller)
    for step in range(120):
        pilot = RNG.uniform(-1, 1, (n, 6))
        pilot[:, 5] = np.where(RNG.uniform(size=n) < 0.6, 0.0, pilot[:, 5])  # yaw stick let go: hold heading
        if step in (40, 41, 42):
            pilot[:, 3:5] = 0.0
        estimates = [_estimate(RNG) for _ in range(n)]
        rpy = np.array([e.rpy for e in estimates])
        rates = np.array([e.angular_velocity_body for e in estimates])
        got = batch.update(pilot, rpy, rates, 0.02)
        want = [c.update(pilot[i], estimates[i], 0.02) for i, c in enumerate(controllers)]
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    if mode == "stabilize":
        np.testing.assert_allclose(batch.heading, [c.heading for c in controllers], atol=1e-12)


def test_mix_batch_is_the_vectored_6dof_mixer_row_by_row():
    pilot = np.concatenate([RNG.uniform(-1, 1, (40, 6)), np.eye(6), -np.eye(6), np.zeros((1, 6))])
    np.testing.assert_allclose(mix_batch(pilot), [mix(row) for row in pilot], rtol=1e-14, atol=1e-15)


def test_batched_headings_are_the_compass_function_row_by_row():
    fields = RNG.normal(0, 0.3, (50, 3))
    ups = RNG.normal(0, 0.2, (50, 3)) + [0.0, 0.0, 1.0]
    want = [heading_from_field(f, u) for f, u in zip(fields, ups, strict=True)]
    got = headings_from_field(fields, ups)
    np.testing.assert_allclose(np.angle(np.exp(1j * np.radians(got - want))), 0.0, atol=1e-11)


def test_batched_dead_reckoning_follows_dead_reckoning_with_and_without_the_dvl():
    motion = MotionModel((17.0, 20.0, 30.0), (4.0, 6.0, 5.0), (18.0, 21.0, 36.0), net_buoyancy_n=2.0)
    params = EstimatorParams(2.0, (0.1, 0.0, 0.05), (-0.05, 0.0, -0.12), motion_model=motion)
    n = 4
    scalar = [DeadReckoning(params, RNG.normal(0, 1, 3), RNG.uniform(-3, 3)) for _ in range(n)]
    batch = BatchedDeadReckoning(params, n)
    for row, estimator in enumerate(scalar):
        estimator.set_attitude(0.1 * row, -0.05 * row, 0.3 * row)
        batch.load(row, estimator)
    for step in range(150):
        accel = RNG.normal(0, 0.3, (n, 3)) + [0.0, 0.0, 9.81]
        gyro = RNG.normal(0, 0.2, (n, 3))
        depth = RNG.uniform(0.3, 1.5, n)
        heading = RNG.uniform(0, 360, n)
        valid = RNG.uniform(size=n) < (0.5 if step < 75 else 1.0)  # lost and found, then always there
        velocity = RNG.normal(0, 0.3, (n, 3))
        thrust = RNG.normal(0, 20, (n, 3))
        batch.update(accel, gyro, depth, heading, valid, velocity, thrust, 0.02)
        for i, estimator in enumerate(scalar):
            readings = {
                "imu": {"accel": accel[i], "gyro": gyro[i]},
                "depth": {"depth_m": depth[i]},
                "dvl": {"velocity_body": velocity[i] if valid[i] else None, "valid": bool(valid[i])},
                "compass": {"heading_deg": heading[i]},
                "thrust": {"force_body": thrust[i]},
            }
            estimator.update(readings, 0.02)
    for i, estimator in enumerate(scalar):
        s = estimator.state
        np.testing.assert_allclose(batch.position[i], s.position, atol=1e-9)
        np.testing.assert_allclose(batch.rpy[i], s.rpy, atol=1e-9)
        np.testing.assert_allclose(batch.velocity_body[i], s.velocity_body, atol=1e-9)
        np.testing.assert_allclose(batch.acceleration_world[i], s.acceleration_world, atol=1e-9)
        np.testing.assert_allclose(batch.quaternion[i], estimator.quaternion, atol=1e-12)


# ----- the vector environment, against SyncVectorEnv ----------------------------------------------
CASES = {
    "go to pose, stabilize": ("MapTidal/GoToPose-v1", {}),
    "station keeping, randomised": ("MapTidal/StationKeeping-v1", {"randomize": True}),
    "thrusters": ("MapTidal/GoToPose-v1", {"action": "thrusters"}),
    "manual at half gain": ("MapTidal/GoToPose-v1", {"flight_mode": "manual", "pilot_gain": 0.5}),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_batch_gives_what_one_robot_environments_give_across_resets(case, flight_backend):
    env_id, options = CASES[case]
    n, length = 2, 12
    batched = gymnasium.make_vec(env_id, num_envs=n, max_episode_steps=length, flat_obs=True, **options)
    sync = gymnasium.make_vec(
        env_id, num_envs=n, vectorization_mode="sync", max_episode_steps=length, flat_obs=True, **options
    )
    try:
        assert isinstance(batched, BatchedPoseEnv)
        assert batched.native == (flight_backend == "native")
        assert batched.observation_space == sync.observation_space
        assert batched.action_space == sync.action_space
        got, _ = batched.reset(seed=11)
        want, _ = sync.reset(seed=11)
        np.testing.assert_array_equal(got, want)
        rng = np.random.default_rng(5)
        ended = 0
        for _ in range(2 * length + 5):  # two episode ends, and the autoreset steps after them
            actions = rng.uniform(-1.2, 1.2, batched.action_space.shape).astype(np.float32)
            got, got_reward, got_end, got_cut, got_info = batched.step(actions)
            want, want_reward, want_end, want_cut, want_info = sync.step(actions)
            np.testing.assert_allclose(got, want, atol=1e-6)
            np.testing.assert_allclose(got_reward, want_reward, atol=1e-6)
            np.testing.assert_array_equal(got_end, want_end)
            np.testing.assert_array_equal(got_cut, want_cut)
            assert sorted(got_info) == sorted(want_info)
            if "is_success" in want_info:
                np.testing.assert_array_equal(got_info["_is_success"], want_info["_is_success"])
                np.testing.assert_array_equal(got_info["is_success"], want_info["is_success"])
            ended += int(got_cut.sum())
        assert ended == 2 * n
    finally:
        batched.close()
        sync.close()


def test_a_partial_reset_resets_only_the_masked_robots(flight_backend):
    n = 3
    batched = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, flat_obs=True)
    sync = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, vectorization_mode="sync", flat_obs=True)
    try:
        batched.reset(seed=2)
        sync.reset(seed=2)
        actions = np.full((n, 6), 0.3, np.float32)
        for _ in range(5):
            batched.step(actions)
            before, *_ = sync.step(actions)
        mask = np.array([True, False, True])
        got, _ = batched.reset(seed=[40, None, 42], options={"reset_mask": mask})
        want, _ = sync.reset(seed=[40, None, 42], options={"reset_mask": mask})
        np.testing.assert_allclose(got, want, atol=1e-6)
        np.testing.assert_allclose(got[1], before[1], atol=1e-6)  # the unmasked robot carried on
        for _ in range(5):
            got, *_ = batched.step(actions)
            want, *_ = sync.step(actions)
        np.testing.assert_allclose(got, want, atol=1e-6)
    finally:
        batched.close()
        sync.close()


def test_make_vec_batches_the_pose_tasks_and_falls_back_where_it_cannot():
    made = gymnasium.make_vec("MapTidal/StationKeeping-v1", num_envs=2)
    assert isinstance(made, BatchedPoseEnv) and made.max_episode_steps == 200
    observations, _ = made.reset(seed=0)
    assert set(observations) == {"pose", "velocity", "depth", "imu", "target"}
    assert observations["target"].shape == (2, 4)
    made.close()
    with pytest.warns(UserWarning, match="image observations"):
        fallback = gymnasium.make_vec(
            "MapTidal/GoToPose-v1", num_envs=2, obs_images="left", image_size=(24, 32)
        )
    try:
        assert isinstance(fallback, gymnasium.vector.SyncVectorEnv)
        observations, _ = fallback.reset(seed=0)
        assert observations["left"].shape == (2, 24, 32, 3)
        for _ in range(3):
            fallback.step(fallback.action_space.sample())
    finally:
        fallback.close()
    with pytest.warns(UserWarning, match="vectored_6dof"):
        gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=1, frame="standard").close()


@pytest.mark.parametrize("mode", ["alt_hold", "poshold"])
def test_the_compiled_batch_flies_the_hold_modes_and_the_numpy_one_leaves_them_to_sync(mode, monkeypatch):
    """ALT_HOLD and POSHOLD have no numpy twin: the batch flies them only on the compiled stack, as the
    one-robot environments do, and without it make_vec falls back on a SyncVectorEnv and says why."""
    n, length = 2, 8
    options = {"flight_mode": mode, "max_episode_steps": length, "flat_obs": True}
    batched = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, **options)
    sync = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, vectorization_mode="sync", **options)
    try:
        assert isinstance(batched, BatchedPoseEnv) and batched.native
        np.testing.assert_array_equal(batched.reset(seed=3)[0], sync.reset(seed=3)[0])
        rng = np.random.default_rng(8)
        for _ in range(length + 3):  # an episode end and the autoreset after it
            actions = rng.uniform(-1.0, 1.0, batched.action_space.shape).astype(np.float32)
            actions[:, :2] *= rng.integers(0, 2, (n, 1))  # POSHOLD: sticks centred half the time
            got, got_reward, *_ = batched.step(actions)
            want, want_reward, *_ = sync.step(actions)
            np.testing.assert_allclose(got, want, atol=1e-6)
            np.testing.assert_allclose(got_reward, want_reward, atol=1e-6)
    finally:
        batched.close()
        sync.close()
    monkeypatch.setenv("MAPTIDAL_FLIGHT", "python")
    with pytest.warns(UserWarning, match=f"{mode!r} is batched only by the compiled flight stack"):
        fallback = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=1, flight_mode=mode)
    assert isinstance(fallback, gymnasium.vector.SyncVectorEnv)
    fallback.close()


def test_bad_actions_and_arguments_raise_before_anything_moves():
    env = BatchedPoseEnv("go_to_pose", 2, flat_obs=True)
    try:
        with pytest.raises(gymnasium.error.ResetNeeded):
            env.step(np.zeros((2, 6), np.float32))
        env.reset(seed=0)
        time_before = [sim.time for sim in env.sims]
        for bad, message in (
            (np.full((2, 6), np.nan, np.float32), "finite"),
            (np.zeros((3, 6), np.float32), "shape"),
            (np.zeros(6, np.float32), "shape"),
        ):
            with pytest.raises(ValueError, match=message):
                env.step(bad)
        assert [sim.time for sim in env.sims] == time_before
        with pytest.raises(ValueError, match="reset_mask"):
            env.reset(options={"reset_mask": [True]})
        with pytest.raises(ValueError, match="seeds"):
            env.reset(seed=[1, 2, 3])
    finally:
        env.close()
    with pytest.raises(ValueError, match="num_envs"):
        BatchedPoseEnv("go_to_pose", 0)
    with pytest.raises(ValueError, match="cannot be batched"):
        BatchedPoseEnv("go_to_pose", 1, obs_images="stereo")
    with pytest.raises(ValueError, match="task"):
        BatchedPoseEnv("tank_inspection", 1)


def test_contacts_cost_the_same_in_the_batch(flight_backend):
    # dived into the floor from just above it: the contact's cost is the one-robot environment's, also
    # in steps where the other robot waits on its autoreset (row 1 is reset again at step 4, so the rows
    # end their 12-step episodes 4 steps apart, and at step 13 row 1 is on the floor while row 0 resets)
    n = 2
    start = {"pose": (-2.0, 0.0, 0.35, 0.3)}
    limit = {"max_episode_steps": 12, "flat_obs": True}
    batched = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, **limit)
    sync = gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, vectorization_mode="sync", **limit)
    try:
        batched.reset(seed=4, options=start)
        sync.reset(seed=4, options=start)
        actions = np.tile(np.array([0.2, 0.0, -1.0, 0.0, 0.0, 0.0], np.float32), (n, 1))
        touched, touched_alone = 0.0, 0.0
        for step in range(1, 26):
            if step == 4:
                again = {**start, "reset_mask": np.array([False, True])}
                batched.reset(seed=9, options=again)
                sync.reset(seed=9, options=again)
            _, got_reward, *_, got_info = batched.step(actions)
            _, want_reward, *_, want_info = sync.step(actions)
            np.testing.assert_allclose(got_reward, want_reward, atol=1e-6)
            np.testing.assert_allclose(got_info["contact_s"], want_info["contact_s"])
            touched += float(got_info["contact_s"].sum())
            if step == 13:
                touched_alone += float(got_info["contact_s"][1])
        assert touched > 0.5  # it did touch the floor, for a while
        assert touched_alone > 0.0  # and touched it while row 0 waited on its reset
    finally:
        batched.close()
        sync.close()


def test_the_readme_example_of_the_batch_runs():
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "gym.md").read_text()
    (block,) = [b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "make_vec(" in b]
    scope: dict = {}
    exec(compile(block, "docs/gym.md", "exec"), scope)
    assert isinstance(scope["envs"], BatchedPoseEnv) and scope["rewards"].shape == (8,)
    scope["envs"].close()


def test_the_compiled_batch_gives_the_same_on_any_number_of_threads():
    """Its robots are independent simulations: shared out over threads they fly what one thread flies,
    bit for bit (with turbulence, randomisation and an episode end)."""
    options = {"num_envs": 5, "max_episode_steps": 6, "flat_obs": True, "randomize": True}
    runs = []
    for threads in (1, 2, 4):
        env = gymnasium.make_vec("MapTidal/StationKeeping-v1", threads=threads, **options)
        assert env.native and env.threads == threads
        observations = [env.reset(seed=21)[0]]
        rng = np.random.default_rng(3)
        for _ in range(9):
            observation, reward, *_ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
            observations += [observation, reward]
        env.close()
        runs.append(np.concatenate([np.ravel(v) for v in observations]))
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0], runs[2])
    with pytest.raises(ValueError, match="threads"):
        BatchedPoseEnv("go_to_pose", 2, threads=0)
