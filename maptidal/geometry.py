"""Camera and frustum geometry shared by task discovery and coverage evaluation.

A viewpoint (a CIP or a task) is a row ``(x, y, z, dx, dy, dz)``: a position and a
unit view direction. Its camera frustum is the pyramid whose apex is the
position, whose axis is the view direction and whose far plane lies at
``range_m`` along that axis. The image has zero roll: its x-axis is horizontal
(``right = view x world_z``); for a camera looking almost straight up or down
(``|view . z| > 0.99``) world x is the up reference instead.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from maptidal.camera import OAKD_HFOV_DEG, OAKD_VFOV_DEG

# Beyond this |view . z| the world z-axis is too close to the view axis to define
# a horizontal image x-axis, so world x becomes the up reference.
VERTICAL_VIEW_LIMIT = 0.99
# The longest distance (m) a frustum, standoff or exclusion radius may have: far beyond what a camera
# sees under water, and small enough that grid cell indices stay finite.
MAX_DISTANCE_M = 100.0


@dataclass(frozen=True)
class CameraModel:
    """A pinhole camera's viewing pyramid.

    Defaults are the pinhole of the OAK-D's stereo pair used in the paper (78.5 x 54.1 deg at
    640 x 400, from Luxonis' spec sheet: :mod:`maptidal.camera`); the range defaults to 2 m,
    twice the paper's 1 m standoff L_i.
    """

    hfov_deg: float = OAKD_HFOV_DEG
    vfov_deg: float = OAKD_VFOV_DEG
    range_m: float = 2.0

    def __post_init__(self) -> None:
        for name in ("hfov_deg", "vfov_deg"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 < value < 180.0):
                raise ValueError(f"{name} must be in (0, 180) degrees, got {value!r}")
        if not (math.isfinite(self.range_m) and 0.0 < self.range_m <= MAX_DISTANCE_M):
            raise ValueError(f"range_m must be a distance in (0, {MAX_DISTANCE_M:g}] m, got {self.range_m!r}")

    @property
    def tan_half_h(self) -> float:
        """tan(hfov / 2): the half-width of the footprint per metre of depth."""
        return math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def tan_half_v(self) -> float:
        """tan(vfov / 2): the half-height of the footprint per metre of depth."""
        return math.tan(math.radians(self.vfov_deg) / 2.0)

    def footprint(self, distance_m: float) -> tuple[float, float]:
        """Width and height (m) of the image footprint on a plane facing the camera."""
        return 2.0 * distance_m * self.tan_half_h, 2.0 * distance_m * self.tan_half_v


def camera_axes(directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the image right and up axes (each ``(N, 3)``) for unit view directions.

    ``right = view x reference`` normalised, with reference world z, or world x
    when ``|view . z| > 0.99``; ``up = right x view``.
    """
    directions = np.atleast_2d(np.asarray(directions, dtype=float))
    reference = np.zeros_like(directions)
    near_vertical = np.abs(directions[:, 2]) > VERTICAL_VIEW_LIMIT
    reference[~near_vertical, 2] = 1.0
    reference[near_vertical, 0] = 1.0
    right = _cross_rows(directions, reference)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    up = _cross_rows(right, directions)
    return right, up


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # row-wise a x b written out: np.cross costs ten times more on the few rows a camera frame has
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def frustum_corners(viewpoint: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Return the five vertices ``(5, 3)`` of one viewpoint's pyramid: apex, then far corners."""
    viewpoint = np.asarray(viewpoint, dtype=float)
    apex, view = viewpoint[:3], viewpoint[3:6]
    right, up = (axis[0] for axis in camera_axes(view[None, :]))
    far_centre = apex + camera.range_m * view
    half_w = camera.range_m * camera.tan_half_h
    half_h = camera.range_m * camera.tan_half_v
    corners = [far_centre + sx * half_w * right + sy * half_h * up for sx in (-1, 1) for sy in (-1, 1)]
    return np.vstack([apex, *corners])


def view_frame(viewpoint: np.ndarray) -> np.ndarray:
    """One viewpoint's rows (view, right, up), as :func:`camera_axes` builds them, in scalar arithmetic:
    ten times cheaper than the batched form for a single camera."""
    x, y, z = (float(v) for v in viewpoint[3:6])
    if abs(z) > VERTICAL_VIEW_LIMIT:  # reference world x: right = view x (1, 0, 0)
        rx, ry, rz = 0.0, z, -y
    else:  # reference world z: right = view x (0, 0, 1)
        rx, ry, rz = y, -x, 0.0
    norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    rx, ry, rz = rx / norm, ry / norm, rz / norm
    # up = right x view
    ux, uy, uz = ry * z - rz * y, rz * x - rx * z, rx * y - ry * x
    return np.array([[x, y, z], [rx, ry, rz], [ux, uy, uz]])


def _view_frames(viewpoints: np.ndarray) -> np.ndarray:
    """Per viewpoint, the rows (view, right, up): ``frame @ offset`` is (depth, x, y)."""
    right, up = camera_axes(viewpoints[:, 3:6])
    return np.stack([viewpoints[:, 3:6], right, up], axis=1)


def _batch_local(
    viewpoints: np.ndarray, frames: np.ndarray, columns: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame (depth, x, y), each ``(B, M)``, of M points ``(3, M)`` seen from B viewpoints."""
    offsets = [columns[k][None, :] - viewpoints[:, k, None] for k in range(3)]
    # frame row j . offset: depth (j = 0), then the right and up offsets
    depth, x, y = (
        frames[:, j, 0, None] * offsets[0]
        + frames[:, j, 1, None] * offsets[1]
        + frames[:, j, 2, None] * offsets[2]
        for j in range(3)
    )
    return depth, x, y


def _inside_local(depth: np.ndarray, x: np.ndarray, y: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Half-space test on camera-frame offsets: depth along the view, x right, y up."""
    inside = depth <= camera.range_m
    inside &= np.abs(x) <= depth * camera.tan_half_h
    inside &= np.abs(y) <= depth * camera.tan_half_v
    inside &= depth >= 0.0
    return inside


def in_frustum(viewpoint: np.ndarray, points: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Boolean mask of the ``points`` (``(K, 3)``) inside one viewpoint's frustum.

    A point is inside when its depth along the view axis is in ``[0, range]`` and
    its lateral offsets are within the half-angles: the four side half-spaces and
    the far plane, boundaries included (as Delaunay.find_simplex counts them).
    """
    return next(frustum_masks(np.asarray(viewpoint, dtype=float).reshape(1, 6), points, camera))


def frustum_masks(viewpoints: np.ndarray, points: np.ndarray, camera: CameraModel) -> Iterator[np.ndarray]:
    """Yield, for each viewpoint row in turn, the mask of ``points`` inside its frustum.

    The camera frames are computed once, and the points are used column-wise so
    that each half-space test runs on contiguous rows: about 4x faster than calling
    :func:`in_frustum` per viewpoint when there are hundreds of viewpoints.
    """
    viewpoints = np.asarray(viewpoints, dtype=float).reshape(-1, 6)
    columns = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3).T)
    for viewpoint, frame in zip(viewpoints, _view_frames(viewpoints), strict=True):
        local = frame @ (columns - viewpoint[:3, None])
        yield _inside_local(local[0], local[1], local[2], camera)


def frustum_bounding_spheres(viewpoints: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, float]:
    """Centres ``(N, 3)`` and the common radius of balls that contain each frustum.

    The smallest ball through the apex and the far-corner circle (radius rho at
    depth L) is centred on the axis at depth ``(L^2 + rho^2) / 2L``; when that lies
    beyond the far plane, the ball around the far-plane centre with radius rho
    holds the apex already.
    """
    viewpoints = np.asarray(viewpoints, dtype=float).reshape(-1, 6)
    depth = camera.range_m
    rho = depth * math.hypot(camera.tan_half_h, camera.tan_half_v)
    centre_depth = min((depth**2 + rho**2) / (2.0 * depth), depth)
    radius = max(centre_depth, math.hypot(depth - centre_depth, rho))
    return viewpoints[:, :3] + centre_depth * viewpoints[:, 3:6], radius


class SpatialGrid:
    """Points bucketed into cubic cells, for neighbour look-ups that return arrays.

    The points are stored sorted by cell key, and a key is linear in the cell
    coordinates, so the 3 x 3 x 3 block of cells around a query point is nine
    contiguous key ranges (three cells each along z). ``near(point)`` returns the
    original indices and coordinates of every point in that block: a superset of
    the points within ``cell_size``. Unlike cKDTree.query_ball_point it builds no
    Python lists and gathers no scattered rows, which matters in loops that ask
    thousands of times.
    """

    def __init__(self, points: np.ndarray, cell_size: float) -> None:
        if not (math.isfinite(cell_size) and cell_size > 0.0):
            raise ValueError(f"cell_size must be positive and finite, got {cell_size!r}")
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        self.cell_size = cell_size
        cells = np.floor(points / cell_size).astype(np.int64)
        low = cells.min(axis=0) if len(cells) else np.zeros(3, np.int64)
        high = cells.max(axis=0) if len(cells) else np.zeros(3, np.int64)
        # One cell of padding each side, and at least 3 cells per axis, keep the
        # nine key ranges of a look-up disjoint even for query points far outside.
        self._origin = low - 1
        self._shape = np.maximum(high - low + 3, 3)
        keys = self._keys(cells)
        self.order = np.argsort(keys, kind="stable")
        self.sorted_keys = keys[self.order]
        # Column-wise (3, N): distance and dot products then run on contiguous rows.
        self.sorted_columns = np.ascontiguousarray(points[self.order].T)
        stride_y, stride_x = int(self._shape[2]), int(self._shape[1] * self._shape[2])
        self._strides = (stride_x, stride_y)
        self._origin_cell = tuple(int(v) for v in self._origin)
        self._row_offsets = np.array(
            [dx * stride_x + dy * stride_y for dx in (-1, 0, 1) for dy in (-1, 0, 1)],
            dtype=np.int64,
        )

    def _keys(self, cells: np.ndarray) -> np.ndarray:
        shifted = cells - self._origin
        return (shifted[..., 0] * self._shape[1] + shifted[..., 1]) * self._shape[2] + shifted[..., 2]

    def cell_keys(self, points: np.ndarray) -> np.ndarray:
        """The cell key of each query point ``(N, 3)``: equal keys mean the same cell."""
        return self._keys(np.floor(np.asarray(points, dtype=float) / self.cell_size).astype(np.int64))

    def near(self, point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Original indices ``(M,)`` and coordinates ``(3, M)`` of the points in the 27 cells."""
        # Plain Python arithmetic: numpy calls on 3-vectors cost more than they save here.
        size, (ox, oy, oz), (stride_x, stride_y) = self.cell_size, self._origin_cell, self._strides
        x, y, z = (float(v) for v in point)
        key = (
            (math.floor(x / size) - ox) * stride_x
            + (math.floor(y / size) - oy) * stride_y
            + (math.floor(z / size) - oz)
        )
        rows = self._row_offsets + key
        starts = np.searchsorted(self.sorted_keys, rows - 1, side="left").tolist()
        ends = np.searchsorted(self.sorted_keys, rows + 1, side="right").tolist()
        slices = [(a, b) for a, b in zip(starts, ends, strict=True) if b > a]
        if len(slices) == 1:
            ((a, b),) = slices
            return self.order[a:b], self.sorted_columns[:, a:b]
        if not slices:
            return np.empty(0, dtype=np.int64), np.empty((3, 0))
        return (
            np.concatenate([self.order[a:b] for a, b in slices]),
            np.concatenate([self.sorted_columns[:, a:b] for a, b in slices], axis=1),
        )


def count_in_frustums(
    viewpoints: np.ndarray,
    points: np.ndarray,
    camera: CameraModel,
    max_pairs: int = 65_536,
) -> np.ndarray:
    """Count, for each viewpoint row, the points inside its frustum.

    A spatial grid over the points, with cells as large as the frustum's bounding
    ball, gives each frustum a small candidate block. Viewpoints whose ball
    centres share a cell share that block, so each such group is tested in one
    batched half-space test of at most ``max_pairs`` point-frustum pairs at a time
    (small enough for the temporaries to stay in cache: 64k pairs measured fastest).
    """
    viewpoints = np.asarray(viewpoints, dtype=float).reshape(-1, 6)
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    counts = np.zeros(len(viewpoints), dtype=np.int64)
    if len(viewpoints) == 0 or len(points) == 0:
        return counts
    centres, radius = frustum_bounding_spheres(viewpoints, camera)
    grid = SpatialGrid(points, radius)
    frames = _view_frames(viewpoints)
    cell_keys = grid.cell_keys(centres)
    _, first_of_group, group_of = np.unique(cell_keys, return_index=True, return_inverse=True)
    for group, first in enumerate(first_of_group):
        _, columns = grid.near(centres[first])
        if columns.shape[1] == 0:
            continue
        members = np.flatnonzero(group_of == group)
        chunk = max(1, max_pairs // columns.shape[1])
        for start in range(0, len(members), chunk):
            batch = members[start : start + chunk]
            depth, x, y = _batch_local(viewpoints[batch], frames[batch], columns)
            counts[batch] = np.count_nonzero(_inside_local(depth, x, y, camera), axis=1)
    return counts


def frustum_count_bounds(
    viewpoints: np.ndarray,
    points: np.ndarray,
    camera: CameraModel,
    cell_size: float | None = None,
    max_pairs: int = 262_144,
) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds on the number of points inside each viewpoint's frustum.

    The points are binned into cubes of ``cell_size`` (default range / 8). A cube whose bounding ball
    lies wholly inside a frustum adds its points to both bounds; one whose ball reaches the frustum
    adds them to the upper bound only; the rest add nothing. Each test is one signed distance per
    frustum face, so the bounds cost cells x viewpoints, not points x viewpoints, and
    ``lower <= exact count <= upper`` holds for every viewpoint.
    """
    viewpoints = np.asarray(viewpoints, dtype=float).reshape(-1, 6)
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    lower = np.zeros(len(viewpoints), dtype=np.int64)
    upper = np.zeros(len(viewpoints), dtype=np.int64)
    if len(viewpoints) == 0 or len(points) == 0:
        return lower, upper
    size = cell_size or camera.range_m / 8.0
    cells, counts = np.unique(np.floor(points / size).astype(np.int64), axis=0, return_counts=True)
    centres = (cells + 0.5) * size
    # a margin far above rounding keeps the bounds rigorous at the boundaries
    ball = size * math.sqrt(3.0) / 2.0 + 1e-9 * max(1.0, float(np.abs(centres).max()))
    side_h = 1.0 / math.hypot(1.0, camera.tan_half_h)  # turns depth*tan - |x| into a distance
    side_v = 1.0 / math.hypot(1.0, camera.tan_half_v)
    frames = _view_frames(viewpoints)
    columns = np.ascontiguousarray(centres.T)
    chunk = max(1, max_pairs // len(centres))
    for start in range(0, len(viewpoints), chunk):
        batch = slice(start, start + chunk)
        depth, x, y = _batch_local(viewpoints[batch], frames[batch], columns)
        # signed distance of each cell centre to the nearest frustum face (positive inside)
        distance = np.minimum(depth, camera.range_m - depth)
        np.minimum(distance, (depth * camera.tan_half_h - np.abs(x)) * side_h, out=distance)
        np.minimum(distance, (depth * camera.tan_half_v - np.abs(y)) * side_v, out=distance)
        lower[batch] = (distance >= ball).astype(np.int64) @ counts
        upper[batch] = (distance >= -ball).astype(np.int64) @ counts
    return lower, upper


def view_angles(direction: np.ndarray, others: np.ndarray) -> np.ndarray:
    """Angles (rad) between one unit direction and each row of ``others``.

    The dot product is clipped to [-1, 1] so that rounding on parallel unit
    vectors gives 0 rather than NaN.
    """
    return np.arccos(np.clip(np.asarray(others) @ np.asarray(direction), -1.0, 1.0))


def point_triangle_distances(points: np.ndarray, triangles: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Distance from each point ``(N, 3)`` to the nearest of ``triangles`` ``(T, 3, 3)``, exactly: the
    distance to the plane where the point projects inside a triangle, else to the nearest edge."""
    points = np.asarray(points, float).reshape(-1, 3)
    triangles = np.asarray(triangles, float).reshape(-1, 3, 3)
    best = np.full(len(points), np.inf)
    if len(points) == 0 or len(triangles) == 0:
        return best
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    normal = _cross_rows(b - a, c - a)
    area2 = np.linalg.norm(normal, axis=1)
    unit = normal / np.where(area2 > 0, area2, 1.0)[:, None]
    for start in range(0, len(points), chunk):
        p = points[start : start + chunk, None, :]  # (n, 1, 3) against (T, 3)
        height = np.einsum("ntk,tk->nt", p - a, unit)
        foot = p - height[..., None] * unit
        # barycentric signs: the foot is inside when it lies left of every edge (in the normal's sense)
        inside = area2 > 0
        for u, v in ((a, b), (b, c), (c, a)):
            inside = inside & (np.einsum("ntk,tk->nt", np.cross(v - u, foot - u), unit) >= 0)
        distance = np.where(inside, np.abs(height), np.inf)
        for u, v in ((a, b), (b, c), (c, a)):
            edge = v - u
            length2 = np.maximum(np.einsum("tk,tk->t", edge, edge), 1e-300)
            s = np.clip(np.einsum("ntk,tk->nt", p - u, edge) / length2, 0.0, 1.0)
            nearest = u + s[..., None] * edge
            distance = np.minimum(distance, np.linalg.norm(p - nearest, axis=2))
        best[start : start + chunk] = distance.min(axis=1)
    return best
