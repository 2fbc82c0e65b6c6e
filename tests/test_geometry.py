"""Frustum and neighbour-grid geometry against independent references."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import Delaunay

from maptidal.geometry import (
    CameraModel,
    SpatialGrid,
    camera_axes,
    count_in_frustums,
    frustum_bounding_spheres,
    frustum_corners,
    frustum_count_bounds,
    in_frustum,
    point_triangle_distances,
    view_frame,
)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("direction", [[1, 0, 0], [0.3, -0.8, 0.2], [0, 0, -1], [0.05, 0.02, 0.998]])
def test_frustum_agrees_with_delaunay_pyramid(direction):
    rng = np.random.default_rng(7)
    camera = CameraModel(72.0, 57.0, 2.0)
    viewpoint = np.concatenate([[0.4, -0.2, 1.0], _unit(direction)])
    points = viewpoint[:3] + rng.uniform(-2.5, 2.5, (20000, 3))
    expected = Delaunay(frustum_corners(viewpoint, camera)).find_simplex(points) >= 0
    got = in_frustum(viewpoint, points, camera)
    assert expected.sum() > 200  # the sample really probes the pyramid
    np.testing.assert_array_equal(got, expected)


def test_camera_axes_have_zero_roll_and_are_orthonormal():
    directions = _unit(np.random.default_rng(1).normal(size=(500, 3)))
    right, up = camera_axes(directions)
    for a, b in ((right, up), (right, directions), (up, directions)):
        np.testing.assert_allclose(np.sum(a * b, axis=1), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(right, axis=1), 1.0)
    level = np.abs(directions[:, 2]) <= 0.99
    np.testing.assert_allclose(right[level, 2], 0.0, atol=1e-12)  # image x-axis horizontal
    assert np.all(up[level, 2] >= 0.0)  # and the image is upright
    vertical = ~level
    if vertical.any():
        np.testing.assert_allclose(right[vertical, 0], 0.0, atol=1e-12)


def test_footprint_on_a_facing_wall_matches_the_field_of_view():
    camera = CameraModel(72.0, 57.0, 2.0)
    width, height = camera.footprint(1.0)
    assert width == pytest.approx(2 * np.tan(np.radians(36)))
    viewpoint = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    inside = [[1.0, 0.99 * width / 2, 0.0], [1.0, 0.0, -0.99 * height / 2]]
    outside = [
        [1.0, 1.01 * width / 2, 0.0],
        [1.0, 0.0, 1.01 * height / 2],
        [2.01, 0, 0],
        [-0.1, 0, 0],
    ]
    assert in_frustum(viewpoint, inside, camera).all()
    assert not in_frustum(viewpoint, outside, camera).any()


def test_count_in_frustums_equals_brute_force():
    rng = np.random.default_rng(3)
    camera = CameraModel(60.0, 45.0, 1.5)
    points = rng.uniform(-3, 3, (4000, 3))
    viewpoints = np.hstack([rng.uniform(-3, 3, (300, 3)), _unit(rng.normal(size=(300, 3)))])
    expected = [np.count_nonzero(in_frustum(v, points, camera)) for v in viewpoints]
    np.testing.assert_array_equal(count_in_frustums(viewpoints, points, camera), expected)
    # Tiny batches exercise the chunking.
    np.testing.assert_array_equal(count_in_frustums(viewpoints, points, camera, max_pairs=10), expected)


def test_bounding_spheres_contain_their_frustums():
    camera = CameraModel(72.0, 57.0, 2.0)
    viewpoints = np.hstack([np.zeros((50, 3)), _unit(np.random.default_rng(4).normal(size=(50, 3)))])
    centres, radius = frustum_bounding_spheres(viewpoints, camera)
    for viewpoint, centre in zip(viewpoints, centres, strict=True):
        corners = frustum_corners(viewpoint, camera)
        assert np.all(np.linalg.norm(corners - centre, axis=1) <= radius * (1 + 1e-12))
    assert radius < camera.range_m * np.sqrt(1 + camera.tan_half_h**2 + camera.tan_half_v**2)


@pytest.mark.parametrize("offset", [0.0, 50.0])
def test_spatial_grid_returns_each_neighbour_once(offset):
    rng = np.random.default_rng(5)
    points = rng.uniform(-2, 2, (3000, 3))
    grid = SpatialGrid(points, 0.7)
    for query in rng.uniform(-3, 3, (40, 3)) + offset * np.array([1, 0, 0]):
        indices, columns = grid.near(query)
        assert len(np.unique(indices)) == len(indices)
        np.testing.assert_array_equal(columns.T, points[indices])
        within = np.flatnonzero(np.linalg.norm(points - query, axis=1) <= 0.7)
        assert set(within) <= set(indices.tolist())


def test_camera_rejects_bad_values():
    for bad in ({"hfov_deg": 0}, {"vfov_deg": 180}, {"range_m": -1}, {"range_m": float("nan")}):
        with pytest.raises(ValueError):
            CameraModel(**bad)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 100_000), cell=st.sampled_from([None, 0.05, 0.3, 1.0]), flat=st.booleans())
def test_count_bounds_bracket_the_exact_count(seed, cell, flat):
    rng = np.random.default_rng(seed)
    camera = CameraModel(72.0, 57.0, 2.0)
    points = rng.uniform(-3, 3, (3000, 3))
    if flat:  # a wall, as discovery sees it: many points on one plane, some on frustum faces
        points[:, 0] = 1.0
    viewpoints = np.hstack([rng.uniform(-1, 1, (60, 3)), _unit(rng.normal(size=(60, 3)))])
    viewpoints[:10, 3:] = [1.0, 0.0, 0.0]  # some look straight at the wall
    exact = count_in_frustums(viewpoints, points, camera)
    lower, upper = frustum_count_bounds(viewpoints, points, camera, cell_size=cell, max_pairs=5000)
    assert np.all(lower <= exact) and np.all(exact <= upper)
    assert upper.sum() > 0


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_point_triangle_distance_agrees_with_dense_sampling(seed):
    """Against the nearest of a 300 x 300 barycentric grid of points on each triangle (independent of the
    plane-or-edge rule): equal within the grid's spacing."""
    rng = np.random.default_rng(seed)
    triangles = rng.uniform(-1, 1, size=(3, 3, 3))
    points = rng.uniform(-2, 2, size=(15, 3))
    ours = point_triangle_distances(points, triangles)
    s, t = np.meshgrid(np.linspace(0, 1, 300), np.linspace(0, 1, 300))
    keep = s + t <= 1.0
    s, t = s[keep], t[keep]
    samples = np.concatenate(
        [tri[0] + s[:, None] * (tri[1] - tri[0]) + t[:, None] * (tri[2] - tri[0]) for tri in triangles]
    )
    spacing = (
        max(np.linalg.norm(tri[i] - tri[j]) for tri in triangles for i in range(3) for j in range(3)) / 299
    )
    for point, distance in zip(points, ours, strict=True):
        sampled = np.linalg.norm(samples - point, axis=1).min()
        assert distance <= sampled + 1e-12
        assert sampled - distance <= spacing


@settings(max_examples=30, deadline=None)
@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1))
def test_the_single_view_frame_equals_the_batched_camera_axes(x, y, z):
    direction = np.array([x, y, z])
    if np.linalg.norm(direction) < 1e-3:
        return
    direction /= np.linalg.norm(direction)
    right, up = camera_axes(direction[None])
    np.testing.assert_allclose(
        view_frame(np.r_[0.0, 0.0, 0.0, direction]), np.vstack([direction, right, up]), atol=1e-12
    )
