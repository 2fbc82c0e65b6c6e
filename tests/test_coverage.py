"""Coverage counting, the ideal gamma bins, MAD, and the ray caster under occlusion."""

import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import gamma

from maptidal.evaluation.coverage import (
    CoverageModel,
    CoverageParams,
    coverage_report,
    ideal_gamma_bins,
    mean_absolute_difference,
    views_histogram,
    views_per_point,
    voxel_centres,
)
from maptidal.geometry import CameraModel, in_frustum
from maptidal.raycast import first_hit_distances, first_hit_distances_from, visible_from
from maptidal.tank import TankModel

CAMERA = CameraModel(72.0, 57.0, 2.0)


def _wall(size: float = 4.0) -> trimesh.Trimesh:
    """A flat square wall in the plane x = 0, centred on (0, 0, 0)."""
    h = size / 2
    vertices = np.array([[0, -h, -h], [0, h, -h], [0, h, h], [0, -h, h]], float)
    return trimesh.Trimesh(vertices, [[0, 1, 2], [0, 2, 3]], process=False)


@pytest.mark.parametrize("distance", [0.5, 1.0, 1.5])
def test_one_viewpoint_facing_a_wall_counts_its_footprint(distance):
    pitch = 0.02
    voxels = voxel_centres(_wall(), pitch)
    views = views_per_point(np.array([[-distance, 0, 0, 1, 0, 0]]), voxels, CAMERA)
    width, height = CAMERA.footprint(distance)
    seen_area = np.count_nonzero(views) * pitch**2
    # The voxel layer straddles the wall plane, so compare with the footprint at its depth
    # within one voxel's worth of border.
    border = (width + height) * 2 * pitch
    assert abs(seen_area - width * height) < border
    assert set(np.unique(views)) <= {0, 1}


def test_wall_beyond_the_far_plane_or_behind_is_not_seen():
    voxels = voxel_centres(_wall(), 0.05)
    far = views_per_point(np.array([[-2.5, 0, 0, 1, 0, 0]]), voxels, CAMERA)
    away = views_per_point(np.array([[-1.0, 0, 0, -1, 0, 0]]), voxels, CAMERA)
    assert far.sum() == 0 and away.sum() == 0


def test_views_per_point_matches_the_per_viewpoint_frustum_test():
    rng = np.random.default_rng(3)
    points = rng.uniform(-3, 3, size=(500, 3))
    directions = rng.normal(size=(15, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    viewpoints = np.hstack([rng.uniform(-1, 1, size=(15, 3)), directions])
    expected = sum(in_frustum(v, points, CAMERA).astype(int) for v in viewpoints)
    np.testing.assert_array_equal(views_per_point(viewpoints, points, CAMERA), expected)


def test_ideal_gamma_bins_match_scipy_and_sum_to_at_most_one():
    bins = ideal_gamma_bins(10)
    reference = gamma(a=4, scale=2 / 3)
    assert bins[0] == pytest.approx(reference.cdf(0.5))
    for k in range(1, 11):
        assert bins[k] == pytest.approx(reference.cdf(k + 0.5) - reference.cdf(k - 0.5))
    assert bins.sum() <= 1.0
    assert bins.sum() == pytest.approx(reference.cdf(10.5))
    assert int(np.argmax(bins)) == 2  # the paper's chosen peak
    assert bins[0] < 0.01  # "less than 1% of voxels inspected less than 0.5 times"


def test_report_on_known_counts():
    views = np.array([0, 1, 1, 2, 2, 2, 3, 12])
    report = coverage_report(views, n_viewpoints=5)
    assert report.pct_uninspected == pytest.approx(12.5)
    assert report.mean_views == pytest.approx(views.mean())
    assert len(report.histogram) == 13  # K = max(10, 12) -> bins 0..12
    assert sum(report.histogram) == pytest.approx(1.0)
    ideal = ideal_gamma_bins(12)
    histogram = np.bincount(views, minlength=13) / len(views)
    assert report.mad_legacy == pytest.approx(np.mean(np.abs(histogram - ideal)))
    # MAD over the fixed bins 0..10 and a tail bin (11+), the ideal renormalised over 0..10, 0 in the tail
    fixed = np.r_[np.bincount(views, minlength=13)[:11], (views >= 11).sum()] / len(views)
    ideal_fixed = np.r_[ideal_gamma_bins(10) / ideal_gamma_bins(10).sum(), 0.0]
    assert report.mad == pytest.approx(np.mean(np.abs(fixed - ideal_fixed)))
    assert len(coverage_report(np.array([0, 1]), 1).histogram) == 11  # K is at least 10
    with pytest.raises(ValueError, match="no voxels"):
        coverage_report(np.array([], dtype=int), 0)


@given(
    st.lists(st.integers(0, 30), min_size=1, max_size=200),
    st.lists(st.integers(11, 60), min_size=1, max_size=100),
)
def test_adding_over_covered_voxels_never_lowers_mad(views, extra):
    """Over the fixed bins, voxels seen 11 or more times only add error; over bins 0..K they did not."""
    before = coverage_report(np.array(views), 1).mad
    after = coverage_report(np.array(views + extra), 1).mad
    assert after >= before - 1e-12


def test_the_legacy_mad_rewarded_over_coverage_and_the_fixed_bins_do_not():
    """Half the voxels over-covered: the legacy MAD improves, the fixed-bin MAD does not."""
    base = np.r_[np.zeros(10, int), np.full(90, 2)]
    over = np.r_[base, np.arange(11, 61)]  # 50 voxels seen 11 to 60 times each
    assert coverage_report(over, 1).mad_legacy < coverage_report(base, 1).mad_legacy  # the old flaw
    assert coverage_report(over, 1).mad >= coverage_report(base, 1).mad


def test_mad_is_zero_only_for_the_ideal_itself():
    ideal = ideal_gamma_bins(10)
    assert mean_absolute_difference(ideal, ideal) == 0.0
    assert mean_absolute_difference(views_histogram(np.full(50, 2), 10), ideal) > 0.05


def _square(x: float, half: float = 1.0) -> np.ndarray:
    return np.array(
        [
            [[x, -half, -half], [x, half, -half], [x, half, half]],
            [[x, -half, -half], [x, half, half], [x, -half, half]],
        ]
    )


def test_first_hit_distance_on_a_known_square():
    origins = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.0, 5, 0]])
    directions = np.array([[1.0, 0, 0], [-1.0, 0, 0], [1.0, 0, 0]])
    hits = first_hit_distances(origins, directions, _square(2.0))
    assert hits[0] == pytest.approx(2.0)
    assert math.isinf(hits[1]) and math.isinf(hits[2])


def _brute_force_first_hit(origin, direction, triangles):
    """Plane intersection, then barycentric coordinates: independent of Moller-Trumbore."""
    best = np.inf
    for triangle in triangles:
        normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
        denominator = normal @ direction
        if abs(denominator) < 1e-12:
            continue
        t = normal @ (triangle[0] - origin) / denominator
        if t <= 1e-9:
            continue
        point = origin + t * direction
        barycentric = trimesh.triangles.points_to_barycentric(triangle[None], point[None])[0]
        if np.all(barycentric >= -1e-9):
            best = min(best, t)
    return best


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_first_hit_distance_agrees_with_brute_force(seed):
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    origins = rng.uniform(-3, 3, size=(30, 3))
    directions = rng.uniform(-0.8, 0.8, size=(30, 3)) - origins
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[::3] *= -1.0  # some rays point away and must miss
    ours = first_hit_distances(origins, directions, mesh.triangles)
    for ray in range(len(origins)):
        expected = _brute_force_first_hit(origins[ray], directions[ray], mesh.triangles)
        assert ours[ray] == pytest.approx(expected, abs=1e-7)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_shared_origin_first_hit_agrees_with_brute_force(seed):
    """The one-origin path (used for every occlusion test) against plane-then-barycentric, per ray."""
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=1.0)
    origin = rng.uniform(-3, 3, size=3) * rng.choice([0.1, 1.0])  # inside the sphere, or outside
    directions = rng.normal(size=(40, 3)) * rng.uniform(0.2, 3.0, size=(40, 1))  # not unit
    ours = first_hit_distances_from(origin, directions, mesh.triangles)
    for ray in range(len(directions)):
        expected = _brute_force_first_hit(origin, directions[ray], mesh.triangles)
        assert ours[ray] == pytest.approx(expected, abs=1e-7)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_visible_from_agrees_with_brute_force_in_a_cluttered_scene(seed):
    """visible_from leaves out triangles whose bounding box misses the box around the origin and the
    points; against the brute-force first hit over every triangle, per point."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-2, 2, size=(30, 1, 3))
    triangles = centres + rng.normal(scale=0.4, size=(30, 3, 3))  # small scattered triangles
    origin = rng.uniform(-1, 1, size=3)
    points = origin + rng.normal(scale=rng.uniform(0.2, 2.0), size=(40, 3))
    tolerance = 0.01
    ours = visible_from(np.r_[origin, 1.0, 0.0, 0.0], points, triangles, tolerance)
    for k, point in enumerate(points):
        distance = float(np.linalg.norm(point - origin))
        hit = _brute_force_first_hit(origin, (point - origin) / distance, triangles)
        assert ours[k] == (hit >= distance - tolerance), k


def test_occlusion_blocks_voxels_behind_a_wall():
    voxels = voxel_centres(_wall(1.0), 0.05)
    viewpoint = np.array([[-1.5, 0, 0, 1, 0, 0]])
    blocker = _square(-0.7, half=0.15)
    plain = views_per_point(viewpoint, voxels, CAMERA)
    occluded = views_per_point(
        viewpoint, voxels, CAMERA, occluders=np.concatenate([blocker, _wall(1.0).triangles]), tolerance=0.06
    )
    assert plain.sum() == len(voxels)
    assert 0 < occluded.sum() < plain.sum()
    assert np.all(occluded <= plain)
    # The shadow of the blocker: voxels whose straight line to the viewpoint crosses it.
    shadowed = np.abs(voxels[:, 1:]).max(axis=1) < 0.15 * 1.5 / 0.8 - 0.05
    assert np.all(occluded[shadowed] == 0)
    assert visible_from(viewpoint[0], np.array([[0.0, 0.9, 0.9]]), blocker, 0.0)[0]


def test_occlusion_mode_on_the_tank_never_counts_more():
    tank = TankModel()
    plain = CoverageModel.from_tank(tank, CoverageParams(voxel_m=0.1))
    occluded = CoverageModel.from_tank(tank, CoverageParams(voxel_m=0.1, occlusion=True))
    np.testing.assert_array_equal(plain.voxels, occluded.voxels)
    # A viewpoint in front of the ladder, looking at the end wall behind it.
    viewpoints = np.array([[-1.0, -0.75, 1.0, 1.0, 0.0, 0.0], [-1.0, 1.6, 1.0, 0.0, 1.0, 0.0]])
    a, b = plain.views(viewpoints), occluded.views(viewpoints)
    assert np.all(b <= a) and b.sum() < a.sum()


def test_coverage_params_validate():
    with pytest.raises(ValueError):
        CoverageParams(voxel_m=0.0)
    with pytest.raises(ValueError):
        _ = CoverageParams(far_m=-1.0).camera
