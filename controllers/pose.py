"""Depth hold, heading hold and 4-DOF go-to-pose / station keeping, with gains from the Fossen model.

**Gains by rule, not by hand.** Each axis is the plant ``M xddot + D xdot = F`` with M the rigid-body
mass or inertia plus its added mass and D the linear damping (Fossen's parameters, from the vehicle
file). Its PID is placed by pole placement on a chosen bandwidth w and damping ratio zeta:

    kp = M w^2,   kd = max(0, 2 zeta M w - D),   ki = kp w / 8

so the closed loop has its poles near -zeta w +- w sqrt(1 - zeta^2) and an integral four times slower
than the loop, which removes the steady offset of the vehicle's net buoyancy or a current. The
bandwidth comes from the axis's thrust authority A (N or N m per unit pilot command, from the mixer
and the thruster layout): w = sqrt(A / (4 M x_ref)), so that an error of x_ref (1 m, or 1 rad) asks
for a quarter of the authority. zeta = 1 (critically damped). The quadratic damping, left out of the
design, only adds damping.

The outputs are body-frame forces and torques, turned into the normalised 6-DOF pilot command of
:mod:`maptidal.controllers.convention` through the inverse of each axis's thrust curve (the T200's deadband
and bend, :meth:`VehicleModel.pilot_command`), so the loops see a linear plant and the same command drives the
simulator's mixer and a real vehicle over MAVLink.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np

from .estimation import MotionModel, StateEstimate, rotation_from_rpy, wrap_angle
from .mixing import MixerParams, allocation_matrix, mix
from .pid import PID, PIDGains
from .thrusters import PwmRange, ThrustCurve
from .trajectory import MotionLimits, PoseReference, TrapezoidalProfile

# index of each body axis (x, y, z, roll, pitch, yaw) in the pilot command, and the sign that turns a
# body-frame force or torque into that pilot axis (sway is right = -y, pitch is nose up = -y torque,
# yaw is turn right = -z torque; maptidal.controllers.convention)
PILOT_SIGN = np.array([1.0, -1.0, 1.0, 1.0, -1.0, -1.0])
_COMMAND_GRID = np.linspace(0.0, 1.0, 101)


@dataclass(frozen=True)
class VehicleModel:
    """What the controllers need to know of a vehicle: the diagonal of M_RB + M_A, the linear and
    quadratic damping (Fossen, per body axis x, y, z, roll, pitch, yaw), and the thruster layout for the
    authority."""

    def damping_force(self, axis: int, speed: float) -> float:
        """Fossen's damping on one axis at ``speed``: (d_lin + d_quad |speed|) speed."""
        return (self.linear_damping[axis] + self.quadratic_damping[axis] * abs(speed)) * speed

    inertia: tuple[float, ...]
    linear_damping: tuple[float, ...]
    quadratic_damping: tuple[float, ...]
    thruster_positions: tuple[tuple[float, float, float], ...]
    thruster_directions: tuple[tuple[float, float, float], ...]
    max_forward_n: float
    max_reverse_n: float
    ardusub_frame: str
    # buoyancy minus weight (N): fed forward by depth control, as ArduPilot feeds its hover throttle
    net_buoyancy_n: float = 0.0
    # the thrusters' static curve through ArduSub's PWM mapping; None: thrust proportional to command
    thrust_curve: ThrustCurve | None = None
    pwm_range: PwmRange = field(default_factory=PwmRange)
    # the thrusters' first-order lag (s) behind their commands; 0: none
    thrust_lag_s: float = 0.0

    def thruster_forces(self, commands) -> np.ndarray:
        """Thrust (N) of each mixed thruster command in [-1, 1]."""
        c = np.asarray(commands, float)
        if self.thrust_curve is None:
            return np.where(c >= 0, c * self.max_forward_n, c * self.max_reverse_n)
        return self.thrust_curve.thrust_from_command(c, self.pwm_range)

    def body_force(self, commands) -> np.ndarray:
        """The body-frame force (N, x y z) that mixed thruster commands in [-1, 1] (M1 first) give; an
        (N, n_thrusters) batch of commands gives (N, 3)."""
        return self.thruster_forces(commands) @ _force_matrix(self).T

    def motion_model(self) -> MotionModel:
        """The translational part of this model, for dead reckoning without a DVL
        (:class:`maptidal.controllers.estimation.MotionModel`)."""
        return MotionModel(
            inertia=tuple(self.inertia[:3]),
            linear_damping=tuple(self.linear_damping[:3]),
            quadratic_damping=tuple(self.quadratic_damping[:3]),
            net_buoyancy_n=self.net_buoyancy_n,
            thrust_lag_s=self.thrust_lag_s,
        )

    @property
    def authority_table(self) -> np.ndarray:
        """``(2, 6, 101)``: the body force or torque magnitude that a pure pilot command of 0, 0.01 .. 1
        on each axis gives, for +command (row 0) and -command (row 1), through the mixer, the thrust
        curve and the thruster layout (worked out once per distinct model; monotone in the command)."""
        return _authority_table(self)

    @property
    def authority(self) -> tuple[np.ndarray, np.ndarray]:
        """Body force or torque at full pilot command on each axis: (for +1, for -1), as magnitudes."""
        table = self.authority_table
        return table[0, :, -1], table[1, :, -1]

    def pilot_command(self, wrench: np.ndarray) -> np.ndarray:
        """The normalised pilot command (6,) that gives a body wrench [F; M] axis by axis: the thrust
        curve is inverted (its deadband and bend), so the feedback loops see a linear plant, as
        thrust-linearising autopilots do. Clipped to [-1, 1]."""
        pilot = np.asarray(wrench, float) * PILOT_SIGN
        inverse = _inverse_tables(self)
        out = np.zeros(6)
        for axis in range(6):
            if pilot[axis] == 0:
                continue
            forces, levels = inverse[0 if pilot[axis] > 0 else 1][axis]
            if forces[-1] <= 0:
                continue
            level = float(np.interp(min(abs(pilot[axis]), forces[-1]), forces, levels))
            out[axis] = np.copysign(level, pilot[axis])
        return out.clip(-1.0, 1.0)


@functools.lru_cache(maxsize=64)
def _force_matrix(model: VehicleModel) -> np.ndarray:
    # thruster forces (N) to body force: the first three rows of the allocation matrix
    matrix = allocation_matrix(model.thruster_positions, model.thruster_directions)[:3].copy()
    matrix.setflags(write=False)
    return matrix


@functools.lru_cache(maxsize=64)
def _authority_table(model: VehicleModel) -> np.ndarray:
    # equal models (every controller of one vehicle) share one table: it costs 1,212 mixer calls
    matrix = allocation_matrix(model.thruster_positions, model.thruster_directions)
    params = MixerParams(model.ardusub_frame)
    table = np.zeros((2, 6, len(_COMMAND_GRID)))
    for row, sign in enumerate((1.0, -1.0)):
        for axis in range(6):
            for j, level in enumerate(_COMMAND_GRID):
                command = np.zeros(6)
                command[axis] = sign * level
                body = matrix @ model.thruster_forces(mix(command, params))
                table[row, axis, j] = abs(body[axis])  # pilot order is body order: x, y, z, r, p, y
    table = np.maximum.accumulate(table, axis=2)
    table.setflags(write=False)
    return table


@functools.lru_cache(maxsize=64)
def _inverse_tables(model: VehicleModel) -> tuple[tuple[tuple[np.ndarray, np.ndarray], ...], ...]:
    # per sign and axis, (force, command) points for np.interp, keeping the last point of every flat run
    # so that the inverse jumps the deadband at once
    table = _authority_table(model)
    out = []
    for row in range(2):
        axes = []
        for axis in range(6):
            forces = table[row, axis]
            keep = np.append(np.diff(forces) > 0, True)
            axes.append((forces[keep], _COMMAND_GRID[keep]))
        out.append(tuple(axes))
    return tuple(out)


def pole_placement_gains(
    inertia: float, damping: float, authority: float, reference_error: float = 1.0, zeta: float = 1.0
) -> PIDGains:
    """The module's gain rule for one axis (see the module docstring); the output is limited to the
    axis's authority."""
    if not (inertia > 0 and authority > 0):
        raise ValueError("pole placement needs a positive inertia and authority")
    bandwidth = math.sqrt(authority / (4.0 * inertia * reference_error))
    kp = inertia * bandwidth**2
    kd = max(0.0, 2.0 * zeta * inertia * bandwidth - damping)
    return PIDGains(
        kp=kp, ki=kp * bandwidth / 8.0, kd=kd, output_limit=authority, integral_limit=0.5 * authority
    )


class PoseController:
    """Holds or tracks a pose (x, y, z, yaw) on the estimated state; optionally holds roll level and
    pitch at the reference's pitch (the Heavy frame can; the standard frame has no pitch authority).

    Position is controlled in the world frame (x and y PIDs, z PID), the force rotated into the body
    frame by the estimated attitude, with feedforward of M a_ref + D v_ref from the reference.
    """

    def __init__(self, model: VehicleModel, hold_roll_pitch: bool | None = None) -> None:
        self.model = model
        self.authority = model.authority
        horizontal = min(self.authority[0][:2].min(), self.authority[1][:2].min())
        vertical = min(self.authority[0][2], self.authority[1][2])
        m, d = model.inertia, model.linear_damping
        self.axes = [
            PID(pole_placement_gains(m[0], d[0], horizontal)),
            PID(pole_placement_gains(m[1], d[1], horizontal)),
            PID(pole_placement_gains(m[2], d[2], vertical)),
        ]
        can_pitch = min(self.authority[0][4], self.authority[1][4]) > 0
        self.hold_roll_pitch = can_pitch if hold_roll_pitch is None else hold_roll_pitch
        # an axis with no authority (the standard frame's pitch) gets placeholder gains: it is never used,
        # since hold_roll_pitch is off there, and pilot_command gives it no command anyway
        self.attitude = [
            PID(pole_placement_gains(m[k], d[k], min(self.authority[0][k], self.authority[1][k]) or 1.0))
            for k in (3, 4, 5)
        ]

    def reset(self) -> None:
        """Forget every integral."""
        for pid in (*self.axes, *self.attitude):
            pid.reset()

    def reset_horizontal(self) -> None:
        """Forget the x and y integrals: for a hold without horizontal position feedback, where what they
        had built up would push on with nothing to stop it."""
        for pid in self.axes[:2]:
            pid.reset()

    def update(self, estimate: StateEstimate, reference: PoseReference, dt: float) -> np.ndarray:
        """The pilot command (6,) that drives the estimate towards the reference."""
        R = rotation_from_rpy(*estimate.rpy)
        velocity_world = R @ estimate.velocity_body
        m = np.asarray(self.model.inertia)
        force_world = np.zeros(3)
        for k, pid in enumerate(self.axes):
            # feedforward of the reference's acceleration and of the damping at its speed; the rigid-body
            # and added mass are taken along the world axis (yaw aligns them for small roll and pitch)
            feedforward = m[k] * reference.acceleration[k] + self.model.damping_force(
                k, reference.velocity[k]
            )
            if k == 2:
                feedforward -= self.model.net_buoyancy_n
            force_world[k] = pid.update(
                reference.position[k],
                estimate.position[k],
                dt,
                measured_rate=velocity_world[k] - reference.velocity[k],
                feedforward=feedforward,
            )
        wrench = np.zeros(6)
        wrench[:3] = R.T @ force_world
        rates = estimate.angular_velocity_body
        yaw_error = wrap_angle(reference.yaw - estimate.yaw)
        wrench[5] = self.attitude[2].update(
            0.0, 0.0, dt, measured_rate=rates[2] - reference.yaw_rate, error=yaw_error
        )
        if self.hold_roll_pitch:
            wrench[3] = self.attitude[0].update(0.0, estimate.rpy[0], dt, measured_rate=rates[0])
            wrench[4] = self.attitude[1].update(reference.pitch, estimate.rpy[1], dt, measured_rate=rates[1])
        return self.model.pilot_command(wrench)


class DepthHold:
    """Holds a depth (m below the surface) with the heave axis alone; other axes are left to the pilot.

    A new setpoint is not a step: the reference moves to it on a trapezoidal profile (``limits``), with
    feedforward of its acceleration and damping, as go-to-pose does, so a depth change does not
    overshoot.
    """

    def __init__(self, model: VehicleModel, limits: MotionLimits | None = None) -> None:
        self.model = model
        self.limits = limits or MotionLimits()
        self.authority = model.authority
        vertical = min(self.authority[0][2], self.authority[1][2])
        self.pid = PID(pole_placement_gains(model.inertia[2], model.linear_damping[2], vertical))
        self._target: float | None = None
        self._start = 0.0
        self._profile = TrapezoidalProfile(0.0, self.limits.max_speed, self.limits.max_accel)
        self._elapsed = 0.0

    def update(
        self, depth_setpoint_m: float, estimate: StateEstimate, surface_z_m: float, dt: float
    ) -> float:
        """The heave command in [-1, 1] (positive up)."""
        target = surface_z_m - depth_setpoint_m
        if self._target is None or abs(target - self._target) > 1e-3:
            here = estimate.position[2] if self._target is None else self._reference(self._elapsed)[0]
            self._start, self._target, self._elapsed = here, target, 0.0
            self._profile = TrapezoidalProfile(
                abs(target - here), self.limits.max_speed, self.limits.max_accel
            )
        self._elapsed += dt
        z_ref, v_ref, a_ref = self._reference(self._elapsed)
        vertical_speed = (rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body)[2]
        feedforward = self.model.inertia[2] * a_ref + self.model.damping_force(2, v_ref)
        feedforward -= self.model.net_buoyancy_n
        force = self.pid.update(
            z_ref, estimate.position[2], dt, measured_rate=vertical_speed - v_ref, feedforward=feedforward
        )
        return float(self.model.pilot_command(np.array([0, 0, force, 0, 0, 0]))[2])

    def _reference(self, t: float) -> tuple[float, float, float]:
        sign = 1.0 if (self._target or 0.0) >= self._start else -1.0
        travelled, speed, accel = self._profile.at(t)
        return self._start + sign * travelled, sign * speed, sign * accel


class HeadingHold:
    """Holds a yaw (rad, counter-clockwise from world +x) with the yaw axis alone."""

    def __init__(self, model: VehicleModel) -> None:
        self.model = model
        self.authority = model.authority
        torque = min(self.authority[0][5], self.authority[1][5])
        self.pid = PID(pole_placement_gains(model.inertia[5], model.linear_damping[5], torque))

    def update(self, yaw_setpoint: float, estimate: StateEstimate, dt: float) -> float:
        """The yaw command in [-1, 1] (positive turns right)."""
        error = wrap_angle(yaw_setpoint - estimate.yaw)
        torque = self.pid.update(0.0, 0.0, dt, measured_rate=estimate.angular_velocity_body[2], error=error)
        return float(self.model.pilot_command(np.array([0, 0, 0, 0, 0, torque]))[5])
