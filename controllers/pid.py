"""A PID controller for one axis: derivative on the measurement, anti-windup and output limits."""

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
