"""Feedback for one axis: our PID (derivative on the measurement, conditional anti-windup) and
ArduPilot's AC_PID with its filters and sqrt_controller, which the ArduSub flight modes use."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class PIDGains:
    """Gains and limits of one :class:`PID`: output = kp e + ki integral(e) - kd d(measurement)/dt.

    ``output_limit`` bounds the output symmetrically (inf: none); ``integral_limit`` bounds the integral
    term's contribution to the output (default: the output limit).
    """

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    output_limit: float = math.inf
    integral_limit: float | None = None

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"PID gain {name} must be finite and >= 0, got {value!r}")
        if not self.output_limit > 0.0:
            raise ValueError(f"output_limit must be > 0, got {self.output_limit!r}")


class PID:
    """One axis of feedback.

    - The derivative acts on the measurement (or a measured rate), not on the error, so a setpoint
      step gives no derivative kick.
    - Anti-windup by conditional integration: the integral grows only while the output is not
      saturated, or while the error drives the output back out of saturation; its contribution is
      also clamped to ``integral_limit``.
    - The output is clipped to ``output_limit``.
    """

    def __init__(self, gains: PIDGains) -> None:
        self.gains = gains
        self.reset()

    def reset(self) -> None:
        """Forget the integral and the last measurement."""
        self.integral = 0.0
        self._last_measurement: float | None = None
        self.saturated = False

    def update(
        self,
        setpoint: float,
        measurement: float,
        dt: float,
        measured_rate: float | None = None,
        feedforward: float = 0.0,
        error: float | None = None,
    ) -> float:
        """The output for this step.

        ``measured_rate`` (the measurement's time derivative, from a rate sensor) replaces the finite
        difference of the measurement; ``error`` replaces ``setpoint - measurement`` (for wrapped angles).
        ``feedforward`` is added before limiting.
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive time step, got {dt!r}")
        g = self.gains
        e = setpoint - measurement if error is None else error
        if measured_rate is None:
            rate = 0.0 if self._last_measurement is None else (measurement - self._last_measurement) / dt
        else:
            rate = measured_rate
        self._last_measurement = measurement
        unclamped = g.kp * e - g.kd * rate + feedforward
        limit = g.output_limit
        integral_limit = g.integral_limit if g.integral_limit is not None else limit
        candidate = self.integral + g.ki * e * dt
        candidate = max(-integral_limit, min(integral_limit, candidate))
        output = unclamped + candidate
        # integrate only if that does not push further into saturation
        if abs(output) <= limit or (output > limit and e < 0) or (output < -limit and e > 0):
            self.integral = candidate
        output = unclamped + self.integral
        self.saturated = abs(output) > limit
        return max(-limit, min(limit, output))


def lowpass_alpha(dt: float, cutoff_hz: float) -> float:
    """ArduPilot's ``calc_lowpass_alpha_dt``: the weight of a new sample in a first-order low-pass
    filter, dt / (dt + 1 / (2 pi f)); 1 (no filtering) for a cutoff of 0."""
    if cutoff_hz <= 0.0:
        return 1.0
    return dt / (dt + 1.0 / (2.0 * math.pi * cutoff_hz))


def sqrt_controller(error: float, p: float, second_order_limit: float, dt: float) -> float:
    """ArduPilot's ``sqrt_controller`` (libraries/AP_Math/control.cpp): a P controller near zero error
    that becomes sqrt(2 a (|e| - a / (2 p^2))) beyond e = a / p^2, so that the rate it asks for can be
    braked at ``second_order_limit`` (a) without overshoot; the output never corrects more than the whole
    error within one ``dt``."""
    if second_order_limit <= 0.0:
        rate = error * p
    elif p == 0.0:
        rate = math.copysign(math.sqrt(2.0 * second_order_limit * abs(error)), error) if error else 0.0
    else:
        linear_distance = second_order_limit / (p * p)
        if error > linear_distance:
            rate = math.sqrt(2.0 * second_order_limit * (error - linear_distance / 2.0))
        elif error < -linear_distance:
            rate = -math.sqrt(2.0 * second_order_limit * (-error - linear_distance / 2.0))
        else:
            rate = error * p
    if dt > 0.0:
        return max(-abs(error) / dt, min(abs(error) / dt, rate))
    return rate


def inverse_sqrt_controller(output: float, p: float, second_order_limit: float) -> float:
    """ArduPilot's ``inv_sqrt_controller``: the error at which :func:`sqrt_controller` (without its
    per-step clamp) asks for ``output``."""
    if second_order_limit > 0.0 and p == 0.0:
        return output * output / (2.0 * second_order_limit)
    if second_order_limit <= 0.0:
        return output / p if p else 0.0
    linear_velocity = second_order_limit / p
    if abs(output) < linear_velocity:
        return output / p
    linear_distance = second_order_limit / (p * p)
    distance = linear_distance / 2.0 + output * output / (2.0 * second_order_limit)
    return math.copysign(distance, output)


@dataclass(frozen=True)
class ACPIDGains:
    """ArduPilot's AC_PID parameters: P, I, D, IMAX (the integrator's bound, in output units) and the
    cutoffs (Hz, 0 for none) of its target (FLTT), error (FLTE) and derivative (FLTD) filters."""

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    imax: float = 0.0
    target_filter_hz: float = 0.0
    error_filter_hz: float = 0.0
    derivative_filter_hz: float = 0.0

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"AC_PID {name} must be finite and >= 0, got {value!r}")


class ACPID:
    """ArduPilot's AC_PID (libraries/AC_PID/AC_PID.cpp, ``update_all``), without its slew limiter
    (SMAX, 0 by default) or feedforward (FF, 0 in ArduSub's rate loops):

    - the target and the error are low-pass filtered (FLTT, FLTE); the first sample sets them;
    - the derivative is the filtered error's, low-pass filtered (FLTD): it differentiates the error,
      not the measurement, so a target step does kick it;
    - the integrator adds ki e dt and is bounded by IMAX; while ``limit`` says the actuators are
      saturated, it may only shrink.
    """

    def __init__(self, gains: ACPIDGains) -> None:
        self.gains = gains
        self.reset()

    def reset(self) -> None:
        """Forget the filters and the integrator (the next sample restarts the filters)."""
        self.integrator = 0.0
        self._reset_filter = True
        self._target = self._error = self._derivative = 0.0

    @property
    def error(self) -> float:
        """The filtered error of the last update."""
        return self._error

    def update(self, target: float, measurement: float, dt: float, limit: bool = False) -> float:
        """The output for this step; 0 for a non-finite input, as AC_PID returns."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive time step, got {dt!r}")
        if not (math.isfinite(target) and math.isfinite(measurement)):
            return 0.0
        g = self.gains
        if self._reset_filter:
            self._reset_filter = False
            self._target = target
            self._error = target - measurement
            self._derivative = 0.0
        else:
            error_last = self._error
            self._target += lowpass_alpha(dt, g.target_filter_hz) * (target - self._target)
            self._error += lowpass_alpha(dt, g.error_filter_hz) * ((self._target - measurement) - self._error)
            derivative = (self._error - error_last) / dt
            self._derivative += lowpass_alpha(dt, g.derivative_filter_hz) * (derivative - self._derivative)
        if g.ki != 0.0:
            shrinking = (self.integrator > 0.0 > self._error) or (self.integrator < 0.0 < self._error)
            if not limit or shrinking:
                self.integrator += self._error * g.ki * dt
                self.integrator = max(-g.imax, min(g.imax, self.integrator))
        else:
            self.integrator = 0.0
        return self._error * g.kp + self.integrator + self._derivative * g.kd
