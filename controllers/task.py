"""Task execution: fly to an inspection pose, hold it within tolerance for a dwell, then say "capture".

The executor is a small state machine over :class:`maptidal.controllers.pose.PoseController` and
:class:`maptidal.controllers.trajectory.PoseTrajectory`, run on the estimated state:

    approach  -> the reference follows a smooth trajectory to the task pose
    hold      -> within tolerance (default 0.1 m and 5 deg); the dwell clock runs, and restarts if the
                 vehicle leaves the tolerance
    capture   -> held for the whole dwell: take the picture (the executor keeps holding the pose)
    timeout   -> the pose was not reached and held within the time limit
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .estimation import StateEstimate, wrap_angle
from .pose import PoseController
from .trajectory import MotionLimits, PoseTrajectory


@dataclass(frozen=True)
class TaskParams:
    """Tolerances, dwell and time limit of one inspection task."""

    position_tolerance_m: float = 0.1
    yaw_tolerance_deg: float = 5.0
    dwell_s: float = 2.0
    timeout_s: float = 120.0
    limits: MotionLimits = field(default_factory=MotionLimits)


class TaskExecutor:
    """Flies one task: ``update`` returns (pilot command, status), status one of "approach", "hold",
    "capture" or "timeout"."""

    def __init__(
        self,
        controller: PoseController,
        estimate: StateEstimate,
        goal,
        goal_yaw: float,
        params: TaskParams | None = None,
    ) -> None:
        self.controller = controller
        self.params = params or TaskParams()
        self.goal, self.goal_yaw = np.array(goal, float), goal_yaw
        self.trajectory = PoseTrajectory(
            estimate.position, estimate.yaw, self.goal, goal_yaw, self.params.limits
        )
        self.elapsed = 0.0
        self.held = 0.0
        self.status = "approach"

    def within_tolerance(self, estimate: StateEstimate) -> bool:
        """Whether the estimate is at the task pose, within both tolerances."""
        close = float(np.linalg.norm(estimate.position - self.goal)) <= self.params.position_tolerance_m
        turned = abs(math.degrees(wrap_angle(self.goal_yaw - estimate.yaw))) <= self.params.yaw_tolerance_deg
        return close and turned

    def update(self, estimate: StateEstimate, dt: float) -> tuple[np.ndarray, str]:
        """One control step on the estimated state."""
        self.elapsed += dt
        command = self.controller.update(estimate, self.trajectory.at(self.elapsed), dt)
        if self.status in ("capture", "timeout"):
            return command, self.status
        if self.elapsed >= self.trajectory.duration and self.within_tolerance(estimate):
            self.held += dt
            self.status = "capture" if self.held >= self.params.dwell_s else "hold"
        else:
            self.held = 0.0
            self.status = "approach"
        if self.status != "capture" and self.elapsed > self.params.timeout_s:
            self.status = "timeout"
        return command, self.status
