"""The keep-clear geometry (maptidal.mission.clearance) against a brute-force walk along the segment."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from maptidal.mission.clearance import capsule_entry, segment_entry, waiting_point

RADIUS = 1.0
point_st = st.tuples(*[st.floats(-3.0, 3.0, allow_nan=False)] * 3).map(np.array)


def _first_inside(start, end, centres, radius, samples=20001):
    """The first of many evenly spaced points along the segment that lies inside a ball, as a
    fraction of the segment, or None."""
    fractions = np.linspace(0.0, 1.0, samples)
    points = start + fractions[:, None] * (end - start)
    inside = np.zeros(samples, bool)
    for centre in centres:
        inside |= np.linalg.norm(points - centre, axis=1) < radius
    hits = np.flatnonzero(inside)
    return None if not len(hits) else float(fractions[hits[0]])


@settings(max_examples=300, deadline=None)
@given(start=point_st, end=point_st, centres=st.lists(point_st, min_size=1, max_size=3))
def test_a_robot_outside_every_ball_stops_where_its_way_first_enters_one(start, end, centres):
    if any(np.linalg.norm(start - c) <= RADIUS + 1e-6 for c in centres):
        return  # outside only (the robot inside a ball: the next test)
    brute = _first_inside(start, end, centres, RADIUS)
    stop = waiting_point(start, end, centres, RADIUS)
    if stop is None:
        # a way that only grazes a ball may touch it between two samples; it never goes deep
        assert brute is None or min(np.linalg.norm(start + brute * (end - start) - c) for c in centres) > 0.99
        return
    point, ball = stop
    fraction = float(np.linalg.norm(point - start) / max(np.linalg.norm(end - start), 1e-12))
    np.testing.assert_allclose(point, start + fraction * (end - start), atol=1e-9)  # on the way, short
    assert abs(np.linalg.norm(point - centres[ball]) - RADIUS) < 1e-6  # on the surface of the ball
    assert all(np.linalg.norm(point - c) >= RADIUS - 1e-6 for c in centres)  # inside none
    if brute is not None:
        assert fraction <= brute + 1e-9 and brute - fraction < 1e-3  # the first entry, not a later one


def _first_inside_capsule(start, end, first, last, radius, samples=2001):
    """The first of many evenly spaced points along the way that lies within ``radius`` of one of many
    evenly spaced points of the capsule's axis, as a fraction of the way, or None: brute force, sharing
    nothing with the module's closed forms."""
    fractions = np.linspace(0.0, 1.0, samples)
    way = start + fractions[:, None] * (end - start)
    axis = first + np.linspace(0.0, 1.0, 401)[:, None] * (last - first)
    nearest = np.min(np.linalg.norm(way[:, None, :] - axis[None, :, :], axis=2), axis=1)
    hits = np.flatnonzero(nearest < radius)
    return None if not len(hits) else float(fractions[hits[0]])


@settings(max_examples=200, deadline=None)
@given(start=point_st, end=point_st, first=point_st, last=point_st)
def test_a_robot_stops_where_its_way_first_enters_a_teammates_capsule(start, end, first, last):
    """A teammate bound somewhere is kept clear of along its way (a capsule), checked against a walk
    along both segments."""
    axis = np.stack([first, last])
    brute_axis = first + np.linspace(0.0, 1.0, 401)[:, None] * (last - first)
    if np.min(np.linalg.norm(brute_axis - start, axis=1)) <= RADIUS + 1e-2:
        return  # outside only, with room for the brute force's spacing
    brute = _first_inside_capsule(start, end, first, last, RADIUS)
    entry = capsule_entry(start, end, axis, RADIUS)
    step = np.linalg.norm(last - first) / 400 + 1e-9
    if entry is None:
        assert (
            brute is None
            or np.min(np.linalg.norm(brute_axis - (start + brute * (end - start)), axis=1)) > RADIUS - step
        )
        return
    point = start + entry * (end - start)
    assert abs(np.min(np.linalg.norm(brute_axis - point, axis=1)) - RADIUS) < step + 1e-6  # on the surface
    if brute is None:  # the way only touches the capsule: it ends on it, or grazes it
        way = start + np.linspace(0.0, 1.0, 2001)[:, None] * (end - start)
        nearest = min(np.min(np.linalg.norm(brute_axis - p, axis=1)) for p in way)
        assert nearest > RADIUS - step - 1e-3
    else:
        assert brute >= entry - 1e-9
        assert (brute - entry) * np.linalg.norm(end - start) < 2e-2  # the first entry, not a later one
    stop = waiting_point(start, end, [axis], RADIUS)
    assert stop is not None and np.allclose(stop[0], point)


def test_a_capsule_of_no_length_is_a_ball():
    start, end, centre = np.array([-3.0, 0.2, 0]), np.array([3.0, 0.1, 0]), np.zeros(3)
    assert capsule_entry(start, end, np.stack([centre, centre]), 1.0) == segment_entry(
        start, end, centre, 1.0
    )


def test_a_robot_crossing_a_teammates_way_waits_before_it():
    """A teammate at the origin bound 3 m along x: a robot crossing that way at x = 2 stops 1 m short of
    it, where the teammate's ball alone would have let it through."""
    teammate, bound = np.zeros(3), np.array([3.0, 0.0, 0.0])
    start, target = np.array([2.0, -3.0, 0.0]), np.array([2.0, 3.0, 0.0])
    assert waiting_point(start, target, [teammate], RADIUS) is None
    stop = waiting_point(start, target, [np.stack([teammate, bound])], RADIUS)
    assert stop is not None
    np.testing.assert_allclose(stop[0], [2.0, -1.0, 0.0])
    # inside the teammate's way but outside its ball, it goes on, and stops short of the ball
    way = np.stack([teammate, bound])
    towards = waiting_point(np.array([2.0, 0.2, 0.0]), np.array([-2.0, 0.2, 0.0]), [way], RADIUS)
    assert towards is not None
    np.testing.assert_allclose(towards[0], [np.sqrt(1.0 - 0.04), 0.2, 0.0])
    assert waiting_point(np.array([2.0, 0.2, 0.0]), np.array([2.0, 3.0, 0.0]), [way], RADIUS) is None


def test_a_robot_inside_a_ball_backs_out_at_its_own_depth_unless_it_is_leaving():
    centre = np.array([0.0, 0.0, 1.0])
    here = np.array([0.3, 0.0, 1.0])
    towards = waiting_point(here, np.array([-2.0, 0.0, 1.0]), [centre], RADIUS)
    assert towards is not None
    np.testing.assert_allclose(towards[0], [1.0, 0.0, 1.0])  # the shortest way out, on its own side
    assert waiting_point(here, np.array([2.0, 0.5, 1.0]), [centre], RADIUS) is None  # leaving: let it go
    on_it = waiting_point(centre, centre, [centre], RADIUS)
    assert on_it is not None and abs(np.linalg.norm(on_it[0] - centre) - RADIUS) < 1e-9
    # below a teammate (a 1200 s mission sent a robot backing out straight down onto the floor, its DVL
    # blind there): it keeps its depth and backs out sideways, to the ball's surface
    below = np.array([0.3, 0.0, 0.5])
    stop = waiting_point(below, centre, [centre], RADIUS)
    assert stop is not None and stop[0][2] == 0.5
    assert abs(np.linalg.norm(stop[0] - centre) - RADIUS) < 1e-9 and stop[0][0] > 0.3
    # right under it, it backs away from where it was going
    under = waiting_point(np.array([0.0, 0.0, 0.4]), np.array([-1.0, 0.0, 1.0]), [centre], RADIUS)
    assert under is not None and under[0][0] > 0.5 and under[0][2] == 0.4


def test_backing_out_of_one_ball_into_another_moves_out_of_that_one_too():
    centres = [np.array([0.0, 0.0, 0.0]), np.array([1.2, 0.0, 0.0])]
    stop = waiting_point(np.array([0.6, 0.1, 0.0]), np.array([0.0, 0.0, 0.0]), centres, RADIUS)
    assert stop is not None
    for centre in centres:
        assert np.linalg.norm(stop[0] - centre) >= RADIUS - 1e-9


def test_segment_entry_is_the_first_crossing():
    assert segment_entry(np.array([-3.0, 0, 0]), np.array([3.0, 0, 0]), np.zeros(3), 1.0) == 2.0 / 6.0
    assert segment_entry(np.array([-3.0, 0, 0]), np.array([-2.5, 0, 0]), np.zeros(3), 1.0) is None  # short
    assert segment_entry(np.array([-3.0, 2, 0]), np.array([3.0, 2, 0]), np.zeros(3), 1.0) is None  # by
    assert segment_entry(np.array([3.0, 0, 0]), np.array([5.0, 0, 0]), np.zeros(3), 1.0) is None  # away
