"""Domain randomisation (issue [rl] part 3): each drawn number reaches the physics, checked against
closed forms with the published BlueROV2 Heavy numbers written out here (von Benzon et al., J. Mar.
Sci. Eng. 2022; our trimmed buoyancy; Blue Robotics' T200 data), never read back from the code under
test; and the environments draw per episode, seeded, reported and checked."""

from __future__ import annotations

import math
import pickle

import gymnasium
import numpy as np
import pytest

import maptidal.envs  # noqa: F401  (registers the MapTidal/ environments)
from maptidal.controllers.thrusters import t200_curve_between
from maptidal.envs import randomization
from maptidal.envs.gym.core import gust_step
from maptidal.envs.randomization import DEFAULT_RANGES, Randomization
from maptidal.envs.simulation import Simulation

# the BlueROV2 Heavy, von Benzon et al. (2022), and the 134.4 N buoyancy we trim it to (2 N net positive)
MASS_KG, IYY, BUOYANCY_N, G = 13.5, 0.23, 134.4, 9.81
ADDED_HEAVE, ADDED_PITCH = 18.68, 0.135
SURGE_LINEAR, SURGE_QUADRATIC = 13.7, 141.0
ADDED_SWAY, SWAY_QUADRATIC = 7.12, 217.0
# Blue Robotics' T200 at full forward / reverse: 51.4 / 39.9 N at 16 V, 36.4 / 28.6 N at 12 V
T200 = {16.0: (51.4, 39.9), 12.0: (36.4, 28.6)}


def _simulation(draw: dict, flight_mode: str = "manual", start=(-3.0, 0.0, 1.0)) -> Simulation:
    sim = Simulation(None, flight_mode=flight_mode)
    sim.reset(seed=0)
    robot = sim.robots[0]
    randomization.apply(sim, robot, draw)
    sim.place(robot, start, 0.0)
    return sim


def _heave_and_pitch_acceleration(sim: Simulation) -> tuple[float, float]:
    """Heave (m/s^2) and pitch (rad/s^2) accelerations over the first physics step from rest."""
    robot = sim.robots[0]
    sim.advance_physics(1)
    truth = sim.ground_truth(robot)
    dt = sim.scenario.timestep_s
    return truth["velocity_body"][2] / dt, truth["angular_velocity_body"][1] / dt


@pytest.mark.parametrize(
    ("mass", "volume", "added"), [(1.0, 1.0, 1.0), (1.05, 0.98, 1.3), (0.95, 1.02, 0.7), (1.0, 1.06, 1.0)]
)
def test_mass_volume_and_added_mass_give_fossens_heave_from_rest(mass, volume, added):
    # (m + Z_w') w' = B - m g at rest, level: no damping yet, buoyancy straight up
    draw = {"mass_scale": mass, "volume_scale": volume, "added_mass_scale": added}
    with _simulation(draw) as sim:
        heave, _ = _heave_and_pitch_acceleration(sim)
    expected = (BUOYANCY_N * volume - MASS_KG * mass * G) / (MASS_KG * mass + ADDED_HEAVE * added)
    assert heave == pytest.approx(expected, rel=0.02, abs=0.002)


@pytest.mark.parametrize("offset_x", [0.01, -0.008])
def test_a_centre_of_buoyancy_moved_forward_pitches_the_nose_up(offset_x):
    # buoyancy B at x = offset ahead of the CG: a moment -offset B about y (y left, z up), so the nose
    # rises for a forward offset; (Iyy + M_q') q' = -offset B. Without the offset the vehicle stays level
    with _simulation({"cb_offset_m": [0.0, 0.0, 0.0]}) as sim:
        _, level = _heave_and_pitch_acceleration(sim)
    with _simulation({"cb_offset_m": [offset_x, 0.0, 0.0]}) as sim:
        _, pitch = _heave_and_pitch_acceleration(sim)
    assert abs(level) < 1e-6
    assert pitch == pytest.approx(-offset_x * BUOYANCY_N / (IYY + ADDED_PITCH), rel=0.02)


def _terminal_surge(draw: dict) -> float:
    with _simulation(draw, flight_mode="stabilize", start=(-5.2, 0.0, 1.0)) as sim:
        robot = sim.robots[0]
        speeds = []
        while sim.time < 2.5:
            sim.step({robot: [1.0, 0, 0, 0, 0, 0]})
            if sim.time > 2.0:
                speeds.append(sim.ground_truth(robot)["velocity_body"][0])
    return float(np.mean(speeds))


def _speed_for_force(force: float, scale: float = 1.0) -> float:
    # F = s (X_u u + X_|u|u u^2), the positive root
    a, b = scale * SURGE_QUADRATIC, scale * SURGE_LINEAR
    return (-b + math.sqrt(b * b + 4 * a * force)) / (2 * a)


def test_voltage_and_damping_set_the_terminal_surge_speed_as_the_damping_law_says():
    nominal = _terminal_surge({"voltage_v": 16.0})
    force = SURGE_LINEAR * nominal + SURGE_QUADRATIC * nominal**2  # what full surge pushes at 16 V
    # at 12 V the T200 gives 36.4 / 51.4 forward and 28.6 / 39.9 reverse: both about 0.71
    at_12v = _terminal_surge({"voltage_v": 12.0})
    ratio = (T200[12.0][0] / T200[16.0][0] + T200[12.0][1] / T200[16.0][1]) / 2
    assert at_12v == pytest.approx(_speed_for_force(force * ratio), rel=0.03)
    doubled = _terminal_surge({"voltage_v": 16.0, "damping_scale": 2.0})
    assert doubled == pytest.approx(_speed_for_force(force, scale=2.0), rel=0.03)
    assert at_12v < nominal * 0.9 and doubled < nominal * 0.8


@pytest.mark.parametrize("voltage", [12.0, 16.0])
def test_the_curve_between_voltages_meets_the_published_ends(voltage):
    curve = t200_curve_between(voltage)
    assert (curve.max_forward_n, curve.max_reverse_n) == pytest.approx(T200[voltage])


def test_the_curve_at_14_volts_lies_halfway():
    curve = t200_curve_between(14.0)
    assert curve.max_forward_n == pytest.approx((51.4 + 36.4) / 2)
    assert curve.deadband_us == pytest.approx((28.0 + 36.0) / 2)
    with pytest.raises(ValueError, match="12 to 16"):
        t200_curve_between(11.0)


def test_the_thrust_lag_is_a_first_order_filter_with_the_drawn_time_constant():
    tau = 0.17
    with _simulation({"thruster_lag_s": tau}) as sim:
        robot = sim.robots[0]
        sim.set_thrusters(robot, np.ones(8))
        steps = round(tau / sim.scenario.timestep_s)
        sim.advance_physics(steps)
        first = sim._ctrl_adr[robot]
        act = sim.data.act[first : first + 8]
    # normalised thrust 1 at full command, reached as 1 - exp(-t / tau)
    np.testing.assert_allclose(act, 1 - math.exp(-steps * 0.002 / tau), rtol=1e-3)


def test_each_thrusters_gain_scales_its_thrust():
    gains = [0.9, 1.1, 1.0, 0.95, 1.05, 0.92, 1.08, 1.0]
    with _simulation({"thruster_gain": gains, "thruster_lag_s": 0.01}) as sim:
        robot = sim.robots[0]
        sim.set_thrusters(robot, np.ones(8))
        sim.advance_physics(100)  # 0.2 s: 20 time constants
        first = sim._ctrl_adr[robot]
        np.testing.assert_allclose(sim.data.act[first : first + 8], gains, rtol=1e-6)


def test_the_sensor_noise_scale_scales_the_depth_noise():
    spreads = []
    for scale in (1.0, 3.0):
        with _simulation({"noise_scale": scale}) as sim:
            robot = sim.robots[0]
            depths = [sim.sensors(robot)["depth"]["depth_m"] for _ in range(600)]
        spreads.append(float(np.std(depths)))
    # the Bar30's 2 mm (SensorNoise's default), then three times it; 600 samples: within 10 %
    assert spreads[0] == pytest.approx(0.002, rel=0.1)
    assert spreads[1] == pytest.approx(0.006, rel=0.1)


def test_the_drawn_current_and_turbidity_reach_the_water():
    with _simulation({"current_m_s": 0.08, "current_heading_rad": math.pi / 2, "turbidity": 0.55}) as sim:
        assert sim.water.params.turbidity == 0.55
        robot = sim.robots[0]
        for _ in range(150):  # 3 s of drifting, thrusters off
            sim.step({robot: np.zeros(6)})
        velocity = sim.ground_truth(robot)["velocity_body"]  # heading 0: body x, y are the world's
        elapsed = sim.time
    # a current c along +y drags the robot by quadratic sway damping alone (Y_v = 0 on the Heavy):
    # (m + Y_v') v' = Y_|v|v (c - v)^2 from rest gives v = c - c / (1 + c Y_|v|v t / (m + Y_v'))
    c = 0.08
    expected = c - c / (1 + c * SWAY_QUADRATIC * elapsed / (MASS_KG + ADDED_SWAY))
    assert velocity[1] == pytest.approx(expected, rel=0.05) and abs(velocity[0]) < 0.005


def test_reset_keeps_the_plant_and_the_robot_keeps_believing_the_nominal_vehicle():
    with _simulation({"mass_scale": 1.05, "damping_scale": 2.0}) as sim:
        robot = sim.robots[0]
        sim.reset(seed=1)
        assert sim.plant(robot).mass == pytest.approx(MASS_KG * 1.05)
        assert sim.model.body_mass[sim.model.body(f"{robot}/base").id] == pytest.approx(MASS_KG * 1.05)
        assert sim._vehicle_models[robot].inertia[0] == pytest.approx(MASS_KG + 6.36)  # believed: nominal


# ----- the environments ---------------------------------------------------------------------------
def test_each_episode_draws_within_the_ranges_seeded_and_reported():
    env = gymnasium.make("MapTidal/GoToPose-v1", randomize=True)
    try:
        _, first = env.reset(seed=5)
        _, again = env.reset(seed=5)
        _, other = env.reset(seed=6)
    finally:
        env.close()
    assert first == again and first != other
    draw = first["randomization"]
    for key, (low, high) in DEFAULT_RANGES.items():
        values = np.atleast_1d(draw[key])
        assert np.all((values >= low) & (values <= high)), key
    assert len(draw["thruster_gain"]) == 8 and len(draw["cb_offset_m"]) == 3


def test_a_fixed_number_is_the_drawn_value_and_unnamed_keys_stay_nominal():
    env = gymnasium.make("MapTidal/GoToPose-v1", randomize={"voltage_v": 12.0})
    try:
        _, info = env.reset(seed=0)
        plant = env.unwrapped.sim.plant(env.unwrapped.robot)
    finally:
        env.close()
    assert info["randomization"] == {"voltage_v": 12.0}
    assert plant.thruster.max_forward_n == pytest.approx(36.4) and plant.mass == MASS_KG


def test_without_randomize_nothing_is_drawn_or_reported():
    env = gymnasium.make("MapTidal/GoToPose-v1")
    try:
        _, info = env.reset(seed=0)
        assert info == {} and env.unwrapped.sim.plant("rov0").mass == MASS_KG
    finally:
        env.close()


def test_a_randomised_episode_replays_bit_for_bit_in_another_environment():
    env = gymnasium.make("MapTidal/StationKeeping-v1", randomize=True, flat_obs=True)
    other = gymnasium.make("MapTidal/StationKeeping-v1", randomize=True, flat_obs=True)
    actions = np.random.default_rng(1).uniform(-1, 1, (20, 6)).astype(np.float32)
    try:
        env.reset(seed=3)
        other.reset(seed=99)  # another draw, put right by the state
        state = env.unwrapped.get_state()
        first = [env.step(a)[0] for a in actions]
        other.unwrapped.set_state(state)
        second = [other.step(a)[0] for a in actions]
        copied = pickle.loads(pickle.dumps(other.unwrapped))
        assert copied.sim.plant("rov0") == env.unwrapped.sim.plant("rov0")
    finally:
        env.close()
        other.close()
    np.testing.assert_array_equal(np.array(first), np.array(second))


@pytest.mark.parametrize("env_id", ["MapTidal/GoToPose-v1", "MapTidal/TeamInspection-v1"])
def test_a_reused_environment_starts_where_a_fresh_one_does(env_id):
    # a reset draws the IMU biases at the robots' noise levels: they must be the scenario's then, not
    # the last episode's drawn ones (a reused environment started 0.5 mm off a fresh one, seed for seed)
    used = gymnasium.make(env_id, randomize=True)
    fresh = gymnasium.make(env_id, randomize=True)
    try:
        used.reset(seed=0)
        got, _ = used.reset(seed=5)
        want, _ = fresh.reset(seed=5)
        hold = used.action_space.sample() if env_id.endswith("TeamInspection-v1") else None
        for _ in range(3):
            action = hold if hold is not None else np.full(6, 0.3, np.float32)
            got, *_ = used.step(action)
            want, *_ = fresh.step(action)
        flat = lambda tree: np.concatenate(  # noqa: E731
            [np.ravel(v) for v in gymnasium.spaces.flatten(used.observation_space, tree)]
        )
        np.testing.assert_array_equal(flat(got), flat(want))
        sensors = lambda env: env.unwrapped.sim._sensors["rov0"]  # noqa: E731
        np.testing.assert_array_equal(sensors(used).gyro_bias, sensors(fresh).gyro_bias)
    finally:
        used.close()
        fresh.close()


def test_a_drawn_noise_scale_scales_the_biases_drawn_at_the_reset():
    env = gymnasium.make("MapTidal/GoToPose-v1", randomize={"noise_scale": 3.0})
    nominal = gymnasium.make("MapTidal/GoToPose-v1", randomize={"noise_scale": 1.0})
    try:
        env.reset(seed=8)
        nominal.reset(seed=8)
        sensors = lambda e: e.unwrapped.sim._sensors["rov0"]  # noqa: E731
        np.testing.assert_allclose(sensors(env).accel_bias, 3.0 * sensors(nominal).accel_bias, rtol=1e-12)
        np.testing.assert_allclose(sensors(env).gyro_bias, 3.0 * sensors(nominal).gyro_bias, rtol=1e-12)
    finally:
        env.close()
        nominal.close()


def test_the_team_draws_each_robot_its_own_vehicle_and_one_water():
    env = gymnasium.make("MapTidal/TeamInspection-v1", randomize=True)
    try:
        _, info = env.reset(seed=2)
        sim = env.unwrapped.sim
        masses = [sim.plant(name).mass for name in env.unwrapped.agents]
    finally:
        env.close()
    draws = info["randomization"]
    assert set(draws) == {"rov0", "rov1"} and masses[0] != masses[1]
    assert "current_m_s" in draws["rov0"] and "current_m_s" not in draws["rov1"]


def _currents(env, steps: int) -> np.ndarray:
    """The water current after each of ``steps`` steps that hold still."""
    hold = np.zeros(env.action_space.shape, np.float32)
    currents = []
    for _ in range(steps):
        env.step(hold)
        currents.append(env.unwrapped.sim.current)
    return np.array(currents)


@pytest.mark.parametrize("dt", [0.02, 0.1])
def test_the_gust_is_an_ornstein_uhlenbeck_process(dt):
    """Over 2000 time constants the gust's standard deviation is sigma on each axis, whatever the step,
    and its correlation after one time constant (2 s) is 1/e, as the process's stationary law says
    (closed forms, not the update's code; tolerances about three standard errors)."""
    rng = np.random.default_rng(7)
    steps = round(4000 / dt)
    gust, samples = np.zeros(3), np.empty((steps, 3))
    for k in range(steps):
        gust = gust_step(gust, 0.05, dt, rng)
        samples[k] = gust
    assert samples.std(axis=0) == pytest.approx([0.05] * 3, rel=0.08)
    lag = round(2.0 / dt)
    correlation = np.mean([np.corrcoef(samples[:-lag, k], samples[lag:, k])[0, 1] for k in range(3)])
    assert correlation == pytest.approx(math.exp(-1.0), abs=0.06)


def test_the_drawn_turbulence_blows_about_the_episodes_current():
    """GoToPose with turbulence drawn: each step's current is the episode's mean current (here a drawn
    0.05 m/s) plus the gust, which moves."""
    env = gymnasium.make("MapTidal/GoToPose-v1", randomize={"turbulence_m_s": 0.05, "current_m_s": 0.05})
    try:
        _, info = env.reset(seed=4)
        mean = env.unwrapped.mean_current.copy()
        hold = np.zeros(env.action_space.shape, np.float32)
        currents, gusts = [], []
        for _ in range(60):
            env.step(hold)
            currents.append(env.unwrapped.sim.current)
            gusts.append(env.unwrapped.gust.copy())
    finally:
        env.close()
    heading = info["randomization"]["current_heading_rad"]
    np.testing.assert_allclose(mean, [0.05 * math.cos(heading), 0.05 * math.sin(heading), 0.0], atol=1e-12)
    np.testing.assert_allclose(np.array(currents), mean + np.array(gusts), atol=1e-12)
    assert np.ptp(np.array(gusts), axis=0).min() > 0.002


def test_without_turbulence_the_current_holds_still():
    for randomize in (None, {"current_m_s": 0.05}):
        env = gymnasium.make("MapTidal/GoToPose-v1", randomize=randomize)
        try:
            env.reset(seed=1)
            currents = _currents(env, 30)
        finally:
            env.close()
        assert np.all(currents == currents[0])


def test_the_team_shares_one_drawn_turbulence():
    env = gymnasium.make("MapTidal/TeamInspection-v1", randomize={"turbulence_m_s": 0.05})
    try:
        _, info = env.reset(seed=2)
        hold = {name: np.zeros(space.shape, np.float32) for name, space in env.action_space.items()}
        currents = []
        for _ in range(20):
            env.step(hold)
            currents.append(env.unwrapped.sim.current)
    finally:
        env.close()
    assert info["randomization"] == {"rov0": {"turbulence_m_s": 0.05}, "rov1": {}}
    assert np.ptp(np.array(currents), axis=0).max() > 0.005


@pytest.mark.parametrize(
    ("randomize", "message"),
    [
        ({"mass": (0.9, 1.1)}, "unknown randomize key"),
        ({"mass_scale": (-1.0, 1.0)}, "mass_scale"),
        ({"mass_scale": (0.0, 1.0)}, "mass_scale"),
        ({"voltage_v": 0.0}, "voltage_v"),
        ({"voltage_v": (12.0, 20.0)}, "voltage_v"),
        ({"turbidity": (0.5, 0.2)}, "low <= high"),
        ({"damping_scale": (math.nan, 1.0)}, "finite"),
        ({"thruster_lag_s": (0.0, 0.1)}, "thruster_lag_s"),
        ({"noise_scale": "big"}, "one number"),
        ({"noise_scale": (True, 2)}, "one number"),
        ("yes", "randomize must be"),
    ],
)
def test_bad_randomisation_is_refused_in_one_line(randomize, message):
    with pytest.raises(ValueError, match=message):
        gymnasium.make("MapTidal/GoToPose-v1", randomize=randomize)


def test_from_option_reads_true_false_and_none():
    assert Randomization.from_option(None) is None and Randomization.from_option(False) is None
    assert {key for key, *_ in Randomization.from_option(True).ranges} == set(DEFAULT_RANGES)
