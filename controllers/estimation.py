"""State estimation from a vehicle's own sensors: attitude, depth and dead-reckoned position.

The controllers run on this estimate, never on ground truth, so they behave alike on the simulator's
sensors and on a real vehicle's telemetry. Frames: world x north (towards the OSB tank's end wall), y
west (left), z up; body x forward, y left, z up. The input is a plain dict of readings, as
``envs.simulation.Simulation.sensors`` returns and as a MAVLink bridge can fill from telemetry:

    {"imu": {"accel": [ax, ay, az], "gyro": [p, q, r]},       # m/s^2 specific force, rad/s, body
     "depth": {"depth_m": d},                                   # m below the surface
     "dvl": {"velocity_body": [u, v, w] or None, "valid": bool},# m/s over ground, body
     "compass": {"heading_deg": h},                             # deg clockwise from north
     "thrust": {"force_body": [X, Y, Z]}}                       # N, body: the thrusters' commanded force

The last is no sensor: it is the force the vehicle's own thruster commands ask for (the simulator's
mixer output, or a real vehicle's SERVO_OUTPUT_RAW through its thrust curve). Without a DVL, or while the
DVL has no bottom lock, the estimator integrates it through the vehicle's motion model
(:class:`MotionModel`) for the velocity, so x and y still move and the controllers still damp.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np


@dataclass
class StateEstimate:
    """The estimated state: world position (m), roll-pitch-yaw (rad), body velocity (m/s) and rates, and
    the world-frame acceleration (m/s^2, gravity taken out of the accelerometer's specific force)."""

    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_body: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity_body: np.ndarray = field(default_factory=lambda: np.zeros(3))
    time_s: float = 0.0
    acceleration_world: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def yaw(self) -> float:
        """Yaw (rad), counter-clockwise from world +x seen from above."""
        return float(self.rpy[2])


STANDARD_GRAVITY = 9.81  # m/s^2, as the simulator's world uses


def cross3(a, b) -> np.ndarray:
    """The cross product of two 3-vectors (np.cross costs ten times more on vectors this small, and
    the estimator calls it every control period)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], float)


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Body-to-world rotation, z-y-x (yaw, then pitch, then roll)."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def wrap_angle(angle: float) -> float:
    """The angle in (-pi, pi]."""
    return math.atan2(math.sin(angle), math.cos(angle))


@dataclass(frozen=True)
class EstimatorParams:
    """Where the water surface is (world z, m), where the pressure sensor and the DVL sit on the body (m
    from the CG), how fast the accelerometer corrects the gyro's tilt, and the vehicle's motion model for
    dead reckoning without a DVL."""

    surface_z_m: float
    depth_sensor_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dvl_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_correction_rad_s: float = 0.2  # complementary filter crossover: gyro above, gravity below
    # the velocity without a DVL (None: x and y stand still while there is no DVL velocity)
    motion_model: MotionModel | None = None


@dataclass(frozen=True)
class MotionModel:
    """The vehicle's translational dynamics for dead reckoning without a DVL (model-aided navigation):
    per body axis k (surge, sway, heave), Fossen's decoupled

        (m + m_A)_k dv_k/dt = tau_k - (d_lin,k + d_quad,k |v_k|) v_k

    with tau the thrusters' commanded force plus the net buoyancy (world up, N) in body axes. The
    Coriolis and centripetal terms are left out (the vehicle is slow), and so is the thrusters' lag. The
    velocity is through the water: a current drifts the estimate by its own speed."""

    inertia: tuple[float, float, float]  # kg, M_RB + M_A along each body axis
    linear_damping: tuple[float, float, float]  # N s / m
    quadratic_damping: tuple[float, float, float]  # N s^2 / m^2
    net_buoyancy_n: float = 0.0  # buoyancy minus weight

    def step(self, velocity_body: np.ndarray, force_body, up_body: np.ndarray, dt: float) -> np.ndarray:
        """The body velocity ``dt`` seconds on, under ``force_body`` (N; thrust, without buoyancy), with
        ``up_body`` the world vertical in body axes. Semi-implicit Euler: the damping is taken at the new
        velocity, so the step is stable at any ``dt``."""
        v = np.asarray(velocity_body, float)
        force = np.asarray(force_body, float) + self.net_buoyancy_n * np.asarray(up_body, float)
        mass, linear, quadratic = self._arrays
        return (mass * v + dt * force) / (mass + dt * (linear + quadratic * np.abs(v)))

    @functools.cached_property
    def _arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # the coefficients as arrays once: step runs every control period
        return tuple(
            np.asarray(values, float)
            for values in (self.inertia, self.linear_damping, self.quadratic_damping)
        )


class DeadReckoning:
    """Attitude from gyro and gravity (a complementary filter; the body's own acceleration, from the
    DVL, taken out of the accelerometer) with the compass for yaw; z from the depth sensor; x and y by
    integrating the body velocity rotated into the world frame. The velocity is the DVL's; without a
    valid DVL reading it comes from ``params.motion_model`` and the ``thrust`` reading where both are
    there, and is otherwise held at its last value. Starts from a known pose."""

    def __init__(self, params: EstimatorParams, start_position, start_yaw: float = 0.0) -> None:
        self.params = params
        self.state = StateEstimate(position=np.asarray(start_position, float).copy())
        self.state.rpy[2] = start_yaw
        self._velocity_world = np.zeros(3)
        self._depth_sensor_position = np.asarray(params.depth_sensor_position, float)

    def update(self, readings: dict, dt: float) -> StateEstimate:
        """Fold in one step's readings (``dt`` seconds since the last) and return the estimate."""
        s = self.state
        imu = readings.get("imu")
        gyro = np.asarray(imu["gyro"], float) if imu is not None else s.angular_velocity_body
        dvl = readings.get("dvl")
        previous_velocity = s.velocity_body.copy()
        dvl_valid = dvl is not None and dvl.get("valid") and dvl.get("velocity_body") is not None
        thrust = readings.get("thrust")
        modelled = not dvl_valid and self.params.motion_model is not None and thrust is not None
        if dvl_valid:
            # the DVL measures its own velocity: take out the lever arm w x r_dvl of a turning vehicle
            s.velocity_body = np.asarray(dvl["velocity_body"], float) - cross3(gyro, self.params.dvl_position)
        elif modelled:
            up_body = rotation_from_rpy(*s.rpy)[2]  # the world vertical in body axes: R's last row
            s.velocity_body = self.params.motion_model.step(
                s.velocity_body, thrust["force_body"], up_body, dt
            )
        if imu is not None:
            s.angular_velocity_body = gyro
            roll, pitch = s.rpy[0] + gyro[0] * dt, s.rpy[1] + gyro[1] * dt
            # the accelerometer reads gravity plus the body's acceleration vdot + w x v (speeding up, a
            # turn at speed), which would otherwise read as a tilt: take it out, from the DVL's velocity
            body_acceleration = (s.velocity_body - previous_velocity) / dt + cross3(gyro, s.velocity_body)
            ax, ay, az = np.asarray(imu["accel"], float) - body_acceleration
            # gravity's direction in the body frame gives roll and pitch when the vehicle is not accelerating
            accel_roll, accel_pitch = math.atan2(ay, az), math.atan2(-ax, math.hypot(ay, az))
            k = min(1.0, self.params.tilt_correction_rad_s * dt)
            s.rpy[0] = roll + k * wrap_angle(accel_roll - roll)
            s.rpy[1] = pitch + k * wrap_angle(accel_pitch - pitch)
        compass = readings.get("compass")
        if compass is not None:
            s.rpy[2] = wrap_angle(-math.radians(compass["heading_deg"]))
        rotation = rotation_from_rpy(*s.rpy)  # the attitude is final from here on
        if imu is not None:
            specific_force = rotation @ np.asarray(imu["accel"], float)
            s.acceleration_world = specific_force - np.array([0.0, 0.0, STANDARD_GRAVITY])
        depth = readings.get("depth")
        if depth is not None:
            sensor_height = float(rotation[2] @ self._depth_sensor_position)
            s.position[2] = self.params.surface_z_m - float(depth["depth_m"]) - sensor_height
        if dvl_valid or modelled:
            self._velocity_world = rotation @ s.velocity_body
        s.position[:2] += self._velocity_world[:2] * dt
        s.time_s += dt
        return s
