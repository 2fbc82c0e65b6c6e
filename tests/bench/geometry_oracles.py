"""Brute-force geometry used as test oracles: slow, obvious, independent of maptidal."""

import numpy as np
from trimesh.triangles import closest_point


def distances_to_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest of ``triangles`` (T, 3, 3), one triangle at a time."""
    return np.array(
        [
            np.linalg.norm(closest_point(triangles, np.repeat(p[None], len(triangles), 0)) - p, axis=1).min()
            for p in np.asarray(points, float).reshape(-1, 3)
        ]
    )
