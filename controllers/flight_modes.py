"""ArduSub's pilot flight modes on the estimated state: MANUAL, STABILIZE, ALT_HOLD and POSHOLD.

The pilot's normalised 6-DOF command (:mod:`maptidal.controllers.convention`) goes in, the mixer's input comes
out, so one pilot input behaves alike in the simulator and on a vehicle. The command is the pilot's stick
as ArduSub's RC channels carry it: MANUAL_CONTROL / 1000 after ArduSub's pilot gain, which the
simulator applies first (:class:`maptidal.controllers.convention.PilotGain`, ``ModeParams.pilot_gain``).

We follow ArduPilot master (ArduSub 4.7.0-dev; the 4.5 behaviour of the depth hold):
``ArduSub/mode_stabilize.cpp``, ``ArduSub/mode_althold.cpp``, ``ArduSub/Attitude.cpp``
(``get_pilot_desired_lean_angles``, ``get_pilot_desired_yaw_rate``, ``get_pilot_desired_climb_rate``),
``ArduSub/config.h`` and ``ArduSub/Parameters.cpp`` (defaults), ``libraries/AC_PID/AC_PID.cpp``,
``libraries/AC_AttitudeControl/AC_AttitudeControl_Sub.h`` (gains and filters) and
``libraries/AP_Math/control.cpp`` (``sqrt_controller``).

- **MANUAL**: the pilot command goes to the mixer unchanged.
- **STABILIZE**: surge, sway and heave pass through (``norm_input``, no dead zone).
  - *Roll and pitch sticks* set lean angles: a dead zone of 30 us of the 400 us half-range (ArduSub's
    RC dead zone on channels 1 and 2) with the rest rescaled, full stick = ANGLE_MAX (4500 cdeg), a
    circular limit on the two together, and the lateral-tilt-to-Euler-roll conversion
    roll = atan(cos(pitch) tan(roll)).
  - *Yaw stick* sets a yaw rate: a dead zone of 40 us (channel 4's) rescaled, and ACRO_YAW_P (3.375)
    times the stick's 4500 cdeg, 151.9 deg/s at full stick. Centred, the vehicle is first braked to zero
    yaw rate for 250 ms while the heading to hold keeps following it, then that heading is held
    ("prevent bounce back after very fast yaw maneuvers", mode_stabilize.cpp and mode_althold.cpp).
  - *Angle loop*: ``sqrt_controller`` of each axis's angle error with ATC_ANG_*_P = 6.0 and the
    acceleration limits ATC_ACCEL_R/P/Y_MAX (1100 deg/s^2; AC_ATC_SUB_ACCEL_Y_MAX_DEGSS for yaw) gives
    the target body rate.
  - *Rate loops*: AC_PID (:class:`maptidal.controllers.pid.ACPID`) with ArduSub's defaults, ATC_RAT_RLL/PIT
    P 0.135, I 0.090, D 0.0036, IMAX 0.444, FLTT = FLTD = 30 Hz; ATC_RAT_YAW P 0.180, I 0.018, D 0,
    IMAX 0.222, FLTT = FLTD = 5 Hz; FLTE 0. The integrator only shrinks while that axis's output is
    saturated (the motors' limit flag).
- **ALT_HOLD**: STABILIZE, with the heave stick a climb rate: inside THR_DZ (100 of the throttle's
  0-1000, so +-0.2 of the stick) none, outside it PILOT_SPEED_UP / DN (500 cm/s) times the distance past
  the dead zone's edge; AC_PosControl holds the depth where the climb stops
  (:class:`maptidal.controllers.position_control.VerticalPositionControl`).
- **POSHOLD**: ALT_HOLD, and centred surge and sway sticks hold the horizontal position with
  AC_PosControl's horizontal cascade, whose lean-angle outputs ArduSub sends to the forward and
  lateral thrusters (``translate_pos_control_rp``); it needs a position estimate (the DVL's dead
  reckoning).

Left out of AC_AttitudeControl: its input shaping and rate feedforward (a deflected yaw stick drives the
yaw rate loop directly, and angle targets are not slewed), and its quaternion attitude error (each axis's
Euler angle error is used, which is close at the leans pilots fly).

**Thrust linearisation.** ArduSub sends its loops' outputs to the thrusters linearly in PWM
(``AP_Motors6DOF::calc_thrust_to_pwm``), while a T200 pushes nothing inside its deadband and then bends
up roughly quadratically (:mod:`maptidal.controllers.thrusters`). By default (``ModeParams.linearise_thrust``)
the mixer's outputs are read as fractions of each thruster's full thrust and the curve is inverted per
thruster (:func:`maptidal.controllers.thrusters.linearise_thrusters`, as ArduCopter linearises its
propellers), which keeps ArduSub's gains meaningful on the measured thrusters. Set it False for ArduSub's
literal path, which the deadband and bend soften (``tests/test_feedback.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .convention import PilotGain
from .estimation import StateEstimate, wrap_angle
from .pid import ACPID, ACPIDGains, sqrt_controller
from .position_control import HorizontalPositionControl, PosControlGains, VerticalPositionControl

FLIGHT_MODES = ("manual", "stabilize", "alt_hold", "poshold")

# ArduSub's AC_AttitudeControl_Sub defaults (see the module docstring)
ATC_ANGLE_P = 6.0
ATC_ACCEL_MAX_RAD_S2 = math.radians(1100.0)
ATC_RATE_ROLL_PITCH = ACPIDGains(
    kp=0.135, ki=0.090, kd=0.0036, imax=0.444, target_filter_hz=30.0, derivative_filter_hz=30.0
)
ATC_RATE_YAW = ACPIDGains(
    kp=0.180, ki=0.018, kd=0.0, imax=0.222, target_filter_hz=5.0, derivative_filter_hz=5.0
)
HEADING_CAPTURE_DELAY_S = 0.25  # mode_stabilize.cpp: "give 250ms to slow down, then set target heading"


def dead_zone(stick: float, width: float) -> float:
    """A stick value in [-1, 1] with ``width`` about the centre cut out and the rest rescaled to reach
    +-1 at full stick (RC_Channel's ``pwm_to_angle_dz``)."""
    magnitude = abs(stick) - width
    if magnitude <= 0.0:
        return 0.0
    return math.copysign(min(1.0, magnitude / (1.0 - width)), stick)


@dataclass(frozen=True)
class ModeParams:
    """ArduSub's stick scaling and dead zones (module docstring), and whether thrust is linearised."""

    max_lean_deg: float = 45.0  # ANGLE_MAX 4500 cdeg
    max_yaw_rate_deg_s: float = 45.0 * 3.375  # ACRO_YAW_P x 4500 cdeg
    roll_pitch_dead_zone: float = 30.0 / 400.0  # RC1/RC2 dead zone, us of the 400 us half-range
    yaw_dead_zone: float = 40.0 / 400.0  # RC4 dead zone
    throttle_dead_zone: float = 100.0 / 500.0  # THR_DZ, of the throttle's 500 half-range
    # POSHOLD: how far a surge or sway stick must move to take over from the position hold
    translation_dead_zone: float = 30.0 / 400.0
    # True (default): the mixer's outputs are read as fractions of each thruster's full thrust and the
    # thrust curve is inverted to reach them (maptidal.controllers.thrusters.linearise_thrusters; what
    # ArduCopter's MOT_THST_EXPO does for propellers). False: ArduSub's literal path, outputs linear in
    # PWM, which the T200's deadband and bend soften (module docstring)
    linearise_thrust: bool = True
    position: PosControlGains = field(default_factory=PosControlGains)
    # the pilot gain a MANUAL_CONTROL stick is scaled by (JS_GAIN and JS_THR_GAIN; PilotGain). 1, not
    # ArduSub's 0.5 default, so that a full command is full authority; a vehicle flown with the gain
    # at 0.5 is matched by PilotGain(0.5)
    pilot_gain: PilotGain = field(default_factory=PilotGain)

    def __post_init__(self) -> None:
        for name in ("max_lean_deg", "max_yaw_rate_deg_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if not 0.0 < self.max_lean_deg <= 80.0:  # ArduSub bounds ANGLE_MAX to 1000-8000 cdeg
            raise ValueError(f"max_lean_deg must lie in (0, 80], got {self.max_lean_deg!r}")
        for name in ("roll_pitch_dead_zone", "yaw_dead_zone", "throttle_dead_zone", "translation_dead_zone"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise ValueError(f"{name} must lie in [0, 1), got {value!r}")


def pilot_lean_angles(roll_stick: float, pitch_stick: float, params: ModeParams) -> tuple[float, float]:
    """ArduSub's ``get_pilot_desired_lean_angles`` on normalised sticks: the target roll and pitch (rad;
    pitch here nose up +, as the stick)."""
    angle_max = math.radians(params.max_lean_deg)
    roll = dead_zone(roll_stick, params.roll_pitch_dead_zone) * angle_max
    pitch = dead_zone(pitch_stick, params.roll_pitch_dead_zone) * angle_max
    total = math.hypot(roll, pitch)
    if total > angle_max:
        roll, pitch = roll * angle_max / total, pitch * angle_max / total
    return math.atan(math.cos(pitch) * math.tan(roll)), pitch


def lean_stick(angle_rad: float, params: ModeParams) -> float:
    """The roll or pitch stick that asks STABILIZE for ``angle_rad`` of lean on its own (the other stick
    centred): the inverse of :func:`pilot_lean_angles` on one axis, saturating at ANGLE_MAX."""
    fraction = min(1.0, abs(angle_rad) / math.radians(params.max_lean_deg))
    if fraction == 0.0:
        return 0.0
    width = params.roll_pitch_dead_zone
    return math.copysign(width + (1.0 - width) * fraction, angle_rad)


def pilot_climb_rate(heave_stick: float, params: ModeParams) -> float:
    """ArduSub's ``get_pilot_desired_climb_rate`` on the normalised heave stick: m/s, up +."""
    g, width = params.position, params.throttle_dead_zone
    if heave_stick > width:
        return g.pilot_speed_up_m_s * (heave_stick - width) / (1.0 - width)
    if heave_stick < -width:
        return g.pilot_speed_down_m_s * (heave_stick + width) / (1.0 - width)
    return 0.0


class FlightController:
    """One robot's flight mode: ``update(pilot, estimate, dt)`` returns the mixer's input (6,)."""

    def __init__(self, mode: str, surface_z_m: float, params: ModeParams | None = None) -> None:
        if mode not in FLIGHT_MODES:
            raise ValueError(f"unknown flight mode {mode!r}; choose one of {', '.join(FLIGHT_MODES)}")
        # every loop here is ArduSub's, with ArduSub's gains, and takes the plant as linear in the command;
        # the thrust curve is either left to soften them (ArduSub's literal path) or linearised per
        # thruster after the mixer (ModeParams.linearise_thrust, applied by whoever drives the thrusters:
        # maptidal.controllers.thrusters.linearise_thrusters), so no vehicle model is needed here
        self.mode, self.surface_z_m = mode, surface_z_m
        self.params = params or ModeParams()
        self.rate = [ACPID(ATC_RATE_ROLL_PITCH), ACPID(ATC_RATE_ROLL_PITCH), ACPID(ATC_RATE_YAW)]
        self._saturated = [False, False, False]
        self.depth_control = VerticalPositionControl(self.params.position, surface_z_m)
        self.position_control = HorizontalPositionControl(self.params.position)
        self.time_s = 0.0
        self._heading: float | None = None
        self._last_yaw_input_s = -math.inf
        self._hold_xy: np.ndarray | None = None

    @property
    def heading(self) -> float | None:
        """The heading (rad, yaw) being held, or followed while the yaw stick is in use."""
        return self._heading

    def update(self, pilot: np.ndarray, estimate: StateEstimate, dt: float) -> np.ndarray:
        """The mixer input for the pilot command ``pilot`` (surge, sway, heave, roll, pitch, yaw)."""
        pilot = np.asarray(pilot, float)
        self.time_s += dt
        if self.mode == "manual":
            return pilot
        p = self.params
        out = pilot.copy()
        rates = estimate.angular_velocity_body
        # attitude: target angles (roll right side down +; pilot pitch + is nose up, our pitch + nose down)
        roll_target, pitch_target = pilot_lean_angles(pilot[3], pilot[4], p)
        for k, target in enumerate((roll_target, -pitch_target)):
            error = wrap_angle(target - estimate.rpy[k])
            rate_target = sqrt_controller(error, ATC_ANGLE_P, ATC_ACCEL_MAX_RAD_S2, dt)
            out[3 + k] = self._rate_loop(k, rate_target, rates[k], dt) * (1.0 if k == 0 else -1.0)
        yaw_rate_target = -dead_zone(pilot[5], p.yaw_dead_zone) * math.radians(p.max_yaw_rate_deg_s)
        if yaw_rate_target != 0.0:  # stick right: clockwise, our yaw falls
            self._heading, self._last_yaw_input_s = estimate.yaw, self.time_s
        elif self.time_s < self._last_yaw_input_s + HEADING_CAPTURE_DELAY_S or self._heading is None:
            self._heading = estimate.yaw  # brake to zero rate, still following the heading
        else:
            error = wrap_angle(self._heading - estimate.yaw)
            yaw_rate_target = sqrt_controller(error, ATC_ANGLE_P, ATC_ACCEL_MAX_RAD_S2, dt)
        out[5] = -self._rate_loop(2, yaw_rate_target, rates[2], dt)
        if self.mode in ("alt_hold", "poshold"):
            climb = pilot_climb_rate(pilot[2], p)
            out[2] = self.depth_control.update_from_climb_rate(climb, estimate, dt)
        if self.mode == "poshold":
            if np.any(np.abs(pilot[:2]) > p.translation_dead_zone) or self._hold_xy is None:
                self._hold_xy = estimate.position[:2].copy()
                self.position_control.reset()
            else:
                out[0], out[1] = self.position_control.update(self._hold_xy, estimate, dt)
        return out.clip(-1.0, 1.0)

    def _rate_loop(self, axis: int, target: float, measured: float, dt: float) -> float:
        output = self.rate[axis].update(target, float(measured), dt, limit=self._saturated[axis])
        self._saturated[axis] = abs(output) >= 1.0
        return output
