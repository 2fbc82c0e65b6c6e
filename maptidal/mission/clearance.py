"""Where a robot waits so as to keep clear of its teammates: the geometry of the mission's keep-clear rule
(``Mission._keep_clear`` says whom a robot gives way to; this module says where it stops).

A teammate is a *capsule* of the clearance radius: every point within that radius of the segment from
where its last message said it was towards where that message said it was bound, as far as it can have
flown since (a teammate that said nothing of where it was bound, or has not had time to move, is a ball).
A robot flies straight from where it is to its reference; it stops where that straight way first enters
a capsule, on its own side, so that it never crosses a teammate, or a teammate's way, to reach a goal
beyond. A robot already inside a teammate's ball (a teammate came to it, or the ball is new) may leave by
any way that takes it farther from the centre; otherwise it backs out horizontally, at its own depth. One
inside only a teammate's way goes on, and stops short of the teammate's ball.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

Shape = np.ndarray  # a ball's centre, shape (3,), or a capsule's axis, shape (2, 3)


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


def nearest_on_axis(point: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The point of the segment ``axis`` (rows: its two ends) nearest ``point``."""
    first, last = axis
    along = last - first
    length2 = float(along @ along)
    if length2 == 0.0:
        return first.copy()
    share = float(np.clip((point - first) @ along / length2, 0.0, 1.0))
    return first + share * along


def capsule_entry(start: np.ndarray, end: np.ndarray, axis: np.ndarray, radius: float) -> float | None:
    """The fraction along the segment ``start`` to ``end`` at which it enters the capsule of ``radius``
    about ``axis`` (rows: its two ends), or None when it does not (``start`` inside counts as not
    entering). The capsule is the union of the balls at the two ends and the cylinder between them, so
    the first entry is the earliest of the first entries into each: through the cylinder's side where
    the crossing lies between the ends (a way that enters the cylinder through an end disc is inside that
    end's ball already)."""
    if float(np.linalg.norm(start - nearest_on_axis(start, axis))) < radius:
        return None
    first, last = axis
    entries = [segment_entry(start, end, first, radius), segment_entry(start, end, last, radius)]
    along = last - first
    length = float(np.linalg.norm(along))
    if length > 0.0:
        unit = along / length
        direction, offset = end - start, start - first
        direction_across = direction - (direction @ unit) * unit
        offset_across = offset - (offset @ unit) * unit
        a = float(direction_across @ direction_across)
        b = 2.0 * float(offset_across @ direction_across)
        c = float(offset_across @ offset_across) - radius * radius
        discriminant = b * b - 4.0 * a * c
        if a > 0.0 and c >= 0.0 and b < 0.0 and discriminant >= 0.0:
            crossing = (-b - np.sqrt(discriminant)) / (2.0 * a)
            share = float((offset + crossing * direction) @ unit) / length
            if crossing <= 1.0 and 0.0 <= share <= 1.0:
                entries.append(float(crossing))
    found = [entry for entry in entries if entry is not None]
    return min(found) if found else None


def waiting_point(
    position: np.ndarray, target: np.ndarray, shapes: Sequence[Shape], radius: float
) -> tuple[np.ndarray, int] | None:
    """Where a robot at ``position`` bound straight for ``target`` stops to keep clear of teammates, each
    a ball of ``radius`` about a centre, or a capsule about an axis given as two rows (where the teammate
    was, where it may be by now on its way), and which one stops it; None when its way is clear (module
    docstring).

    Inside a teammate's ball (about where it was) and not leaving it, the robot backs out horizontally,
    at its own depth, away from the centre: never down onto the floor or up to the surface, where a
    teammate above or below would send it (on the floor its DVL is blind and its thrust moves nothing,
    and its estimate runs off). Right under or over the centre it backs away from its target. If that
    point lies in another ball it is moved out of that one in turn, a few rounds at most (where balls
    overlap, the last one wins). Inside only a teammate's way, it does not back out (the teammate keeps
    clear of it, or it backs out of the teammate's ball as that comes), and stops where its way enters
    the ball. Otherwise it stops where its straight way first enters a capsule: between where it is and
    where it was going, so in water it was already bound through."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    axes = [_as_axis(shape) for shape in shapes]
    heading = target - position
    for index, axis in enumerate(axes):
        offset = position - axis[0]
        if float(np.linalg.norm(offset)) < radius and float(heading @ offset) <= 0.0:
            point, blocking = position, index  # inside, and not on its way out
            for _ in range(3):
                moved = False
                for other, other_axis in enumerate(axes):
                    moved_out = _out_horizontally(point, other_axis[0], radius, heading)
                    if moved_out is not None:
                        point, blocking, moved = moved_out, other, True
                if not moved:
                    break
            return point, blocking
    fractions = [
        capsule_entry(position, target, axis, radius)
        if float(np.linalg.norm(position - nearest_on_axis(position, axis))) >= radius
        else segment_entry(position, target, axis[0], radius)
        for axis in axes
    ]
    entered = [(fraction, index) for index, fraction in enumerate(fractions) if fraction is not None]
    if not entered:
        return None
    fraction, index = min(entered)
    return position + fraction * heading, index


def _as_axis(shape: Shape) -> np.ndarray:
    """A ball's centre as a capsule of zero length; a capsule's axis as it is."""
    shape = np.asarray(shape, float)
    return np.stack([shape, shape]) if shape.shape == (3,) else shape.reshape(2, 3)


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
