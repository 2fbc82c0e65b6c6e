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
        """Fold in one frame's observations; returns which were accepted ``(N,)``. Rows with NaNs are
        skipped; an id seen twice in one call is folded in twice, in order."""
        ids = np.asarray(ids, int).reshape(-1)
        points = np.asarray(points_world, float).reshape(-1, 3)
        covariances = np.asarray(covariances_world, float).reshape(-1, 3, 3)
        accepted = np.zeros(len(ids), bool)
        rows = np.flatnonzero(np.isfinite(points).all(axis=1) & np.isfinite(covariances).all(axis=(1, 2)))
        while len(rows):
            # a batch of distinct ids at a time (one frame's ids are distinct: one batch)
            _, first = np.unique(ids[rows], return_index=True)
            batch = rows[np.sort(first)]
            accepted[batch] = self._add_distinct(ids[batch], points[batch], covariances[batch])
            rows = np.setdiff1d(rows, batch, assume_unique=True)
        return accepted

    def _add_distinct(self, ids: np.ndarray, points: np.ndarray, covariances: np.ndarray) -> np.ndarray:
        # every matrix operation batched over the observations: a frame has a few hundred
        information = np.linalg.inv(covariances)
        vectors = np.einsum("nij,nj->ni", information, points)
        known = np.array([k in self._count for k in ids.tolist()], bool) & self.params.enabled
        keep = np.ones(len(ids), bool)
        if self.params.gate > 0 and known.any():
            rows = np.flatnonzero(known)
            estimate_cov = np.linalg.inv(np.stack([self._information[k] for k in ids[rows].tolist()]))
            fused = np.stack([self._vector[k] for k in ids[rows].tolist()])
            residual = points[rows] - np.einsum("nij,nj->ni", estimate_cov, fused)
            weighted = np.linalg.solve(covariances[rows] + estimate_cov, residual[..., None])[..., 0]
            outside = np.einsum("ni,ni->n", residual, weighted) > self.params.gate**2
            keep[rows[outside]] = False
            self.rejected += int(outside.sum())
        for row in np.flatnonzero(keep).tolist():
            landmark = int(ids[row])
            if known[row]:
                self._information[landmark] = self._information[landmark] + information[row]
                self._vector[landmark] = self._vector[landmark] + vectors[row]
                self._count[landmark] += 1
            else:
                self._information[landmark] = information[row]
                self._vector[landmark] = vectors[row]
                self._count[landmark] = 1
        return keep

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
