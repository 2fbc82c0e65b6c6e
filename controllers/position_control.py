"""ArduSub's position controller (AC_PosControl with ArduSub's defaults), for ALT_HOLD and POSHOLD.

Structure and gains from ArduPilot's ``libraries/AC_AttitudeControl/AC_PosControl.cpp`` (the ArduSub
branch of its defaults) and ``ArduSub/motors.cpp`` (``translate_pos_control_rp``):

- **vertical**: a position P (PSC_POSZ_P = 3.0 /s) gives a climb-rate target, a velocity P
  (PSC_VELZ_P = 8.0 /s) an acceleration target, and an acceleration PID on the measured vertical
  acceleration (PSC_ACCZ_P = 0.5, PSC_ACCZ_I = 0.1, PSC_ACCZ_IMAX = 100, working in cm/s^2 with its
  output scaled by 0.001) the throttle about ArduSub's hover point of 0.5, which the 6-DOF mixer reads
  as the bidirectional heave command 2 (throttle - 0.5);
- **horizontal**: a position P (PSC_POSXY_P = 1.0 /s) gives a velocity target, a velocity PID
  (PSC_VELXY_P = 1.0, PSC_VELXY_I = 0.5, PSC_VELXY_D = 0, PSC_VELXY_IMAX = 1000 cm/s^2) an acceleration
  target, which AC_PosControl turns into lean angles atan(a / g); ArduSub does not lean but sends them,
  divided by ANGLE_MAX (4500 cdeg, ArduPilot's DEFAULT_ANGLE_MAX), to the forward and lateral thrusters.

The speed limits of the position P stages (``max_climb_m_s``, ``max_speed_m_s``) are our choices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.estimation import StateEstimate, rotation_from_rpy

GRAVITY = 9.80665


@dataclass(frozen=True)
class PosControlGains:
    """ArduSub's PSC_* defaults (module docstring) and our speed limits."""

    pos_z_p: float = 3.0
    vel_z_p: float = 8.0
    acc_z_p: float = 0.5
    acc_z_i: float = 0.1
    acc_z_imax: float = 100.0  # in the PID's units: 100 = 0.1 of throttle
    pos_xy_p: float = 1.0
    vel_xy_p: float = 1.0
    vel_xy_i: float = 0.5
    vel_xy_d: float = 0.0
    vel_xy_imax_cm_s2: float = 1000.0
    angle_max_deg: float = 45.0
    max_climb_m_s: float = 0.5
    max_speed_m_s: float = 0.5


class VerticalPositionControl:
    """ArduSub's depth hold: ``update`` returns the heave command in [-1, 1] (up +)."""

    def __init__(self, gains: PosControlGains | None = None) -> None:
        self.gains = gains or PosControlGains()
        self._integral = 0.0

    def reset(self) -> None:
        """Forget the acceleration integral."""
        self._integral = 0.0

    def update(self, z_target_m: float, estimate: StateEstimate, dt: float) -> float:
        """The heave command that holds world height ``z_target_m`` (m, up +)."""
        g = self.gains
        velocity_world = rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body
        climb = float(
            np.clip(g.pos_z_p * (z_target_m - estimate.position[2]), -g.max_climb_m_s, g.max_climb_m_s)
        )
        accel_target_cm = g.vel_z_p * (climb - velocity_world[2]) * 100.0
        error_cm = accel_target_cm - float(estimate.acceleration_world[2]) * 100.0
        self._integral = float(
            np.clip(self._integral + g.acc_z_i * error_cm * dt, -g.acc_z_imax, g.acc_z_imax)
        )
        throttle = 0.001 * (g.acc_z_p * error_cm + self._integral)  # about the hover point 0.5
        return float(np.clip(2.0 * throttle, -1.0, 1.0))


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
