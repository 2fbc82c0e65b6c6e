"""An independent 6-DOF Fossen model of a BlueROV2, integrated with scipy's solve_ivp.

Written in the body frame with a quaternion, straight from Fossen (2011) Eq. 6.4
with diagonal matrices, with no MuJoCo: the test oracle for envs.hydrodynamics.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation


def simulate(vehicle, thruster_commands, duration, gravity=9.81, max_step=0.002):
    """Integrate from rest, level, under constant thruster commands: (t, positions, body velocities)."""
    n = vehicle.n_thrusters
    positions = np.asarray(vehicle.thruster_positions)
    directions = np.asarray(vehicle.thruster_directions)
    mass = np.array([vehicle.mass] * 3 + list(vehicle.inertia)) + np.asarray(vehicle.added_mass)
    dlin, dquad = np.asarray(vehicle.linear_damping), np.asarray(vehicle.quadratic_damping)
    inertia = np.asarray(vehicle.inertia)
    u = np.asarray(thruster_commands, float)
    tau_lag = vehicle.thruster.time_constant_s

    def rhs(_t, s):
        q = s[3:7] / np.linalg.norm(s[3:7])  # w, x, y, z
        R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        v, w, act = s[7:10], s[10:13], s[13:]
        force = np.where(act >= 0, act * vehicle.thruster.max_forward_n, act * vehicle.thruster.max_reverse_n)
        tau = np.concatenate([force @ directions, np.cross(positions, force[:, None] * directions).sum(0)])
        nu = np.concatenate([v, w])
        tau -= (dlin + dquad * np.abs(nu)) * nu
        up = R.T @ np.array([0.0, 0.0, 1.0])
        tau[:3] += (vehicle.buoyancy_n - vehicle.mass * gravity) * up
        tau[3:] += np.cross(vehicle.centre_of_buoyancy, vehicle.buoyancy_n * up)
        tau[:3] -= vehicle.mass * np.cross(w, v)
        tau[3:] -= np.cross(w, inertia * w)
        nudot = tau / mass
        qdot = 0.5 * np.array(
            [
                -q[1] * w[0] - q[2] * w[1] - q[3] * w[2],
                q[0] * w[0] + q[2] * w[2] - q[3] * w[1],
                q[0] * w[1] - q[1] * w[2] + q[3] * w[0],
                q[0] * w[2] + q[1] * w[1] - q[2] * w[0],
            ]
        )
        return np.concatenate([R @ v, qdot, nudot, (u - act) / tau_lag])

    state = np.zeros(13 + n)
    state[3] = 1.0
    t_eval = np.arange(0.0, duration + 1e-9, 0.02)
    sol = solve_ivp(rhs, (0.0, duration), state, t_eval=t_eval, max_step=max_step, rtol=1e-8, atol=1e-10)
    return sol.t, sol.y[:3].T, sol.y[7:13].T
