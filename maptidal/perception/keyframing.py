"""Keyframe selection by time, translation and rotation (issue [perception]).

A frame becomes a keyframe when at least ``min_interval_s`` has passed since the last keyframe and the
camera has moved ``min_translation_m`` or turned ``min_rotation_deg`` since it, or ``max_interval_s``
has passed. The first frame is always one.

Defaults: ``min_interval_s = 0.2`` s is Kimera-VIO's ``intra_keyframe_time`` (MIT-SPARK/Kimera-VIO,
params/Euroc/FrontendParams.yaml). The motion thresholds are our choice: 8 cm is about 8 % of the 1 m
working range L_i (Ruediger & Banerjee, Sec. IV.B), so that the paper's slow 0.5 m rise gives its
"first 7 keyframes" over the rise (one every 8.3 cm); 10 deg is about a seventh of the OAK-D's 72 deg
horizontal field of view, so consecutive keyframes of a yaw sweep overlap by most of the image. A
hovering robot still makes one every ``max_interval_s = 2`` s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from maptidal.perception.recording import CameraPose

_TIME_SLACK_S = 1e-6


@dataclass(frozen=True)
class KeyframeParams:
    """Thresholds of :class:`KeyframeSelector` (module docstring)."""

    min_interval_s: float = 0.2
    max_interval_s: float = 2.0
    min_translation_m: float = 0.08
    min_rotation_deg: float = 10.0

    def __post_init__(self) -> None:
        values = (self.min_interval_s, self.max_interval_s, self.min_translation_m, self.min_rotation_deg)
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError("keyframe thresholds must be finite and >= 0")
        if self.max_interval_s < self.min_interval_s:
            raise ValueError("max_interval_s must be at least min_interval_s")


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (deg) of the rotation between two rotation matrices."""
    cosine = (np.trace(np.asarray(a).T @ np.asarray(b)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


class KeyframeSelector:
    """Decides frame by frame which frames are keyframes (module docstring)."""

    def __init__(self, params: KeyframeParams | None = None) -> None:
        self.params = params or KeyframeParams()
        self._last: tuple[float, CameraPose] | None = None

    def is_keyframe(self, time_s: float, pose: CameraPose) -> bool:
        """Whether the frame at ``time_s`` with ``pose`` is a keyframe (and, if so, remember it)."""
        p = self.params
        if self._last is not None:
            last_time, last_pose = self._last
            # a microsecond's slack: frame times that are sums of physics steps come out a hair short
            # of a whole interval (0.9999999999999998 s), which would drop every other keyframe
            elapsed = time_s - last_time + _TIME_SLACK_S
            if elapsed < p.min_interval_s:
                return False
            moved = float(np.linalg.norm(pose.position - last_pose.position)) >= p.min_translation_m
            turned = rotation_angle_deg(last_pose.rotation, pose.rotation) >= p.min_rotation_deg
            if not (moved or turned or elapsed >= p.max_interval_s):
                return False
        self._last = (time_s, pose)
        return True
