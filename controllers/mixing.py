"""ArduSub's motor mixing for the BlueROV2 frames, and the physical allocation matrix.

:func:`mix` turns a pilot command (:mod:`maptidal.controllers.convention`) into normalised
thruster commands in [-1, 1] exactly as ArduSub's AP_Motors6DOF does
(``output_armed_stabilizing``), including how it handles saturation:

- ``vectored`` (BlueROV2 standard, 6 thrusters): each motor gets
  ``roll*r + pitch*p + yaw*y + throttle*t + forward*f + lateral*l`` clipped to
  [-1, 1]; the forward command of the "rear" thrusters (by direction of travel) is
  limited to ``1 - k |throttle|`` to decouple forward and vertical motion
  (MOT_FV_CPLNG_K, default 1.0).
- ``vectored_6dof`` (Heavy, 8 thrusters): roll/pitch/throttle and
  yaw/forward/lateral are mixed separately; each group is divided by its largest
  absolute value when that exceeds 1, then the two are summed and clipped.

The factors are ArduSub's (ArduPilot's AP_Motors6DOF.cpp; docs/references.md). They are normalised
mixing factors, not physics: :func:`allocation_matrix` builds the physical map from
thruster forces to body wrench from positions and directions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .convention import pilot_command

# Rows: motors M1..; columns: roll, pitch, yaw, throttle, forward, lateral (AP_Motors6DOF).
VECTORED_FACTORS = np.array(
    [
        [0, 0, +1, 0, -1, +1],
        [0, 0, -1, 0, -1, -1],
        [0, 0, -1, 0, +1, +1],
        [0, 0, +1, 0, +1, -1],
        [+1, 0, 0, -1, 0, 0],
        [-1, 0, 0, -1, 0, 0],
    ],
    dtype=float,
)
VECTORED_6DOF_FACTORS = np.array(
    [
        [0, 0, +1, 0, -1, +1],
        [0, 0, -1, 0, -1, -1],
        [0, 0, -1, 0, +1, +1],
        [0, 0, +1, 0, +1, -1],
        [+1, -1, 0, -1, 0, 0],
        [-1, -1, 0, -1, 0, 0],
        [+1, +1, 0, -1, 0, 0],
        [-1, +1, 0, -1, 0, 0],
    ],
    dtype=float,
)
FRAMES: dict[str, np.ndarray] = {"vectored": VECTORED_FACTORS, "vectored_6dof": VECTORED_6DOF_FACTORS}

# ArduSub's forward_coupling_direction: which motors count as "rear" for a forward command.
_FORWARD_COUPLING_DIRECTION = np.array([-1, -1, 1, 1, 0, 0], dtype=float)


@dataclass(frozen=True)
class MixerParams:
    """ArduSub mixer settings: the frame and MOT_FV_CPLNG_K (forward/vertical coupling)."""

    frame: str = "vectored_6dof"
    forward_vertical_coupling: float = 1.0

    def __post_init__(self) -> None:
        if self.frame not in FRAMES:
            raise ValueError(f"unknown ArduSub frame {self.frame!r}; choose one of {sorted(FRAMES)}")


# the Heavy's factor columns (roll, pitch, yaw, throttle, forward, lateral) taken in pilot-command order
# (surge, sway, heave, roll, pitch, yaw), so that a motor's mix is one dot product with the command
_6DOF_BY_PILOT_AXIS = VECTORED_6DOF_FACTORS[:, [4, 5, 3, 0, 1, 2]]
# vectored_6dof mixes two groups apart: roll, pitch and throttle (pilot axes 3, 4, 2); yaw, forward and
# lateral (5, 0, 1)
_ROLL_PITCH_THROTTLE = _6DOF_BY_PILOT_AXIS * np.array([0, 0, 1, 1, 1, 0], float)
_YAW_FORWARD_LATERAL = _6DOF_BY_PILOT_AXIS * np.array([1, 1, 0, 0, 0, 1], float)


def mix(command, params: MixerParams | None = None) -> np.ndarray:
    """Thruster commands in [-1, 1] for a pilot command, as ArduSub mixes them.

    ``command`` is anything :func:`maptidal.controllers.convention.pilot_command` accepts.
    Returns one value per motor, M1 first.
    """
    params = params or MixerParams()
    pilot = pilot_command(command)
    if params.frame == "vectored_6dof":
        rpt = _ROLL_PITCH_THROTTLE @ pilot
        yfl = _YAW_FORWARD_LATERAL @ pilot
        rpt_max = max(1.0, float(np.abs(rpt).max()))
        yfl_max = max(1.0, float(np.abs(yfl).max()))
        return (rpt / rpt_max + yfl / yfl_max).clip(-1.0, 1.0)
    forward, lateral, throttle, roll, pitch, yaw = (float(v) for v in pilot)
    r, p, y, t, f, lat = FRAMES[params.frame].T
    rpy = roll * r + pitch * p + yaw * y
    limit = max(0.0, 1.0 - params.forward_vertical_coupling * abs(throttle))
    forward_per_motor = np.full(len(r), forward)
    if forward != 0.0:
        rear = ((forward < 0) == (_FORWARD_COUPLING_DIRECTION < 0)) & (_FORWARD_COUPLING_DIRECTION != 0)
        forward_per_motor[rear] = np.clip(forward, -limit, limit)
    linear = throttle * t + forward_per_motor * f + lateral * lat
    return np.clip(rpy + linear, -1.0, 1.0)


def allocation_matrix(positions: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """The physical map ``(6, n)`` from thruster forces (N) to body wrench [F; M].

    ``positions`` ``(n, 3)`` are thruster positions relative to the centre of gravity
    and ``directions`` ``(n, 3)`` the force direction of a positive command, in the
    body frame (x forward, y left, z up).
    """
    positions = np.asarray(positions, float)
    directions = np.asarray(directions, float)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    return np.vstack([directions.T, np.cross(positions, directions).T])
