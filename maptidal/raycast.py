"""Vectorised ray casting against a small triangle soup (Moller-Trumbore).

The tank scenes have a few hundred triangles and the casts a few thousand rays, so a
dense rays x triangles test in chunks is simpler and faster than building a BVH, and
needs no optional dependency (trimesh's fast path wants embree).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

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


@dataclass(frozen=True, eq=False)
class Occluders:
    """A triangle soup prepared for rays from one origin at a time (:meth:`first_hits_from`).

    With a common origin o, Moller-Trumbore's per-pair cross products become per-triangle vectors that
    are linear in o: with ``n = e2 x e1``, det = d . n, u = d . (e2 x o - e2 x v0) / det,
    v = d . (o x e1 - v0 x e1) / det and t = (-o . n - e2 . (v0 x e1)) / det. The parts without o are
    computed once here, so a cast costs one ``(N, 3) @ (3, 3T)`` product.
    """

    triangles: np.ndarray
    v0: np.ndarray
    edge1: np.ndarray
    edge2: np.ndarray
    normal: np.ndarray  # e2 x e1
    e2_x_v0: np.ndarray
    v0_x_e1: np.ndarray
    t_offset: np.ndarray  # e2 . (v0 x e1)

    @classmethod
    def of(cls, triangles: np.ndarray) -> Occluders:
        """Prepare ``(T, 3, 3)`` triangles."""
        triangles = np.asarray(triangles, float).reshape(-1, 3, 3)
        v0 = triangles[:, 0]
        edge1, edge2 = triangles[:, 1] - v0, triangles[:, 2] - v0
        v0_x_e1 = np.cross(v0, edge1)
        return cls(
            triangles,
            v0,
            edge1,
            edge2,
            np.cross(edge2, edge1),
            np.cross(edge2, v0),
            v0_x_e1,
            np.einsum("tk,tk->t", edge2, v0_x_e1),
        )

    def first_hits_from(
        self,
        origin: np.ndarray,
        directions: np.ndarray,
        epsilon: float = 1e-9,
        within: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """:func:`first_hit_distances` for rays from one ``origin`` ``(3,)``.

        ``within``: a box (low, high corners) that holds every ray's stretch of interest; triangles whose
        bounding box misses it are left out, so a hit outside the box may be missed (reported as inf).
        """
        directions = np.asarray(directions, float).reshape(-1, 3)
        hits = np.full(len(directions), np.inf)
        if len(directions) == 0 or len(self.triangles) == 0:
            return hits
        o = np.asarray(origin, float).reshape(3)
        normal, e2_x_v0, v0_x_e1, t_offset, edges = (
            self.normal,
            self.e2_x_v0,
            self.v0_x_e1,
            self.t_offset,
            self._edges,
        )
        if within is not None:
            low, high = within
            meets = np.flatnonzero(np.all(self._box_low <= high, 1) & np.all(self._box_high >= low, 1))
            if len(meets) == 0:
                return hits
            normal, e2_x_v0, v0_x_e1, t_offset = (
                normal[meets],
                e2_x_v0[meets],
                v0_x_e1[meets],
                t_offset[meets],
            )
            edges = edges[np.concatenate((meets, meets + len(self.triangles)))]
        n_triangles = len(normal)
        # a x o for rows a is a @ skew: the cross products with the origin in one 3 x 3 product
        skew = np.array([[0.0, -o[2], o[1]], [o[2], 0.0, -o[0]], [-o[1], o[0], 0.0]])
        crossed = edges @ skew  # (e2 x o; e1 x o)
        if n_triangles == len(self.triangles):
            basis = self._basis  # reused between calls (one caller at a time: not for threads)
        else:
            basis = np.empty((3, 3 * n_triangles))
            basis[:, :n_triangles] = normal.T
        basis[:, n_triangles : 2 * n_triangles] = (crossed[:n_triangles] - e2_x_v0).T
        basis[:, 2 * n_triangles :] = (-crossed[n_triangles:] - v0_x_e1).T
        t_numerator = -(normal @ o) - t_offset
        step = max(1, _CHUNK_PAIRS // n_triangles)
        for start in range(0, len(directions), step):
            products = directions[start : start + step] @ basis
            det = products[:, :n_triangles]
            parallel = np.abs(det) < epsilon
            inv = 1.0 / np.where(parallel, 1.0, det)
            u = products[:, n_triangles : 2 * n_triangles] * inv
            v = products[:, 2 * n_triangles :] * inv
            t = t_numerator * inv
            valid = (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > epsilon) & ~parallel
            hits[start : start + step] = np.where(valid, t, np.inf).min(axis=1)
        return hits

    @functools.cached_property
    def _box_low(self) -> np.ndarray:
        return self.triangles.min(axis=1)

    @functools.cached_property
    def _box_high(self) -> np.ndarray:
        return self.triangles.max(axis=1)

    @functools.cached_property
    def _edges(self) -> np.ndarray:
        return np.vstack([self.edge2, self.edge1])

    @functools.cached_property
    def _basis(self) -> np.ndarray:
        # (3, 3T): the det columns (e2 x e1) fixed; the u and v columns filled per origin
        basis = np.zeros((3, 3 * len(self.triangles)))
        basis[:, : len(self.triangles)] = self.normal.T
        return basis


def first_hit_distances_from(
    origin: np.ndarray, directions: np.ndarray, triangles: np.ndarray | Occluders, epsilon: float = 1e-9
) -> np.ndarray:
    """:func:`first_hit_distances` for rays that share one ``origin`` ``(3,)`` (:class:`Occluders`)."""
    occluders = triangles if isinstance(triangles, Occluders) else Occluders.of(triangles)
    return occluders.first_hits_from(origin, directions, epsilon)


def visible_from(
    viewpoint: np.ndarray, points: np.ndarray, triangles: np.ndarray | Occluders, tolerance: float
) -> np.ndarray:
    """Mask of the ``points`` that a ray from ``viewpoint`` reaches unblocked.

    A point counts as reached when nothing is hit more than ``tolerance`` (m) before
    it: points on a surface (or voxel centres near one) are hit by their own surface
    at about their own distance.
    """
    points = np.asarray(points, float).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, bool)
    origin = np.asarray(viewpoint, float)[:3]
    offsets = points - origin
    distances = np.linalg.norm(offsets, axis=1)
    safe = np.where(distances > 0.0, distances, 1.0)
    occluders = triangles if isinstance(triangles, Occluders) else Occluders.of(triangles)
    # only what lies between the origin and the points can block: the box around them holds every segment
    box = (np.minimum(points.min(0), origin), np.maximum(points.max(0), origin))
    hits = occluders.first_hits_from(origin, offsets / safe[:, None], within=box)
    return hits >= distances - tolerance
