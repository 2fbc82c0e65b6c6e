"""A scripted controller for the pose tasks (``MapTidal/GoToPose-v1``, ``MapTidal/StationKeeping-v1``):
the baseline a learned policy is compared with (``examples/train_ppo.py``, ``tests/gym_policies.py``)."""

from __future__ import annotations

import numpy as np


def scripted_pose(observation) -> np.ndarray:
    """A proportional-derivative controller on the observed target (forward, left, up offsets in the
    heading frame and the yaw error, counter-clockwise) and the body velocity."""
    forward, left, up, yaw = (float(v) for v in observation["target"])
    velocity = observation["velocity"]
    command = [
        1.5 * forward - 1.0 * velocity[0],
        -(1.5 * left - 1.0 * velocity[1]),  # pilot sway is right +
        1.5 * up - 1.0 * velocity[2],
        0.0,
        0.0,
        -(1.0 * yaw - 0.3 * velocity[5]),  # pilot yaw is turn right +
    ]
    return np.clip(command, -1.0, 1.0)
