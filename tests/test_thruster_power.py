"""The T200's electrical power law (maptidal.controllers.thrusters.T200_POWER) against the maker's measured
current at 12 V (tests/data/t200_current_12v.csv, typed from the workbook), and the simulator's odometry:
the thruster energy a robot draws and the distance it travels, against references built here."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from maptidal.controllers.thrusters import T200_12V, T200_POWER, ThrusterPower, command_to_pwm
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.simulation import PATH_STEP_M, Odometry, Simulation
from maptidal.envs.vehicle import ThrusterParams, load_vehicle
from maptidal.tank import TankModel, open_water_config

SHEET = Path(__file__).parent / "data" / "t200_current_12v.csv"
OPEN_WATER = TankModel(open_water_config(40.0))
START = (-15.0, 0.0, 15.0)


def measured_12v() -> tuple[np.ndarray, np.ndarray]:
    """The workbook's 12 V sheet: pulse widths (us) and supply power (W, current times 12 V)."""
    table = np.loadtxt(SHEET, delimiter=",", comments="#", skiprows=5)
    return table[:, 0], 12.0 * table[:, 1]


def open_water_sim(voltage_v: float = 12.0) -> Simulation:
    vehicle = dataclasses.replace(load_vehicle("heavy"), thruster=ThrusterParams(voltage_v=voltage_v))
    sim = Simulation(Scenario("open", OPEN_WATER, (RobotSpec("rov", vehicle, START),)))
    sim.reset(seed=3)
    return sim


def test_the_power_law_follows_the_measured_current_at_12_volts():
    """Wherever a thruster makes at least a tenth of its full thrust, the law's power is within 15 % of
    12 V times the measured current, 4 % on average, and within 8 % at full throttle either way."""
    pwm, measured = measured_12v()
    thrust = T200_12V.thrust_n(pwm)
    predicted = T200_POWER.watts(thrust)
    for side in (pwm > 1500, pwm < 1500):
        loaded = side & (np.abs(thrust) >= 0.1 * np.abs(thrust[side]).max())
        error = np.abs(predicted[loaded] - measured[loaded]) / measured[loaded]
        assert error.max() < 0.15 and error.mean() < 0.04, (error.max(), error.mean())
        full = side & (np.abs(thrust) == np.abs(thrust[side]).max())
        assert predicted[full] == pytest.approx(measured[full], rel=0.08)
    assert T200_POWER.watts(0.0) == 0.0


def test_the_plain_python_sums_are_the_numpy_laws():
    act = np.random.default_rng(2).uniform(-1.0, 1.0, 8)
    act[0] = 0.0
    thruster = ThrusterParams(voltage_v=12.0)
    forces = thruster.lagged_forces(act)
    assert T200_POWER.total_watts(forces.tolist()) == pytest.approx(T200_POWER.watts(forces).sum(), rel=1e-12)
    assert thruster.power_w(act.tolist()) == pytest.approx(T200_POWER.watts(forces).sum(), rel=1e-12)


def test_a_bad_power_law_is_refused():
    with pytest.raises(ValueError, match="positive"):
        ThrusterPower(0.669, 1.61, -0.79, 1.68)
    with pytest.raises(ValueError, match="positive"):
        ThrusterPower(float("nan"), 1.61, 0.79, 1.68)


def test_the_simulated_thrusters_draw_what_the_sheet_says():
    """Four thrusters held at +0.8 (1820 us) and four at -0.6 (1260 us) on a 12 V plant: once the thrust
    has settled, the energy drawn per second is the sheet's current at those pulse widths times 12 V."""
    sim = open_water_sim(12.0)
    command = np.array([0.8] * 4 + [-0.6] * 4)
    for _ in range(50):  # 1 s, ten lag time constants
        sim.step({"rov": command}, mode="thrusters")
    before = sim.odometry("rov").thruster_energy_j
    for _ in range(100):  # 2 s
        sim.step({"rov": command}, mode="thrusters")
    drawn_w = (sim.odometry("rov").thruster_energy_j - before) / 2.0
    pwm, measured = measured_12v()
    expected_w = np.interp(command_to_pwm(command), pwm, measured).sum()
    assert drawn_w == pytest.approx(expected_w, rel=0.08)
    assert sim.odometry("rov").thruster_energy_j > drawn_w  # the first second counted too


def test_idle_thrusters_draw_nothing_and_the_reset_clears_the_count():
    sim = open_water_sim(16.0)
    for _ in range(25):
        sim.step({"rov": np.zeros(8)}, mode="thrusters")
    assert sim.odometry("rov").thruster_energy_j == 0.0
    for _ in range(25):
        sim.step({"rov": np.full(8, 0.5)}, mode="thrusters")
    assert sim.odometry("rov").thruster_energy_j > 0.0
    sim.reset(seed=3)
    assert sim.odometry("rov") == type(sim.odometry("rov"))()


def test_the_path_is_the_length_flown_not_the_displacement():
    """Surge forward for 4 s, then back for 4 s: the path is the speed integrated over time (a reference
    from velocities, not positions) to within one path step, at least the two legs' straight lengths,
    and far more than the start-to-end distance; a teleport by place() adds nothing, and neither does a
    bob smaller than a path step."""
    sim = open_water_sim(16.0)
    period = sim.scenario.control_period_s
    positions = [np.array(sim.ground_truth("rov")["position"])]
    speed_integral = 0.0
    for surge in (0.6, -0.6):
        for _ in range(200):
            speed_before = np.linalg.norm(sim.data.qvel[:3])
            sim.step({"rov": {"surge": surge}})
            speed_integral += 0.5 * (speed_before + np.linalg.norm(sim.data.qvel[:3])) * period
        positions.append(np.array(sim.ground_truth("rov")["position"]))
    legs = sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(positions))
    path = sim.odometry("rov").path_m
    assert legs > 1.0
    assert path == pytest.approx(speed_integral, rel=0.03)
    assert legs - PATH_STEP_M <= path < 1.1 * legs
    assert path > 1.5 * np.linalg.norm(positions[-1] - positions[0])
    sim.place("rov", (5.0, 5.0, 10.0))
    sim.step({"rov": np.zeros(8)}, mode="thrusters")
    assert sim.odometry("rov").path_m == path


def test_the_path_leaves_out_bobbing_and_counts_slow_travel():
    """Positions that bob by up to 2 cm about a point for 1000 periods add nothing; a straight crawl
    of 1 mm a period for 1000 periods adds its metre, to within one path step."""
    rng = np.random.default_rng(5)
    odometry = Odometry()
    for offset in rng.uniform(-0.01, 0.01, (1000, 3)):
        odometry.move_to(np.array([1.0, 2.0, 3.0]) + offset)
    assert odometry.path_m == 0.0
    for k in range(1, 1001):
        odometry.move_to(np.array([1.0 + 0.001 * k, 2.0, 3.0]))
    assert 1.0 - PATH_STEP_M - 0.02 <= odometry.path_m <= 1.0 + 0.02


def test_the_contact_time_is_the_time_the_hull_touches_something():
    """Hovering free, no contact time; pushed down onto the floor, the periods in which the simulator's
    contact list names the robot, times the period."""
    sim = open_water_sim(16.0)
    period = sim.scenario.control_period_s
    for _ in range(50):
        sim.step({"rov": np.zeros(8)}, mode="thrusters")
    assert sim.odometry("rov").contact_s == 0.0
    sim.place("rov", (-15.0, 0.0, 0.3))
    touching = 0
    for _ in range(150):  # 3 s pushing down
        sim.step({"rov": {"heave": -0.6}})
        touching += any(contact.robot == "rov" for contact in sim.contacts())
    assert touching > 50
    assert sim.odometry("rov").contact_s == pytest.approx(touching * period, abs=1e-9)


def test_two_robots_that_touch_both_count_it():
    vehicle = load_vehicle("heavy")
    robots = (RobotSpec("a", vehicle, START), RobotSpec("b", vehicle, (START[0] + 0.3, START[1], START[2])))
    sim = Simulation(Scenario("open", OPEN_WATER, robots))
    sim.reset(seed=3)
    sim.step({"a": np.zeros(8), "b": np.zeros(8)}, mode="thrusters")  # overlapping: pushed apart
    assert any({contact.robot, contact.other} == {"a", "b"} for contact in sim.contacts())
    assert sim.odometry("a").contact_s > 0 and sim.odometry("a").contact_s == sim.odometry("b").contact_s


def test_the_odometry_is_part_of_the_saved_state():
    sim = open_water_sim(16.0)
    for _ in range(20):
        sim.step({"rov": {"surge": 0.5}})
    state = sim.get_state()
    saved = sim.odometry("rov")
    for _ in range(20):
        sim.step({"rov": {"surge": 0.5}})
    later = sim.odometry("rov")
    sim.set_state(state)
    assert sim.odometry("rov") == saved
    for _ in range(20):
        sim.step({"rov": {"surge": 0.5}})
    assert sim.odometry("rov") == later
