"""The routes of a robot exploring (issue [loop]): the yaw sweep it makes where it starts and where it
recovers, and the survey it flies to a look at its map's frontier (:mod:`maptidal.exploration`).

A sweep turns the camera ``sweep_rad`` (under 90 deg) to each side of a heading and back: at the loop's
60 deg, with the OAK-D's 78.5 deg field of view, its frames see 99 deg either side. It holds its place
while it turns. No simulator plays a part: these run on a real robot's companion computer too.

The turn back to the heading shows no heading the sweep did not, but it takes a second set of frames of
the middle of the view. A sweep without it (to one side, then across, reaching the first side on the
way to a look) halved a survey's median time (36 s to 20 s) but, on seeds 0-9 of the default tank, left
more of the walls uninspected on the missions with no collision (CHANGELOG, session 32), so the sweep
turns back. A survey with ``sweep_rad`` 0 is the flight to the look alone: the loop's robots without a
DVL survey so (``MissionParams.survey_sweep_no_dvl_deg``), and those with one sweep faster
(``sweep_rate_dvl_deg_s``: the limits a sweep is given may differ from the flight's).
"""

from __future__ import annotations

import numpy as np

from maptidal.controllers.trajectory import MotionLimits, PoseTrajectory, Route

__all__ = ["survey_route", "sweep_legs"]


def sweep_legs(
    position: np.ndarray, yaw: float, sweep_rad: float, limits: MotionLimits
) -> list[PoseTrajectory]:
    """A yaw sweep at ``position``, facing ``yaw``: to ``sweep_rad`` one side, across to the other, and
    back to ``yaw``, holding the place."""
    return [
        PoseTrajectory(position, yaw, position, yaw + sweep_rad, limits),
        PoseTrajectory(position, yaw + sweep_rad, position, yaw - sweep_rad, limits),
        PoseTrajectory(position, yaw - sweep_rad, position, yaw, limits),
    ]


def survey_route(
    start: np.ndarray,
    start_yaw: float,
    look: np.ndarray,
    yaw: float,
    sweep_rad: float,
    limits: MotionLimits,
    sweep_limits: MotionLimits | None = None,
) -> Route:
    """A survey from ``start`` facing ``start_yaw``: fly to ``look``, turning on the way to the look's
    heading ``yaw``, then sweep there (``sweep_legs``, within ``sweep_limits``, by default ``limits``;
    none when ``sweep_rad`` is 0)."""
    sweep = sweep_legs(look, yaw, sweep_rad, sweep_limits or limits) if sweep_rad > 0 else []
    return Route([PoseTrajectory(start, start_yaw, look, yaw, limits), *sweep])
