"""The T200's thrust against its ESC pulse width, and ArduSub's command-to-PWM mapping.

**ArduSub's mapping** (``AP_Motors6DOF::calc_thrust_to_pwm``, ArduPilot master): a mixed thruster
command ``c`` in [-1, 1] becomes the pulse width

    pwm = 1500 + c * (MOT_PWM_MAX - 1500)   for c > 0
    pwm = 1500 + c * (1500 - MOT_PWM_MIN)   otherwise

linear, with no thrust linearisation (Sub does not use ArduCopter's MOT_THST_EXPO). ArduSub's defaults
are MOT_PWM_MIN = 1100 and MOT_PWM_MAX = 1900 us, the T200's own range.

**The T200 curve** (Blue Robotics, "T200-Public-Performance-Data-10-20V-September-2019.xlsx", the
maker's bollard-pull measurements of thrust against pulse width at 10 to 20 V). Each side of the
curve is zero inside a deadband about 1500 us and then rises roughly quadratically (thrust goes with
the square of propeller speed, and the ESC's speed is roughly linear in pulse width beyond the
deadband). We model each side as

    s = (|pwm - 1500| - deadband) / (400 - deadband),   clipped to [0, 1]
    thrust = thrust_max * s (s + k) / (1 + k)

a quadratic through zero at the deadband's edge and through ``thrust_max`` at 1100 or 1900 us; the
shape constant ``k`` sets how far it bends (k -> infinity is a straight line, k = 0 a pure square).

Numbers (:data:`T200_CURVES`):

- deadband and full thrust per voltage, as read off the workbook by a public fit (duburi_sim,
  ``docs/physics.md``, "The T200 thrust curve"; mean error 0.20 N, max 1.77 N at 16 V): 16 V
  1472-1528 us, 51.4 N forward, 39.9 N reverse; 12 V 1464-1536 us, 36.4 N and 28.6 N. Blue Robotics'
  product page gives 5.25 / 4.07 kgf (51.5 / 39.9 N) at 16 V and 3.71 / 2.92 kgf at 12 V, the same;
- the shape ``k`` from a public quadratic least-squares fit of the 12 V sheet ("EMPIRICAL FIT TO
  PUBLISHED T200 12V Data": thrust = a pwm^2 + b pwm + c on 1540-1900 and 1100-1460 us): its roots
  give k = 1.285 forward and 1.484 reverse. No published fit of the 16 V shape was found, so 16 V
  uses the same normalised shape; its check against a third fit is in ``tests/test_thrusters.py``.

**The T200's electrical power** (:data:`T200_POWER`), for a mission's thruster energy. The same
workbook's 12 V sheet gives the supply current at each pulse width (4 us steps; 16.9 A at full forward,
17.0 A at full reverse). With the 12 V thrust curve above, power against thrust follows a power law
on each side,

    P = c |T|^a     (W, T in N),

which momentum theory predicts with a = 1.5 for an ideal propeller (Rankine-Froude actuator disk:
P = T^1.5 / sqrt(2 rho A)); the measured a is about 1.6 (motor and ESC losses grow with load). A
least-squares fit of log P on log T over every pulse width with at least 10 % of full thrust gives
a = 1.610, c = 0.669 forward and a = 1.679, c = 0.790 reverse: mean error 2 %, at most 13 %, and
7 % high at full forward throttle (``tests/test_thruster_power.py`` checks it against the sheet,
transcribed in ``tests/data``).
The law is used at every voltage: at a given bollard thrust the propeller, not the supply, sets the
power, to first order. At 16 V it predicts 380 W (23.7 A) at full forward thrust (51.4 N).

Not modelled: thrust and power changing with inflow speed (the data is bollard pull), battery sag,
the interaction of neighbouring thrusters, and the electronics' idle draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEUTRAL_PWM_US = 1500.0
T200_PWM_MIN_US = 1100.0
T200_PWM_MAX_US = 1900.0


@dataclass(frozen=True)
class PwmRange:
    """ArduSub's output range for its thrusters: MOT_PWM_MIN and MOT_PWM_MAX (us), defaults 1100 / 1900."""

    pwm_min_us: float = T200_PWM_MIN_US
    pwm_max_us: float = T200_PWM_MAX_US

    def __post_init__(self) -> None:
        if not (self.pwm_min_us < NEUTRAL_PWM_US < self.pwm_max_us):
            raise ValueError(
                f"PWM range {self.pwm_min_us}-{self.pwm_max_us} us must straddle "
                f"the neutral {NEUTRAL_PWM_US} us"
            )


def command_to_pwm(command, pwm: PwmRange = PwmRange()) -> np.ndarray:
    """ArduSub's ``calc_thrust_to_pwm``: thruster commands in [-1, 1] (clipped) to pulse widths (us)."""
    c = np.asarray(command, float).clip(-1.0, 1.0)
    up, down = pwm.pwm_max_us - NEUTRAL_PWM_US, NEUTRAL_PWM_US - pwm.pwm_min_us
    return NEUTRAL_PWM_US + c * np.where(c > 0, up, down)


def pwm_to_command(pulse_us, pwm: PwmRange = PwmRange()) -> np.ndarray:
    """The inverse of :func:`command_to_pwm`: pulse widths (us) to thruster commands in [-1, 1]."""
    p = np.asarray(pulse_us, float).clip(pwm.pwm_min_us, pwm.pwm_max_us) - NEUTRAL_PWM_US
    up, down = pwm.pwm_max_us - NEUTRAL_PWM_US, NEUTRAL_PWM_US - pwm.pwm_min_us
    return np.where(p > 0, p / up, p / down)


@dataclass(frozen=True)
class ThrustCurve:
    """A thruster's static curve at one supply voltage: thrust (N) against pulse width (us).

    deadband_us: half-width of the zero-thrust band about 1500 us;
    forward_shape, reverse_shape: the shape constant k of each side (module docstring).
    """

    voltage_v: float
    max_forward_n: float
    max_reverse_n: float
    deadband_us: float
    forward_shape: float
    reverse_shape: float

    def __post_init__(self) -> None:
        if not (self.max_forward_n > 0 and self.max_reverse_n > 0):
            raise ValueError("a thrust curve needs positive forward and reverse thrust")
        if not (0 <= self.deadband_us < NEUTRAL_PWM_US - T200_PWM_MIN_US):
            raise ValueError(f"deadband {self.deadband_us} us must lie in [0, 400) us")
        if not (self.forward_shape >= 0 and self.reverse_shape >= 0):
            raise ValueError("thrust curve shapes must be >= 0")

    def thrust_n(self, pulse_us) -> np.ndarray:
        """Static thrust (N, positive forward) at each pulse width (us; clipped to 1100-1900)."""
        p = np.asarray(pulse_us, float).clip(T200_PWM_MIN_US, T200_PWM_MAX_US) - NEUTRAL_PWM_US
        span = (NEUTRAL_PWM_US - T200_PWM_MIN_US) - self.deadband_us
        s = ((np.abs(p) - self.deadband_us) / span).clip(0.0, 1.0)
        k = np.where(p >= 0, self.forward_shape, self.reverse_shape)
        peak = np.where(p >= 0, self.max_forward_n, -self.max_reverse_n)
        return peak * s * (s + k) / (1.0 + k)

    def pulse_us(self, thrust_n) -> np.ndarray:
        """The pulse width (us) that gives each thrust (N; clipped to the curve's range): the inverse
        of :func:`thrust_n` outside the deadband, 1500 for zero."""
        f = np.asarray(thrust_n, float)
        forward = f >= 0
        peak = np.where(forward, self.max_forward_n, self.max_reverse_n)
        k = np.where(forward, self.forward_shape, self.reverse_shape)
        y = (np.abs(f) / peak).clip(0.0, 1.0) * (1.0 + k)  # s^2 + k s = y
        s = (-k + np.sqrt(k * k + 4.0 * y)) / 2.0
        span = (NEUTRAL_PWM_US - T200_PWM_MIN_US) - self.deadband_us
        offset = np.where(s > 0, self.deadband_us + s * span, 0.0)
        return NEUTRAL_PWM_US + np.where(forward, offset, -offset)

    def thrust_from_command(self, command, pwm: PwmRange = PwmRange()) -> np.ndarray:
        """Thrust (N) of each thruster command in [-1, 1], through ArduSub's linear PWM mapping."""
        return self.thrust_n(command_to_pwm(command, pwm))

    def command_for_thrust(self, thrust_n, pwm: PwmRange = PwmRange()) -> np.ndarray:
        """The thruster command in [-1, 1] that gives each thrust (N): the curve inverted."""
        return pwm_to_command(self.pulse_us(thrust_n), pwm)


def linearise_thrusters(commands, curve: ThrustCurve, pwm: PwmRange = PwmRange()) -> np.ndarray:
    """Thruster commands in [-1, 1] read as fractions of full forward (>= 0) or full reverse (< 0)
    thrust, turned into the commands that give those thrusts through ``curve``: thrust linearisation
    after the mixer, per thruster (ArduCopter does the same for propellers with MOT_THST_EXPO)."""
    c = np.asarray(commands, float).clip(-1.0, 1.0)
    wanted = np.where(c >= 0, c * curve.max_forward_n, c * curve.max_reverse_n)
    return np.where(c == 0, 0.0, curve.command_for_thrust(wanted, pwm))


# Blue Robotics' T200 at its two usual supply voltages (module docstring for the sources).
T200_16V = ThrustCurve(16.0, 51.4, 39.9, 28.0, 1.285, 1.484)
T200_12V = ThrustCurve(12.0, 36.4, 28.6, 36.0, 1.285, 1.484)
T200_CURVES: dict[float, ThrustCurve] = {16.0: T200_16V, 12.0: T200_12V}


@dataclass(frozen=True)
class ThrusterPower:
    """Electrical power (W) a thruster draws to make a static thrust ``T`` (N): ``c |T|^a``, with one
    coefficient ``c`` and exponent ``a`` for forward thrust and one for reverse (module docstring)."""

    forward_coefficient: float
    forward_exponent: float
    reverse_coefficient: float
    reverse_exponent: float

    def __post_init__(self) -> None:
        values = (
            self.forward_coefficient,
            self.forward_exponent,
            self.reverse_coefficient,
            self.reverse_exponent,
        )
        if not all(np.isfinite(v) and v > 0 for v in values):
            raise ValueError(f"thruster power coefficients and exponents must be positive, got {values}")

    def watts(self, thrust_n) -> np.ndarray:
        """The power (W) drawn for each thrust (N; >= 0 forward, < 0 reverse)."""
        thrust = np.asarray(thrust_n, float)
        magnitude = np.abs(thrust)
        forward = self.forward_coefficient * magnitude**self.forward_exponent
        reverse = self.reverse_coefficient * magnitude**self.reverse_exponent
        return np.where(thrust >= 0, forward, reverse)

    def total_watts(self, thrust_n: list[float]) -> float:
        """The summed power (W) of a few thrusts (N): :meth:`watts` summed, in plain Python, which beats
        numpy on a vehicle's eight thrusters, as the simulator sums them every control period."""
        total = 0.0
        for thrust in thrust_n:
            if thrust >= 0:
                total += self.forward_coefficient * thrust**self.forward_exponent
            else:
                total += self.reverse_coefficient * (-thrust) ** self.reverse_exponent
        return total


# the T200's power law, fitted to the 2019 workbook's 12 V sheet (module docstring)
T200_POWER = ThrusterPower(0.669, 1.610, 0.790, 1.679)


def linear_curve(max_forward_n: float, max_reverse_n: float) -> ThrustCurve:
    """A straight line through zero (no deadband, thrust proportional to command), for studies."""
    return ThrustCurve(0.0, max_forward_n, max_reverse_n, 0.0, 1e9, 1e9)


def t200_curve(voltage_v: float) -> ThrustCurve:
    """The T200 curve at ``voltage_v`` (12 or 16 V; the two published here)."""
    try:
        return T200_CURVES[float(voltage_v)]
    except KeyError:
        raise ValueError(f"no T200 curve for {voltage_v} V; known: {sorted(T200_CURVES)} V") from None


def t200_curve_between(voltage_v: float) -> ThrustCurve:
    """The T200 curve at a supply voltage from 12 to 16 V: full thrust and deadband interpolated
    linearly between the two published curves (:data:`T200_CURVES`), the shape kept. The interpolation
    is our assumption: the workbook's 14 V sheet is not transcribed here. A BlueROV2's 4S lithium-ion
    battery (14.8 V nominal) sags across this range as it drains."""
    v = float(voltage_v)
    if not (12.0 <= v <= 16.0):
        raise ValueError(f"the T200 curve is known from 12 to 16 V, got {voltage_v!r} V")
    t = (v - 12.0) / 4.0
    low, high = T200_12V, T200_16V

    def between(a: float, b: float) -> float:
        return a + t * (b - a)

    return ThrustCurve(
        v,
        between(low.max_forward_n, high.max_forward_n),
        between(low.max_reverse_n, high.max_reverse_n),
        between(low.deadband_us, high.deadband_us),
        low.forward_shape,
        low.reverse_shape,
    )
