"""How far a vehicle may have moved that its motion model did not say: pushes, seen by the accelerometer.

A robot without a DVL dead-reckons its horizontal velocity on a motion model of its own thrust
(:class:`maptidal.controllers.estimation.MotionModel`). The model knows the thrusters, the buoyancy and
the water's drag; a teammate's hull, a wall or the floor it does not. Pushed, the vehicle moves as the
model does not say, and its estimate, sure of itself, holds still. Pressed against a wall, the model
flies on while the vehicle stands.

This module does not correct the estimate: following a push on the accelerometer ran away in the loop
(a tilt error of 0.01 rad while rubbing a wall leaks 0.1 m/s^2 of gravity into the integrated velocity;
CHANGELOG, session 36). It says how far off the estimate may have gone, so that the front end's
uncertainty grows with it (``VisualOdometry.update``'s ``unmodelled_m``): its relocalisation then searches
wider, and the mission calls a robot that far off lost, sends it where its map is surest, and fixes it.

Each control period :meth:`UnmodelledMotion.update` takes the period's mean specific force
(``imu["accel_mean"]``: an impact of a few milliseconds is in it, where an end-of-period sample misses
it), the gyro, the attitude and the estimator's body velocity, and compares the body acceleration the
accelerometer measured (specific force less gravity, less a slowly learned offset: the accelerometer's
bias and the vertical's own error) with the one the model gave, ``v' + w x v``. Gravity is taken out
along a vertical of the watch's own: the gyro's, less its learned bias, drawn slowly towards the
estimator's while no push is on and left alone through one. The estimator's own tilt correction
takes a push's acceleration for gravity's within seconds, and integrating against it lost half a
teammate's push in the default mission. The difference is low-passed as a vector over ``settle_s``:

- **Quiet** while the filtered difference stays under ``start_m_s2``; the offset learns from it over
  ``offset_s``.
- **A push** begins above ``start_m_s2``: the unmodelled velocity starts from the difference's leaky
  integral over the last ``recent_s`` (the velocity change while the filter rose) and integrates the
  difference each period (the period means sum to the
  velocity change exactly); its horizontal speed integrates into the unmodelled displacement. It follows
  both cases: a push (the vehicle's speed, then the drag that slows it, which the model does not see
  either), and a stop against a wall (the wall's impact takes the model's speed off the vehicle; the
  model flies on, and the velocity stays at minus the model's speed until the model stops too).
- **Over** once, after ``settle_s``, the filtered difference is under ``end_m_s2`` and the unmodelled
  horizontal speed under ``end_speed_m_s`` plus what the attitude's tilt error could have made of it
  since the push began (``tilt_drift_m_s2`` a second: the model explains the motion again, and what is
  left of the push is too slow for the accelerometer to follow), or after ``max_s``.
  The speed is bounded by ``max_speed_m_s``, above the vehicle's top speed, so that a tilt error in
  contact cannot grow it without end.
- **Coasting** on what is left: a pushed vehicle glides on for long after, for the water's drag slows
  it less the slower it goes (the Heavy's sway has no linear damping at all: from 5 cm/s it drifts
  17 cm in the next 10 s). Given the vehicle's mass and damping (``inertia``, ``linear_damping`` and
  ``quadratic_damping``, Fossen's diagonal model as the estimator's
  :class:`maptidal.controllers.estimation.MotionModel` has them), the unmodelled velocity then decays as
  that drag slows it, and its displacement still counts, until it is under ``rest_speed_m_s`` or
  ``coast_s`` has passed. The glide's slowing is then taken out of the difference, so that it does
  not start a push of its own; a new push while coasting starts from the velocity left. Without them
  a push ends where the accelerometer loses it.

The thresholds are the free flight's. With the thrusters' lag in the model, 130 s of the default
mission's flight without contact (seed 8, the robot without a DVL) gave a filtered difference of
0.022 m/s^2 at the median, 0.057 at the 99th percentile and 0.075 at most; a push begins at twice
that most and ends under it. A teammate's push at full stick starts at 5 m/s^2 or more, a wall's stop
at 17 m/s^2, a gentle shove at 0.25 m/s^2 (CHANGELOG, session 36).

numpy-free: plain floats, since it runs every control period for every robot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from maptidal.controllers.estimation import STANDARD_GRAVITY


@dataclass(frozen=True)
class UnmodelledMotionParams:
    """When the accelerometer says the motion model is wrong, and for how long (module docstring)."""

    start_m_s2: float = 0.15
    end_m_s2: float = 0.075
    settle_s: float = 0.5
    recent_s: float = 1.0
    # the watch's own vertical follows the estimator's this slowly, and not during a push (_vertical)
    vertical_s: float = 10.0
    offset_s: float = 10.0
    # below this the unmodelled speed adds under 5 cm a second: the free flight's drift without a DVL
    # (2e-3 m^2/s, OdometryParams.drift_m2_s_no_dvl, is 4.5 cm in the first second)
    end_speed_m_s: float = 0.05
    # the accelerometer's velocity drifts by up to this much a second from the attitude's tilt error,
    # which contact makes (its Mahony correction then trusts a wrong model acceleration): 0.003 rad, times
    # g, in the default mission's meetings (seed 3, session 37). A push whose speed that drift could
    # have made is over
    tilt_drift_m_s2: float = 0.03
    max_s: float = 10.0
    max_speed_m_s: float = 1.0  # above the Heavy's top speed, 0.91 m/s (assets/bluerov2/README.md)
    # the vehicle's drag, per body axis, for the glide after a push (None: no glide counted): kg, N s/m,
    # N s^2/m^2, the motion model's own (MotionModel.inertia, linear_damping, quadratic_damping)
    inertia: tuple[float, float, float] | None = None
    linear_damping: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quadratic_damping: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rest_speed_m_s: float = 0.005  # a glide this slow adds under 5 mm a second
    coast_s: float = 30.0

    def __post_init__(self) -> None:
        names = (
            "start_m_s2",
            "end_m_s2",
            "settle_s",
            "recent_s",
            "vertical_s",
            "offset_s",
            "end_speed_m_s",
            "tilt_drift_m_s2",
            "max_s",
            "max_speed_m_s",
            "rest_speed_m_s",
            "coast_s",
        )
        for name in names:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be finite and > 0, got {value!r}")
        if self.end_m_s2 >= self.start_m_s2:
            raise ValueError(f"end_m_s2 ({self.end_m_s2}) must be below start_m_s2 ({self.start_m_s2})")
        if self.inertia is not None:
            drag = (*self.inertia, *self.linear_damping, *self.quadratic_damping)
            if (
                len(drag) != 9
                or not all(math.isfinite(v) and v >= 0.0 for v in drag)
                or min(self.inertia) <= 0
            ):
                raise ValueError(
                    "inertia (> 0), linear_damping and quadratic_damping (>= 0) must be three finite "
                    f"numbers each, got {self.inertia!r}, {self.linear_damping!r}, {self.quadratic_damping!r}"
                )

    @classmethod
    def for_model(cls, model, **settings) -> UnmodelledMotionParams:
        """These parameters with the glide of a vehicle whose motion model is ``model`` (anything with
        ``inertia``, ``linear_damping`` and ``quadratic_damping``, per body axis, as
        :class:`maptidal.controllers.estimation.MotionModel` has them)."""
        return cls(
            inertia=tuple(float(v) for v in model.inertia),
            linear_damping=tuple(float(v) for v in model.linear_damping),
            quadratic_damping=tuple(float(v) for v in model.quadratic_damping),
            **settings,
        )


def up_in_body(roll: float, pitch: float) -> tuple[float, float, float]:
    """The world's vertical in body axes (the last row of the z-y-x body-to-world rotation)."""
    return (-math.sin(pitch), math.sin(roll) * math.cos(pitch), math.cos(roll) * math.cos(pitch))


class UnmodelledMotion:
    """The displacement a vehicle's motion model has not accounted for (module docstring).

    Feed it every control period with :meth:`update`; :meth:`take` returns the horizontal displacement
    (m) gathered since the last take. ``pushes`` counts the pushes begun, ``pushing`` says whether one is
    measured now, ``coasting`` whether what one left glides on."""

    def __init__(self, params: UnmodelledMotionParams | None = None) -> None:
        self.params = params or UnmodelledMotionParams()
        self.offset = [0.0, 0.0, 0.0]  # the accelerometer's learned offset from the model, body, m/s^2
        self.filtered = [0.0, 0.0, 0.0]  # the low-passed difference, body, m/s^2
        self.velocity = [0.0, 0.0, 0.0]  # the unmodelled velocity during a push, body, m/s
        self.pushing = False
        self.coasting = False
        self.elapsed_s = 0.0
        self.pushes = 0
        self._displacement_m = 0.0
        self._previous_velocity: tuple[float, float, float] | None = None
        self._recent = [0.0, 0.0, 0.0]  # the difference's leaky integral over recent_s, m/s
        self._up: list[float] | None = None  # the watch's own vertical, body axes (_vertical)
        self._gyro_bias = [0.0, 0.0, 0.0]  # rad/s, learned (_vertical)

    def reset(self) -> None:
        """Forget the motion so far (a period the model did not fly: a DVL measured the velocity)."""
        self.filtered = [0.0, 0.0, 0.0]
        self._recent = [0.0, 0.0, 0.0]
        self._up = None  # the gyro was not followed: start again from the estimator's vertical
        self.velocity = [0.0, 0.0, 0.0]
        self.pushing = self.coasting = False
        self._previous_velocity = None

    def take(self) -> float:
        """The unmodelled horizontal displacement (m) since the last call; it starts again from zero."""
        taken, self._displacement_m = self._displacement_m, 0.0
        return taken

    def update(
        self,
        specific_force_body: Sequence[float],
        gyro_body: Sequence[float],
        roll: float,
        pitch: float,
        velocity_body: Sequence[float],
        dt: float,
        modelled: bool = True,
    ) -> None:
        """Fold in one control period of ``dt`` seconds: the period's mean specific force (m/s^2, body),
        the gyro (rad/s, body), the attitude at its end (rad) and the estimator's body velocity at its end
        (m/s), which its motion model gave when ``modelled``. A period that did not run on the model (a
        DVL's velocity) resets the push and the velocity it compares with."""
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be finite and > 0, got {dt!r}")
        values = (*specific_force_body, *gyro_body, roll, pitch, *velocity_body)
        if not all(math.isfinite(v) for v in values):
            return  # a bad reading says nothing about the model; the next good one goes on
        velocity = (float(velocity_body[0]), float(velocity_body[1]), float(velocity_body[2]))
        previous, self._previous_velocity = self._previous_velocity, velocity
        if not modelled:
            self.reset()
            self._previous_velocity = velocity
            return
        if previous is None:
            return
        p = self.params
        wx, wy, wz = (float(g) for g in gyro_body)
        vx, vy, vz = velocity
        # the model's body acceleration v' + w x v, and the accelerometer's (specific force less gravity)
        model = (
            (vx - previous[0]) / dt + wy * vz - wz * vy,
            (vy - previous[1]) / dt + wz * vx - wx * vz,
            (vz - previous[2]) / dt + wx * vy - wy * vx,
        )
        up = self._vertical(gyro_body, up_in_body(roll, pitch), dt)
        difference = [
            float(specific_force_body[i]) - STANDARD_GRAVITY * up[i] - self.offset[i] - model[i]
            for i in range(3)
        ]
        if self.coasting:  # the glide's slowing is explained: what is left is new
            glide = self._glide(dt)
            difference = [difference[i] - glide[i] for i in range(3)]
        gain = min(dt / p.settle_s, 1.0)
        # the velocity change the difference made over the last recent_s or so (a leaky integral): a push
        # that builds up over a second has given most of its speed by the time the filter passes
        # start_m_s2, more than the filter's own memory holds
        keep = max(1.0 - dt / p.recent_s, 0.0)
        recent = self._recent = [keep * self._recent[i] + dt * difference[i] for i in range(3)]
        before = self.filtered
        self.filtered = [before[i] + gain * (difference[i] - before[i]) for i in range(3)]
        size = math.sqrt(sum(f * f for f in self.filtered))
        if not self.pushing:
            if size <= p.start_m_s2:
                learn = min(dt / p.offset_s, 1.0)
                self.offset = [self.offset[i] + learn * difference[i] for i in range(3)]
                if self.coasting:
                    self.elapsed_s += dt
                    horizontal = self._count(up, dt)
                    if horizontal < p.rest_speed_m_s or self.elapsed_s >= p.coast_s:
                        self.coasting = False
                        self.velocity = [0.0, 0.0, 0.0]
                return
            self.pushing, self.coasting, self.elapsed_s = True, False, 0.0
            self.pushes += 1
            # what the push gave while the filter rose (the difference's recent integral, but for this
            # period's, which the push's own step adds below), on top of what an earlier one left gliding
            self.velocity = [self.velocity[i] + recent[i] - dt * difference[i] for i in range(3)]
        self.elapsed_s += dt
        velocity_off = [self.velocity[i] + dt * difference[i] for i in range(3)]
        speed = math.sqrt(sum(v * v for v in velocity_off))
        if speed > p.max_speed_m_s:
            velocity_off = [v * (p.max_speed_m_s / speed) for v in velocity_off]
        self.velocity = velocity_off
        horizontal = self._count(up, dt)
        drifted = p.end_speed_m_s + p.tilt_drift_m_s2 * self.elapsed_s
        settled = self.elapsed_s >= p.settle_s and size < p.end_m_s2 and horizontal < drifted
        if settled or self.elapsed_s >= p.max_s:
            self.pushing = False
            # the filter and the recent integral start again from nothing: what they hold is this push's
            self.filtered, self._recent = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
            self.coasting, self.elapsed_s = p.inertia is not None and settled, 0.0
            if not self.coasting:
                self.velocity = [0.0, 0.0, 0.0]

    def _vertical(
        self, gyro_body: Sequence[float], estimated: tuple[float, float, float], dt: float
    ) -> tuple[float, float, float]:
        """The watch's own vertical (the world's up in body axes), carried through each period by the
        gyro less its learned bias (the body turning at w, a fixed vector's body coordinates turn as
        u' = u x w). While no push is on it is drawn towards the estimator's vertical over ``vertical_s``,
        and the gyro's bias is learned from that pull, as Mahony's filter's integral term learns it
        (critically damped: the integral gain is a quarter of the proportional gain squared). The
        estimator's tilt correction takes a push's acceleration for gravity's within seconds (its gain,
        0.2 rad/s); this one, slower and held on the gyro alone through a push, keeps the vertical the
        push began with, and the gyro's bias does not tilt it meanwhile (0.0008 rad/s in the simulator
        after a minute, which tilts a vertical 0.008 rad in 10 s: 0.08 m/s^2 of gravity)."""
        if self._up is None:
            self._up = list(estimated)
            return estimated
        ux, uy, uz = self._up
        wx, wy, wz = (float(gyro_body[i]) - self._gyro_bias[i] for i in range(3))
        if not self.pushing:
            # est x u turns u towards est (u x (est x u) = est - u (u . est))
            ex = estimated[1] * uz - estimated[2] * uy
            ey = estimated[2] * ux - estimated[0] * uz
            ez = estimated[0] * uy - estimated[1] * ux
            proportional = 1.0 / self.params.vertical_s
            integral = 0.25 * proportional * proportional
            self._gyro_bias = [
                self._gyro_bias[0] - integral * ex * dt,
                self._gyro_bias[1] - integral * ey * dt,
                self._gyro_bias[2] - integral * ez * dt,
            ]
            wx, wy, wz = wx + proportional * ex, wy + proportional * ey, wz + proportional * ez
        ux, uy, uz = (
            ux + dt * (uy * wz - uz * wy),
            uy + dt * (uz * wx - ux * wz),
            uz + dt * (ux * wy - uy * wx),
        )
        norm = math.sqrt(ux * ux + uy * uy + uz * uz)
        self._up = [ux / norm, uy / norm, uz / norm]
        return (self._up[0], self._up[1], self._up[2])

    def _count(self, up: tuple[float, float, float], dt: float) -> float:
        """Add the unmodelled velocity's horizontal part over ``dt`` to the displacement; that speed."""
        along_up = sum(self.velocity[i] * up[i] for i in range(3))
        horizontal = math.sqrt(max(sum(v * v for v in self.velocity) - along_up * along_up, 0.0))
        self._displacement_m += horizontal * dt
        return horizontal

    def _glide(self, dt: float) -> list[float]:
        """One period of the glide after a push: the unmodelled velocity slowed by the vehicle's drag
        (implicitly, so that a long period cannot reverse it); the acceleration that was (m/s^2)."""
        p = self.params
        before = self.velocity
        self.velocity = [
            v / (1.0 + dt * (p.linear_damping[i] + p.quadratic_damping[i] * abs(v)) / p.inertia[i])
            for i, v in enumerate(before)
        ]
        return [(self.velocity[i] - before[i]) / dt for i in range(3)]
