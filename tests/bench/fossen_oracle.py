"""An independent 6-DOF Fossen model of a BlueROV2, integrated with scipy's solve_ivp: the test oracle
for envs.hydrodynamics.

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
- tau: each thruster's force along its direction at its position; thrust = a * 50 N forward,
  a * 40 N reverse (T200), a the command after a first-order lag.

S(a) is the skew-symmetric matrix with S(a) b = a x b. The parameters are read from
assets/bluerov2/bluerov2.toml here, with tomllib, so that this oracle shares no parameter handling with
envs.vehicle either.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

VEHICLE_TOML = Path(__file__).resolve().parents[2] / "assets" / "bluerov2" / "bluerov2.toml"
GRAVITY = 9.81


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
    max_forward: float
    max_reverse: float
    time_constant: float


def read_vehicle(frame: str, **changes) -> Vehicle:
    """The frame's parameters from the TOML; ``changes`` replace fields (for closed-form cases)."""
    document = tomllib.loads(VEHICLE_TOML.read_text())
    table, thruster = document[frame], document["thruster"]
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
        max_forward=float(thruster["max_forward_n"]),
        max_reverse=float(thruster["max_reverse_n"]),
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
    u = np.asarray(thruster_commands, float)
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
        g = -np.concatenate([f_g + f_b, np.cross(vehicle.r_b, f_b)])
        force = np.where(act >= 0.0, act * vehicle.max_forward, act * vehicle.max_reverse)
        tau = np.concatenate(
            [
                force @ vehicle.directions,
                np.cross(vehicle.positions, force[:, None] * vehicle.directions).sum(0),
            ]
        )
        coriolis = (C_RB + (C_A if added_mass_coriolis else 0.0)) @ nu_r
        nudot_r = np.linalg.solve(M, tau - coriolis - D @ nu_r - g)
        # nu = nu_r + [R^T v_c; 0], and d/dt (R^T v_c) = -w x (R^T v_c)
        nudot = nudot_r - np.concatenate([np.cross(w, v_c_body), np.zeros(3)])
        qdot = 0.5 * np.array(
            [
                -q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                q[0] * w[1] - q[1] * w[2] + q[3] * w[0],
                q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
            ]
        )
        return np.concatenate([R @ nu[:3], qdot, nudot, (u - act) / vehicle.time_constant])

    state = np.zeros(13 + n)
    state[3:7] = initial_quaternion
    state[7:13] = initial_velocity
    t_eval = np.arange(0.0, duration + 1e-9, dt)
    sol = solve_ivp(rhs, (0.0, duration), state, t_eval=t_eval, max_step=0.002, rtol=1e-8, atol=1e-10)
    quaternions = sol.y[3:7].T / np.linalg.norm(sol.y[3:7].T, axis=1, keepdims=True)
    return sol.t, sol.y[:3].T, quaternions, sol.y[7:13].T
