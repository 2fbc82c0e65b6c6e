"""Stereo visual odometry fused with dead reckoning (issue [perception]): the third localisation source.

- **Frame to frame.** The previous frame's stereo points (optical frame) of the landmarks tracked into
  the current frame, and their current pixels, give the camera's motion by PnP with RANSAC
  (``cv2.solvePnPRansac``, EPnP as in Kimera-VIO's front end, at least ``min_inliers`` inliers; Kimera
  asks for 20).
- **Fused with dead reckoning.** A simple complementary filter on the increments: the attitude is the
  dead reckoning's (gravity and the compass keep it from drifting), and the translation increment
  is ``w`` times the visual one plus ``1 - w`` times the dead reckoning's, both expressed in the world
  frame, with one weight for the horizontal axes and one for depth (the pressure sensor measures depth
  outright, so vision gets less say there). Without enough inliers the dead-reckoning increment is
  used alone.
- **Without a DVL** (``has_dvl=False``) the dead reckoning's horizontal motion is either model-aided
  (``model_aided=True``: the velocity from the thrust commands through the vehicle's motion model,
  :class:`controllers.estimation.MotionModel`, as the simulator's estimator does), and then weighs as
  much as vision (``visual_weight_model_aided``), or there is none at all (``model_aided=False``, a
  vehicle whose autopilot has no horizontal estimate without a DVL), and vision carries it wholly.
- **A gate.** Where the dead reckoning moves horizontally, a visual step that disagrees with it by more
  than ``max_disagreement_m`` is dropped as a wrong PnP solution (a planar wall fools PnP into steps
  of tens of centimetres the wrong way), as a filter gates an innovation.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from maptidal.perception.recording import CameraPose


@dataclass(frozen=True)
class OdometryParams:
    """PnP RANSAC settings and the visual weight ``w`` of the translation increment."""

    min_inliers: int = 20
    min_inlier_ratio: float = 0.5
    reprojection_px: float = 1.5
    # a step longer than this is a bad solution (a planar wall can fool PnP): 1.5 m/s, the BlueROV2's top
    # speed (Blue Robotics' product page), at 5 frames/s
    max_step_m: float = 0.3
    visual_weight: float = 0.8  # horizontal, with a DVL
    visual_weight_depth: float = 0.2
    has_dvl: bool = True
    model_aided: bool = True
    # without a DVL, model-aided: in the default mission the model-aided step is off by 2 cm (median) and
    # 12 cm (90th percentile) over a 1 s frame and the good visual steps by about as much (README,
    # "Closed-loop mission"), so the two weigh alike
    visual_weight_model_aided: float = 0.5
    # the gate, per frame: the model-aided step's error over a 1 s frame comes from the unmodelled thrust
    # lag and the model's error, about 20 % of a 0.25 m/s speed (5 cm); the gate is some 2.5 times that
    max_disagreement_m: float = 0.12

    @property
    def horizontal_weight(self) -> float:
        """The visual weight of the horizontal translation increment (module docstring)."""
        if self.has_dvl:
            return self.visual_weight
        return self.visual_weight_model_aided if self.model_aided else 1.0

    @property
    def dead_reckons_horizontally(self) -> bool:
        """Whether the dead reckoning's horizontal motion means anything (a DVL or a motion model)."""
        return self.has_dvl or self.model_aided


def relative_motion(
    points_previous: np.ndarray, pixels_current: np.ndarray, camera_matrix: np.ndarray, params: OdometryParams
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """The transform (R, t) from the previous optical frame to the current one (``x_cur = R x_prev + t``)
    and the inlier count, or None when PnP finds fewer than ``min_inliers``."""
    points = np.asarray(points_previous, np.float64).reshape(-1, 3)
    pixels = np.asarray(pixels_current, np.float64).reshape(-1, 2)
    if len(points) < max(params.min_inliers, 6):
        return None
    ok, rvec, tvec, inliers = cv2.solvePnPRansac(
        points,
        pixels,
        np.asarray(camera_matrix, np.float64),
        None,
        reprojectionError=params.reprojection_px,
        iterationsCount=200,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if (
        not ok
        or inliers is None
        or len(inliers) < max(params.min_inliers, params.min_inlier_ratio * len(points))
    ):
        return None
    keep = inliers.ravel()
    # refine on the inliers (Levenberg-Marquardt from the RANSAC solution)
    rvec, tvec = cv2.solvePnPRefineLM(
        points[keep], pixels[keep], np.asarray(camera_matrix, np.float64), None, rvec, tvec
    )
    rotation, _ = cv2.Rodrigues(rvec)
    return rotation, tvec.ravel(), len(keep)


class VisualOdometry:
    """Fuses frame-to-frame PnP with dead-reckoning increments (module docstring)."""

    def __init__(self, params: OdometryParams | None = None) -> None:
        self.params = params or OdometryParams()
        self.pose: CameraPose | None = None
        self._last_dr: CameraPose | None = None
        self.visual_updates = 0
        self.gated = 0  # visual steps dropped by the gate

    def update(
        self, dead_reckoning: CameraPose, motion: tuple[np.ndarray, np.ndarray, int] | None
    ) -> CameraPose:
        """The fused pose after one frame, from this frame's dead-reckoned pose and the visual motion
        (:func:`relative_motion`, None when PnP failed; a step longer than ``max_step_m``, or one the gate
        refuses, is dropped as a wrong solution). The first frame starts at the dead reckoning."""
        if self.pose is None or self._last_dr is None:
            self.pose, self._last_dr = dead_reckoning, dead_reckoning
            return self.pose
        dr_step = dead_reckoning.position - self._last_dr.position
        step = dr_step
        if motion is not None:
            rotation, translation, _ = motion
            # the previous camera centre seen from the current camera is t; the current centre in the
            # previous optical frame is -R^T t, and in the world the previous pose's rotation applies
            visual_step = self.pose.rotation @ (-rotation.T @ translation)
            if np.linalg.norm(visual_step) > self.params.max_step_m:
                motion = None  # faster than the vehicle can move: a wrong solution
            elif (
                self.params.dead_reckons_horizontally
                and np.linalg.norm((visual_step - dr_step)[:2]) > self.params.max_disagreement_m
            ):
                motion = None  # the gate: too far from where the dead reckoning says the camera went
                self.gated += 1
        if motion is not None:
            horizontal = self.params.horizontal_weight
            w = np.array([horizontal, horizontal, self.params.visual_weight_depth])
            step = w * visual_step + (1.0 - w) * dr_step
            self.visual_updates += 1
        self.pose = CameraPose(self.pose.position + step, dead_reckoning.rotation)
        self._last_dr = dead_reckoning
        return self.pose
