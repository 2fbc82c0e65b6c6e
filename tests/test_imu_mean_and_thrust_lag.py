"""Two facts the robot without a DVL dead-reckons on: the IMU's period-mean specific force
(``imu["accel_mean"]``, :mod:`maptidal.envs.simulation`) and the thrusters' lag in its motion model
(:attr:`maptidal.controllers.estimation.MotionModel.thrust_lag_s`).

References that share no code with what they test: the equivalence principle (free fall reads zero),
the true velocity change across an impact, MuJoCo's own first-order actuator filter (the plant's thrust
lag) and the simulated truth of a flight."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from maptidal.controllers.estimation import STANDARD_GRAVITY, DeadReckoning
from maptidal.controllers.pose import _force_matrix
from maptidal.envs.scenario import load_scenario
from maptidal.envs.sensors import SensorNoise
from maptidal.envs.simulation import Simulation

MISSION = load_scenario("mission")  # rov1 has no DVL: its estimator dead-reckons on its motion model
QUIET = SensorNoise(0, 0, 0, 0, 0, 0, 0)


def near_the_side_wall() -> object:
    """The mission's two Heavies in the open part of the tank, rov1 0.17 m from the right side wall."""
    rov0, rov1 = MISSION.robots
    return dataclasses.replace(
        MISSION,
        robots=(
            dataclasses.replace(rov0, position=(-3.0, 0.6, 1.0)),
            dataclasses.replace(rov1, position=(-3.0, -1.45, 1.0)),
        ),
    )


# ----- the IMU's period mean -----------------------------------------------------------------------
def test_the_period_mean_reads_g_at_rest_and_zero_in_free_fall():
    sim = Simulation(MISSION, flight_mode="manual")
    sim.reset(seed=0)
    for robot in sim.robots:
        sim.set_sensor_noise(robot, QUIET, rescale_biases=True)
    sim.track_estimate("rov1")
    sim.set_hydrodynamics(False)  # no buoyancy, no drag: the robots fall freely
    sim.step()
    sim.step()
    falling = sim.latest_readings("rov1")["imu"]["accel_mean"]
    assert np.allclose(falling, 0.0, atol=1e-9)  # a falling accelerometer feels nothing
    assert sim.ground_truth("rov1")["velocity_body"][2] < -0.3  # and it does fall
    resting = Simulation(MISSION, flight_mode="manual")
    resting.reset(seed=0)
    resting.set_sensor_noise("rov1", QUIET, rescale_biases=True)
    resting.track_estimate("rov1")
    resting.set_hydrodynamics(False)
    resting.model.opt.gravity[:] = 0.0
    resting.step()
    assert np.allclose(resting.latest_readings("rov1")["imu"]["accel_mean"], 0.0, atol=1e-9)


def test_the_period_mean_holds_an_impact_the_sample_misses():
    """Flown into the side wall, the robot stops within a few milliseconds: its velocity change from
    rest, summed from the period means, is the true one; summed from the end-of-period samples it
    misses the stop."""
    sim = Simulation(near_the_side_wall(), flight_mode="stabilize")
    sim.reset(seed=0)
    for robot in sim.robots:
        sim.set_sensor_noise(robot, QUIET, rescale_biases=True)
    period = sim.scenario.control_period_s
    gravity = np.array([0.0, 0.0, -STANDARD_GRAVITY])
    slot = sim._slots["rov1"]
    start = sim.data.qvel[slot.dof_adr : slot.dof_adr + 3].copy()
    mean_sum, sample_sum, fastest = np.zeros(3), np.zeros(3), 0.0
    for _ in range(100):
        sim.step({"rov1": {"sway": 0.6}, "rov0": {}})
        rotation = sim.data.xmat[slot.body_id].reshape(3, 3)
        imu = sim.latest_readings("rov1")["imu"]
        mean_sum += (rotation @ np.asarray(imu["accel_mean"]) + gravity) * period
        sample_sum += (rotation @ np.asarray(imu["accel"]) + gravity) * period
        fastest = max(fastest, -float(sim.data.qvel[slot.dof_adr + 1]))
    change = sim.data.qvel[slot.dof_adr : slot.dof_adr + 3] - start
    assert sim.odometry("rov1").contact_s > 0.5  # it hit the wall and stayed there
    assert fastest > 0.2 and abs(change[1]) < 0.1  # under way towards it (-y), then stopped
    assert np.allclose(mean_sum, change, atol=1e-6)
    assert abs(sample_sum[1] - change[1]) > 0.5 * fastest


# ----- the thrusters' lag in the model ---------------------------------------------------------------
def test_the_lagged_force_is_near_the_plants_lagged_thrust():
    """The estimator filters the commanded body force with the thrusters' lag; the plant's thrust is
    MuJoCo's first-order actuator state (filterexact) on each thruster's normalised thrust, through the
    thrust curve's forward and reverse scales. Where a thruster's thrust changes sign the two part (the
    scales differ), so over 4 s of random commands under STABILIZE the lagged force is some 6 % of the
    force off the plant's, and the commanded force, unlagged, 90 %."""
    sim = Simulation(MISSION, flight_mode="stabilize")
    sim.reset(seed=3)
    rng = np.random.default_rng(5)
    model = sim._vehicle_models["rov1"]
    assert model.motion_model().thrust_lag_s == pytest.approx(0.1)  # the T200's, assets/bluerov2
    matrix = _force_matrix(model)
    lagged, commanded, size = [], [], []
    command = np.zeros(6)
    for step in range(200):
        if step % 10 == 0:
            command = rng.uniform(-0.6, 0.6, 6)
        sim.step({"rov1": command, "rov0": {}})
        act = np.asarray(sim.ground_truth("rov1")["thrusters"])
        plant = sim.plant("rov1").thruster.lagged_forces(act) @ matrix.T
        lagged.append(np.linalg.norm(sim._estimators["rov1"].thrust_lagged - plant))
        commanded.append(
            np.linalg.norm(np.asarray(sim.latest_readings("rov1")["thrust"]["force_body"]) - plant)
        )
        size.append(np.linalg.norm(plant))
    assert np.mean(lagged) < 0.1 * np.mean(size)
    assert np.mean(lagged) < 0.15 * np.mean(commanded)


def test_the_lag_keeps_the_dead_reckoning_on_the_plant():
    """20 s of random commands, a new one every 0.1 s, without touching anything: the estimator with
    the thrusters' lag in its model stays within 5 cm of the truth; the same model without the lag
    leads the vehicle at every change of command and ends more than 15 cm off."""
    sim = Simulation(MISSION, flight_mode="stabilize")
    sim.reset(seed=7)
    params = sim._estimators["rov1"].params
    start = sim.ground_truth("rov1")
    unlagged_model = dataclasses.replace(params.motion_model, thrust_lag_s=0.0)
    replays = {
        "lagged": DeadReckoning(params, start["position"], start["rpy"][2]),
        "unlagged": DeadReckoning(
            dataclasses.replace(params, motion_model=unlagged_model), start["position"], start["rpy"][2]
        ),
    }
    rng = np.random.default_rng(7)
    period = sim.scenario.control_period_s
    command = np.zeros(6)
    for k in range(1000):
        if k % 5 == 0:
            command = rng.uniform(-0.6, 0.6, 6)
        sim.step({"rov1": command, "rov0": {}})
        for estimator in replays.values():
            estimator.update(sim.latest_readings("rov1"), period)
    assert sim.odometry("rov1").contact_s == 0.0
    truth = np.asarray(sim.ground_truth("rov1")["position"])
    error = {name: float(np.hypot(*(e.state.position[:2] - truth[:2]))) for name, e in replays.items()}
    assert error["lagged"] < 0.05 and error["unlagged"] > 0.15, error
    # the simulator's own estimator is the lagged one (it folded in one reading more, at the reset)
    assert np.allclose(sim.estimate("rov1").position, replays["lagged"].state.position, atol=1e-3)
