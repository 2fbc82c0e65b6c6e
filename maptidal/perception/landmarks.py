"""World-frame landmark fusion (issue [perception]): each tracked landmark's stereo observations,
weighted by their covariance, with outlier rejection. The simplest stand-in for Kimera's smart factors,
which refine a landmark over every frame that saw it and so make its meshes smoother than one frame's
triangulation.

- **One observation.** Stereo triangulation ``p = (b / d) (u - c_x, v - c_y, f)`` (optical frame,
  ``f_x = f_y = f``) has the Jacobian ``dp/du = (b / d) e_x``, ``dp/dv = (b / d) e_y``,
  ``dp/dd = -p / d``, so with independent pixel noise ``sigma_px`` on u and v and disparity noise
  ``sigma_d`` its covariance is ``J diag(sigma_px^2, sigma_px^2, sigma_d^2) J^T``: the depth standard
  deviation grows as ``z^2 sigma_d / (f b)``, the lateral one as ``z sigma_px / f``. It is rotated into
  the world with the camera's pose.
- **Fusion.** Information form: a landmark keeps ``Lambda = sum Sigma_i^-1`` and
  ``eta = sum Sigma_i^-1 x_i``; its position is ``Lambda^-1 eta``, the weighted least-squares point of its
  observations (tested against a stacked, whitened least-squares solve).
- **Outliers.** From its second observation on, a new observation whose Mahalanobis distance from the
  current estimate (covariance ``Sigma_new + Lambda^-1``) exceeds ``gate`` is rejected and counted: a
  mismatch or a tracking slip, which one frame's triangulation would keep.

With an estimated pose (not the ground truth), ``pose_sigma_m^2 I`` is added to each observation's
covariance, so that the gate does not reject a landmark seen again from a pose that has drifted by a
centimetre. The fusion cannot undo the drift itself: landmarks placed with a drifting pose estimate
inherit it, as the paper warns. OpenCV-free; numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FusionParams:
    """Stereo noise (px) and the outlier gate (Mahalanobis distance; 3.37 is chi-square's 99 % for 3 degrees
    of freedom). ``disparity_sigma_px`` is the same 0.25 px our synthetic keyframes assume
    (:class:`maptidal.camera.StereoCameraParams`); ``pixel_sigma_px`` is KLT's sub-pixel accuracy."""

    disparity_sigma_px: float = 0.25
    pixel_sigma_px: float = 0.5
    pose_sigma_m: float = (
        0.01  # an estimated pose's position error per axis, added to estimated-pose observations
    )
    gate: float = 3.37
    enabled: bool = True  # off: each observation replaces the last (one frame's triangulation)


def stereo_covariances(
    points_camera: np.ndarray, disparity: np.ndarray, focal_px: float, params: FusionParams | None = None
) -> np.ndarray:
    """Optical-frame covariances ``(N, 3, 3)`` of triangulated points ``(N, 3)`` with their disparities
    ``(N,)`` (module docstring)."""
    params = params or FusionParams()
    points = np.asarray(points_camera, float).reshape(-1, 3)
    d = np.asarray(disparity, float).reshape(-1)
    scale = points[:, 2] / focal_px  # = b / d
    jacobian = np.zeros((len(points), 3, 3))
    jacobian[:, 0, 0] = scale
    jacobian[:, 1, 1] = scale
    jacobian[:, :, 2] = -points / d[:, None]
    noise = np.diag([params.pixel_sigma_px**2, params.pixel_sigma_px**2, params.disparity_sigma_px**2])
    return jacobian @ noise @ jacobian.transpose(0, 2, 1)


class LandmarkMap:
    """Fused world-frame landmarks by id (module docstring)."""

    def __init__(self, params: FusionParams | None = None) -> None:
        self.params = params or FusionParams()
        self._information: dict[int, np.ndarray] = {}
        self._vector: dict[int, np.ndarray] = {}
        self._count: dict[int, int] = {}
        self.rejected = 0

    def __len__(self) -> int:
        return len(self._count)

    def add(self, ids: np.ndarray, points_world: np.ndarray, covariances_world: np.ndarray) -> np.ndarray:
        """Fold in one frame's observations; returns which were accepted ``(N,)``."""
        ids = np.asarray(ids, int).reshape(-1)
        points = np.asarray(points_world, float).reshape(-1, 3)
        covariances = np.asarray(covariances_world, float).reshape(-1, 3, 3)
        accepted = np.zeros(len(ids), bool)
        for row, landmark in enumerate(ids.tolist()):
            point, covariance = points[row], covariances[row]
            if not (np.all(np.isfinite(point)) and np.all(np.isfinite(covariance))):
                continue
            information = np.linalg.inv(covariance)
            if landmark in self._count and self.params.enabled:
                if self._count[landmark] >= 1 and self.params.gate > 0:
                    estimate_cov = np.linalg.inv(self._information[landmark])
                    residual = point - estimate_cov @ self._vector[landmark]
                    distance2 = residual @ np.linalg.solve(covariance + estimate_cov, residual)
                    if distance2 > self.params.gate**2:
                        self.rejected += 1
                        continue
                self._information[landmark] = self._information[landmark] + information
                self._vector[landmark] = self._vector[landmark] + information @ point
                self._count[landmark] += 1
            else:
                self._information[landmark] = information
                self._vector[landmark] = information @ point
                self._count[landmark] = 1
            accepted[row] = True
        return accepted

    def positions(self, ids: np.ndarray) -> np.ndarray:
        """Fused positions ``(N, 3)`` of ``ids``; NaN rows for ids never observed."""
        ids = np.asarray(ids, int).reshape(-1)
        out = np.full((len(ids), 3), np.nan)
        for row, landmark in enumerate(ids.tolist()):
            if landmark in self._count:
                out[row] = np.linalg.solve(self._information[landmark], self._vector[landmark])
        return out

    def observations(self, ids: np.ndarray) -> np.ndarray:
        """How many accepted observations each of ``ids`` has (0 when never observed)."""
        return np.array([self._count.get(int(k), 0) for k in np.asarray(ids).reshape(-1)], int)
