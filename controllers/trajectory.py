"""Smooth references for go-to-pose: trapezoidal velocity profiles under speed and acceleration limits."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .estimation import wrap_angle


@dataclass(frozen=True)
class TrapezoidalProfile:
    """Travel ``distance`` (>= 0) from rest to rest with at most ``max_speed`` and ``max_accel``.

    Accelerate at ``max_accel``, cruise, decelerate; a short move that never reaches the speed limit
    is a triangle. :meth:`at` gives (travelled, speed, acceleration) at any time.
    """

    distance: float
    max_speed: float
    max_accel: float

    def __post_init__(self) -> None:
        if not (self.max_speed > 0 and self.max_accel > 0 and self.distance >= 0):
            raise ValueError("a profile needs distance >= 0 and positive speed and acceleration limits")

    @property
    def peak_speed(self) -> float:
        """The highest speed reached: the limit, or less on a short move."""
        return min(self.max_speed, math.sqrt(self.distance * self.max_accel))

    @property
    def ramp_time(self) -> float:
        """Seconds spent accelerating (and again decelerating)."""
        return self.peak_speed / self.max_accel

    @property
    def duration(self) -> float:
        """Seconds from start to stop."""
        if self.distance == 0:
            return 0.0
        ramp = self.ramp_time
        cruise = (self.distance - self.max_accel * ramp**2) / self.peak_speed
        return 2 * ramp + max(0.0, cruise)

    def at(self, t: float) -> tuple[float, float, float]:
        """(distance travelled, speed, acceleration) at time ``t`` (s)."""
        total, ramp, v, a = self.duration, self.ramp_time, self.peak_speed, self.max_accel
        if self.distance == 0 or t >= total:
            return self.distance, 0.0, 0.0
        if t <= 0:
            return 0.0, 0.0, 0.0
        if t < ramp:
            return 0.5 * a * t * t, a * t, a
        if t <= total - ramp:
            return 0.5 * a * ramp * ramp + v * (t - ramp), v, 0.0
        left = total - t
        return self.distance - 0.5 * a * left * left, a * left, -a


@dataclass(frozen=True)
class PoseReference:
    """Where the vehicle should be at one instant: position, velocity, acceleration (world), yaw and rate,
    and the pitch (rad, nose down +) a vehicle that can pitch should hold (0: level)."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    yaw: float
    yaw_rate: float = 0.0
    pitch: float = 0.0


@dataclass(frozen=True)
class MotionLimits:
    """Speed and acceleration limits of a move (defaults: gentle, well inside a BlueROV2's authority)."""

    max_speed: float = 0.3  # m/s
    max_accel: float = 0.15  # m/s^2
    max_yaw_rate: float = 0.5  # rad/s
    max_yaw_accel: float = 0.5  # rad/s^2


class PoseTrajectory:
    """A straight line from one pose (x, y, z, yaw) to another, position and yaw each on a trapezoidal
    profile, both stretched to the longer of the two durations so they start and end together."""

    def __init__(self, start, start_yaw: float, goal, goal_yaw: float, limits: MotionLimits | None = None):
        limits = limits or MotionLimits()
        self.start, self.goal = np.array(start, float), np.array(goal, float)  # copies: an estimate moves on
        offset = self.goal - self.start
        self.length = float(np.linalg.norm(offset))
        self.direction = offset / self.length if self.length > 0 else np.zeros(3)
        self.start_yaw = start_yaw
        self.turn = wrap_angle(goal_yaw - start_yaw)
        line = TrapezoidalProfile(self.length, limits.max_speed, limits.max_accel)
        spin = TrapezoidalProfile(abs(self.turn), limits.max_yaw_rate, limits.max_yaw_accel)
        self.duration = max(line.duration, spin.duration)
        # slow the faster profile down so both take the same time (scale its limits)
        self._line = _stretched(line, self.duration)
        self._spin = _stretched(spin, self.duration)

    def at(self, t: float) -> PoseReference:
        """The reference at time ``t`` since the start of the move."""
        s, v, a = self._line.at(t)
        angle, rate, _ = self._spin.at(t)
        sign = 1.0 if self.turn >= 0 else -1.0
        return PoseReference(
            self.start + s * self.direction,
            v * self.direction,
            a * self.direction,
            wrap_angle(self.start_yaw + sign * angle),
            sign * rate,
        )


def _stretched(profile: TrapezoidalProfile, duration: float) -> TrapezoidalProfile:
    """The same distance over ``duration`` (>= the profile's own): both limits scaled by one factor."""
    if profile.distance == 0 or profile.duration >= duration:
        return profile
    # a triangle/trapezoid's duration scales as 1/k when speed and acceleration scale as k and k^2
    k = profile.duration / duration
    return TrapezoidalProfile(profile.distance, profile.max_speed * k, profile.max_accel * k * k)


@dataclass(frozen=True)
class Hold:
    """Stay at one pose (x, y, z, yaw) for ``duration`` seconds: a leg of a :class:`Route`."""

    position: np.ndarray
    yaw: float
    duration: float

    def at(self, t: float) -> PoseReference:
        """The reference at any time: the pose, at rest."""
        return PoseReference(np.asarray(self.position, float), np.zeros(3), np.zeros(3), self.yaw)


class Route:
    """Legs (:class:`PoseTrajectory` or :class:`Hold`) flown one after another; ``at(t)`` is the reference
    ``t`` seconds from the start, and past the end the last leg's end, held."""

    def __init__(self, legs: list) -> None:
        if not legs:
            raise ValueError("a route needs at least one leg")
        self.legs = list(legs)
        self.starts = np.cumsum([0.0, *(leg.duration for leg in self.legs[:-1])])
        self.duration = float(self.starts[-1] + self.legs[-1].duration)

    def at(self, t: float) -> PoseReference:
        """The reference at time ``t`` since the route began."""
        k = max(0, int(np.searchsorted(self.starts, t, side="right")) - 1)
        return self.legs[k].at(t - self.starts[k])
