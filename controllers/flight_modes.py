"""ArduSub's pilot flight modes on the estimated state: MANUAL, STABILIZE, ALT_HOLD and POSHOLD.

The pilot's normalised 6-DOF command (:mod:`controllers.convention`) goes in, the mixer's input comes
out, so one pilot input behaves alike in the simulator and on a vehicle:

- **MANUAL**: the pilot command goes to the mixer unchanged.
- **STABILIZE**: the roll and pitch sticks set lean angles (centred: level) and the yaw stick a yaw rate
  (centred: hold the heading); surge, sway and heave pass through. Structure and default gains are
  ArduSub's AC_AttitudeControl_Sub (ArduPilot, libraries/AC_AttitudeControl/AC_AttitudeControl_Sub.h):
  an angle P controller (ATC_ANG_*_P = 6.0) gives a target body rate, and rate PIDs give the mixer's
  roll, pitch and yaw inputs (ATC_RAT_RLL/PIT: P 0.135, I 0.090, D 0.0036, IMAX 0.444; ATC_RAT_YAW:
  P 0.180, I 0.018, D 0, IMAX 0.222).
- **ALT_HOLD**: STABILIZE, and the heave stick drives the vertical thrusters; centred, the depth at
  which it was released is held by ArduSub's vertical position controller (AC_PosControl's position,
  velocity and acceleration cascade with ArduSub's PSC_* defaults; :mod:`controllers.position_control`).
- **POSHOLD**: ALT_HOLD, and centred surge and sway sticks hold the horizontal position with
  AC_PosControl's horizontal cascade, whose lean-angle outputs ArduSub sends to the forward and
  lateral thrusters (``translate_pos_control_rp``); it needs a position estimate (the DVL's dead
  reckoning).

The largest lean angle and yaw rate at full stick (``ModeParams``) are our choices, not checked against
ArduSub's parameter defaults.

**Thrust linearisation.** ArduSub sends its loops' outputs to the thrusters linearly in PWM
(``AP_Motors6DOF::calc_thrust_to_pwm``), while a T200 pushes nothing inside its deadband and then bends
up roughly quadratically (:mod:`controllers.thrusters`). With ArduSub's default gains on the published
BlueROV2 Heavy model, that literal path lets a full surge pitch the Heavy 8 deg before it settles within
2.5 deg, and turns at 57 % of the stick's yaw rate after 4 s (``tests/test_feedback.py``). By default
(``ModeParams.linearise_thrust``) the mixer's outputs are read as fractions of each thruster's full
thrust and the curve is inverted per thruster (:func:`controllers.thrusters.linearise_thrusters`, as
ArduCopter linearises its propellers), which keeps ArduSub's gains meaningful on the measured
thrusters. Set it False for ArduSub's literal path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controllers.estimation import StateEstimate, wrap_angle
from controllers.pid import PID, PIDGains
from controllers.position_control import HorizontalPositionControl, PosControlGains, VerticalPositionControl

FLIGHT_MODES = ("manual", "stabilize", "alt_hold", "poshold")

# ArduSub's AC_AttitudeControl_Sub defaults (see the module docstring)
ATC_ANGLE_P = 6.0
ATC_RATE_ROLL_PITCH = PIDGains(kp=0.135, ki=0.090, kd=0.0036, output_limit=1.0, integral_limit=0.444)
ATC_RATE_YAW = PIDGains(kp=0.180, ki=0.018, kd=0.0, output_limit=1.0, integral_limit=0.222)


@dataclass(frozen=True)
class ModeParams:
    """Stick scaling and dead zone of the assisted modes (our choices)."""

    max_lean_deg: float = 30.0
    max_yaw_rate_deg_s: float = 90.0
    stick_dead_zone: float = 0.05
    # True (default): the mixer's outputs are read as fractions of each thruster's full thrust and the
    # thrust curve is inverted to reach them (controllers.thrusters.linearise_thrusters; what
    # ArduCopter's MOT_THST_EXPO does for propellers). False: ArduSub's literal path, outputs linear in
    # PWM, which the T200's deadband and bend soften (module docstring)
    linearise_thrust: bool = True
    position: PosControlGains = field(default_factory=PosControlGains)


class FlightController:
    """One robot's flight mode: ``update(pilot, estimate, dt)`` returns the mixer's input (6,)."""

    def __init__(self, mode: str, surface_z_m: float, params: ModeParams | None = None) -> None:
        if mode not in FLIGHT_MODES:
            raise ValueError(f"unknown flight mode {mode!r}; choose one of {', '.join(FLIGHT_MODES)}")
        # every loop here is ArduSub's, with ArduSub's gains, and takes the plant as linear in the command;
        # the thrust curve is either left to soften them (ArduSub's literal path) or linearised per
        # thruster after the mixer (ModeParams.linearise_thrust, applied by whoever drives the thrusters:
        # controllers.thrusters.linearise_thrusters), so no vehicle model is needed here
        self.mode, self.surface_z_m = mode, surface_z_m
        self.params = params or ModeParams()
        self.rate = [PID(ATC_RATE_ROLL_PITCH), PID(ATC_RATE_ROLL_PITCH), PID(ATC_RATE_YAW)]
        self.depth_control = VerticalPositionControl(self.params.position)
        self.position_control = HorizontalPositionControl(self.params.position)
        self._heading: float | None = None
        self._depth: float | None = None
        self._hold_xy: np.ndarray | None = None

    def update(self, pilot: np.ndarray, estimate: StateEstimate, dt: float) -> np.ndarray:
        """The mixer input for the pilot command ``pilot`` (surge, sway, heave, roll, pitch, yaw)."""
        pilot = np.asarray(pilot, float)
        if self.mode == "manual":
            return pilot
        p = self.params
        out = pilot.copy()
        # attitude: target angles (roll right side down +; pilot pitch + is nose up, our pitch + nose down)
        lean = math.radians(p.max_lean_deg)
        targets = (pilot[3] * lean, -pilot[4] * lean)
        rates = estimate.angular_velocity_body
        for k, target in enumerate(targets):
            rate_target = ATC_ANGLE_P * wrap_angle(target - estimate.rpy[k])
            out[3 + k] = self.rate[k].update(rate_target, rates[k], dt) * (1.0 if k == 0 else -1.0)
        if abs(pilot[5]) > p.stick_dead_zone or self._heading is None:
            self._heading = estimate.yaw
            yaw_rate_target = -pilot[5] * math.radians(p.max_yaw_rate_deg_s)  # stick right: clockwise
        else:
            yaw_rate_target = ATC_ANGLE_P * wrap_angle(self._heading - estimate.yaw)
        out[5] = -self.rate[2].update(yaw_rate_target, rates[2], dt)
        if self.mode in ("alt_hold", "poshold"):
            if abs(pilot[2]) > p.stick_dead_zone:
                # the pilot climbs or dives at will; the depth is captured when the stick is released
                self._depth = None
                out[2] = pilot[2]
            else:
                if self._depth is None:
                    self._depth = self.surface_z_m - estimate.position[2]
                    self.depth_control.reset()
                out[2] = self.depth_control.update(self.surface_z_m - self._depth, estimate, dt)
        if self.mode == "poshold":
            if np.any(np.abs(pilot[:2]) > p.stick_dead_zone) or self._hold_xy is None:
                self._hold_xy = estimate.position[:2].copy()
                self.position_control.reset()
            else:
                out[0], out[1] = self.position_control.update(self._hold_xy, estimate, dt)
        return out.clip(-1.0, 1.0)
