"""The flight stack of N robots at once, as numpy arrays with one row per robot: ArduSub's STABILIZE
(and MANUAL), the vectored-6DOF mixer and the dead-reckoning estimator.

Each class here is the N-row twin of a one-robot class, written as the same arithmetic on arrays, so
that N robots cost about what one does in Python (a batched environment,
``maptidal.envs.gym.batched``). The one-robot classes stay the reference:

- :class:`BatchedACPID` is :class:`maptidal.controllers.pid.ACPID`;
- :class:`BatchedStabilize` is :class:`maptidal.controllers.flight_modes.FlightController` in
  "stabilize" or "manual" (ALT_HOLD and POSHOLD are not batched);
- :func:`mix_batch` is :func:`maptidal.controllers.mixing.mix` for the vectored_6dof frame;
- :class:`BatchedDeadReckoning` is :class:`maptidal.controllers.estimation.DeadReckoning` with every
  sensor present (IMU, depth, compass; the DVL valid or not row by row) and a motion model.

Each ``load`` copies one robot's state from its one-robot twin, so a batch can start where a
one-robot object stands. ``tests/test_batched.py`` holds the twins to the same numbers.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .estimation import STANDARD_GRAVITY, DeadReckoning, EstimatorParams
from .flight_modes import (
    ATC_ACCEL_MAX_RAD_S2,
    ATC_ANGLE_P,
    ATC_RATE_ROLL_PITCH,
    ATC_RATE_YAW,
    HEADING_CAPTURE_DELAY_S,
    FlightController,
    ModeParams,
)
from .mixing import _ROLL_PITCH_THROTTLE, _YAW_FORWARD_LATERAL
from .pid import ACPID, ACPIDGains, lowpass_alpha

BATCHED_MODES = ("manual", "stabilize")


# ----- elementwise helpers: the scalar functions of the same names, on arrays ------------------------
def wrap_angles(angle: np.ndarray) -> np.ndarray:
    """Angles in (-pi, pi] (:func:`maptidal.controllers.estimation.wrap_angle`)."""
    return np.arctan2(np.sin(angle), np.cos(angle))


def dead_zones(stick: np.ndarray, width: float) -> np.ndarray:
    """:func:`maptidal.controllers.flight_modes.dead_zone` on an array of sticks."""
    magnitude = np.abs(stick) - width
    return np.where(magnitude <= 0.0, 0.0, np.copysign(np.minimum(1.0, magnitude / (1.0 - width)), stick))


def sqrt_controllers(error: np.ndarray, p: float, second_order_limit: float, dt: float) -> np.ndarray:
    """:func:`maptidal.controllers.pid.sqrt_controller` on an array of errors (p and the limit > 0)."""
    if not (p > 0.0 and second_order_limit > 0.0):
        raise ValueError("the batched sqrt controller needs p > 0 and a second-order limit > 0")
    linear_distance = second_order_limit / (p * p)
    magnitude = np.abs(error)
    curved = np.sqrt(2.0 * second_order_limit * np.maximum(magnitude - linear_distance / 2.0, 0.0))
    rate = np.where(magnitude > linear_distance, np.copysign(curved, error), error * p)
    if dt > 0.0:
        return np.maximum(-magnitude / dt, np.minimum(magnitude / dt, rate))
    return rate


def _bilinear_tensor(terms: dict[int, list[tuple[float, int, int]]], size_a: int, size_b: int, outputs: int):
    """The (size_a * size_b, outputs) matrix T with out_k = sum of coefficient a_i b_j over ``terms[k]``."""
    tensor = np.zeros((size_a * size_b, outputs))
    for k, products in terms.items():
        for coefficient, i, j in products:
            tensor[i * size_b + j, k] += coefficient
    tensor.setflags(write=False)
    return tensor


# a x b, q (x) d and R(q) as bilinear forms: one outer product and one matrix product per call, a few
# numpy calls instead of dozens (at N = 16 numpy's cost is the number of calls, not their size)
_CROSS = _bilinear_tensor(
    {0: [(1, 1, 2), (-1, 2, 1)], 1: [(1, 2, 0), (-1, 0, 2)], 2: [(1, 0, 1), (-1, 1, 0)]}, 3, 3, 3
)
_QUATERNION_PRODUCT = _bilinear_tensor(
    {
        0: [(1, 0, 0), (-1, 1, 1), (-1, 2, 2), (-1, 3, 3)],
        1: [(1, 0, 1), (1, 1, 0), (1, 2, 3), (-1, 3, 2)],
        2: [(1, 0, 2), (-1, 1, 3), (1, 2, 0), (1, 3, 1)],
        3: [(1, 0, 3), (1, 1, 2), (-1, 2, 1), (1, 3, 0)],
    },
    4,
    4,
    4,
)
_ROTATION = _bilinear_tensor(
    {
        0: [(-2, 2, 2), (-2, 3, 3)],
        1: [(2, 1, 2), (-2, 0, 3)],
        2: [(2, 1, 3), (2, 0, 2)],
        3: [(2, 1, 2), (2, 0, 3)],
        4: [(-2, 1, 1), (-2, 3, 3)],
        5: [(2, 2, 3), (-2, 0, 1)],
        6: [(2, 1, 3), (-2, 0, 2)],
        7: [(2, 2, 3), (2, 0, 1)],
        8: [(-2, 1, 1), (-2, 2, 2)],
    },
    4,
    4,
    9,
)
_IDENTITY_FLAT = np.eye(3).ravel()


def _outer_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    outer = a[..., :, None] * b[..., None, :]
    return outer.reshape(*outer.shape[:-2], -1)


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (N, 3) arrays (either may be one (3,) row)."""
    return _outer_rows(a, b) @ _CROSS


def rotations_from_quaternions(q: np.ndarray) -> np.ndarray:
    """(N, 3, 3) body-to-world rotations of (N, 4) unit quaternions (w, x, y, z)."""
    return (_outer_rows(q, q) @ _ROTATION + _IDENTITY_FLAT).reshape(-1, 3, 3)


def rpy_from_rotations(rotation: np.ndarray) -> np.ndarray:
    """(N, 3) roll, pitch, yaw (rad; z-y-x) of (N, 3, 3) rotations."""
    pitch = -np.arcsin(np.clip(rotation[:, 2, 0], -1.0, 1.0))
    roll = np.arctan2(rotation[:, 2, 1], rotation[:, 2, 2])
    yaw = np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])
    return np.stack((roll, pitch, yaw), axis=-1)


def rotate_quaternions(q: np.ndarray, rotation_vector: np.ndarray) -> np.ndarray:
    """:func:`maptidal.controllers.estimation.rotate_quaternion` row by row: q (x) exp(v / 2), normalised."""
    angle = np.sqrt(np.einsum("ij,ij->i", rotation_vector, rotation_vector))
    small = angle < 1e-12
    if small.any():
        cosine = np.where(small, 1.0, np.cos(angle / 2))
        scale = np.where(small, 0.5, np.sin(angle / 2) / np.where(small, 1.0, angle))
    else:  # the usual case, in fewer numpy calls (each costs a few microseconds whatever N)
        cosine, scale = np.cos(angle / 2), np.sin(angle / 2) / angle
    half = np.empty((len(angle), 4))
    half[:, 0] = cosine
    np.multiply(rotation_vector, scale[:, None], out=half[:, 1:])
    out = _outer_rows(q, half) @ _QUATERNION_PRODUCT
    return out / np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]


def mix_batch(pilot: np.ndarray) -> np.ndarray:
    """(N, 8) thruster commands of (N, 6) pilot commands through ArduSub's vectored_6dof mixer (the
    BlueROV2 Heavy's; :func:`maptidal.controllers.mixing.mix`)."""
    rpt = pilot @ _ROLL_PITCH_THROTTLE.T
    yfl = pilot @ _YAW_FORWARD_LATERAL.T
    rpt_max = np.maximum(1.0, np.abs(rpt).max(axis=1, keepdims=True))
    yfl_max = np.maximum(1.0, np.abs(yfl).max(axis=1, keepdims=True))
    return (rpt / rpt_max + yfl / yfl_max).clip(-1.0, 1.0)


# ----- the rate loops -------------------------------------------------------------------------------
class BatchedACPID:
    """N robots' AC_PID loops on A axes (one set of gains per axis): :class:`ACPID` on (N, A) arrays."""

    def __init__(self, gains: Sequence[ACPIDGains], n: int) -> None:
        self.gains = tuple(gains)
        column = lambda name: np.array([getattr(g, name) for g in self.gains], float)  # noqa: E731
        self.kp, self.ki, self.kd, self.imax = (column(name) for name in ("kp", "ki", "kd", "imax"))
        self._every_axis_integrates = bool((self.ki != 0.0).all())
        self._cutoffs = {
            name: column(name) for name in ("target_filter_hz", "error_filter_hz", "derivative_filter_hz")
        }
        shape = (n, len(self.gains))
        self.integrator = np.zeros(shape)
        self.reset_filter = np.ones(shape, bool)
        self.target, self.error, self.derivative = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        self._alphas: dict[float, tuple[np.ndarray, ...]] = {}

    def load(self, row: int, pids: Sequence[ACPID]) -> None:
        """Take row ``row``'s state from one robot's loops (one :class:`ACPID` per axis)."""
        for axis, pid in enumerate(pids):
            self.integrator[row, axis] = pid.integrator
            self.reset_filter[row, axis] = pid._reset_filter
            self.target[row, axis], self.error[row, axis] = pid._target, pid._error
            self.derivative[row, axis] = pid._derivative

    def _alpha(self, dt: float) -> tuple[np.ndarray, ...]:
        if dt not in self._alphas:
            self._alphas[dt] = tuple(
                np.array([lowpass_alpha(dt, hz) for hz in cutoffs]) for cutoffs in self._cutoffs.values()
            )
        return self._alphas[dt]

    def update(self, target: np.ndarray, measurement: np.ndarray, dt: float, limit: np.ndarray) -> np.ndarray:
        """The (N, A) outputs; 0 where an input is not finite, which leaves that loop as it was."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive time step, got {dt!r}")
        finite = np.isfinite(target) & np.isfinite(measurement)
        all_finite = bool(finite.all())  # the usual case: no masking needed
        if not all_finite:
            target, measurement = np.where(finite, target, 0.0), np.where(finite, measurement, 0.0)
        alpha_target, alpha_error, alpha_derivative = self._alpha(dt)
        filtered_target = self.target + alpha_target * (target - self.target)
        error = self.error + alpha_error * ((filtered_target - measurement) - self.error)
        slope = (error - self.error) / dt
        derivative = self.derivative + alpha_derivative * (slope - self.derivative)
        first = self.reset_filter
        resetting = bool(first.any())
        if resetting:  # the first sample after a reset sets the filters
            filtered_target = np.where(first, target, filtered_target)
            error = np.where(first, target - measurement, error)
            derivative = np.where(first, 0.0, derivative)
        shrinking = ((self.integrator > 0.0) & (error < 0.0)) | ((self.integrator < 0.0) & (error > 0.0))
        grown = np.minimum(np.maximum(self.integrator + error * self.ki * dt, -self.imax), self.imax)
        integrator = np.where(~limit | shrinking, grown, self.integrator)
        if not self._every_axis_integrates:
            integrator = np.where(self.ki != 0.0, integrator, 0.0)
        output = error * self.kp + integrator + derivative * self.kd
        if all_finite:
            self.target, self.error, self.derivative, self.integrator = (
                filtered_target,
                error,
                derivative,
                integrator,
            )
            if resetting:
                self.reset_filter = np.zeros_like(first)
            return output
        self.target = np.where(finite, filtered_target, self.target)
        self.error = np.where(finite, error, self.error)
        self.derivative = np.where(finite, derivative, self.derivative)
        self.integrator = np.where(finite, integrator, self.integrator)
        self.reset_filter = self.reset_filter & ~finite
        return np.where(finite, output, 0.0)


class BatchedStabilize:
    """N robots' flight controllers in STABILIZE (or MANUAL, where the pilot command goes straight to
    the mixer): :meth:`FlightController.update` on (N, 6) pilot commands."""

    def __init__(self, mode: str, n: int, params: ModeParams | None = None) -> None:
        if mode not in BATCHED_MODES:
            raise ValueError(f"the batched flight stack flies {BATCHED_MODES}, not {mode!r}")
        self.mode, self.params = mode, params or ModeParams()
        self.rate = BatchedACPID((ATC_RATE_ROLL_PITCH, ATC_RATE_ROLL_PITCH, ATC_RATE_YAW), n)
        self.saturated = np.zeros((n, 3), bool)
        self.time_s = np.zeros(n)
        self.heading = np.zeros(n)
        self.heading_set = np.zeros(n, bool)
        self.last_yaw_input_s = np.full(n, -math.inf)
        p = self.params
        self._dead_zone_widths = np.array([p.roll_pitch_dead_zone, p.roll_pitch_dead_zone, p.yaw_dead_zone])

    def load(self, row: int, controller: FlightController) -> None:
        """Take row ``row``'s state from one robot's :class:`FlightController`."""
        if controller.mode != self.mode:
            raise ValueError(f"row {row} flies {controller.mode}, this batch {self.mode}")
        self.rate.load(row, controller.rate)
        self.saturated[row] = controller._saturated
        self.time_s[row] = controller.time_s
        self.heading_set[row] = controller._heading is not None
        self.heading[row] = controller._heading if controller._heading is not None else 0.0
        self.last_yaw_input_s[row] = controller._last_yaw_input_s

    def update(self, pilot: np.ndarray, rpy: np.ndarray, rates: np.ndarray, dt: float) -> np.ndarray:
        """The (N, 6) mixer inputs for pilot commands (surge, sway, heave, roll, pitch, yaw) on the
        estimated attitude ``rpy`` (N, 3) and body rates ``rates`` (N, 3)."""
        self.time_s = self.time_s + dt
        if self.mode == "manual":
            return pilot
        p = self.params
        out = pilot.copy()
        angle_max = math.radians(p.max_lean_deg)
        # the roll, pitch and yaw sticks' dead zones at once (numpy's cost here is per call, not per row)
        sticks = dead_zones(pilot[:, 3:6], self._dead_zone_widths)
        roll, pitch = sticks[:, 0] * angle_max, sticks[:, 1] * angle_max
        total = np.hypot(roll, pitch)
        over = total > angle_max
        if over.any():
            safe_total = np.where(over, total, 1.0)
            roll = np.where(over, roll * angle_max / safe_total, roll)
            pitch = np.where(over, pitch * angle_max / safe_total, pitch)
        roll_target = np.arctan(np.cos(pitch) * np.tan(roll))
        yaw = rpy[:, 2]
        yaw_rate = -sticks[:, 2] * math.radians(p.max_yaw_rate_deg_s)
        stick = yaw_rate != 0.0
        capture = ~stick & (
            (self.time_s < self.last_yaw_input_s + HEADING_CAPTURE_DELAY_S) | ~self.heading_set
        )
        hold = ~stick & ~capture
        self.heading = np.where(stick | capture, yaw, self.heading)
        self.heading_set = self.heading_set | stick | capture
        self.last_yaw_input_s = np.where(stick, self.time_s, self.last_yaw_input_s)
        # the three angle loops at once: roll and pitch to their targets, yaw to the held heading
        angles = np.column_stack((roll_target, -pitch, self.heading))
        errors = wrap_angles(angles - rpy)
        targets = sqrt_controllers(errors, ATC_ANGLE_P, ATC_ACCEL_MAX_RAD_S2, dt)
        targets[:, 2] = np.where(hold, targets[:, 2], yaw_rate)
        outputs = self.rate.update(targets, rates, dt, limit=self.saturated)
        self.saturated = np.abs(outputs) >= 1.0
        out[:, 3], out[:, 4], out[:, 5] = outputs[:, 0], -outputs[:, 1], -outputs[:, 2]
        return out.clip(-1.0, 1.0)


# ----- the estimator --------------------------------------------------------------------------------
class BatchedDeadReckoning:
    """N robots' :class:`DeadReckoning` estimators, every sensor present, the DVL valid or not per row;
    without a valid DVL a row's velocity comes from the motion model and the commanded thrust."""

    def __init__(self, params: EstimatorParams, n: int) -> None:
        if params.motion_model is None:
            raise ValueError("the batched estimator needs a motion model (EstimatorParams.motion_model)")
        self.params = params
        self.quaternion = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
        self.position, self.rpy = np.zeros((n, 3)), np.zeros((n, 3))
        self.velocity_body, self.angular_velocity_body = np.zeros((n, 3)), np.zeros((n, 3))
        self.acceleration_world, self.velocity_world = np.zeros((n, 3)), np.zeros((n, 3))
        self.time_s = np.zeros(n)
        self._dvl_position = np.asarray(params.dvl_position, float)
        self._depth_sensor_position = np.asarray(params.depth_sensor_position, float)
        model = params.motion_model
        self._mass, self._linear, self._quadratic = (
            np.asarray(v, float) for v in (model.inertia, model.linear_damping, model.quadratic_damping)
        )
        self._net_buoyancy_n = model.net_buoyancy_n
        self._thrust_lag_s = model.thrust_lag_s
        # each row's commanded force through the thrusters' lag, and whether its last period ran on the
        # model (DeadReckoning.thrust_lagged, modelled_last)
        self.thrust_lagged = np.zeros((n, 3))
        self.modelled_last = np.ones(n, bool)

    def load(self, row: int, estimator: DeadReckoning) -> None:
        """Take row ``row``'s state from one robot's :class:`DeadReckoning`."""
        if estimator.params != self.params:
            raise ValueError(f"row {row}'s estimator has other parameters than this batch's")
        s = estimator.state
        self.quaternion[row] = estimator.quaternion
        self.position[row], self.rpy[row] = s.position, s.rpy
        self.velocity_body[row], self.angular_velocity_body[row] = s.velocity_body, s.angular_velocity_body
        self.acceleration_world[row], self.velocity_world[row] = (
            s.acceleration_world,
            estimator._velocity_world,
        )
        self.time_s[row] = s.time_s
        self.thrust_lagged[row] = estimator.thrust_lagged
        self.modelled_last[row] = estimator.modelled_last

    def update(
        self,
        accel: np.ndarray,
        gyro: np.ndarray,
        depth_m: np.ndarray,
        heading_deg: np.ndarray,
        dvl_valid: np.ndarray,
        dvl_velocity: np.ndarray,
        thrust_force: np.ndarray | None,
        dt: float,
    ) -> None:
        """Fold in one control period's readings, (N, 3) or (N,) each: :meth:`DeadReckoning.update`.
        ``thrust_force`` (the commanded body force, N) is only read where the DVL has no lock, and may be
        None while every row's DVL reading is valid."""
        p = self.params
        previous_velocity = self.velocity_body
        velocity = dvl_velocity - cross_rows(gyro, self._dvl_position)
        if not dvl_valid.all():
            if thrust_force is None:
                raise ValueError("a DVL reading is invalid: the motion model needs the thrust force")
            # the motion model (MotionModel.step) where the DVL has no lock
            up_body = rotations_from_quaternions(self.quaternion)[:, 2]
            force = thrust_force
            if self._thrust_lag_s > 0.0:
                settled = self.thrust_lagged + (1.0 - math.exp(-dt / self._thrust_lag_s)) * (
                    force - self.thrust_lagged
                )
                lagged = np.where(self.modelled_last[:, None], settled, force)
                self.thrust_lagged = np.where(dvl_valid[:, None], self.thrust_lagged, lagged)
                force = lagged
            force = force + self._net_buoyancy_n * up_body
            momentum = self._mass * previous_velocity
            force = force - cross_rows(gyro, momentum)
            damping = self._linear + self._quadratic * np.abs(previous_velocity)
            modelled = (momentum + dt * force) / (self._mass + dt * damping)
            velocity = np.where(dvl_valid[:, None], velocity, modelled)
        self.velocity_body, self.angular_velocity_body = velocity, gyro
        self.modelled_last = ~dvl_valid
        self.quaternion = rotate_quaternions(self.quaternion, gyro * dt)
        rotation = rotations_from_quaternions(self.quaternion)
        body_acceleration = (velocity - previous_velocity) / dt + cross_rows(gyro, velocity)
        measured_up = accel - body_acceleration
        norm = np.sqrt(np.einsum("ij,ij->i", measured_up, measured_up))
        tilt_gain = min(p.tilt_correction_rad_s, 1.0 / dt)
        usable = norm > 1e-6  # an accelerometer reading that says where up is
        if usable.all():
            correction = tilt_gain * cross_rows(measured_up / norm[:, None], rotation[:, 2])
        else:
            safe_norm = np.where(usable, norm, 1.0)[:, None]
            correction = np.where(
                usable[:, None], tilt_gain * cross_rows(measured_up / safe_norm, rotation[:, 2]), 0.0
            )
        yaw = np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])
        error = wrap_angles(-np.radians(heading_deg) - yaw)
        heading_gain = min(p.heading_correction_rad_s, 1.0 / dt)
        correction = correction + (heading_gain * error)[:, None] * rotation[:, 2]
        turned = correction.any(axis=1)
        if turned.all():  # the usual case
            self.quaternion = rotate_quaternions(self.quaternion, correction * dt)
            rotation = rotations_from_quaternions(self.quaternion)
        elif turned.any():
            self.quaternion = np.where(
                turned[:, None], rotate_quaternions(self.quaternion, correction * dt), self.quaternion
            )
            rotation = rotations_from_quaternions(self.quaternion)
        self.rpy = rpy_from_rotations(rotation)
        self.acceleration_world = np.einsum("nij,nj->ni", rotation, accel) - np.array(
            [0.0, 0.0, STANDARD_GRAVITY]
        )
        sensor_height = rotation[:, 2] @ self._depth_sensor_position
        position = self.position.copy()
        position[:, 2] = p.surface_z_m - depth_m - sensor_height
        self.velocity_world = np.einsum("nij,nj->ni", rotation, velocity)
        position[:, :2] += self.velocity_world[:, :2] * dt
        self.position = position
        self.time_s = self.time_s + dt
