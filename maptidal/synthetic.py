"""Synthetic wall meshes for demos, tests and benchmarks.

The wall lies in the plane ``x = 0`` (y across, z up) and faces ``-x``, towards a
robot standing off it. Its relief has the features the paper's keyframes show:
an inset window recessed 0.1 m and a ladder's two rails standing off the wall.

- :func:`wall_grid_mesh` is a regular, jittered grid of a chosen face count, for
  benchmarks at 1k, 10k and 100k faces.
- :func:`wall_keyframe_mesh` imitates one Kimera keyframe mesh: sparse keypoints,
  denser at feature edges, triangulated by a 2D Delaunay and lifted onto the
  wall, faces oriented towards the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay


@dataclass(frozen=True)
class WallFeatures:
    """Relief of the synthetic wall (metres, wall coordinates y across, z up)."""

    window_centre: tuple[float, float] = (0.0, 0.0)
    window_size: tuple[float, float] = (1.0, 0.6)
    window_recess: float = 0.1
    ladder_rails_y: tuple[float, float] = (0.6, 1.0)
    rail_width: float = 0.06
    rail_standoff: float = 0.15

    def depth(self, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Wall surface x at wall coordinates (y, z): +recess in the window, -standoff on rails."""
        x = np.zeros(np.broadcast(y, z).shape)
        (cy, cz), (w, h) = self.window_centre, self.window_size
        x = np.where((np.abs(y - cy) < w / 2) & (np.abs(z - cz) < h / 2), self.window_recess, x)
        for rail in self.ladder_rails_y:
            x = np.where(np.abs(y - rail) < self.rail_width / 2, -self.rail_standoff, x)
        return x

    def edge_distance(self, y: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Distance (m) from (y, z) to the nearest feature edge: window frame or rail side."""
        (cy, cz), (w, h) = self.window_centre, self.window_size
        dy, dz = np.abs(y - cy) - w / 2, np.abs(z - cz) - h / 2
        frame = np.where(
            (dy > 0) & (dz > 0),
            np.hypot(dy, dz),
            np.where(dy > 0, dy, np.where(dz > 0, dz, -np.maximum(dy, dz))),
        )
        distances = [np.abs(frame)]
        distances += [np.abs(np.abs(y - rail) - self.rail_width / 2) for rail in self.ladder_rails_y]
        return np.min(distances, axis=0)


def _orient_towards_minus_x(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    flip = np.cross(v1 - v0, v2 - v0)[:, 0] > 0.0
    faces = faces.copy()
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def wall_grid_mesh(
    n_faces: int,
    width: float = 4.0,
    height: float = 2.0,
    roughness: float = 0.005,
    seed: int = 0,
    features: WallFeatures | None = WallFeatures(),
) -> tuple[np.ndarray, np.ndarray]:
    """A jittered grid mesh of about ``n_faces`` triangles covering a ``width x height`` wall."""
    if n_faces < 2:
        raise ValueError(f"n_faces must be at least 2, got {n_faces}")
    rng = np.random.default_rng(seed)
    cells = n_faces / 2.0
    ny = max(1, round(np.sqrt(cells * width / height)))
    nz = max(1, round(cells / ny))
    y, z = np.meshgrid(
        np.linspace(-width / 2, width / 2, ny + 1), np.linspace(-height / 2, height / 2, nz + 1)
    )
    pitch = min(width / ny, height / nz)
    y = y + rng.uniform(-0.25, 0.25, y.shape) * pitch
    z = z + rng.uniform(-0.25, 0.25, z.shape) * pitch
    x = rng.normal(0.0, roughness, y.shape)
    if features is not None:
        x = x + features.depth(y, z)
    vertices = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    index = np.arange((ny + 1) * (nz + 1)).reshape(nz + 1, ny + 1)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.vstack([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return vertices, _orient_towards_minus_x(vertices, faces)


def wall_keyframe_mesh(
    centre_y: float,
    centre_z: float = 0.0,
    width: float = 2.4,
    height: float = 1.6,
    n_keypoints: int = 170,
    edge_fraction: float = 0.6,
    depth_noise: float = 0.01,
    seed: int = 0,
    features: WallFeatures = WallFeatures(),
) -> tuple[np.ndarray, np.ndarray]:
    """One Kimera-like keyframe mesh of the patch of wall a camera sees.

    ``edge_fraction`` of the keypoints cluster at feature edges (as a corner
    detector fires there) and the rest scatter over the flat wall. The keypoints
    are triangulated by a 2D Delaunay in wall coordinates and lifted onto the
    relief with Gaussian depth noise.
    """
    rng = np.random.default_rng(seed)
    half_w, half_h = width / 2, height / 2
    n_edge = round(n_keypoints * edge_fraction)
    # Rejection-sample the edge cluster: accept with a weight that decays away from edges.
    edge_points: list[np.ndarray] = []
    while sum(len(p) for p in edge_points) < n_edge:
        y = rng.uniform(centre_y - half_w, centre_y + half_w, 4 * n_edge)
        z = rng.uniform(centre_z - half_h, centre_z + half_h, 4 * n_edge)
        accept = rng.random(len(y)) < np.exp(-features.edge_distance(y, z) / 0.05)
        edge_points.append(np.column_stack([y[accept], z[accept]]))
    edge = np.vstack(edge_points)[:n_edge]
    flat = np.column_stack(
        [
            rng.uniform(centre_y - half_w, centre_y + half_w, n_keypoints - n_edge),
            rng.uniform(centre_z - half_h, centre_z + half_h, n_keypoints - n_edge),
        ]
    )
    corners = np.array([[sy, sz] for sy in (-half_w, half_w) for sz in (-half_h, half_h)])
    yz = np.vstack([corners + [centre_y, centre_z], edge, flat])
    x = features.depth(yz[:, 0], yz[:, 1]) + rng.normal(0.0, depth_noise, len(yz))
    vertices = np.column_stack([x, yz])
    faces = Delaunay(yz).simplices.astype(np.int64)
    return vertices, _orient_towards_minus_x(vertices, faces)
