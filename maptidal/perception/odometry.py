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
  :class:`maptidal.controllers.estimation.MotionModel`, as the simulator's estimator does), and then weighs as
  much as vision (``visual_weight_model_aided``), or there is none at all (``model_aided=False``, a
  vehicle whose autopilot has no horizontal estimate without a DVL), and vision carries it wholly.
- **A gate.** Where the dead reckoning moves horizontally, a visual step that disagrees with it by more
  than ``max_disagreement_m`` is dropped as a wrong PnP solution (a planar wall fools PnP into steps
  of tens of centimetres the wrong way), as a filter gates an innovation.
- **A DVL that drops out.** A DVL gives no velocity while a beam finds nothing in its range: over a
  teammate passing beneath it closer than its minimum range, the robot's estimator runs on its motion
  model instead, and a robot pushed while in contact moves as that model does not say. In variant B of
  the tank (seed 6) the DVL robot was so carried 22 cm off in 1.5 s, and, still sure of itself to
  5 mm, refused every fix after and made its anchors where it believed it was: it stayed 22 cm off
  for the rest of the mission. So the robot's owner says how long in each frame the dead reckoning ran
  without its DVL (``unaided_s``), and until its next fix the robot is as unsure as one without a DVL:
  its variance grows at the rate of one (``drift_m2_s_no_dvl``, adapting to the fixes as it does), its
  visual steps weigh as that robot's, and it makes no anchors once past their bound. A Kalman filter
  whose velocity measurement is missing does the same.
"""

from __future__ import annotations

import math
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
    # horizontal, with a DVL: the inverse-variance weight of a visual step (about 2 cm off over a 1 s
    # frame, the good steps of the robot without a DVL: docs/mission.md) against the DVL's
    # (about 1 mm, drift_m2_s_dvl over 1 s): 0.25 %. Until session 15 it was 0.8, and the DVL robot meshed
    # on a pose 58 cm off (median, 600 s of the default mission) where its DVL alone was 3 cm off
    visual_weight: float = 0.0025
    visual_weight_depth: float = 0.2
    has_dvl: bool = True
    model_aided: bool = True
    # without a DVL, model-aided: in the default mission the model-aided step is off by 2 cm (median) and
    # 12 cm (90th percentile) over a 1 s frame and the good visual steps by about as much
    # (docs/mission.md), so the two weigh alike
    visual_weight_model_aided: float = 0.5
    # the gate, per frame: the model-aided step's error over a 1 s frame comes from the unmodelled thrust
    # lag and the model's error, about 20 % of a 0.25 m/s speed (5 cm); the gate is some 2.5 times that
    max_disagreement_m: float = 0.12
    # the horizontal position's uncertainty, for weighing a relocalisation (maptidal.perception.
    # relocalisation) against the dead reckoning as a Kalman filter does: it starts at start_sigma_m (a
    # known launch spot) and grows as a random walk of drift_m2_s per second. Without a DVL 2e-3 m^2/s,
    # 30 cm after 45 s: the default mission's robot without a DVL drifted 15 cm in 50 s flying freely and
    # 1 m in 60 s against a wall, where the thrust it asks for moves it less than its model says (session
    # 15, between fixes); with a DVL 1e-6 m^2/s, 3.5 cm after 1200 s, the DVL robot's drift there
    start_sigma_m: float = 0.01
    drift_m2_s_no_dvl: float = 2e-3
    # the drift rate adapts to the fixes, up to max_drift_scale times its own: a fix whose normalised
    # innovation squared (innovation^2 over the prediction's and the fix's variances; 2 on average for
    # a right model, two degrees of freedom) exceeds 2, or one the gate refused, scales it by 1.5, one
    # below 0.5 by 0.9 down to 1: a motion model whose coefficients are off drifts faster than it says.
    # With a DVL it does not adapt: a fix that surprises a DVL is the fix's error (a place mapped from a
    # pose a few cm off), and letting such fixes speed its drift up pulled one 33 cm off in 1200 s
    max_drift_scale: float = 20.0
    max_drift_scale_dvl: float = 1.0
    drift_m2_s_dvl: float = 1e-6


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
        self.fixes = 0  # relocalisations applied (correct)
        self.sigma_m = self.params.start_sigma_m  # the horizontal position's standard deviation
        self.drift_scale = 1.0  # how much faster than its parameter the position drifts (adapted)
        # a robot with a DVL whose dead reckoning has run without it since its last fix
        self.unaided = False

    @property
    def dvl_aided(self) -> bool:
        """Whether the horizontal dead reckoning stands on a DVL now: a robot with one whose DVL has not
        dropped out since its last fix (module docstring)."""
        return self.params.has_dvl and not self.unaided

    def _horizontal_weight(self) -> float:
        """The visual weight of the horizontal translation increment, as the dead reckoning stands now."""
        if self.dvl_aided:
            return self.params.visual_weight
        return self.params.visual_weight_model_aided if self.params.model_aided else 1.0

    def update(
        self,
        dead_reckoning: CameraPose,
        motion: tuple[np.ndarray, np.ndarray, int] | None,
        dt_s: float = 0.0,
        unaided_s: float = 0.0,
        unmodelled_m: float = 0.0,
    ) -> CameraPose:
        """The fused pose after one frame, from this frame's dead-reckoned pose and the visual motion
        (:func:`relative_motion`, None when PnP failed; a step longer than ``max_step_m``, or one the gate
        refuses, is dropped as a wrong solution), ``dt_s`` after the last frame (the horizontal variance
        grows by ``drift_m2_s dt_s``), of which the dead reckoning ran ``unaided_s`` without its DVL (a
        robot with one is then as unsure as one without until its next fix), and in which it may have
        moved ``unmodelled_m`` that its motion model did not say (pushed or blocked:
        :class:`maptidal.perception.unmodelled.UnmodelledMotion`), which adds to the standard deviation
        outright: a push is one displacement, not a random walk. The first frame starts at the dead
        reckoning."""
        if self.params.has_dvl and unaided_s > 0.0:
            self.unaided = True
        if self.pose is None or self._last_dr is None:
            self.pose, self._last_dr = dead_reckoning, dead_reckoning
            return self.pose
        base = self.params.drift_m2_s_dvl if self.dvl_aided else self.params.drift_m2_s_no_dvl
        drift = base * self.drift_scale
        self.sigma_m = float(np.sqrt(self.sigma_m**2 + drift * max(dt_s, 0.0)))
        if math.isfinite(unmodelled_m) and unmodelled_m > 0.0:
            self.sigma_m += unmodelled_m
        dr_step = dead_reckoning.position - self._last_dr.position
        step = dr_step
        if motion is not None:
            rotation, translation, _ = motion
            # the previous camera centre seen from the current camera is t; the current centre in the
            # previous optical frame is -R^T t, and in the world the previous pose's rotation applies
            visual_step = self.pose.rotation @ (-rotation.T @ translation)
            if np.linalg.norm(visual_step) > self.params.max_step_m:
                motion = None  # faster than the vehicle can move: a wrong solution
            elif (self.dvl_aided or self.params.model_aided) and np.linalg.norm(
                (visual_step - dr_step)[:2]
            ) > self.params.max_disagreement_m:
                motion = None  # the gate: too far from where the dead reckoning says the camera went
                self.gated += 1
        if motion is not None:
            horizontal = self._horizontal_weight()
            w = np.array([horizontal, horizontal, self.params.visual_weight_depth])
            step = w * visual_step + (1.0 - w) * dr_step
            self.visual_updates += 1
        self.pose = CameraPose(self.pose.position + step, dead_reckoning.rotation)
        self._last_dr = dead_reckoning
        return self.pose

    def correct(self, centre: np.ndarray, sigma_m: float) -> CameraPose:
        """Fold in a relocalisation's camera ``centre`` of horizontal standard deviation ``sigma_m``: the
        horizontal position moves the Kalman gain ``s^2 / (s^2 + sigma_m^2)`` of the way (``s`` this
        estimate's ``sigma_m``), and its variance shrinks by ``1 - gain``; depth stays the pressure
        sensor's. The next frame's increments carry on from there."""
        if self.pose is None:
            raise RuntimeError("a fix before the first frame")
        gain = self.sigma_m**2 / (self.sigma_m**2 + sigma_m**2)
        innovation = np.asarray(centre, float)[:2] - self.pose.position[:2]
        normalised = float(innovation @ innovation) / (self.sigma_m**2 + sigma_m**2)
        if normalised > 2.0:
            self.surprised()
        elif normalised < 0.5:
            self.drift_scale = max(1.0, 0.9 * self.drift_scale)
        position = self.pose.position.copy()
        position[:2] += gain * (np.asarray(centre, float)[:2] - position[:2])
        self.pose = CameraPose(position, self.pose.rotation)
        self.sigma_m = float(np.sqrt((1.0 - gain) * self.sigma_m**2))
        self.fixes += 1
        if self.unaided:  # found again: the DVL, back, keeps the say
            self.unaided, self.drift_scale = False, 1.0
        return self.pose

    def surprised(self) -> None:
        """A fix farther off than the uncertainty allowed (or refused for it): the drift rate grows by
        half, up to ``max_drift_scale`` times its own (``max_drift_scale_dvl`` while a DVL keeps the
        say; a robot whose DVL dropped out adapts as one without a DVL)."""
        limit = self.params.max_drift_scale_dvl if self.dvl_aided else self.params.max_drift_scale
        self.drift_scale = min(limit, 1.5 * self.drift_scale)
