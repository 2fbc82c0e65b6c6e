"""The attitude estimator (controllers/estimation.py) against references it shares no code with: a
closed-form rotation whose body rates come from finite differences of its matrices, and the simulator's
ground truth while the vehicle leans and turns."""

import math

import numpy as np
import pytest

from maptidal.controllers.estimation import (
    DeadReckoning,
    EstimatorParams,
    quaternion_from_rpy,
    rotation_from_quaternion,
    rpy_from_rotation,
    wrap_angle,
)
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.tank import TankModel, open_water_config


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    m = np.eye(3)
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def _true_rotation(t: float) -> np.ndarray:
    """A coupled manoeuvre: rolling and pitching back and forth while turning at 0.8 rad/s, built as
    Rz(yaw) Ry(pitch) Rx(roll) from elementary rotations."""
    roll, pitch, yaw = 0.35 * math.sin(0.7 * t), 0.25 * math.sin(0.5 * t + 1.0), 0.8 * t
    return _axis_rotation(2, yaw) @ _axis_rotation(1, pitch) @ _axis_rotation(0, roll)


def _body_rate(t: float, h: float = 1e-5) -> np.ndarray:
    """The body angular velocity from R^T dR/dt (central differences): no Euler-rate formula."""
    skew = _true_rotation(t).T @ (_true_rotation(t + h) - _true_rotation(t - h)) / (2 * h)
    return np.array([skew[2, 1], skew[0, 2], skew[1, 0]])


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    return math.acos(max(-1.0, min(1.0, (np.trace(a.T @ b) - 1.0) / 2.0)))


@pytest.mark.parametrize("corrections", [0.0, 0.2])
def test_the_gyro_is_integrated_as_body_rates_through_a_lean_while_turning(corrections):
    """60 s of coupled roll, pitch and yaw from perfect sensors: the estimate follows the rotation
    within 1e-4 rad with the gravity and compass corrections off (pure integration), and on. Reading
    body rates as Euler-angle rates is off by tens of degrees here."""
    dt = 0.02
    params = EstimatorParams(0.0, tilt_correction_rad_s=corrections, heading_correction_rad_s=corrections)
    estimator = DeadReckoning(params, (0.0, 0.0, -1.0), 0.0)
    estimator.set_attitude(*rpy_from_rotation(_true_rotation(0.0)))
    worst = 0.0
    for k in range(round(60.0 / dt)):
        t = k * dt
        after = _true_rotation(t + dt)
        readings = {
            "imu": {"gyro": _body_rate(t + dt / 2).tolist(), "accel": (after.T @ [0, 0, 9.81]).tolist()},
            "compass": {"heading_deg": math.degrees(-rpy_from_rotation(after)[2]) % 360.0},
        }
        state = estimator.update(readings, dt)
        estimated = rotation_from_quaternion(quaternion_from_rpy(*state.rpy))
        worst = max(worst, _angle_between(estimated, after))
    assert worst < 1e-4


def test_gravity_and_the_compass_pull_a_wrong_start_back_at_the_crossover_rate():
    """Started 10 deg off in roll and 20 deg off in yaw, at rest: each error decays as exp(-k t)."""
    k = 0.2
    estimator = DeadReckoning(
        EstimatorParams(0.0, tilt_correction_rad_s=k, heading_correction_rad_s=k), (0, 0, 0), 0.0
    )
    estimator.set_attitude(math.radians(10), 0.0, math.radians(20))
    at_rest = {"imu": {"gyro": [0.0, 0.0, 0.0], "accel": [0.0, 0.0, 9.81]}, "compass": {"heading_deg": 0.0}}
    for _ in range(round(5.0 / 0.02)):
        state = estimator.update(at_rest, 0.02)
    expected = math.exp(-k * 5.0)  # sin(e) ~ e for the tilt; the yaw error is corrected linearly
    assert state.rpy[0] == pytest.approx(math.radians(10) * expected, rel=0.03)
    assert state.rpy[2] == pytest.approx(math.radians(20) * expected, rel=0.03)
    assert abs(state.rpy[1]) < 1e-4  # second-order coupling of the two corrections only


def test_bad_correction_rates_are_refused():
    with pytest.raises(ValueError, match="tilt_correction_rad_s"):
        EstimatorParams(0.0, tilt_correction_rad_s=-1.0)
    with pytest.raises(ValueError, match="heading_correction_rad_s"):
        EstimatorParams(0.0, heading_correction_rad_s=math.nan)


# ----- against the simulator's truth, with the scenario's sensor noise and biases -------------------

OPEN_WATER = TankModel(open_water_config(30.0))
START = (-15.0, 0.0, 15.0)
ESTIMATE_BOUND_DEG = 1.0  # stated bound on roll, pitch and yaw over 60 s


def _stabilised_heavy() -> Simulation:
    robot = RobotSpec("rov", load_vehicle("heavy"), START)
    sim = Simulation(Scenario("open", OPEN_WATER, (robot,)), flight_mode="stabilize")
    sim.reset(seed=3)
    return sim


def _worst_errors(sim: Simulation, commands) -> tuple[np.ndarray, np.ndarray]:
    """Fly (command, seconds) pairs; the largest |estimate - truth| per axis (rad) and the largest
    true roll and pitch."""
    worst, leaned = np.zeros(3), np.zeros(2)
    for command, seconds in commands:
        for _ in range(round(seconds / sim.scenario.control_period_s)):
            sim.step({"rov": command})
            truth = np.asarray(sim.ground_truth("rov")["rpy"])
            error = sim.estimate("rov").rpy - truth
            error[2] = wrap_angle(error[2])
            worst = np.maximum(worst, np.abs(error))
            leaned = np.maximum(leaned, np.abs(truth[:2]))
    return worst, leaned


def test_the_estimate_holds_while_the_heavy_leans_and_turns_for_a_minute():
    """STABILIZE, roll stick 0.3 and full yaw for 60 s: the Heavy holds a lean while it spins, the case
    where integrating body rates as Euler rates put the roll estimate 8.7 deg off while the truth swung
    about zero."""
    worst, leaned = _worst_errors(_stabilised_heavy(), [({"roll": 0.3, "yaw": 1.0}, 60.0)])
    assert leaned[0] > math.radians(8)  # it does lean
    assert np.all(worst < math.radians(ESTIMATE_BOUND_DEG)), np.degrees(worst)


def test_the_estimate_holds_through_a_pitch_and_roll_sequence():
    sequence = [
        ({"pitch": 0.4}, 8.0),
        ({"pitch": 0.4, "roll": -0.4}, 8.0),
        ({"roll": 0.4, "yaw": -0.5}, 8.0),
        ({"pitch": -0.4, "yaw": 0.5, "surge": 0.5}, 8.0),
        ({}, 8.0),
    ]
    worst, leaned = _worst_errors(_stabilised_heavy(), sequence)
    assert np.all(leaned > math.radians(8))
    assert np.all(worst < math.radians(ESTIMATE_BOUND_DEG)), np.degrees(worst)
