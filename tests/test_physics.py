"""The simulated BlueROV2 against an independent solve_ivp Fossen model and closed-form figures."""

import math

import mujoco
import numpy as np
import pytest
from fossen_oracle import read_vehicle, simulate

from maptidal.controllers.mixing import MixerParams, mix
from maptidal.envs import hydrodynamics
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.sensors import SensorNoise
from maptidal.envs.simulation import Simulation, SimulationError
from maptidal.envs.vehicle import load_vehicle
from maptidal.tank import TankModel, open_water_config

QUIET = SensorNoise(0, 0, 0, 0, 0, 0, 0)
OPEN_WATER = TankModel(open_water_config(30.0))


def open_water(frame: str, yaw_deg: float = 0.0, **vehicle) -> Simulation:
    robot = RobotSpec("rov", load_vehicle(frame, **vehicle), (-15.0, 0.0, 15.0), yaw_deg)
    return Simulation(Scenario("open", OPEN_WATER, (robot,), noise=QUIET))


def run(sim: Simulation, command: dict, duration: float, mode: str = "pilot"):
    times, velocities, rpys = [], [], []
    for _ in range(round(duration / sim.scenario.control_period_s)):
        sim.step({"rov": command}, mode=mode)
        truth = sim.ground_truth("rov")
        times.append(sim.time)
        velocities.append(truth["velocity_body"] + truth["angular_velocity_body"])
        rpys.append(truth["rpy"])
    return np.array(times), np.array(velocities), np.array(rpys)


def t63(times, speed):
    final = speed[-1]
    return float(times[np.argmax(np.abs(speed) >= 0.632 * abs(final))])


# (frame, pilot command, axis index, duration): steady speeds and time constants
CASES = [
    ("heavy", {"surge": 1.0}, 0, 4.0),
    ("heavy", {"sway": 1.0}, 1, 4.0),
    ("heavy", {"heave": -0.6}, 2, 3.0),
    ("standard", {"surge": 0.6}, 0, 4.0),
    ("standard", {"sway": -1.0}, 1, 4.0),
    ("standard", {"heave": 0.7}, 2, 3.0),
]


@pytest.mark.parametrize(("frame", "command", "axis", "duration"), CASES)
def test_step_response_matches_solve_ivp(frame, command, axis, duration):
    sim = open_water(frame)
    times, velocities, _ = run(sim, command, duration)
    vehicle = sim.scenario.robots[0].vehicle
    thrusters = mix(command, MixerParams(vehicle.ardusub_frame))
    ref_t, _, _, ref_nu = simulate(
        read_vehicle(frame), thrusters, duration, added_mass_coriolis=vehicle.added_mass_coriolis
    )
    ours, ref = velocities[:, axis], np.interp(times, ref_t, ref_nu[:, axis])
    assert abs(ours[-1] - ref[-1]) <= 0.05 * abs(ref[-1])
    assert abs(t63(times, ours) - t63(times, ref)) <= 0.05 * t63(times, ref) + 0.02  # one control period
    assert np.max(np.abs(ours - ref)) <= 0.05 * abs(ref[-1])


# Terminal speeds at full command, closed form: thrust = d_l u + d_q u^2 (+ net buoyancy on heave).
# Thrust at full command, T200 at 16 V (Blue Robotics' 2019 workbook): 51.4 N forward, 39.9 N reverse.
# Surge and sway: all four horizontal thrusters at 45 deg, two running forward and two in reverse.
# Heave up: the vertical thrusters point down, so they all run in reverse (Heavy 4, standard 2).
T200_FORWARD_N, T200_REVERSE_N = 51.4, 39.9
HORIZONTAL_N = (2 * T200_FORWARD_N + 2 * T200_REVERSE_N) * 0.7071
# (linear, quadratic) per axis surge, sway, heave, typed in from assets/bluerov2/README.md's table
DAMPING = {
    "heavy": [(13.7, 141.0), (0.0, 217.0), (33.0, 190.0)],
    "standard": [(4.03, 54.72), (6.22, 65.20), (5.18, 111.34)],
}
VERTICAL_THRUSTERS = {"heavy": 4, "standard": 2}
NET_BUOYANCY_N = 2.0


def terminal_speed(d_l: float, d_q: float, force: float) -> float:
    """The positive root of d_q u^2 + d_l u = force."""
    return (-d_l + math.sqrt(d_l**2 + 4 * d_q * force)) / (2 * d_q)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
@pytest.mark.parametrize(("command", "axis"), [({"surge": 1.0}, 0), ({"sway": -1.0}, 1), ({"heave": 1.0}, 2)])
def test_terminal_speeds_are_the_closed_form_balance_of_thrust_and_drag(frame, command, axis):
    """C_A off: the Munk moment would lean the Heavy and tumble the standard frame at these speeds
    (test_fossen.py); this is the damping balance alone. The standard frame's full surge is Blue
    Robotics' ~1.5 m/s."""
    sim = open_water(frame, added_mass_coriolis=False)
    _, velocities, _ = run(sim, command, 8.0)
    d_l, d_q = DAMPING[frame][axis]
    force = HORIZONTAL_N if axis < 2 else VERTICAL_THRUSTERS[frame] * T200_REVERSE_N + NET_BUOYANCY_N
    expected = terminal_speed(d_l, d_q, force)
    assert abs(velocities[-1, axis]) == pytest.approx(expected, rel=0.01)
    if (frame, axis) == ("standard", 0):
        assert expected == pytest.approx(1.5, abs=0.01)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_idle_vehicle_rises_slowly_at_the_buoyancy_drag_balance(frame):
    sim = open_water(frame)
    _, velocities, _ = run(sim, {}, 6.0)
    vehicle = sim.scenario.robots[0].vehicle
    net = vehicle.buoyancy_n - vehicle.mass * 9.81
    zl, zq = vehicle.linear_damping[2], vehicle.quadratic_damping[2]
    expected = (-zl + math.sqrt(zl**2 + 4 * zq * net)) / (2 * zq)
    assert 0 < expected < 0.2
    assert velocities[-1, 2] == pytest.approx(expected, rel=0.05)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_tilted_vehicle_levels_itself(frame):
    sim = open_water(frame)
    sim.data.qpos[3:7] = [math.cos(0.2), math.sin(0.2), 0.0, 0.0]  # 0.4 rad roll
    mujoco.mj_forward(sim.model, sim.data)
    _, _, rpys = run(sim, {}, 30.0)
    assert np.max(np.abs(rpys[-100:, 0])) < 0.5 * 0.4
    assert abs(np.mean(rpys[-100:, 0])) < 0.02


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_pure_sway_does_not_yaw_and_pure_heave_does_not_pitch_or_roll(frame):
    sim = open_water(frame, yaw_deg=30.0)
    _, velocities, rpys = run(sim, {"sway": 1.0}, 3.0)
    assert np.max(np.abs(velocities[:, 5])) < 1e-6
    assert np.max(np.abs(rpys[:, 2] - math.radians(30))) < 1e-6
    sim.reset()
    _, velocities, rpys = run(sim, {"heave": -1.0}, 3.0)
    assert np.max(np.abs(rpys[:, :2])) < 1e-6 and np.max(np.abs(velocities[:, 3:5])) < 1e-6


def test_native_and_numpy_callbacks_give_the_same_forces():
    sim = open_water("heavy", added_mass_coriolis=True)
    rng = np.random.default_rng(3)
    for _ in range(5):
        sim.data.qvel[:] = rng.normal(0, 0.5, 6)
        forces = _forces_from_both_backends(sim, rng)
        assert np.abs(forces["native"]).max() > 1.0
        np.testing.assert_allclose(forces["native"], forces["numpy"], rtol=1e-9, atol=1e-9)


def _forces_from_both_backends(sim: Simulation, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random attitude and thruster states, then the passive forces of the numpy and C callbacks."""
    quat = rng.normal(size=4)
    sim.data.qpos[3:7] = quat / np.linalg.norm(quat)
    sim.data.act[:] = rng.uniform(-1, 1, 8)
    forces = {}
    for backend in ("numpy", "native"):
        assert hydrodynamics.install_callback(prefer_native=backend == "native") == backend
        mujoco.mj_forward(sim.model, sim.data)
        forces[backend] = sim.data.qfrc_passive.copy()
    return forces


def test_hydrodynamics_off_leaves_a_bare_rigid_body():
    sim = open_water("heavy")
    sim.set_hydrodynamics(False)
    run(sim, {"surge": 1.0}, 1.0)
    truth = sim.ground_truth("rov")
    assert truth["velocity_body"][2] == pytest.approx(-9.81, rel=0.01)  # free fall, no thrust
    assert abs(truth["velocity_body"][0]) < 1e-9


def test_nan_state_raises_a_clear_error():
    sim = open_water("heavy")
    sim.data.qvel[0] = np.nan
    with pytest.raises(SimulationError, match="NaN"):
        sim.step({"rov": {}})


def test_a_divergence_is_dated_when_it_happened_not_after_mujocos_restart():
    sim = open_water("heavy")
    run(sim, {}, 2.0)
    sim.data.qvel[0] = np.nan  # MuJoCo restarts a bad state at t = 0 and warns
    with pytest.raises(SimulationError, match=r"after t = 2\.000 s"):
        sim.step({"rov": {}})


def test_a_current_beyond_five_metres_a_second_is_refused():
    sim = open_water("heavy")
    sim.set_current([3.0, 3.0, 0.0])  # 4.2 m/s: a stress test, allowed
    with pytest.raises(ValueError, match="beyond 5 m/s"):
        sim.set_current([1e6, 0.0, 0.0])


def test_collision_with_the_wall_is_reported():
    sim = Simulation()
    sim.reset(seed=0)
    for _ in range(150):
        sim.step({"rov0": {"surge": 1.0, "heave": 0.1}})
    contacts = sim.contacts()
    assert contacts and all(c.robot == "rov0" and c.other == "tank" for c in contacts)
    assert max(c.normal_force_n for c in contacts) > 1.0


def test_thrusters_lose_thrust_across_the_water_surface():
    level = np.eye(3)
    positions = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.05], [0.0, 0.0, -0.5]])
    wet = hydrodynamics.thruster_wet_fractions(positions, level, cg_z=10.0, surface_z=10.0, fade_m=0.05)
    np.testing.assert_allclose(wet, [0.5, 0.0, 1.0])
    # rolled 90 deg about x: the body's +y now points up, so a thruster at +y rises with it
    rolled = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    up = hydrodynamics.thruster_wet_fractions([[0, 0.2, 0]], rolled, cg_z=9.9, surface_z=10.0, fade_m=0.05)
    assert up[0] == 0.0


def test_a_vehicle_in_air_gets_no_thrust_and_one_under_water_does():
    speeds = {}
    for height in (16.0, -1.0):  # metres above the surface of OPEN_WATER (z = 30)
        sim = open_water("heavy")
        sim.data.qpos[2] = 30.0 + height
        mujoco.mj_forward(sim.model, sim.data)
        run(sim, {"surge": 1.0}, 0.5)
        speeds[height] = sim.ground_truth("rov")["velocity_body"][0]
    assert abs(speeds[16.0]) < 1e-3  # falling through air, propellers spinning in vain
    assert speeds[-1.0] > 0.2


def test_native_and_numpy_agree_for_thrusters_at_the_surface():
    sim = open_water("heavy")
    rng = np.random.default_rng(8)
    for _ in range(5):
        sim.data.qpos[2] = 30.0 + rng.uniform(-0.2, 0.2)
        forces = _forces_from_both_backends(sim, rng)
        np.testing.assert_allclose(forces["native"], forces["numpy"], rtol=1e-9, atol=1e-9)
