"""Vectorised ray casting against a small triangle soup (Moller-Trumbore).

The tank scenes have a few hundred triangles and the casts a few thousand rays, so a
dense rays x triangles test in chunks is simpler and faster than building a BVH, and
needs no optional dependency (trimesh's fast path wants embree).
"""

from __future__ import annotations

import numpy as np

# Rays x triangles pairs per chunk: large enough to amortise numpy's overhead, small
# enough that the temporaries stay in a few MB.
_CHUNK_PAIRS = 200_000


def first_hit_distances(
    origins: np.ndarray,
    directions: np.ndarray,
    triangles: np.ndarray,
    epsilon: float = 1e-9,
) -> np.ndarray:
    """Distance along each ray to the first triangle it hits (``inf`` when none).

    ``origins`` and ``directions`` are ``(N, 3)`` (directions need not be unit; the
    distance is in units of the direction's length), ``triangles`` is ``(T, 3, 3)``.
    Both faces of a triangle count, and only hits at positive distance.
    """
    origins = np.asarray(origins, float).reshape(-1, 3)
    directions = np.asarray(directions, float).reshape(-1, 3)
    triangles = np.asarray(triangles, float).reshape(-1, 3, 3)
    hits = np.full(len(origins), np.inf)
    if len(origins) == 0 or len(triangles) == 0:
        return hits
    v0 = triangles[:, 0]
    edge1 = triangles[:, 1] - v0
    edge2 = triangles[:, 2] - v0
    step = max(1, _CHUNK_PAIRS // len(triangles))
    for start in range(0, len(origins), step):
        o = origins[start : start + step, None, :]
        d = directions[start : start + step, None, :]
        p = np.cross(d, edge2[None])
        det = np.einsum("rtk,tk->rt", p, edge1)
        parallel = np.abs(det) < epsilon
        inv = 1.0 / np.where(parallel, 1.0, det)
        s = o - v0[None]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        q = np.cross(s, edge1[None])
        v = np.einsum("rtk,rtk->rt", d, q) * inv
        t = np.einsum("tk,rtk->rt", edge2, q) * inv
        valid = ~parallel & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > epsilon)
        hits[start : start + step] = np.where(valid, t, np.inf).min(axis=1)
    return hits


def visible_from(
    viewpoint: np.ndarray, points: np.ndarray, triangles: np.ndarray, tolerance: float
) -> np.ndarray:
    """Mask of the ``points`` that a ray from ``viewpoint`` reaches unblocked.

    A point counts as reached when nothing is hit more than ``tolerance`` (m) before
    it: points on a surface (or voxel centres near one) are hit by their own surface
    at about their own distance.
    """
    points = np.asarray(points, float).reshape(-1, 3)
    offsets = points - np.asarray(viewpoint, float)[:3]
    distances = np.linalg.norm(offsets, axis=1)
    safe = np.where(distances > 0.0, distances, 1.0)
    hits = first_hit_distances(
        np.broadcast_to(viewpoint[:3], points.shape), offsets / safe[:, None], triangles
    )
    return hits >= distances - tolerance
