"""The simulated BlueROV2 against Fossen's equations: coupled manoeuvres against an independent matrix
oracle (tests/bench/fossen_oracle.py), and closed forms written from the published parameters.

The closed forms take their numbers from the sources (von Benzon et al. 2022 for the Heavy, Wu 2018
for the standard frame; docs/references.md), transcribed here, so that a wrong number in the vehicle
file fails them as well as a wrong equation in the simulator.
"""

import math

import mujoco
import numpy as np
import pytest
from fossen_oracle import normalised, read_vehicle, simulate, thrust
from scipy.linalg import expm
from scipy.optimize import brentq

from maptidal.controllers.mixing import MixerParams, mix
from maptidal.envs.hydrodynamics import hull_wet_fraction
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.sensors import SensorNoise
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.tank import TankModel, open_water_config

G = 9.81
QUIET = SensorNoise(0, 0, 0, 0, 0, 0, 0)
OPEN_WATER = TankModel(open_water_config(40.0))
START = np.array([-20.0, 0.0, 20.0])

# Published parameters, transcribed from the papers (mass kg, inertia kg m^2, added mass, damping
# magnitudes, CB height above the CG in m): von Benzon et al. 2022 (Heavy), Wu 2018 (standard).
PUBLISHED = {
    "heavy": {
        "mass": 13.5,
        "inertia": (0.26, 0.23, 0.37),
        "added": (6.36, 7.12, 18.68, 0.189, 0.135, 0.222),
        "linear": (13.7, 0.0, 33.0, 0.0, 0.8, 0.0),
        "quadratic": (141.0, 217.0, 190.0, 1.19, 0.47, 1.5),
        # the CB 4.9 cm above the CG of bluerov2_ignition's Heavy (von Benzon publishes 1 cm, with which
        # full surge or sway in MANUAL tumbles it; assets/bluerov2/README.md)
        "bg": 0.049,
    },
    "standard": {
        "mass": 11.5,
        "inertia": (0.16, 0.16, 0.16),
        "added": (5.5, 12.7, 14.57, 0.12, 0.12, 0.12),
        "linear": (4.03, 6.22, 5.18, 0.07, 0.07, 0.07),
        # Wu's translational terms (18.18, 21.66, 36.99) x 3.01: calibrated to the 1.5 m/s top speed
        "quadratic": (54.72, 65.20, 111.34, 1.55, 1.55, 1.55),
        "bg": 0.02,
    },
}


def command_for_thrust(vehicle, force: float) -> float:
    """The thruster command whose thrust, by the oracle's own T200 transcription, is ``force`` (N)."""
    if force == 0:
        return 0.0
    return brentq(lambda a: float(thrust(vehicle, [a])[0]) - force, 0.0, np.sign(force), xtol=1e-12)


def quaternion(roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """(w, x, y, z) of roll about x, then pitch about y, then yaw about z (z-y-x, world axes)."""
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def open_water(frame: str, current=(0.0, 0.0, 0.0), **vehicle) -> Simulation:
    robot = RobotSpec("rov", load_vehicle(frame, **vehicle), tuple(START))
    return Simulation(Scenario("open", OPEN_WATER, (robot,), noise=QUIET, current=tuple(current)))


def start(sim: Simulation, nu0=(0, 0, 0, 0, 0, 0), q0=(1, 0, 0, 0), thrusters=None) -> None:
    """Set the robot's attitude, body velocity and (already lagged) thruster states."""
    sim.data.qpos[3:7] = q0
    mujoco.mj_forward(sim.model, sim.data)
    R = sim.data.xmat[sim.model.body("rov/base").id].reshape(3, 3)
    sim.data.qvel[:3] = R @ np.asarray(nu0[:3], float)  # the free joint's linear velocity is in world axes
    sim.data.qvel[3:6] = nu0[3:]
    if thrusters is not None:
        sim.data.act[: len(thrusters)] = thrusters
    mujoco.mj_forward(sim.model, sim.data)


def fly(sim: Simulation, thrusters: np.ndarray, duration: float):
    """Hold thruster commands; return times, positions, quaternions and body velocities."""
    times, positions, quaternions, velocities = [], [], [], []
    for _ in range(round(duration / sim.scenario.control_period_s)):
        sim.step({"rov": thrusters}, mode="thrusters")
        truth = sim.ground_truth("rov")
        times.append(sim.time)
        positions.append(truth["position"])
        quaternions.append(truth["quaternion"])
        velocities.append(truth["velocity_body"] + truth["angular_velocity_body"])
    return np.array(times), np.array(positions), np.array(quaternions), np.array(velocities)


def attitude_error(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Angle (rad) between attitudes, row by row."""
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(q1 * q2, axis=1)), 0.0, 1.0))


# (name, frame, pilot command, initial body velocity, initial attitude (roll, pitch, yaw), current, seconds)
MANOEUVRES = [
    (
        "surge while yawing",
        "heavy",
        {"surge": 0.3, "yaw": 0.4},
        (0, 0, 0, 0, 0, 0),
        (0, 0, 0),
        (0, 0, 0),
        6.0,
    ),
    (
        "surge while yawing",
        "standard",
        {"surge": 0.3, "yaw": 0.4},
        (0, 0, 0, 0, 0, 0),
        (0, 0, 0),
        (0, 0, 0),
        6.0,
    ),
    (
        "heave while pitching",
        "heavy",
        {"heave": 0.4, "pitch": 0.3},
        (0, 0, 0, 0, 0, 0),
        (0, 0.3, 0),
        (0, 0, 0),
        5.0,
    ),
    ("heave while pitching", "standard", {"heave": 0.4}, (0, 0, 0, 0, 0.5, 0), (0, 0.3, 0), (0, 0, 0), 5.0),
    ("roll release", "heavy", {}, (0, 0, 0, 0, 0, 0), (0.5, 0, 0), (0, 0, 0), 8.0),
    ("roll release", "standard", {}, (0, 0, 0, 0, 0, 0), (0.5, 0, 0), (0, 0, 0), 8.0),
    (
        "turn at speed",
        "heavy",
        {"surge": 0.35, "yaw": -0.6},
        (0.35, 0, 0, 0, 0, 0),
        (0, 0, 0.5),
        (0, 0, 0),
        6.0,
    ),
    (
        "turn at speed",
        "standard",
        {"surge": 0.3, "yaw": -0.6},
        (0.3, 0, 0, 0, 0, 0),
        (0, 0, 0.5),
        (0, 0, 0),
        6.0,
    ),
    (
        "turn in a current",
        "heavy",
        {"surge": 0.3, "yaw": 0.6},
        (0, 0, 0, 0, 0, 0),
        (0, 0, 0),
        (0.3, 0.2, 0),
        6.0,
    ),
    (
        "turn in a current",
        "standard",
        {"sway": 0.3, "yaw": 0.6},
        (0, 0, 0, 0, 0, 0),
        (0, 0, 0),
        (0.3, 0.2, 0),
        6.0,
    ),
]


@pytest.mark.parametrize("coriolis", [True, False], ids=["C_A on", "C_A off"])
@pytest.mark.parametrize(
    ("name", "frame", "command", "nu0", "rpy0", "current", "duration"),
    MANOEUVRES,
    ids=[f"{m[0]}-{m[1]}" for m in MANOEUVRES],
)
def test_coupled_manoeuvres_match_the_book(name, frame, command, nu0, rpy0, current, duration, coriolis):
    sim = open_water(frame, current=current, added_mass_coriolis=coriolis)
    thrusters = mix(command, MixerParams(sim.scenario.robots[0].vehicle.ardusub_frame))
    q0 = quaternion(*rpy0)
    start(sim, nu0, q0)
    times, positions, quaternions, velocities = fly(sim, thrusters, duration)
    ref_t, ref_p, ref_q, ref_nu = simulate(
        read_vehicle(frame), thrusters, duration, coriolis, current, nu0, q0, dt=sim.scenario.control_period_s
    )
    k = np.searchsorted(ref_t, times - 1e-9)
    ref_p, ref_q, ref_nu = ref_p[k] + START, ref_q[k], ref_nu[k]
    travelled = max(float(np.linalg.norm(np.diff(ref_p, axis=0), axis=1).sum()), 0.05)
    assert np.max(np.linalg.norm(positions - ref_p, axis=1)) <= 0.05 * travelled
    for block in (slice(0, 3), slice(3, 6)):
        scale = max(float(np.abs(ref_nu[:, block]).max()), 0.02)
        assert np.max(np.abs(velocities[:, block] - ref_nu[:, block])) <= 0.05 * scale
    turned = max(float(attitude_error(ref_q, np.tile(ref_q[0], (len(ref_q), 1))).max()), 0.1)
    assert np.max(attitude_error(quaternions, ref_q)) <= 0.05 * turned


def _coasting(frame: str, coriolis: bool, **overrides) -> Simulation:
    """No thrust, weight = buoyancy, so that a closed form holds exactly."""
    mass = PUBLISHED[frame]["mass"]
    return open_water(frame, added_mass_coriolis=coriolis, buoyancy_n=mass * G, **overrides)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_pure_yaw_rotates_the_velocity_as_the_added_mass_coriolis_term_says(frame):
    """Coasting at u0 while yawing at r0 with no damping and equal surge and sway added mass a:
    with C_A the world velocity stays fixed; without it the body's momentum equation is
    (m + a) vdot = -m w x v, so the world velocity turns at r0 a / (m + a)."""
    p = PUBLISHED[frame]
    a = p["added"][0]
    added = (a, a, *p["added"][2:])
    zero = (0.0,) * 6
    u0, r0, duration = 0.5, 1.0, 1.0
    for coriolis in (True, False):
        sim = _coasting(frame, coriolis, added_mass=added, linear_damping=zero, quadratic_damping=zero)
        start(sim, (u0, 0, 0, 0, 0, r0))
        fly(sim, np.zeros(len(sim.data.act)), duration)
        v = sim.data.qvel[:2]
        turned = math.atan2(v[1], v[0])
        expected = 0.0 if coriolis else r0 * duration * a / (p["mass"] + a)
        assert turned == pytest.approx(expected, abs=math.radians(0.1)), coriolis
        assert math.hypot(*v) == pytest.approx(u0, rel=1e-3 if coriolis else 0.02)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
@pytest.mark.parametrize("axis", [3, 4], ids=["roll", "pitch"])
def test_free_roll_and_pitch_periods_follow_the_metacentric_height(frame, axis):
    """Undamped small oscillation: (I + a) thetaddot = -B BG theta, period 2 pi sqrt((I + a) / (B BG))."""
    p = PUBLISHED[frame]
    inertia, added = p["inertia"][axis - 3], p["added"][axis]
    buoyancy = p["mass"] * G
    expected = 2 * math.pi * math.sqrt((inertia + added) / (buoyancy * p["bg"]))
    zero = (0.0,) * 6
    sim = _coasting(frame, True, linear_damping=zero, quadratic_damping=zero)
    angle = 0.03
    start(sim, q0=quaternion(angle, 0, 0) if axis == 3 else quaternion(0, angle, 0))
    times, _, _, velocities = fly(sim, np.zeros(len(sim.data.act)), 3.2 * expected)
    rate = velocities[:, axis]
    crossings = times[1:][np.diff(np.sign(rate)) != 0]
    assert len(crossings) >= 5
    period = 2 * float(np.mean(np.diff(crossings)))
    assert period == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("frame", ["heavy", "standard"])
@pytest.mark.parametrize("axis", [0, 1, 2], ids=["surge", "sway", "heave"])
def test_coasting_decays_as_the_damping_law_integrates(frame, axis):
    """(m + a) udot = -(d_l + d_q u) u from u0 > 0 integrates to
    u(t) = d_l c e^(-k t) / (1 - d_q c e^(-k t)), k = d_l / (m + a), c = u0 / (d_l + d_q u0);
    with d_l = 0 it is u0 / (1 + d_q u0 t / (m + a))."""
    p = PUBLISHED[frame]
    inertia = p["mass"] + p["added"][axis]
    d_l, d_q, u0 = p["linear"][axis], p["quadratic"][axis], 0.6
    sim = _coasting(frame, True)
    nu0 = np.zeros(6)
    nu0[axis] = u0
    start(sim, nu0)
    times, _, _, velocities = fly(sim, np.zeros(len(sim.data.act)), 2.0)
    if d_l > 0:
        k, c = d_l / inertia, u0 / (d_l + d_q * u0)
        expected = d_l * c * np.exp(-k * times) / (1 - d_q * c * np.exp(-k * times))
    else:
        expected = u0 / (1 + d_q * u0 * times / inertia)
    np.testing.assert_allclose(velocities[:, axis], expected, rtol=0.02, atol=0.002)


def _pitch_heave_matrix(frame: str, u0: float, coriolis: bool = True, bg: float | None = None) -> np.ndarray:
    """The pitch-heave equations linearised about steady surge u0 (states w, q, theta; z up, y left,
    so positive pitch is nose down), from Fossen's C_RB, C_A, D and g with the published numbers:

        (m + a3) wdot = -d3 w + (m + c a1) u0 q
        (Iy + a5) qdot = -d5 q + c (a3 - a1) u0 w - B BG theta    (the Munk moment, the restoring moment)
        thetadot = q

    with c = 1 when the added-mass Coriolis terms C_A are on and 0 when off.
    """
    p = PUBLISHED[frame]
    m, a1, a3, a5 = p["mass"], p["added"][0], p["added"][2], p["added"][4]
    bg = p["bg"] if bg is None else bg
    iy, d3, d5, stiffness = p["inertia"][1], p["linear"][2], p["linear"][4], p["mass"] * G * bg
    c = 1.0 if coriolis else 0.0
    return np.array(
        [
            [-d3 / (m + a3), (m + c * a1) * u0 / (m + a3), 0.0],
            [c * (a3 - a1) * u0 / (iy + a5), -d5 / (iy + a5), -stiffness / (iy + a5)],
            [0.0, 1.0, 0.0],
        ]
    )


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_pitch_at_speed_follows_the_linearised_munk_equation(frame):
    """A small pitch at surge speed evolves as the linearised equations say, with C_A and without.
    With C_A the Munk moment (a3 - a1) u0 w works against the restoring moment B BG theta: the standard
    frame (BG 2 cm) is unstable above 0.47 m/s; the Heavy with its CB 4.9 cm above the CG stays stable at
    0.8 m/s, where von Benzon's 1 cm would make it unstable."""
    u0, theta0 = 0.8, 1e-3
    growth = np.linalg.eigvals(_pitch_heave_matrix(frame, u0)).real.max()
    if frame == "standard":
        assert growth > 0.05  # unstable at 0.8 m/s
    else:
        assert growth < 0 < np.linalg.eigvals(_pitch_heave_matrix(frame, u0, bg=0.01)).real.max()
    assert np.linalg.eigvals(_pitch_heave_matrix(frame, 0.3)).real.max() < 0  # stable at 0.3 m/s
    assert np.linalg.eigvals(_pitch_heave_matrix(frame, u0, coriolis=False)).real.max() < 0
    p = PUBLISHED[frame]
    drag = p["linear"][0] * u0 + p["quadratic"][0] * u0**2
    for coriolis in (True, False):
        sim = _coasting(frame, coriolis)
        vehicle = sim.scenario.robots[0].vehicle
        # the horizontal thrusters push exactly the drag at u0, so the speed holds
        directions = np.asarray(vehicle.thruster_directions)[:4]
        forces = np.sign(directions[:, 0]) * drag / np.abs(directions[:, 0]).sum()
        thrusters = np.zeros(vehicle.n_thrusters)
        thrusters[:4] = [command_for_thrust(read_vehicle(frame), f) for f in forces]
        lagged = np.zeros(vehicle.n_thrusters)
        lagged[:4] = normalised(forces)  # already at their steady thrust
        start(sim, (u0, 0, 0, 0, 0, 0), quaternion(0, theta0, 0), lagged)
        times, _, quaternions, _ = fly(sim, thrusters, 3.0)
        pitch = np.array([math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x)))) for w, x, y, z in quaternions])
        system = _pitch_heave_matrix(frame, u0, coriolis)
        linear = np.array([(expm(system * t) @ [0.0, 0.0, theta0])[2] for t in times])
        small = np.cumprod(np.abs(linear) < 0.05).astype(bool)  # while the linearisation holds
        assert times[small][-1] > 1.5
        error = np.abs(pitch[small] - linear[small])
        assert np.max(error) <= 0.1 * np.max(np.abs(linear[small])), coriolis


def test_hull_wet_fraction_follows_the_attitude():
    hull = (0.457, 0.575, 0.254)
    level, on_side = np.eye(3), np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])  # rolled 90 deg
    assert hull_wet_fraction(hull, level, cg_z=10.0, surface_z=10.0) == pytest.approx(0.5)
    assert hull_wet_fraction(hull, level, cg_z=10.0 - 0.127 / 2, surface_z=10.0) == pytest.approx(0.75)
    # on its side the hull reaches 0.2875 m up and down: a quarter of its width under water here
    assert hull_wet_fraction(hull, on_side, cg_z=10.0 + 0.575 / 4, surface_z=10.0) == pytest.approx(0.25)
    assert hull_wet_fraction(hull, on_side, cg_z=10.0 - 0.3, surface_z=10.0) == 1.0
    assert hull_wet_fraction(hull, level, cg_z=10.2, surface_z=10.0) == 0.0


def test_mixer_factors_are_ardusubs_on_all_six_axes():
    """AP_Motors6DOF's factors (roll, pitch, yaw, throttle, forward, lateral), transcribed here from
    ArduPilot's libraries/AP_Motors/AP_Motors6DOF.cpp, SUB_FRAME_VECTORED and SUB_FRAME_VECTORED_6DOF."""
    vectored = [
        (0, 0, 1, 0, -1, 1),
        (0, 0, -1, 0, -1, -1),
        (0, 0, -1, 0, 1, 1),
        (0, 0, 1, 0, 1, -1),
        (1, 0, 0, -1, 0, 0),
        (-1, 0, 0, -1, 0, 0),
    ]
    six_dof = vectored[:4] + [
        (1, -1, 0, -1, 0, 0),
        (-1, -1, 0, -1, 0, 0),
        (1, 1, 0, -1, 0, 0),
        (-1, 1, 0, -1, 0, 0),
    ]
    # our pilot axes in ArduSub's factor columns: surge = forward, sway = lateral, heave = throttle
    column = {"surge": 4, "sway": 5, "heave": 3, "roll": 0, "pitch": 1, "yaw": 2}
    for frame, factors in (("vectored", vectored), ("vectored_6dof", six_dof)):
        for axis, k in column.items():
            got = mix({axis: 0.5}, MixerParams(frame))
            np.testing.assert_allclose(
                got, [0.5 * f[k] for f in factors], atol=1e-12, err_msg=f"{frame} {axis}"
            )


@pytest.mark.parametrize("frame", ["heavy", "standard"])
def test_roll_and_pitch_commands_turn_the_vehicle_the_named_way(frame):
    """Roll right side down and, on the Heavy, pitch nose up (maptidal.controllers.convention), in the
    physics."""
    sim = open_water(frame)
    vehicle = sim.scenario.robots[0].vehicle
    _, _, _, velocities = fly(sim, mix({"roll": 0.4}, MixerParams(vehicle.ardusub_frame)), 0.5)
    assert velocities[-1, 3] > 0.05  # +x forward: a positive roll rate lowers the right (-y) side
    if frame == "heavy":
        sim.reset()
        _, _, _, velocities = fly(sim, mix({"pitch": 0.4}, MixerParams(vehicle.ardusub_frame)), 0.5)
        assert velocities[-1, 4] < -0.05  # +y left: nose up is a negative pitch rate
