"""An independent 6-DOF Fossen model of a BlueROV2, integrated with scipy's solve_ivp: the test oracle
for maptidal.envs.hydrodynamics.

Written from the book, in matrix form, with no MuJoCo and none of the simulator's code: T. I. Fossen,
"Handbook of Marine Craft Hydrodynamics and Motion Control", Wiley 2011. In the relative velocity
nu_r = nu - [R^T v_c; 0] of an irrotational, constant current v_c (Ch. 10, ocean currents), the
equations of motion read

    (M_RB + M_A) nudot_r + C_RB(nu_r) nu_r + C_A(nu_r) nu_r + D(nu_r) nu_r + g(eta) = tau

- M_RB = diag(m, m, m, Ix, Iy, Iz): origin at the CG, principal axes (Ch. 3);
- C_RB(nu) = [[m S(w), 0], [0, -S(I w)]], the parametrisation independent of the linear velocity
  that makes the relative form exact under a constant current (Ch. 3 and 10);
- M_A = diag of the added masses, C_A(nu_r) = [[0, -S(A11 v_r)], [-S(A11 v_r), -S(A22 w)]] (Eq. 6.43);
- D(nu_r) = D_lin + D_quad |nu_r|, diagonal (Ch. 6);
- g(eta) = -[f_g + f_b; r_b x f_b] with f_g = R^T [0, 0, -W], f_b = R^T [0, 0, B] (Ch. 4, here z up);
- tau: each thruster's force along its direction at its position. A command u becomes a static
  thrust through ArduSub's linear command-to-PWM mapping (pwm = 1500 + u * 400 with MOT_PWM_MIN/MAX
  1100/1900) and the T200 curve transcribed below (:func:`t200_thrust`); the thrust follows it with a
  first-order lag.

S(a) is the skew-symmetric matrix with S(a) b = a x b. The parameters are read from
assets/bluerov2/bluerov2.toml here, with tomllib, so that this oracle shares no parameter handling with
maptidal.envs.vehicle either.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

VEHICLE_TOML = Path(__file__).resolve().parents[2] / "assets" / "bluerov2" / "bluerov2.toml"
GRAVITY = 9.81


# The T200 curve, transcribed here from its public sources rather than from maptidal.controllers.thrusters:
# - a least-squares quadratic of Blue Robotics' 12 V sheet ("EMPIRICAL FIT TO PUBLISHED T200 12V
#   Data"): thrust (N) = a pwm^2 + b pwm + c, forward on 1540-1900 us, reverse on 1100-1460 us;
# - deadband and full thrust at 16 V as read off Blue Robotics' 2019 workbook (duburi_sim's
#   docs/physics.md table): zero on 1472-1528 us, 51.4 N at 1900 us, -39.9 N at 1100 us.
# The 16 V curve is the 12 V polynomial stretched from its own zero crossing to the 16 V deadband
# edge and scaled to the 16 V maximum.
FIT_12V_FORWARD = (1.27100189603788e-4, -0.33277857760984, 211.033461129255)
FIT_12V_REVERSE = (-9.16411681345042e-5, 0.316235205225523, -266.314177431551)
DEADBAND_16V_US = (1472.0, 1528.0)
MAX_16V_N = (51.4, 39.9)


def t200_thrust(pwm: np.ndarray) -> np.ndarray:
    """Thrust (N) of a T200 at 16 V at each pulse width (us)."""
    pwm = np.clip(np.asarray(pwm, float), 1100.0, 1900.0)
    out = np.zeros_like(pwm)
    for coefficients, edge, end, peak, side in (
        (FIT_12V_FORWARD, DEADBAND_16V_US[1], 1900.0, MAX_16V_N[0], pwm > DEADBAND_16V_US[1]),
        (FIT_12V_REVERSE, DEADBAND_16V_US[0], 1100.0, -MAX_16V_N[1], pwm < DEADBAND_16V_US[0]),
    ):
        roots = np.roots(coefficients).real
        zero = roots[np.argmin(np.abs(roots - 1500.0))]  # the 12 V fit's own deadband edge
        stretched = zero + (pwm - edge) * (end - zero) / (end - edge)
        value = np.polyval(coefficients, stretched) / np.polyval(coefficients, end) * peak
        out = np.where(side, value, out)
    return out


def skew(a: np.ndarray) -> np.ndarray:
    """Fossen's S(a), the skew-symmetric matrix with S(a) b = a x b (Eq. 2.10)."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


@dataclass(frozen=True)
class Vehicle:
    """The numbers of one frame, straight from the TOML."""

    mass: float
    inertia: np.ndarray
    buoyancy: float
    r_b: np.ndarray
    added: np.ndarray
    d_lin: np.ndarray
    d_quad: np.ndarray
    positions: np.ndarray
    directions: np.ndarray
    thrust_model: str
    time_constant: float


def read_vehicle(frame: str, **changes) -> Vehicle:
    """The frame's parameters from the TOML; ``changes`` replace fields (for closed-form cases)."""
    document = tomllib.loads(VEHICLE_TOML.read_text())
    table, thruster = document[frame], document["thruster"]
    if (thruster["voltage_v"], thruster["pwm_min_us"], thruster["pwm_max_us"]) != (16.0, 1100.0, 1900.0):
        raise NotImplementedError("the oracle transcribes the T200 at 16 V with ArduSub's default PWM range")
    directions = np.array(table["thruster_directions"], float)
    vehicle = Vehicle(
        mass=float(table["mass"]),
        inertia=np.array(table["inertia"], float),
        buoyancy=float(table["buoyancy_n"]),
        r_b=np.array(table["centre_of_buoyancy"], float),
        added=np.array(table["added_mass"], float),
        d_lin=np.array(table["linear_damping"], float),
        d_quad=np.array(table["quadratic_damping"], float),
        positions=np.array(table["thruster_positions"], float),
        directions=directions / np.linalg.norm(directions, axis=1, keepdims=True),
        thrust_model=str(thruster["model"]),
        time_constant=float(thruster["time_constant_s"]),
    )
    return replace(
        vehicle,
        **{k: (np.asarray(v, float) if isinstance(v, list | tuple) else v) for k, v in changes.items()},
    )


def rotation(q: np.ndarray) -> np.ndarray:
    """Body-to-world rotation of a unit quaternion (w, x, y, z) (Fossen Eq. 2.72)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def thrust(vehicle: Vehicle, commands: np.ndarray) -> np.ndarray:
    """Static thrust (N) of thruster commands in [-1, 1]: ArduSub's PWM mapping and the T200 curve, or
    a straight line through the same maxima for the "linear" model."""
    a = np.clip(np.asarray(commands, float), -1.0, 1.0)
    if vehicle.thrust_model == "linear":
        return np.where(a >= 0.0, a * MAX_16V_N[0], a * MAX_16V_N[1])
    return t200_thrust(1500.0 + 400.0 * a)


def normalised(force: np.ndarray) -> np.ndarray:
    """Thrust (N) as a fraction of full forward (>= 0) or full reverse (< 0) thrust."""
    force = np.asarray(force, float)
    return np.where(force >= 0.0, force / MAX_16V_N[0], force / MAX_16V_N[1])


def simulate(
    vehicle: Vehicle,
    thruster_commands,
    duration: float,
    added_mass_coriolis: bool = True,
    current=(0.0, 0.0, 0.0),
    initial_velocity=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    initial_quaternion=(1.0, 0.0, 0.0, 0.0),
    dt: float = 0.02,
):
    """Integrate under constant thruster commands from the given body velocity and attitude.

    Returns (t, world positions (N, 3), quaternions (N, 4), body velocities nu (N, 6))."""
    n = len(vehicle.positions)
    # the curve is static and the lag acts on the thrust: lagged normalised thrust towards this target
    target = normalised(thrust(vehicle, thruster_commands))
    v_c = np.asarray(current, float)
    M = np.diag(np.concatenate([[vehicle.mass] * 3, vehicle.inertia])) + np.diag(vehicle.added)
    A11, A22 = np.diag(vehicle.added[:3]), np.diag(vehicle.added[3:])
    I_b = np.diag(vehicle.inertia)
    weight = vehicle.mass * GRAVITY

    def rhs(_t, s):
        q = s[3:7] / np.linalg.norm(s[3:7])
        R = rotation(q)
        nu, act = s[7:13], s[13:]
        v_c_body = R.T @ v_c
        nu_r = nu - np.concatenate([v_c_body, np.zeros(3)])
        v_r, w = nu_r[:3], nu_r[3:]
        C_RB = np.block([[vehicle.mass * skew(w), np.zeros((3, 3))], [np.zeros((3, 3)), -skew(I_b @ w)]])
        C_A = np.block([[np.zeros((3, 3)), -skew(A11 @ v_r)], [-skew(A11 @ v_r), -skew(A22 @ w)]])
        D = np.diag(vehicle.d_lin + vehicle.d_quad * np.abs(nu_r))
        f_g = R.T @ np.array([0.0, 0.0, -weight])
        f_b = R.T @ np.array([0.0, 0.0, vehicle.buoyancy])
        g = -np.concatenate([f_g + f_b, skew(vehicle.r_b) @ f_b])
        force = np.where(act >= 0.0, act * MAX_16V_N[0], act * MAX_16V_N[1])
        tau = np.concatenate(
            [
                force @ vehicle.directions,
                np.cross(vehicle.positions, force[:, None] * vehicle.directions).sum(0),
            ]
        )
        coriolis = (C_RB + (C_A if added_mass_coriolis else 0.0)) @ nu_r
        nudot_r = np.linalg.solve(M, tau - coriolis - D @ nu_r - g)
        # nu = nu_r + [R^T v_c; 0], and d/dt (R^T v_c) = -w x (R^T v_c)
        nudot = nudot_r - np.concatenate([skew(w) @ v_c_body, np.zeros(3)])
        qdot = 0.5 * np.array(
            [
                -q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                q[0] * w[1] - q[1] * w[2] + q[3] * w[0],
                q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
            ]
        )
        return np.concatenate([R @ nu[:3], qdot, nudot, (target - act) / vehicle.time_constant])

    state = np.zeros(13 + n)
    state[3:7] = initial_quaternion
    state[7:13] = initial_velocity
    t_eval = np.arange(0.0, duration + 1e-9, dt)
    # RK45 chooses its own steps for rtol 1e-8 (the thrust's lag and the commands are smooth after t = 0)
    sol = solve_ivp(rhs, (0.0, duration), state, t_eval=t_eval, rtol=1e-8, atol=1e-10)
    quaternions = sol.y[3:7].T / np.linalg.norm(sol.y[3:7].T, axis=1, keepdims=True)
    return sol.t, sol.y[:3].T, quaternions, sol.y[7:13].T
