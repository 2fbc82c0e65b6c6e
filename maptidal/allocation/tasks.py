"""Auction tasks: inspection viewpoints as the auction and the modem see them.

A task is a viewpoint (position and viewing direction, as Map-TIDAL discovery emits them) plus the
capabilities a robot needs to do it. Poses are quantised when a task is created, to the resolution the
acoustic message carries (position 1 cm, direction well under 0.5 deg), so that every robot computes its
bids from exactly the same numbers as the robot that discovered the task.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

# Capability bits. A task's `requires` mask and a robot's capability mask use the same bits.
CAPABILITIES: tuple[str, ...] = ("camera", "dvl", "tool", "sonar", "light", "manipulator")

POSITION_STEP_M = 0.01  # issue #5: positions travel to 1 cm
POSITION_LIMIT_M = 327.67  # int16 centimetres
# Direction as 12-bit azimuth and 12-bit elevation: steps of 0.088 and 0.044 deg (issue #5 asks ~0.5 deg).
AZIMUTH_STEPS = 4096
ELEVATION_STEPS = 4095

MISSION_ORIGIN = 255  # origin byte of tasks given in the mission plan rather than discovered by a robot


class TaskError(ValueError):
    """A task or capability that cannot be represented."""


def capability_mask(names: Iterable[str]) -> int:
    """Bit mask of capability names; unknown names raise TaskError."""
    mask = 0
    for name in names:
        if name not in CAPABILITIES:
            raise TaskError(f"unknown capability {name!r}; known: {', '.join(CAPABILITIES)}")
        mask |= 1 << CAPABILITIES.index(name)
    return mask


def capability_names(mask: int) -> list[str]:
    """The capability names of a bit mask."""
    return [name for bit, name in enumerate(CAPABILITIES) if mask >> bit & 1]


def task_key(origin: int, counter: int) -> int:
    """Network-wide task key: the discovering robot's index and its own task counter.

    Robots mint keys without coordination, so two robots never mint the same key."""
    if not 0 <= origin <= 255 or not 0 <= counter <= 0xFFFF:
        raise TaskError(f"task key out of range: origin {origin}, counter {counter}")
    return origin << 16 | counter


def quantise_position(position: Iterable[float]) -> tuple[int, int, int]:
    """Centimetre integers of a position; raises TaskError outside the int16 range or on NaN."""
    values = [float(v) for v in position]
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise TaskError(f"task position must be 3 finite numbers, got {values}")
    if any(abs(v) > POSITION_LIMIT_M for v in values):
        raise TaskError(f"task position {values} outside +-{POSITION_LIMIT_M} m")
    return tuple(round(v / POSITION_STEP_M) for v in values)  # type: ignore[return-value]


def quantise_direction(direction: Iterable[float]) -> tuple[int, int]:
    """12-bit azimuth and elevation codes of a viewing direction (any non-zero length)."""
    d = np.asarray([float(v) for v in direction], dtype=float)
    norm = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
    if not math.isfinite(norm) or norm < 1e-9:
        raise TaskError(f"task direction must be a finite non-zero 3-vector, got {d.tolist()}")
    d /= norm
    azimuth = math.atan2(d[1], d[0]) % (2 * math.pi)
    elevation = math.asin(max(-1.0, min(1.0, d[2])))
    az_code = round(azimuth / (2 * math.pi) * AZIMUTH_STEPS) % AZIMUTH_STEPS
    el_code = round((elevation + math.pi / 2) / math.pi * ELEVATION_STEPS)
    return az_code, el_code


def direction_from_codes(az_code: int, el_code: int) -> np.ndarray:
    """Unit vector of 12-bit azimuth and elevation codes."""
    azimuth = az_code / AZIMUTH_STEPS * 2 * math.pi
    elevation = el_code / ELEVATION_STEPS * math.pi - math.pi / 2
    return np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )


@dataclass(frozen=True)
class Task:
    """One inspection task with its pose already quantised to the message resolution.

    key: network-wide key (see task_key); name: a human label (not sent over the modem);
    position_cm: int16 centimetres; direction_code: 12-bit azimuth and elevation; requires: capability
    bit mask."""

    key: int
    position_cm: tuple[int, int, int]
    direction_code: tuple[int, int]
    requires: int = 0
    name: str = ""

    @classmethod
    def create(
        cls,
        key: int,
        position: Iterable[float],
        direction: Iterable[float] = (1.0, 0.0, 0.0),
        requires: Iterable[str] | int = (),
        name: str = "",
    ) -> Task:
        """A task from a metric pose; the pose is quantised here, once, for everybody."""
        mask = requires if isinstance(requires, int) else capability_mask(requires)
        return cls(key, quantise_position(position), quantise_direction(direction), mask, name or f"k{key}")

    @property
    def position(self) -> np.ndarray:
        """Position in metres (after quantisation)."""
        return np.asarray(self.position_cm, dtype=float) * POSITION_STEP_M

    @property
    def direction(self) -> np.ndarray:
        """Unit viewing direction (after quantisation)."""
        return direction_from_codes(*self.direction_code)
