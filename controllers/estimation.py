"""State estimation from a vehicle's own sensors: attitude, depth and dead-reckoned position.

The controllers run on this estimate, never on ground truth, so they behave alike on the simulator's
sensors and on a real vehicle's telemetry. Frames: world x north (towards the OSB tank's end wall), y
west (left), z up; body x forward, y left, z up. The input is a plain dict of readings, as
``envs.simulation.Simulation.sensors`` returns and as a MAVLink bridge can fill from telemetry:

    {"imu": {"accel": [ax, ay, az], "gyro": [p, q, r]},       # m/s^2 specific force, rad/s, body
     "depth": {"depth_m": d},                                   # m below the surface
     "dvl": {"velocity_body": [u, v, w] or None, "valid": bool},# m/s over ground, body
     "compass": {"heading_deg": h}}                             # deg clockwise from north
"""

from __future__ import annotations

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
    from the CG), and how fast the accelerometer corrects the gyro's tilt."""

    surface_z_m: float
    depth_sensor_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dvl_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tilt_correction_rad_s: float = 0.2  # complementary filter crossover: gyro above, gravity below


class DeadReckoning:
    """Attitude from gyro and gravity (a complementary filter; the body's own acceleration, from the
    DVL, taken out of the accelerometer) with the compass for yaw; z from the
    depth sensor; x and y by integrating the DVL's velocity rotated into the world frame (held at its
    last value while the DVL has no bottom lock). Starts from a known pose."""

    def __init__(self, params: EstimatorParams, start_position, start_yaw: float = 0.0) -> None:
        self.params = params
        self.state = StateEstimate(position=np.asarray(start_position, float).copy())
        self.state.rpy[2] = start_yaw
        self._velocity_world = np.zeros(3)

    def update(self, readings: dict, dt: float) -> StateEstimate:
        """Fold in one step's readings (``dt`` seconds since the last) and return the estimate."""
        s = self.state
        imu = readings.get("imu")
        gyro = np.asarray(imu["gyro"], float) if imu is not None else s.angular_velocity_body
        dvl = readings.get("dvl")
        previous_velocity = s.velocity_body.copy()
        if dvl is not None and dvl.get("valid") and dvl.get("velocity_body") is not None:
            # the DVL measures its own velocity: take out the lever arm w x r_dvl of a turning vehicle
            s.velocity_body = np.asarray(dvl["velocity_body"], float) - cross3(gyro, self.params.dvl_position)
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
        if imu is not None:
            specific_force = rotation_from_rpy(*s.rpy) @ np.asarray(imu["accel"], float)
            s.acceleration_world = specific_force - np.array([0.0, 0.0, STANDARD_GRAVITY])
        depth = readings.get("depth")
        if depth is not None:
            sensor_height = (rotation_from_rpy(*s.rpy) @ np.asarray(self.params.depth_sensor_position))[2]
            s.position[2] = self.params.surface_z_m - float(depth["depth_m"]) - sensor_height
        if dvl is not None and dvl.get("valid") and dvl.get("velocity_body") is not None:
            self._velocity_world = rotation_from_rpy(*s.rpy) @ s.velocity_body
        s.position[:2] += self._velocity_world[:2] * dt
        s.time_s += dt
        return s
