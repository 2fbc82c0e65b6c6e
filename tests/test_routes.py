"""The exploring robot's routes (issue [loop], maptidal.mission.routes): the headings a sweep and a survey
show, sampled along the route, against the sweep's definition, and the places they hold."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maptidal.controllers.estimation import wrap_angle
from maptidal.controllers.trajectory import MotionLimits, PoseTrajectory, Route
from maptidal.mission.params import MissionParams
from maptidal.mission.routes import survey_route, sweep_legs

LIMITS = MotionLimits(max_speed=0.25, max_accel=0.1, max_yaw_rate=math.radians(12), max_yaw_accel=0.2)
SWEEP = math.radians(60)


def _samples(route: Route, step_s: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(N, 3)`` and headings ``(N,)`` along the route, every ``step_s``, its legs' ends
    included."""
    times = np.sort([*np.arange(0.0, route.duration, step_s), *route.starts, route.duration])
    poses = [route.at(t) for t in times]
    return np.array([p.position for p in poses]), np.array([p.yaw for p in poses])


def _assert_continuous(route: Route) -> None:
    """Each leg starts where the one before it ended, in place and heading."""
    for before, after in zip(route.legs, route.legs[1:], strict=False):
        end, start = before.at(before.duration), after.at(0.0)
        np.testing.assert_allclose(end.position, start.position, atol=1e-9)
        assert wrap_angle(end.yaw - start.yaw) == pytest.approx(0, abs=1e-9)


def _headings_shown(yaws: np.ndarray, about: float) -> tuple[float, float]:
    """The least and greatest heading, relative to ``about``, the route turned through."""
    relative = np.array([wrap_angle(y - about) for y in yaws])
    return float(relative.min()), float(relative.max())


@pytest.mark.parametrize("yaw", [0.0, 2.9, -3.1])
def test_a_sweep_turns_to_each_side_and_back_holding_its_place(yaw):
    position = np.array([1.0, -2.0, 0.7])
    route = Route(sweep_legs(position, yaw, SWEEP, LIMITS))
    _assert_continuous(route)
    positions, yaws = _samples(route)
    np.testing.assert_allclose(positions, np.broadcast_to(position, positions.shape), atol=1e-12)
    low, high = _headings_shown(yaws, yaw)
    assert low == pytest.approx(-SWEEP, abs=1e-9) and high == pytest.approx(SWEEP, abs=1e-9)
    assert yaws[0] == pytest.approx(yaw)
    assert wrap_angle(yaws[-1] - yaw) == pytest.approx(0, abs=1e-9)
    # the three turns, 60, 120 and 60 deg, and nothing more
    turns = 2 * PoseTrajectory(position, 0, position, SWEEP, LIMITS).duration
    turns += PoseTrajectory(position, 0, position, 2 * SWEEP, LIMITS).duration
    assert route.duration == pytest.approx(turns)


@pytest.mark.parametrize("start_yaw", [0.3, -2.5, 3.0])
@pytest.mark.parametrize("yaw", [0.0, math.pi, -2.0])
def test_a_survey_flies_to_the_look_facing_its_heading_then_sweeps_there(start_yaw, yaw):
    start, look = np.array([-1.0, 0.5, 1.0]), np.array([-2.0, -0.3, 0.6])
    route = survey_route(start, start_yaw, look, yaw, SWEEP, LIMITS)
    _assert_continuous(route)
    positions, yaws = _samples(route)
    np.testing.assert_allclose(positions[0], start)
    assert yaws[0] == pytest.approx(start_yaw)
    arrival = route.at(route.starts[1])
    np.testing.assert_allclose(arrival.position, look, atol=1e-9)
    assert wrap_angle(arrival.yaw - yaw) == pytest.approx(0, abs=1e-9)
    # at the look it shows every heading of the sweep, holding its place, and ends facing the heading
    at_look = np.linalg.norm(positions - look, axis=1) < 1e-9
    low, high = _headings_shown(yaws[at_look], yaw)
    assert low == pytest.approx(-SWEEP, abs=1e-9) and high == pytest.approx(SWEEP, abs=1e-9)
    assert np.allclose(positions[-1], look) and wrap_angle(yaws[-1] - yaw) == pytest.approx(0, abs=1e-9)


@pytest.mark.parametrize(
    "bad", [{"explore_yaw_deg": 90.0}, {"explore_yaw_deg": 0.0}, {"yaw_rate_deg_s": 0.0}]
)
def test_a_sweep_that_cannot_turn_the_short_way_is_refused(bad):
    with pytest.raises(ValueError, match="explore_yaw_deg"):
        MissionParams(**bad)


@pytest.mark.parametrize("bad", [-1.0, 81.0, float("nan"), "45"])
def test_a_survey_pitch_outside_0_to_80_deg_is_refused(bad):
    with pytest.raises(ValueError, match="survey_pitch_deg"):
        MissionParams(survey_pitch_deg=bad)


@pytest.mark.parametrize("yaw", [0.0, 2.9])
def test_a_survey_without_a_sweep_ends_at_the_look_facing_its_heading(yaw):
    start, look = np.array([-1.0, 0.5, 1.0]), np.array([-2.0, -0.3, 0.6])
    route = survey_route(start, 0.3, look, yaw, 0.0, LIMITS)
    assert len(route.legs) == 1  # the flight alone: no turn at the look
    flight = PoseTrajectory(start, 0.3, look, yaw, LIMITS)
    assert route.duration == pytest.approx(flight.duration)
    end = route.at(route.duration)
    np.testing.assert_allclose(end.position, look, atol=1e-9)
    assert wrap_angle(end.yaw - yaw) == pytest.approx(0, abs=1e-9)


@pytest.mark.parametrize("name", ["survey_sweep_deg", "survey_sweep_no_dvl_deg"])
@pytest.mark.parametrize("bad", [-1.0, 90.0, float("nan"), "30"])
def test_a_survey_sweep_outside_0_to_90_deg_is_refused(name, bad):
    with pytest.raises(ValueError, match=name):
        MissionParams(**{name: bad})


@pytest.mark.parametrize("bad", [0.0, -5.0, float("inf"), float("nan"), "39"])
def test_a_sweep_rate_that_is_not_a_positive_number_is_refused(bad):
    with pytest.raises(ValueError, match="sweep_rate_dvl_deg_s"):
        MissionParams(sweep_rate_dvl_deg_s=bad)
