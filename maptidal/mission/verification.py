"""Whether a captured image shows what its task asked for: the judge of "done" (issue [truthful-loop]).

A robot flies to a task on its own estimate and says it is done when the estimate is within tolerance.
The simulator knows where the camera really was; a task counts as **verified** only when the true
camera position of the capture lies within ``position_tolerance_m`` of the task's viewpoint and the true
optical axis within ``direction_tolerance_deg`` of the task's viewing direction, in full (pitch
included). The robot never sees this verdict: it is the evaluation's, as a diver's check of the images
would be. The coverage evaluation scores the verified views only.

The viewing direction's pitch is what the vehicle must pitch to, its camera being fixed on the nose:
:func:`view_pitch`. A robot declines a task whose pitch is beyond what it can hold
(:func:`pitch_to_fly`), with the reason in the event log.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ViewCheck:
    """A capture against its task: how far the true camera was from the viewpoint (m), how far its
    optical axis from the viewing direction (deg), and whether both are within tolerance."""

    position_error_m: float
    direction_error_deg: float
    verified: bool


def check_view(
    camera_position,
    camera_forward,
    task_position,
    task_direction,
    position_tolerance_m: float,
    direction_tolerance_deg: float,
) -> ViewCheck:
    """Judge one capture (true camera position and unit optical axis) against its task."""
    forward = np.asarray(camera_forward, float)
    direction = np.asarray(task_direction, float)
    cosine = float(forward @ direction) / (np.linalg.norm(forward) * np.linalg.norm(direction))
    angle = math.degrees(math.acos(max(-1.0, min(1.0, cosine))))
    distance = float(np.linalg.norm(np.asarray(camera_position, float) - np.asarray(task_position, float)))
    return ViewCheck(distance, angle, distance <= position_tolerance_m and angle <= direction_tolerance_deg)


def view_pitch(direction) -> float:
    """The vehicle pitch (rad, nose down +) that points a nose camera along ``direction`` (world, z up):
    the body's forward axis is (cos yaw cos pitch, sin yaw cos pitch, -sin pitch)."""
    d = np.asarray(direction, float)
    return -math.asin(max(-1.0, min(1.0, float(d[2] / np.linalg.norm(d)))))


def pitch_to_fly(pitch: float, max_pitch_deg: float, direction_tolerance_deg: float) -> float | None:
    """The pitch (rad) to hold for a view that needs ``pitch``: the view's own pitch, capped at
    ``max_pitch_deg``, when the cap leaves the view within ``direction_tolerance_deg``; None when the
    vehicle cannot view it (it declines the task)."""
    cap = math.radians(max_pitch_deg)
    if abs(pitch) - cap > math.radians(direction_tolerance_deg):
        return None
    return max(-cap, min(cap, pitch))
