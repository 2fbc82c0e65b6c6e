"""ArduSub's position controller (AC_PosControl with ArduSub's defaults), for ALT_HOLD and POSHOLD.

Structure and gains from ArduPilot's ``libraries/AC_AttitudeControl/AC_PosControl.cpp`` (the ArduSub
branch of its defaults), ``ArduSub/mode_althold.cpp`` and ``ArduSub/motors.cpp``
(``translate_pos_control_rp``), ArduPilot master (ArduSub 4.7.0-dev):

- **vertical** (:class:`VerticalPositionControl`): the target comes from the pilot's climb rate, as in
  ArduSub 4.5 and later (``D_set_pos_target_from_climb_rate_cms``): the desired climb rate moves towards
  the pilot's at PILOT_ACCEL_Z (100 cm/s^2) and the target depth integrates it, so when the stick is
  centred the target stops where the climb stops (no depth is captured at release, and none comes back).
  While the throttle is saturated in the direction the target moves, the target and its rate stand
  still (AP_Math's ``update_pos_vel_accel`` with the motors' limit), so it never runs away from a
  vehicle that cannot follow. Then the cascade: a position P (PSC_POSZ_P = 3.0 /s) through
  ``sqrt_controller`` with the correction limits ALT_HOLD sets (the pilot's speeds, PILOT_SPEED_UP =
  PILOT_SPEED_DN = 500 cm/s, and PILOT_ACCEL_Z), plus the target's climb rate as feedforward, gives a
  climb-rate target; a velocity P (PSC_VELZ_P = 8.0 /s) an acceleration target; and an acceleration PID
  on the measured vertical acceleration (PSC_ACCZ_P = 0.5, PSC_ACCZ_I = 0.1, PSC_ACCZ_IMAX = 100,
  working in cm/s^2 with its output scaled by 0.001) the throttle about ArduSub's hover point of 0.5,
  which the 6-DOF mixer reads as the bidirectional heave command 2 (throttle - 0.5). The target stays
  SURFACE_DEPTH (10 cm) below the surface, ArduSub's default limit;
- **horizontal**: a position P (PSC_POSXY_P = 1.0 /s) gives a velocity target, a velocity PID
  (PSC_VELXY_P = 1.0, PSC_VELXY_I = 0.5, PSC_VELXY_D = 0, PSC_VELXY_IMAX = 1000 cm/s^2) an acceleration
  target, which AC_PosControl turns into lean angles atan(a / g); ArduSub does not lean but sends them,
  divided by ANGLE_MAX (4500 cdeg, ArduPilot's DEFAULT_ANGLE_MAX), to the forward and lateral thrusters.

Left out: the jerk limit of AC_PosControl's shaping (the climb rate moves at the acceleration limit
alone) and the velocity loop's I and D terms (0 by default for the vertical axis in our reading). The
horizontal speed limit of the position P stage (``max_speed_m_s``) is our choice.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .estimation import StateEstimate, rotation_from_rpy
from .pid import inverse_sqrt_controller, sqrt_controller

GRAVITY = 9.80665


@dataclass(frozen=True)
class PosControlGains:
    """ArduSub's PSC_* and PILOT_* defaults (module docstring) and our horizontal speed limit."""

    pos_z_p: float = 3.0
    vel_z_p: float = 8.0
    acc_z_p: float = 0.5
    acc_z_i: float = 0.1
    acc_z_imax: float = 100.0  # in the PID's units: 100 = 0.1 of throttle
    pilot_speed_up_m_s: float = 5.0  # PILOT_SPEED_UP 500 cm/s (ArduSub config.h PILOT_VELZ_MAX)
    pilot_speed_down_m_s: float = 5.0  # PILOT_SPEED_DN 0: the same as up
    pilot_accel_z_m_s2: float = 1.0  # PILOT_ACCEL_Z 100 cm/s^2
    surface_depth_m: float = 0.10  # SURFACE_DEPTH -10 cm: the shallowest target
    pos_xy_p: float = 1.0
    vel_xy_p: float = 1.0
    vel_xy_i: float = 0.5
    vel_xy_d: float = 0.0
    vel_xy_imax_cm_s2: float = 1000.0
    angle_max_deg: float = 45.0
    max_speed_m_s: float = 0.5


class VerticalPositionControl:
    """ArduSub's depth hold (module docstring): :meth:`update_from_climb_rate` flies the pilot's climb
    rate and holds where it stops; :meth:`update` holds a given height. Both return the heave command in
    [-1, 1] (up +)."""

    def __init__(self, gains: PosControlGains | None = None, surface_z_m: float = math.inf) -> None:
        self.gains = gains or PosControlGains()
        self.surface_z_m = surface_z_m
        self.reset()

    def reset(self) -> None:
        """Forget the acceleration integral and the target (the next climb-rate update starts it at the
        vehicle's height and climb rate, as ``D_init_controller`` does)."""
        self._integral = 0.0
        self.target_z: float | None = None
        self.target_climb_m_s = 0.0
        self.limit = 0  # +1 / -1: the last heave command saturated up / down
        self._velocity_error = 0.0

    def update_from_climb_rate(self, climb_rate_m_s: float, estimate: StateEstimate, dt: float) -> float:
        """The heave command that flies the pilot's ``climb_rate_m_s`` (m/s, up +) and, at 0, holds the
        height where the climb stopped."""
        g = self.gains
        z = float(estimate.position[2])
        if self.target_z is None:
            self.target_z = z
            self.target_climb_m_s = float((rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body)[2])
        climb = max(-g.pilot_speed_down_m_s, min(g.pilot_speed_up_m_s, float(climb_rate_m_s)))
        # move the target on unless that pushes further into a saturated throttle (update_pos_vel_accel)
        step = self.target_climb_m_s * dt
        if not (step * self.limit > 0 and (self.target_z - z) * self.limit > 0):
            self.target_z += step
        accel = g.pilot_accel_z_m_s2
        change = max(-accel * dt, min(accel * dt, climb - self.target_climb_m_s))
        if not (change * self.limit > 0 and self._velocity_error * self.limit > 0):
            self.target_climb_m_s += change
        ceiling = self.surface_z_m - g.surface_depth_m
        if self.target_z > ceiling:
            self.target_z, self.target_climb_m_s = ceiling, min(self.target_climb_m_s, 0.0)
        return self._cascade(self.target_z, self.target_climb_m_s, estimate, dt)

    def update(self, z_target_m: float, estimate: StateEstimate, dt: float) -> float:
        """The heave command that holds world height ``z_target_m`` (m, up +)."""
        return self._cascade(float(z_target_m), 0.0, estimate, dt)

    def _cascade(self, z_target: float, feedforward: float, estimate: StateEstimate, dt: float) -> float:
        g = self.gains
        z = float(estimate.position[2])
        velocity_world = rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body
        # AC_P_1D: the error is bounded where the correction reaches the pilot's speed, and the target
        # with it, so it stays within reach of the vehicle
        error = z_target - z
        up = inverse_sqrt_controller(g.pilot_speed_up_m_s, g.pos_z_p, g.pilot_accel_z_m_s2)
        down = inverse_sqrt_controller(g.pilot_speed_down_m_s, g.pos_z_p, g.pilot_accel_z_m_s2)
        if error > up or error < -down:
            error = max(-down, min(up, error))
            if self.target_z is not None:
                self.target_z = z + error
        climb = feedforward + sqrt_controller(error, g.pos_z_p, g.pilot_accel_z_m_s2, dt)
        self._velocity_error = climb - float(velocity_world[2])
        accel_target_cm = g.vel_z_p * self._velocity_error * 100.0
        error_cm = accel_target_cm - float(estimate.acceleration_world[2]) * 100.0
        self._integral = float(
            np.clip(self._integral + g.acc_z_i * error_cm * dt, -g.acc_z_imax, g.acc_z_imax)
        )
        throttle = 0.001 * (g.acc_z_p * error_cm + self._integral)  # about the hover point 0.5
        heave = 2.0 * throttle
        self.limit = 1 if heave > 1.0 else -1 if heave < -1.0 else 0
        return float(np.clip(heave, -1.0, 1.0))


class HorizontalPositionControl:
    """ArduSub's horizontal position hold: ``update`` returns (forward, lateral) commands in [-1, 1]
    (lateral: right +)."""

    def __init__(self, gains: PosControlGains | None = None) -> None:
        self.gains = gains or PosControlGains()
        self._integral = np.zeros(2)
        self._last_error: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the velocity integral."""
        self._integral = np.zeros(2)
        self._last_error = None

    def update(self, xy_target_m, estimate: StateEstimate, dt: float) -> tuple[float, float]:
        """The forward and lateral commands that hold the world position ``xy_target_m``."""
        g = self.gains
        velocity_world = (rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body)[:2]
        velocity_target = g.pos_xy_p * (np.asarray(xy_target_m, float) - estimate.position[:2])
        speed = float(np.linalg.norm(velocity_target))
        if speed > g.max_speed_m_s:
            velocity_target *= g.max_speed_m_s / speed
        error_cm = (velocity_target - velocity_world) * 100.0
        self._integral = self._integral + g.vel_xy_i * error_cm * dt
        norm = float(np.linalg.norm(self._integral))
        if norm > g.vel_xy_imax_cm_s2:
            self._integral *= g.vel_xy_imax_cm_s2 / norm
        derivative = np.zeros(2) if self._last_error is None else (error_cm - self._last_error) / dt
        self._last_error = error_cm
        accel_world_cm = g.vel_xy_p * error_cm + self._integral + g.vel_xy_d * derivative
        # into the heading frame: forward along the nose, right to starboard (our world yaw is
        # counter-clockwise from +x)
        c, s = math.cos(estimate.yaw), math.sin(estimate.yaw)
        forward_cm = c * accel_world_cm[0] + s * accel_world_cm[1]
        right_cm = s * accel_world_cm[0] - c * accel_world_cm[1]
        angle_max = math.radians(g.angle_max_deg)
        forward = math.atan(forward_cm / (GRAVITY * 100.0)) / angle_max
        lateral = math.atan(right_cm / (GRAVITY * 100.0)) / angle_max
        return float(np.clip(forward, -1.0, 1.0)), float(np.clip(lateral, -1.0, 1.0))
