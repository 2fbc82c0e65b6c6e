"""Validation helpers shared by the configuration loaders (scenarios, tank files, auction files).

Each takes the error class to raise, so that every loader reports its own kind of error with a message
naming the offending value."""

from __future__ import annotations

import math


def require(condition: bool, message: str, error: type[Exception] = ValueError) -> None:
    """Raise error(message) unless condition holds."""
    if not condition:
        raise error(message)


def check_keys(table: dict, allowed: set[str], where: str, error: type[Exception] = ValueError) -> None:
    """Reject keys of table that are not in allowed (typos must not be silently ignored)."""
    for key in table:
        require(
            key in allowed, f"unknown key {key!r} in {where}; allowed: {', '.join(sorted(allowed))}", error
        )


def finite_vector(value, where: str, size: int = 3, error: type[Exception] = ValueError) -> tuple[float, ...]:
    """A tuple of `size` finite floats, or error naming `where`."""
    ok = isinstance(value, list | tuple) and len(value) == size
    ok = ok and all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value
    )
    require(ok, f"{where} must be {size} finite numbers, got {value!r}", error)
    return tuple(float(v) for v in value)


def finite_number(
    value, where: str, minimum: float = -math.inf, error: type[Exception] = ValueError
) -> float:
    """A finite float >= minimum, or error naming `where`."""
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    require(ok and value >= minimum, f"{where} must be a finite number >= {minimum}, got {value!r}", error)
    return float(value)
