"""The one action convention: a normalised 6-DOF pilot command, as ArduSub reads it.

A command is six numbers in [-1, 1], in this order::

    surge  (forward +)      sway  (right +)      heave (up +)
    roll   (right side down +)   pitch (nose up +)   yaw (turn right, clockwise from above +)

These are ArduSub's pilot inputs (forward, lateral, throttle, roll, pitch, yaw in
AP_Motors6DOF; docs/references.md), so the same vector drives
the simulator's mixer and, through MANUAL_CONTROL / RC overrides, a real vehicle.
Heave is ArduSub's bidirectional throttle: 0 is neutral.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

AXES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")


class CommandError(ValueError):
    """A command that is not six finite numbers, or names an unknown axis."""


def pilot_command(values: Sequence[float] | Mapping[str, float] | np.ndarray | None = None) -> np.ndarray:
    """A validated pilot command ``(6,)`` from a sequence in :data:`AXES` order or a mapping.

    Missing axes of a mapping are 0. Values are clipped to [-1, 1]; NaN or infinite
    values raise :class:`CommandError`, so a bad command never reaches the thrusters.
    """
    if values is None:
        return np.zeros(6)
    if isinstance(values, Mapping):
        unknown = set(values) - set(AXES)
        if unknown:
            raise CommandError(f"unknown command axis {sorted(unknown)}; axes are {', '.join(AXES)}")
        values = [float(values.get(axis, 0.0)) for axis in AXES]
    command = np.asarray(values, dtype=float)
    if command.shape != (6,):
        raise CommandError(f"a pilot command has 6 values ({', '.join(AXES)}), got shape {command.shape}")
    if not np.isfinite(command).all():
        raise CommandError(f"a pilot command must be finite, got {command.tolist()}")
    return command.clip(-1.0, 1.0)


def parse_command(text: str) -> np.ndarray:
    """Parse ``"surge=1.0,heave=-0.2"`` into a pilot command; unnamed axes are 0.

    Stricter than :func:`pilot_command`, since a person typed it: an axis named twice or a value
    outside [-1, 1] raises :class:`CommandError` instead of being clipped.
    """
    values: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise CommandError(f"expected axis=value, got {item!r}")
        if name in values:
            raise CommandError(f"axis {name!r} is given twice")
        try:
            number = float(value)
        except ValueError:
            raise CommandError(f"{name}: {value!r} is not a number") from None
        if not -1.0 <= number <= 1.0:
            raise CommandError(f"{name}={value.strip()} is outside [-1, 1] (commands are normalised)")
        values[name] = number
    return pilot_command(values)


@dataclass(frozen=True)
class PilotGain:
    """ArduSub's pilot gain: how much of each RC channel's range a full MANUAL_CONTROL stick takes.

    ArduSub turns MANUAL_CONTROL into RC channels in ``Sub::transform_manual_control_to_rc_override``
    (``ArduSub/joystick.cpp``, ArduPilot master): forward x, lateral y and yaw r (each +-1000) go to
    ``1500 + stick x 0.4 x gain`` us, throttle z (0 to 1000, 500 neutral) to
    ``1500 + (z - 500) x 0.8 x gain x JS_THR_GAIN`` us, each constrained to 1100-1900 us. As fractions of
    the 400 us half-range that is ``stick x gain`` and ``heave x gain x JS_THR_GAIN``, clipped to [-1, 1].
    Roll and pitch do not come through MANUAL_CONTROL and are not scaled. ``gain`` is the live
    joystick gain, set at boot from JS_GAIN_DEFAULT (:func:`boot_gain`; ArduSub's default 0.5) and
    stepped by joystick buttons; ArduSub bounds it to [0.1, 1.0]. ``throttle_gain`` is JS_THR_GAIN
    (default 1.0, range 0.5 to 4.0 in ArduSub's parameter table)."""

    gain: float = 1.0
    throttle_gain: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.gain, bool) or not (
            isinstance(self.gain, int | float) and 0.1 <= self.gain <= 1.0
        ):
            raise ValueError(
                f"the pilot gain (JS_GAIN) lies in [0.1, 1.0] as ArduSub bounds it, got {self.gain!r}"
            )
        throttle = self.throttle_gain
        if isinstance(throttle, bool) or not (isinstance(throttle, int | float) and 0.5 <= throttle <= 4.0):
            raise ValueError(f"JS_THR_GAIN lies in [0.5, 4.0] (ArduSub's range), got {self.throttle_gain!r}")

    def apply(self, command: np.ndarray) -> np.ndarray:
        """The command as ArduSub's RC channels carry it: surge, sway and yaw times ``gain``, heave times
        ``gain x throttle_gain``, clipped to [-1, 1]; roll and pitch unchanged. ``command`` is one (6,)
        command or an (N, 6) batch of them."""
        if self.gain == 1.0 and self.throttle_gain == 1.0:
            return command
        scaled = np.array(command, float)
        scaled[..., [0, 1, 5]] *= self.gain
        scaled[..., 2] *= self.gain * self.throttle_gain
        return scaled.clip(-1.0, 1.0)


def boot_gain(default: float, minimum: float, maximum: float, steps: int) -> float:
    """The pilot gain ArduSub starts with (``Sub::init_joystick``): JS_GAIN_DEFAULT within
    [JS_GAIN_MIN, JS_GAIN_MAX] (or with JS_GAIN_STEPS 1), else the step nearest the middle, bounded to
    [0.1, 1.0]."""
    steps = max(int(steps), 1)
    if steps == 1 or minimum - 0.01 < default < maximum + 0.01:
        gain = min(max(default, minimum), maximum)
    else:
        gain = minimum + (steps // 2 - 1) * (maximum - minimum) / (steps - 1)
    if not math.isfinite(gain):
        raise ValueError(f"the joystick gain parameters give no finite gain: {default}, {minimum}, {maximum}")
    return min(max(gain, 0.1), 1.0)
