"""Kimera-style per-keyframe mesh: 2D Delaunay on pixels, lifted to 3D landmarks.

Follows Kimera-VIO's Mesher (docs/references.md), steps 1-4 and the orientation note:

1. the vertices are the keypoints that have a 3D landmark;
2. OpenCV Subdiv2D triangulates their pixels over the image rectangle, and only
   triangles whose three vertices are real keypoints inside the image are kept;
3. each triangle is lifted to the landmarks; one without a 3D point is dropped;
4. bad triangles are rejected (each test is skipped when its threshold <= 0):
   side ratio shortest / longest, elongation in the camera frame, longest side;
5. faces are wound so that their normal points towards the camera.

Merging keyframes into a running mesh (Kimera's step 5) is not done: Map-TIDAL
runs on each keyframe's mesh.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class MesherParams:
    """Bad-triangle thresholds; defaults are Kimera's shipped configs (docs/references.md)."""

    min_ratio_largest_smallest_side: float = 0.2
    min_elongation_ratio: float = 0.2
    max_triangle_side_m: float = 2.0

    @classmethod
    def preset(cls, name: str) -> MesherParams:
        """A named reading of Kimera-VIO's thresholds (:data:`MESHER_PRESETS`)."""
        try:
            return MESHER_PRESETS[name]
        except KeyError:
            raise ValueError(f"unknown mesher preset {name!r}; known: {', '.join(MESHER_PRESETS)}") from None


# Kimera-VIO's two sets of bad-triangle thresholds, neither of which the paper names: the flag files its
# launch files ship (``configs``: 0.2, 0.2, 2.0 m; our default) and the gflags defaults in its code
# (``code-defaults``: 0.5, 0.5, 0.5 m; DEFINE_double in Kimera-VIO's Mesher and its parameter docs)
MESHER_PRESETS: dict[str, MesherParams] = {
    "configs": MesherParams(0.2, 0.2, 2.0),
    "code-defaults": MesherParams(0.5, 0.5, 0.5),
}


@dataclass
class KeyframeMesh:
    """A keyframe mesh: ``vertices`` (V, 3), ``faces`` (F, 3) and, per vertex, the
    index of the input keypoint it came from (``keypoint_ids``)."""

    vertices: np.ndarray
    faces: np.ndarray
    keypoint_ids: np.ndarray


def delaunay_triangles(pixels: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """Triangles ``(F, 3)`` of keypoint indices from OpenCV's Subdiv2D over the image.

    Pixels outside ``[0, width) x [0, height)`` are not inserted. When two keypoints
    share a pixel, the first one inserted is kept. Triangles touching Subdiv2D's
    virtual outer vertices are dropped.
    """
    width, height = image_size
    pixels = np.asarray(pixels, dtype=np.float32).reshape(-1, 2)
    inside = np.flatnonzero(
        np.isfinite(pixels).all(axis=1)
        & (pixels[:, 0] >= 0)
        & (pixels[:, 0] < width)
        & (pixels[:, 1] >= 0)
        & (pixels[:, 1] < height)
    )
    if len(inside) < 3:
        return np.empty((0, 3), dtype=np.int64)
    subdiv = cv2.Subdiv2D((0, 0, int(width), int(height)))
    index_of: dict[tuple[float, float], int] = {}
    for k in inside:
        key = (float(pixels[k, 0]), float(pixels[k, 1]))
        if key not in index_of:
            index_of[key] = int(k)
            subdiv.insert(key)
    triangles = []
    for x1, y1, x2, y2, x3, y3 in subdiv.getTriangleList():
        ids = [index_of.get((float(x), float(y))) for x, y in ((x1, y1), (x2, y2), (x3, y3))]
        if None not in ids:
            triangles.append(ids)
    return np.array(triangles, dtype=np.int64).reshape(-1, 3)


def triangle_quality_mask(
    corners: np.ndarray, camera_position: np.ndarray, camera_forward: np.ndarray, params: MesherParams
) -> np.ndarray:
    """Which triangles ``(F, 3, 3)`` (world frame) pass Kimera's bad-triangle tests."""
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)
    longest, shortest = sides.max(axis=1), sides.min(axis=1)
    keep = np.ones(len(corners), dtype=bool)
    if params.min_ratio_largest_smallest_side > 0.0:
        keep &= shortest >= params.min_ratio_largest_smallest_side * longest
    if params.max_triangle_side_m > 0.0:
        keep &= longest <= params.max_triangle_side_m
    if params.min_elongation_ratio > 0.0:
        # Camera frame: depth z along the optical axis; rescale each point by z_min / z.
        offsets = corners - camera_position
        depth = offsets @ camera_forward
        z_min, z_max = depth.min(axis=1), depth.max(axis=1)
        scaled = offsets * (z_min[:, None] / depth)[:, :, None]
        spread = np.linalg.norm(scaled - np.roll(scaled, -1, axis=1), axis=2).max(axis=1)
        span = z_max - z_min
        with np.errstate(divide="ignore"):
            elongation = np.where(span > 0.0, spread / np.where(span > 0.0, span, 1.0), np.inf)
        keep &= elongation >= params.min_elongation_ratio
    return keep


def kimera_mesh(
    pixels: np.ndarray,
    landmarks: np.ndarray,
    image_size: tuple[int, int],
    camera_position: np.ndarray,
    camera_forward: np.ndarray,
    params: MesherParams | None = None,
) -> KeyframeMesh:
    """Build one keyframe's mesh from keypoint pixels ``(N, 2)`` and landmarks ``(N, 3)``.

    A landmark row of NaN means "no 3D point" (no stereo match): such keypoints are
    not vertices. ``camera_position`` and the unit optical axis ``camera_forward``
    (world frame) orient the faces and define depth for the elongation test.
    """
    params = params or MesherParams()
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    landmarks = np.asarray(landmarks, float).reshape(-1, 3)
    if len(pixels) != len(landmarks):
        raise ValueError(f"{len(pixels)} pixels but {len(landmarks)} landmarks")
    camera_position = np.asarray(camera_position, float)
    camera_forward = np.asarray(camera_forward, float)
    valid = np.isfinite(landmarks).all(axis=1)
    valid &= (landmarks - camera_position) @ camera_forward > 0.0
    candidates = np.where(valid[:, None], pixels, np.nan)
    triangles = delaunay_triangles(candidates, image_size)
    empty = KeyframeMesh(np.empty((0, 3)), np.empty((0, 3), np.int64), np.empty(0, np.int64))
    if len(triangles) == 0:
        return empty
    corners = landmarks[triangles]
    triangles = triangles[triangle_quality_mask(corners, camera_position, camera_forward, params)]
    if len(triangles) == 0:
        return empty
    corners = landmarks[triangles]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    towards_camera = camera_position - corners.mean(axis=1)
    flip = np.einsum("ij,ij->i", normals, towards_camera) < 0.0
    triangles[flip] = triangles[flip][:, [0, 2, 1]]
    used, faces = np.unique(triangles, return_inverse=True)
    return KeyframeMesh(landmarks[used], faces.reshape(-1, 3).astype(np.int64), used)
