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

from collections.abc import Mapping, Sequence

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
