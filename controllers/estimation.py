"""State estimation from a vehicle's own sensors: attitude, depth and dead-reckoned position.

The controllers run on this estimate, never on ground truth, so they behave alike on the simulator's
sensors and on a real vehicle's telemetry. Frames: world x north (towards the OSB tank's end wall), y
west (left), z up; body x forward, y left, z up. The input is a plain dict of readings, as
``maptidal.envs.simulation.Simulation.sensors`` returns and as a MAVLink bridge can fill from telemetry:

    {"imu": {"accel": [ax, ay, az], "gyro": [p, q, r],        # m/s^2 specific force, rad/s, body
             "accel_mean": [ax, ay, az]},                       # optional: the period's mean specific force
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
    from the CG), how fast gravity and the compass correct the gyro's attitude, and the vehicle's
    motion model for dead reckoning without a DVL."""

    surface_z_m: float
    depth_sensor_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dvl_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # complementary filter crossovers (rad/s): the gyro above, gravity (roll, pitch) and the compass
    # (yaw) below. At 0.2 rad/s a gyro bias b leaves a b / 0.2 error (1e-4 rad/s: 0.03 deg), and the
    # compass's 1 deg white noise at 50 Hz comes through as about 0.05 deg (sigma sqrt(k dt / 2))
    tilt_correction_rad_s: float = 0.2
    heading_correction_rad_s: float = 0.2
    # the velocity without a DVL (None: x and y stand still while there is no DVL velocity)
    motion_model: MotionModel | None = None

    def __post_init__(self) -> None:
        for name in ("tilt_correction_rad_s", "heading_correction_rad_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")


@dataclass(frozen=True)
class MotionModel:
    """The vehicle's translational dynamics for dead reckoning without a DVL (model-aided navigation):
    per body axis k (surge, sway, heave), Fossen's decoupled

        (m + m_A)_k dv_k/dt = tau_k - (d_lin,k + d_quad,k |v_k|) v_k

    with tau the thrusters' commanded force plus the net buoyancy (world up, N) in body axes. Given the
    body's angular velocity w (the gyro), the translational Coriolis and centripetal force of Fossen's
    C_RB + C_A for a diagonal mass, -w x ((m + m_A) v), is added: a turning vehicle's momentum keeps its
    direction in the world while the body turns under it. Leaving it out made the model-aided step of a
    robot turning 10 deg/s at 0.25 m/s 1 to 2 cm/s off along its surge axis (session 17,
    ``tests/bench/diag_localisation.py``). The thrusters' first-order lag behind their commands,
    ``thrust_lag_s``, is the estimator's to apply (:class:`DeadReckoning` filters the commanded force
    with it before :meth:`step`): without it the model's acceleration leads the vehicle's by the lag at
    every change of command, by 0.1 to 0.3 m/s^2 over half a second in a mission's flight, and by
    0.02 to 0.06 m/s^2 with it (CHANGELOG, session 36). The velocity is through the water: a current
    drifts the estimate by its own speed."""

    inertia: tuple[float, float, float]  # kg, M_RB + M_A along each body axis
    linear_damping: tuple[float, float, float]  # N s / m
    quadratic_damping: tuple[float, float, float]  # N s^2 / m^2
    net_buoyancy_n: float = 0.0  # buoyancy minus weight
    thrust_lag_s: float = 0.0  # the thrusters' first-order lag behind their commands (s); 0: none

    def step(
        self,
        velocity_body: np.ndarray,
        force_body,
        up_body: np.ndarray,
        dt: float,
        angular_velocity_body: np.ndarray | None = None,
    ) -> np.ndarray:
        """The body velocity ``dt`` seconds on, under ``force_body`` (N; thrust, without buoyancy), with
        ``up_body`` the world vertical in body axes and, when given, the body's angular velocity (rad/s)
        for the Coriolis and centripetal force. Semi-implicit Euler: the damping is taken at the new
        velocity, so the step is stable at any ``dt``; the Coriolis force at the old one."""
        v = np.asarray(velocity_body, float)
        force = np.asarray(force_body, float) + self.net_buoyancy_n * np.asarray(up_body, float)
        mass, linear, quadratic = self._arrays
        momentum = mass * v
        if angular_velocity_body is not None:
            force = force - cross3(angular_velocity_body, momentum)
        return (momentum + dt * force) / (mass + dt * (linear + quadratic * np.abs(v)))

    def perturbed(self, fraction: float) -> MotionModel:
        """This model with its coefficients off by ``fraction`` the way that misleads most: the inertia
        ``fraction`` too large, both dampings and the net buoyancy ``fraction`` too small (the estimator
        of a vehicle whose coefficients are known only so well; ``fraction`` in [0, 1))."""
        if not (0.0 <= fraction < 1.0):
            raise ValueError(f"a motion model's error must be in [0, 1), got {fraction!r}")
        more, less = 1.0 + fraction, 1.0 - fraction
        return MotionModel(
            inertia=tuple(more * v for v in self.inertia),
            linear_damping=tuple(less * v for v in self.linear_damping),
            quadratic_damping=tuple(less * v for v in self.quadratic_damping),
            net_buoyancy_n=less * self.net_buoyancy_n,
            thrust_lag_s=self.thrust_lag_s,
        )

    @functools.cached_property
    def _arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        # the coefficients as arrays once: step runs every control period
        return tuple(
            np.asarray(values, float)
            for values in (self.inertia, self.linear_damping, self.quadratic_damping)
        )


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The body-to-world unit quaternion (w, x, y, z) of z-y-x roll, pitch, yaw."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def rotation_from_quaternion(q) -> np.ndarray:
    """The body-to-world rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (rad; z-y-x) of a body-to-world rotation matrix."""
    R = rotation
    pitch = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    return math.atan2(float(R[2, 1]), float(R[2, 2])), pitch, math.atan2(float(R[1, 0]), float(R[0, 0]))


def rotate_quaternion(q: np.ndarray, rotation_vector) -> np.ndarray:
    """``q`` turned by the body-frame rotation vector (axis times angle, rad): q (x) exp(v / 2),
    exact for a rate held constant over the step, normalised."""
    vx, vy, vz = (float(v) for v in rotation_vector)
    angle = math.sqrt(vx * vx + vy * vy + vz * vz)
    if angle < 1e-12:
        c, s = 1.0, 0.5  # sin(a/2)/a -> 1/2
    else:
        c, s = math.cos(angle / 2), math.sin(angle / 2) / angle
    dw, dx, dy, dz = c, s * vx, s * vy, s * vz
    w, x, y, z = (float(v) for v in q)
    out = np.array(
        [
            w * dw - x * dx - y * dy - z * dz,
            w * dx + x * dw + y * dz - z * dy,
            w * dy - x * dz + y * dw + z * dx,
            w * dz + x * dy - y * dx + z * dw,
        ]
    )
    return out / math.sqrt(float(out @ out))


class DeadReckoning:
    """Attitude, depth and dead-reckoned position from a vehicle's own sensors. Starts from a known pose.

    - **Attitude** is a unit quaternion that integrates the gyro's body rates exactly (q <- q (x)
      exp(w dt / 2)), so roll, pitch and yaw stay right when the vehicle leans while it turns: body rates
      are not Euler-angle rates. Gravity and the compass correct it in a complementary filter of the
      Mahony kind, the structure of ArduPilot's DCM attitude estimator (AP_AHRS_DCM, after Premerlani and
      Bizard's "Direction Cosine Matrix IMU: Theory"): the accelerometer's gravity direction, with the
      body's own acceleration (from the DVL or the motion model) taken out, turns the estimated vertical
      towards it at ``tilt_correction_rad_s``, and the compass's heading turns the yaw about the world
      vertical at ``heading_correction_rad_s``, which leaves roll and pitch alone.
    - **z** comes from the depth sensor, through its lever arm.
    - **x and y** integrate the body velocity rotated into the world frame. The velocity is the DVL's;
      without a valid DVL reading it comes from ``params.motion_model`` and the ``thrust`` reading where
      both are there (the commanded force through the thrusters' lag, ``MotionModel.thrust_lag_s``),
      and is otherwise held at its last value.
    """

    def __init__(self, params: EstimatorParams, start_position, start_yaw: float = 0.0) -> None:
        self.params = params
        self.state = StateEstimate(position=np.asarray(start_position, float).copy())
        self.state.rpy[2] = start_yaw
        self.quaternion = quaternion_from_rpy(0.0, 0.0, start_yaw)
        self._velocity_world = np.zeros(3)
        self._depth_sensor_position = np.asarray(params.depth_sensor_position, float)
        # the commanded force through the thrusters' lag (MotionModel.thrust_lag_s), from rest, and
        # whether the last period ran on the model (after a DVL period the force is taken as settled)
        self.thrust_lagged = np.zeros(3)
        self.modelled_last = True

    def set_attitude(self, roll: float, pitch: float, yaw: float) -> None:
        """Restart the attitude estimate at ``roll``, ``pitch``, ``yaw`` (rad, z-y-x)."""
        self.quaternion = quaternion_from_rpy(roll, pitch, yaw)
        self.state.rpy[:] = (roll, pitch, yaw)

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
        rotation = rotation_from_quaternion(self.quaternion)
        if dvl_valid:
            # the DVL measures its own velocity: take out the lever arm w x r_dvl of a turning vehicle
            s.velocity_body = np.asarray(dvl["velocity_body"], float) - cross3(gyro, self.params.dvl_position)
        elif modelled:
            up_body = rotation[2]  # the world vertical in body axes: R's last row
            force = np.asarray(thrust["force_body"], float)
            lag = self.params.motion_model.thrust_lag_s
            if lag > 0.0:
                if self.modelled_last:
                    self.thrust_lagged = self.thrust_lagged + (1.0 - math.exp(-dt / lag)) * (
                        force - self.thrust_lagged
                    )
                else:
                    self.thrust_lagged = force.copy()
                force = self.thrust_lagged
            s.velocity_body = self.params.motion_model.step(s.velocity_body, force, up_body, dt, gyro)
        self.modelled_last = modelled
        if imu is not None:
            s.angular_velocity_body = gyro
            # predict: the gyro's turn over the period; then correct, against readings taken at its end
            self.quaternion = rotate_quaternion(self.quaternion, gyro * dt)
            rotation = rotation_from_quaternion(self.quaternion)
            correction = np.zeros(3)
            # the accelerometer reads gravity plus the body's acceleration vdot + w x v (speeding up, a
            # turn at speed), which would otherwise read as a tilt: take it out, from the body velocity
            body_acceleration = (s.velocity_body - previous_velocity) / dt + cross3(gyro, s.velocity_body)
            measured_up = np.asarray(imu["accel"], float) - body_acceleration
            norm = math.sqrt(float(measured_up @ measured_up))
            if norm > 1e-6:
                # Mahony's correction: the rate that turns the estimated vertical towards the measured
                # one, |e| = sin(angle between them), so the tilt error decays at the crossover rate
                k = min(self.params.tilt_correction_rad_s, 1.0 / dt)
                correction += k * cross3(measured_up / norm, rotation[2])
            compass = readings.get("compass")
            if compass is not None:
                # a turn about the world vertical (its body axes: R's last row) changes the z-y-x yaw
                # alone
                yaw = math.atan2(float(rotation[1, 0]), float(rotation[0, 0]))
                error = wrap_angle(-math.radians(compass["heading_deg"]) - yaw)
                k = min(self.params.heading_correction_rad_s, 1.0 / dt)
                correction += k * error * rotation[2]
            if correction.any():
                self.quaternion = rotate_quaternion(self.quaternion, correction * dt)
                rotation = rotation_from_quaternion(self.quaternion)
        elif readings.get("compass") is not None:
            # no gyro to filter with: take the compass's heading as it is
            roll, pitch, _ = rpy_from_rotation(rotation)
            yaw = wrap_angle(-math.radians(readings["compass"]["heading_deg"]))
            self.quaternion = quaternion_from_rpy(roll, pitch, yaw)
            rotation = rotation_from_quaternion(self.quaternion)
        s.rpy[:] = rpy_from_rotation(rotation)  # the attitude is final from here on
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
