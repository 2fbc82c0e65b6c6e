"""Where a robot waits so as to keep clear of its teammates: the geometry of the mission's keep-clear rule
(``Mission._keep_clear`` says whom a robot gives way to; this module says where it stops).

A teammate is a ball of the clearance radius about where its last message said it was. A robot flies
straight from where it is to its reference; it stops where that straight way first enters a ball, on its
own side, so that it never crosses a teammate to reach a goal beyond it. A robot already inside a ball
(a teammate came to it, or the ball is new) may leave by any way that takes it farther from the centre;
otherwise it backs out horizontally, at its own depth.
"""

from __future__ import annotations

import numpy as np


def segment_entry(start: np.ndarray, end: np.ndarray, centre: np.ndarray, radius: float) -> float | None:
    """The fraction along the segment ``start`` to ``end`` at which it enters the ball of ``radius``
    about ``centre``, or None when it does not (``start`` inside the ball counts as not entering)."""
    direction = end - start
    offset = start - centre
    a = float(direction @ direction)
    c = float(offset @ offset) - radius * radius
    if a == 0.0 or c < 0.0:
        return None
    b = 2.0 * float(offset @ direction)
    discriminant = b * b - 4.0 * a * c
    if b >= 0.0 or discriminant < 0.0:  # heading away, or passing by
        return None
    entry = (-b - np.sqrt(discriminant)) / (2.0 * a)
    return float(entry) if entry <= 1.0 else None


def waiting_point(
    position: np.ndarray, target: np.ndarray, centres: list[np.ndarray], radius: float
) -> tuple[np.ndarray, int] | None:
    """Where a robot at ``position`` bound straight for ``target`` stops to stay out of every ball of
    ``radius`` about ``centres``, and which ball stops it; None when its way is clear (module docstring).

    Inside a ball and not leaving it, the robot backs out horizontally, at its own depth, away from the
    centre: never down onto the floor or up to the surface, where a teammate above or below would send
    it (on the floor its DVL is blind and its thrust moves nothing, and its estimate runs off). Right
    under or over the centre it backs away from its target. If that point lies in another ball it is
    moved out of that one in turn, a few rounds at most (where balls overlap, the last one wins).
    Outside every ball, it stops where its straight way first enters one: between where it is and where
    it was going, so in water it was already bound through."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    heading = target - position
    for index, centre in enumerate(centres):
        offset = position - centre
        if float(np.linalg.norm(offset)) < radius and float(heading @ offset) <= 0.0:
            point, blocking = position, index  # inside, and not on its way out
            for _ in range(3):
                moved = False
                for other, ball in enumerate(centres):
                    moved_out = _out_horizontally(point, ball, radius, heading)
                    if moved_out is not None:
                        point, blocking, moved = moved_out, other, True
                if not moved:
                    break
            return point, blocking
    fractions = [segment_entry(position, target, centre, radius) for centre in centres]
    entered = [(fraction, index) for index, fraction in enumerate(fractions) if fraction is not None]
    if not entered:
        return None
    fraction, index = min(entered)
    return position + fraction * heading, index


def _out_horizontally(
    point: np.ndarray, centre: np.ndarray, radius: float, heading: np.ndarray
) -> np.ndarray | None:
    """``point`` moved horizontally to the surface of the ball, or None when it is not inside."""
    offset = point - centre
    if float(np.linalg.norm(offset)) >= radius - 1e-9:
        return None
    reach = np.sqrt(max(radius * radius - offset[2] * offset[2], 0.0))  # the ball's radius at this depth
    away = offset[:2]
    if np.linalg.norm(away) < 1e-9:
        away = -heading[:2]
    if np.linalg.norm(away) < 1e-9:
        away = np.array([1.0, 0.0])
    away = away / np.linalg.norm(away)
    return np.array([centre[0] + reach * away[0], centre[1] + reach * away[1], point[2]])
