"""Map-aware discovery's rules (maptidal.map_discovery), each against a scene built by hand: walls and a
floor as planes with stereo-sized noise, normals written down, cameras placed where a robot would be. The
references share nothing with the module but numpy: a normal is the plane's written normal, a free voxel is
one a ray written out here crosses, a covered point is one a frustum tested point by point sees."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from maptidal.discovery import DiscoveryParams
from maptidal.map_discovery import (
    MapAwareParams,
    RobotMap,
    coverage_cells,
    discover_on_map,
    fit_planes,
    gap_views,
    lift_into_free,
    lift_offsets,
    near_teammates,
    reachable_on_map,
    refit_on_faces,
    views_left_to_take,
    views_repeated,
    water_surface,
)

NOISE_M = 0.01  # fused landmarks' noise about a wall 1.5 m away (tests below stay far from the gates)


def _plane_points(origin, u, v, size_u, size_v, spacing, rng, noise=NOISE_M):
    """Points on the rectangle ``origin + s u + t v`` (s in [0, size_u], t in [0, size_v]), jittered along
    the normal ``u x v`` by ``noise``."""
    origin, u, v = (np.asarray(a, float) for a in (origin, u, v))
    normal = np.cross(u, v)
    s, t = np.meshgrid(np.arange(0, size_u + 1e-9, spacing), np.arange(0, size_v + 1e-9, spacing))
    points = origin + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    return points + rng.normal(0, noise, (len(points), 1)) * normal


def _wall_scene(rng):
    """A wall at x = 3 (facing -x, 4 m wide, 2 m high) and a floor at z = 0, seen by a camera at
    (1, 2, 1): the landmarks, their ids, and the camera."""
    wall = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.1, rng)
    floor = _plane_points([1.2, 0, 0], [1, 0, 0], [0, 1, 0], 1.8, 4.0, 0.1, rng)
    points = np.vstack([wall, floor])
    return points, np.arange(len(points)), np.array([1.0, 2.0, 1.0])


def _map_of(points, ids, camera, params=None) -> RobotMap:
    robot_map = RobotMap(params or MapAwareParams())
    robot_map.add_keyframe(camera, ids, points)
    return robot_map


def _face_at(points, centre):
    """Three landmarks around ``centre``, as the mesher would join them."""
    distance = np.linalg.norm(points - centre, axis=1)
    order = np.argsort(distance)
    return order[:3]


# ----- rule 2: normals from local fits -----------------------------------------------------------------


def test_a_plane_fit_recovers_the_written_normal_and_is_flat():
    rng = np.random.default_rng(0)
    normal = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    u = np.cross(normal, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    points = _plane_points([0, 0, 0], u, v, 1.0, 1.0, 0.05, rng)
    _, fitted, variation, support = fit_planes(points, [[0.5 * (u + v)]], 0.3, 8)
    assert support[0] >= 30
    assert math.degrees(math.acos(min(1.0, abs(float(fitted[0] @ normal))))) < 3.0
    assert variation[0] < 0.01


def test_a_crease_between_two_planes_is_not_flat():
    rng = np.random.default_rng(1)
    wall = _plane_points([0, 0, 0], [0, 1, 0], [0, 0, 1], 1.0, 1.0, 0.05, rng)
    floor = _plane_points([0, 0, 0], [0, 1, 0], [-1, 0, 0], 1.0, 1.0, 0.05, rng)
    points = np.vstack([wall, floor])
    _, _, variation, _ = fit_planes(points, [[0.0, 0.5, 0.0]], 0.3, 8)
    # half on each plane: the smallest axis carries a quarter of the spread, about 0.1 (module docstring)
    assert variation[0] > MapAwareParams().max_surface_variation


def test_the_fits_at_once_are_each_neighbourhoods_own_fit():
    """Every fit of a cloud far from the origin, against a literal one: the neighbours by brute-force
    distance, numpy's covariance about their mean, and its smallest eigenvector, one centre at a time."""
    rng = np.random.default_rng(3)
    points = rng.normal(size=(600, 3)) * [0.6, 0.6, 0.05] + [40.0, -25.0, 3.0]
    centres = points[rng.choice(len(points), 80, replace=False)] + rng.normal(scale=0.05, size=(80, 3))
    centroid, normal, variation, support = fit_planes(points, centres, 0.3, 8)
    fitted = 0
    for row, centre in enumerate(centres):
        local = points[np.linalg.norm(points - centre, axis=1) <= 0.3]
        assert support[row] == len(local)
        if len(local) < 8:
            assert np.isnan(variation[row])
            continue
        values, vectors = np.linalg.eigh(np.cov(local.T, bias=True))
        np.testing.assert_allclose(centroid[row], local.mean(axis=0), atol=1e-9)
        assert abs(float(normal[row] @ vectors[:, 0])) == pytest.approx(1.0, abs=1e-9)
        assert variation[row] == pytest.approx(values[0] / values.sum(), abs=1e-9)
        fitted += 1
    assert fitted > 40


def test_too_few_points_give_no_fit():
    _, normal, variation, support = fit_planes(np.eye(3), [[0, 0, 0]], 2.0, 8)
    assert support[0] == 3 and np.isnan(normal).all() and np.isnan(variation[0])


def test_a_candidate_looks_along_the_fitted_normal_not_its_tilted_face():
    rng = np.random.default_rng(2)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera)
    # a face on the wall whose own vertices are displaced so that its normal tilts about 25 degrees
    vertices = np.array([[3.0, 1.9, 1.0], [2.95, 2.1, 1.0], [3.05, 2.0, 1.2]])
    own = np.cross(vertices[1] - vertices[0], vertices[2] - vertices[0])
    own /= np.linalg.norm(own)
    assert math.degrees(math.acos(abs(own @ [-1, 0, 0]))) > 20
    params = MapAwareParams(plane_tolerance_m=0.1)
    robot_map.params = params
    result = discover_on_map(robot_map, vertices, [[0, 1, 2]], camera)
    assert len(result.final) == 1
    assert np.allclose(result.final[0, 3:], [1, 0, 0], atol=0.05)  # looks at the wall along +x
    assert abs(result.final[0, 0] - 2.0) < 0.05  # standoff 1 m in front of the wall at x = 3


# ----- rule 3: no candidates on bridging faces ---------------------------------------------------------


def test_a_face_bridging_the_wall_and_the_floor_yields_no_candidate():
    rng = np.random.default_rng(3)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera)
    wall_face = points[_face_at(points, [3.0, 2.0, 1.0])]
    # a face with two corners on the wall, low down, and one on the floor 0.8 m out: its centroid hangs in
    # the water, off both planes
    bridge = np.array([[3.0, 2.0, 0.4], [3.0, 2.2, 0.4], [2.2, 2.1, 0.0]])
    vertices = np.vstack([wall_face, bridge])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2], [3, 4, 5]], camera)
    assert result.bridging + result.no_support + result.not_planar == 1
    assert len(result.final) == 1
    assert result.final[0, 0] == pytest.approx(2.0, abs=0.05)


def test_a_face_across_a_near_and_a_far_wall_is_off_the_plane():
    rng = np.random.default_rng(4)
    near = _plane_points([2.0, 0, 0], [0, 1, 0], [0, 0, 1], 1.5, 2.0, 0.1, rng)  # y in [0, 1.5]
    far = _plane_points([3.0, 1.5, 0], [0, 1, 0], [0, 0, 1], 2.5, 2.0, 0.1, rng)  # y in [1.5, 4]
    points = np.vstack([near, far])
    camera = np.array([0.5, 2.0, 1.0])
    robot_map = _map_of(points, np.arange(len(points)), camera)
    # two corners on the near wall's edge, one on the far wall: the face spans the step between them
    vertices = np.array([[2.0, 1.45, 1.0], [2.0, 1.45, 1.2], [3.0, 1.7, 1.1]])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2]], camera)
    assert len(result.final) == 0
    assert result.bridging + result.not_planar + result.no_support == 1


def test_a_small_face_in_the_crease_is_refused_as_not_planar():
    rng = np.random.default_rng(10)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera)
    # a face hugging the line where the wall meets the floor: it lies close to the fitted (diagonal)
    # plane, so only the planarity test tells that its support spans two surfaces
    vertices = np.array([[2.97, 2.0, 0.03], [2.99, 2.1, 0.01], [2.96, 2.05, 0.0]])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2]], camera)
    assert result.not_planar == 1 and len(result.final) == 0


def _angle_deg(a, b) -> float:
    return math.degrees(math.acos(min(1.0, abs(float(np.dot(a, b))))))


def _cloud_ball(rng, centre, radius, count):
    """Points spread evenly through a ball: a cloud with no surface in it."""
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return np.asarray(centre, float) + directions * radius * rng.uniform(0, 1, (count, 1)) ** (1 / 3)


def test_a_dense_point_on_the_wall_beside_the_floor_is_fitted_again_from_its_nearest_points():
    """A dense-depth candidate is a face shrunk to a point: no plane of its own. Its second try starts
    from the plane of its nearest map points, and comes out on the wall's written normal; the same points
    as a line (two corners apart) still do not hold."""
    rng = np.random.default_rng(32)
    points, ids, camera = _wall_scene(rng)
    params = MapAwareParams(min_new_fraction=0.0, min_new_points=1)
    heights = (0.1, 0.2, 0.3)
    spots = np.array([points[_face_at(points, [3.0, 2.0, z])[0]] for z in heights])
    triangles = np.repeat(spots[:, None, :], 3, axis=1)
    _, _, variation, _ = fit_planes(points, spots, params.support_radius_m, params.min_support)
    assert (variation > params.max_surface_variation).all()  # the ball holds the floor too
    centre, normal, holds = refit_on_faces(points, triangles, params)
    assert holds.all()
    for row in range(len(heights)):
        assert _angle_deg(normal[row], [1.0, 0.0, 0.0]) < 5.0
        assert centre[row, 0] == pytest.approx(3.0, abs=0.02)
    line = triangles.copy()
    line[:, 2] = line[:, 0] + [0.0, 0.1, 0.0]
    line[:, 1] = line[:, 0] + [0.0, 0.05, 0.0]  # three corners on one line
    assert not refit_on_faces(points, line, params)[2].any()
    # in discovery, as dense candidates: level views of the wall, counted as refitted
    result = discover_on_map(
        _map_of(points, ids, camera, params),
        np.zeros((0, 3)),
        np.zeros((0, 3), int),
        camera,
        surface_points=spots,
        candidate_cell_m=0.05,
    )
    assert result.refitted == 3 and result.not_planar == 0 and len(result.final) >= 1
    for row in result.final:
        assert _angle_deg(row[3:], [1.0, 0.0, 0.0]) < 5.0


def test_a_face_on_the_wall_beside_the_floor_is_fitted_again_on_the_wall_alone():
    rng = np.random.default_rng(31)
    points, ids, camera = _wall_scene(rng)
    params = MapAwareParams(min_new_fraction=0.0, min_new_points=1)
    heights = (0.1, 0.2, 0.3)
    triangles = np.stack([points[_face_at(points, [3.0, 2.0, z])] for z in heights])
    # the whole ball holds the floor too: not planar, which is what the second try is for
    centres = triangles.mean(axis=1)
    _, _, variation, _ = fit_planes(points, centres, params.support_radius_m, params.min_support)
    assert (variation > params.max_surface_variation).all()
    centre, normal, holds = refit_on_faces(points, triangles, params)
    assert holds.all()
    for row in range(len(heights)):
        # the wall's written normal, and a centre on the wall (x = 3) near the face
        assert _angle_deg(normal[row], [1.0, 0.0, 0.0]) < 5.0
        assert centre[row, 0] == pytest.approx(3.0, abs=0.02)
        assert np.linalg.norm(centre[row, 1:] - triangles[row].mean(axis=0)[1:]) < params.support_radius_m
    # in discovery the faces give level views of the wall, counted as refitted
    vertices = triangles.reshape(-1, 3)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    result = discover_on_map(_map_of(points, ids, camera, params), vertices, faces, camera)
    assert result.refitted == 3 and result.not_planar == 0 and len(result.final) >= 1
    for row in result.final:
        assert _angle_deg(row[3:], [1.0, 0.0, 0.0]) < 5.0 and row[0] == pytest.approx(2.0, abs=0.05)
    # without the second try they are refused as not planar
    once = discover_on_map(
        _map_of(points, ids, camera, replace(params, refit_iterations=0)), vertices, faces, camera
    )
    assert once.not_planar == 3 and once.refitted == 0 and len(once.final) == 0


def test_the_refit_brings_a_tilted_face_back_to_its_wall():
    rng = np.random.default_rng(32)
    points, _, _ = _wall_scene(rng)
    # a face on the wall whose corners sit 4 cm off it either way: its own plane is tilted by some 20 deg
    face = np.array([[2.96, 2.0, 0.2], [3.04, 2.15, 0.22], [3.0, 2.05, 0.35]])
    own = np.cross(face[1] - face[0], face[2] - face[0])
    assert _angle_deg(own / np.linalg.norm(own), [1.0, 0.0, 0.0]) > 15.0
    _, normal, holds = refit_on_faces(points, face[None], MapAwareParams())
    assert holds[0] and _angle_deg(normal[0], [1.0, 0.0, 0.0]) < 5.0
    # one refit is not enough to get it there
    _, once, _ = refit_on_faces(points, face[None], MapAwareParams(refit_iterations=1))
    assert not np.isfinite(once[0]).all() or _angle_deg(once[0], [1.0, 0.0, 0.0]) > _angle_deg(
        normal[0], [1.0, 0.0, 0.0]
    )


@pytest.mark.parametrize("reach", [0.2, 0.4, 0.6])
def test_a_face_bridging_the_crease_is_not_fitted_again(reach):
    rng = np.random.default_rng(33)
    points, ids, camera = _wall_scene(rng)
    # corners on the wall at height `reach` and on the floor `reach` out: the centroid in the water
    bridges = np.array(
        [
            [[3.0, 2.0, reach], [3.0 - reach, 2.1, 0.0], [3.0, 2.2, reach]],
            [[3.0, 2.0, reach], [3.0 - reach, 2.1, 0.0], [3.0 - reach, 2.25, 0.0]],
        ]
    )
    _, _, holds = refit_on_faces(points, bridges, MapAwareParams())
    assert not holds.any()
    result = discover_on_map(
        _map_of(points, ids, camera), bridges.reshape(-1, 3), np.arange(6).reshape(2, 3), camera
    )
    assert result.refitted == 0 and len(result.final) == 0


def test_a_band_through_a_cloud_is_no_plane():
    rng = np.random.default_rng(34)
    cloud = _cloud_ball(rng, [0.0, 0.0, 0.0], 0.5, 3000)
    face = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.02], [0.01, 0.05, 0.1]])
    _, _, holds = refit_on_faces(cloud, face[None], MapAwareParams())
    assert not holds[0]
    # the band's evenness is what refuses it: without that test the band passes for a plane
    _, _, loose = refit_on_faces(cloud, face[None], MapAwareParams(min_band_concentration=0.0))
    assert loose[0]


def test_a_line_of_points_is_no_plane_to_fit_again_on():
    rng = np.random.default_rng(37)
    # a ladder rail (a line of points along z) in a thin cloud: the ball is not planar, and the band
    # about a face on the rail holds the rail's points all near the plane, but spread one way only
    rail = np.column_stack([np.zeros(200), np.zeros(200), np.linspace(-0.5, 0.5, 200)])
    points = np.vstack([rail, _cloud_ball(rng, [0.0, 0.0, 0.0], 0.5, 60)])
    face = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, 0.1], [0.0, 0.05, 0.0]])
    _, _, variation, _ = fit_planes(points, face.mean(axis=0)[None], 0.5, 8)
    assert variation[0] > MapAwareParams().max_surface_variation
    _, _, holds = refit_on_faces(points, face[None], MapAwareParams())
    assert not holds[0]
    # the band's points are gathered near the plane (the rail lies in it): only their spread, across
    # the rail a few cloud points' worth, tells the line from a surface
    band = points[np.abs(points[:, 0]) <= 0.1]
    assert np.mean(np.abs(band[:, 0]) <= 0.05) >= MapAwareParams().min_band_concentration


def test_a_face_off_a_planar_balls_plane_gets_no_second_try():
    rng = np.random.default_rng(35)
    wall = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.1, rng)
    # a ladder rail 15 cm in front of the wall: a line of points, too few to spoil the wall's flatness
    rail = np.column_stack([np.full(40, 2.85), np.full(40, 2.5), np.linspace(0.0, 2.0, 40)])
    points = np.vstack([wall, rail])
    camera = np.array([1.0, 2.0, 1.0])
    face = np.array([[2.85, 2.5, 1.0], [3.0, 2.6, 1.0], [2.85, 2.5, 1.2]])
    _, _, variation, _ = fit_planes(points, face.mean(axis=0)[None], 0.5, 8)
    assert variation[0] <= MapAwareParams().max_surface_variation
    result = discover_on_map(_map_of(points, np.arange(len(points)), camera), face, [[0, 1, 2]], camera)
    assert result.bridging == 1 and result.refitted == 0 and len(result.final) == 0


def test_faces_beyond_the_region_to_inspect_yield_no_candidate():
    rng = np.random.default_rng(36)
    points, ids, camera = _wall_scene(rng)
    # the wall at x = 3 from y = 0 to 4; a launch at (1, 0.5, 1) and a 2.5 m region: the face at y = 1 is
    # 2.06 m away, the one at y = 3 is 3.2 m away (written out: sqrt(2^2 + 0.5^2) and sqrt(2^2 + 2.5^2))
    near, far = points[_face_at(points, [3.0, 1.0, 1.0])], points[_face_at(points, [3.0, 3.0, 1.0])]
    vertices, faces = np.vstack([near, far]), [[0, 1, 2], [3, 4, 5]]
    params = MapAwareParams(min_new_fraction=0.0, min_new_points=1)
    everywhere = discover_on_map(_map_of(points, ids, camera, params), vertices, faces, camera)
    assert everywhere.outside == 0 and len(everywhere.final) == 2
    bounded = replace(params, region_centre=(1.0, 0.5, 1.0), region_radius_m=2.5)
    result = discover_on_map(_map_of(points, ids, camera, bounded), vertices, faces, camera)
    assert result.outside == 1 and len(result.final) == 1
    assert result.final[0, 1] == pytest.approx(1.0, abs=0.1)
    assert result.counts()["outside"] == 1
    # a region holding no face leaves nothing to do, and says so
    none = discover_on_map(
        _map_of(points, ids, camera, replace(bounded, region_radius_m=0.5)), vertices, faces, camera
    )
    assert none.outside == 2 and len(none.final) == 0


def test_faces_outside_the_box_to_inspect_yield_no_candidate_nor_count_in_rule_5():
    """A box of the wall from y = 0 to 2 (grown by plane_tolerance_m): the face at y = 1 is in it, the one
    at y = 3 is not; and a view of the box's edge is new only for what of the box it adds."""
    rng = np.random.default_rng(36)
    points, ids, camera = _wall_scene(rng)
    near, far = points[_face_at(points, [3.0, 1.0, 1.0])], points[_face_at(points, [3.0, 3.0, 1.0])]
    vertices, faces = np.vstack([near, far]), [[0, 1, 2], [3, 4, 5]]
    params = MapAwareParams(
        min_new_fraction=0.0, min_new_points=1, region_box=((2.9, 0.0, 0.0), (3.1, 2.0, 2.0))
    )
    result = discover_on_map(_map_of(points, ids, camera, params), vertices, faces, camera)
    assert result.outside == 1 and len(result.final) == 1
    assert result.final[0, 1] == pytest.approx(1.0, abs=0.1)
    # rule 5's cells: only those in the box grown by the plane tolerance (brute force on the cells)
    cells = coverage_cells(points, params)
    every = (np.unique(np.floor(points / 0.1), axis=0) + 0.5) * 0.1
    low, high = np.array([2.8, -0.1, -0.1]), np.array([3.2, 2.1, 2.1])
    expected = every[np.all((every >= low) & (every <= high), axis=1)]
    assert sorted(map(tuple, cells.round(6))) == sorted(map(tuple, expected.round(6)))
    # a view at y = 2.6 looking at the wall past the box's edge sees cells of the box only at y <= 2.1:
    # views taken over the box leave it nothing, though it shows 1.7 m of wall beyond
    taken = np.array([[2.0, 1.0, 1.0, 1.0, 0.0, 0.0], [2.0, 1.8, 1.0, 1.0, 0.0, 0.0]])
    edge = np.array([[2.0, 2.6, 1.0, 1.0, 0.0, 0.0]])
    boxed = _map_of(points, ids, camera, replace(params, min_new_points=8))
    assert views_left_to_take(boxed, edge, taken).tolist() == [False]
    unboxed = _map_of(points, ids, camera, replace(params, min_new_points=8, region_box=None))
    assert views_left_to_take(unboxed, edge, taken).tolist() == [True]
    with pytest.raises(ValueError, match="region_box"):
        MapAwareParams(region_box=((0, 0, 0), (1, -1, 1)))
    with pytest.raises(ValueError, match="region_box"):
        MapAwareParams(region_box=((0, 0), (1, 1)))


# ----- rule 4: free space from the robot's own map -----------------------------------------------------


def _ray_crosses(camera, targets, position, voxel, stop):
    """Exact, by the slab method (Kay and Kajiya 1986): does a ray from ``camera`` towards any target,
    stopping ``stop`` short of it, pass through the voxel holding ``position``?"""
    low = np.floor(np.asarray(position) / voxel) * voxel
    high = low + voxel
    offsets = targets - camera
    lengths = np.linalg.norm(offsets, axis=1)
    directions = offsets / lengths[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low = (low - camera) / directions
        t_high = (high - camera) / directions
    enter = np.nanmax(np.minimum(t_low, t_high), axis=1)
    leave = np.nanmin(np.maximum(t_low, t_high), axis=1)
    return bool(np.any((enter <= leave) & (leave >= 0.0) & (enter <= lengths - stop)))


def test_seen_water_is_what_the_cameras_rays_crossed():
    rng = np.random.default_rng(5)
    points, ids, camera = _wall_scene(rng)
    params = MapAwareParams()
    robot_map = _map_of(points, ids, camera, params)
    probes = rng.uniform([0.5, -0.5, -0.5], [3.5, 4.5, 2.5], (300, 3))
    brute = np.array([_ray_crosses(camera, points, p, params.voxel_m, params.ray_stop_m) for p in probes])
    assert brute.sum() > 20 and (~brute).sum() > 20
    # sampling every half voxel can miss a corner a ray only grazes: allow a few such voxels
    assert np.mean(robot_map.seen_free(probes) == brute) > 0.97
    assert not robot_map.seen_free(probes[~brute]).sum() > 0.05 * (~brute).sum()


def test_viewpoints_behind_a_wall_under_the_floor_or_at_the_surface_are_refused():
    rng = np.random.default_rng(6)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera, MapAwareParams(surface_z=2.0))
    rows = np.array(
        [
            [2.0, 2.0, 1.0, 1, 0, 0],  # in front of the wall, looking at it: fine
            [4.0, 2.0, 1.0, -1, 0, 0],  # behind the wall, looking back through it
            [2.0, 2.0, -0.6, 0, 0, 1],  # under the floor
            [1.5, 2.0, 1.9, 1, 0, 0],  # 10 cm under the surface
            [2.8, 2.0, 1.0, 1, 0, 0],  # 20 cm from the wall
        ]
    )
    assert reachable_on_map(robot_map, rows, 1.0).tolist() == [True, False, False, False, False]


def test_a_viewpoint_needs_water_seen_beneath_it_where_the_floor_has_few_landmarks():
    # a dense wall at x = 3 and a floor at z = 0 with a landmark only every 1.2 m, seen at a grazing
    # angle: a viewpoint 20 cm above the floor, on the ray to a floor landmark, is farther than the
    # clearance from every landmark, but the water beneath it was never seen
    rng = np.random.default_rng(8)
    wall = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.05, rng)
    xs, ys = np.meshgrid(np.arange(-1.2, 3.0, 1.2), np.arange(-0.4, 4.5, 1.2))
    floor = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    points = np.vstack([wall, floor])
    robot_map = _map_of(points, np.arange(len(points)), np.array([0.0, 2.0, 1.0]))
    rows = np.array([[2.0, 2.0, 1.0, 1, 0, 0], [1.92, 2.0, 0.2, 1, 0, 0]])
    nearest = np.min(np.linalg.norm(points[:, None] - rows[None, :, :3], axis=2), axis=0)
    assert nearest[1] > robot_map.params.clearance_m  # the landmarks alone would let it pass
    assert robot_map.seen_free(rows[:, :3]).all()  # and it lies in water a grazing ray crossed
    assert reachable_on_map(robot_map, rows, 1.0).tolist() == [True, False]


def test_a_landmark_on_the_line_of_sight_blocks_the_view():
    rng = np.random.default_rng(7)
    points, _, camera = _wall_scene(rng)
    pillar = np.column_stack([np.full(21, 2.5), np.full(21, 2.0), np.linspace(0.5, 1.5, 21)])
    everything = np.vstack([points, pillar])
    robot_map = _map_of(everything, np.arange(len(everything)), camera)
    rows = np.array([[2.0, 2.0, 1.0, 1, 0, 0], [2.0, 3.0, 1.0, 1, 0, 0]])
    # the pillar at x = 2.5 stands between the first viewpoint and the wall, not the second
    ok = reachable_on_map(robot_map, rows, 1.0)
    assert ok.tolist() == [False, True]


def test_the_tank_model_is_never_read():
    # what the module imports (read from its syntax tree): numpy, scipy and the paper's own modules; no
    # tank, scenario, free-space check or simulator
    import ast

    import maptidal.map_discovery as module

    tree = ast.parse(Path(module.__file__).read_text())
    imported = {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)}
    imported |= {
        alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names
    }
    assert imported <= {
        "__future__",
        "math",
        "collections.abc",
        "dataclasses",
        "numpy",
        "scipy.spatial",
        "cv2",
        "maptidal.discovery",
        "maptidal.geometry",
    }, imported


# ----- rule 5: views that add little -------------------------------------------------------------------


def _sees(viewpoint, points, discovery):
    """Brute force: the points inside one view's frustum, from the field of view written out."""
    position, direction = viewpoint[:3], viewpoint[3:]
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(direction, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, direction)
    rel = points - position
    depth = rel @ direction
    x, y = rel @ right, rel @ true_up
    tan_h = math.tan(math.radians(discovery.hfov_deg / 2))
    tan_v = math.tan(math.radians(discovery.vfov_deg / 2))
    return (
        (depth >= 0)
        & (depth <= discovery.far_range)
        & (np.abs(x) <= depth * tan_h + 1e-9)
        & (np.abs(y) <= depth * tan_v + 1e-9)
    )


def test_a_view_the_known_tasks_already_cover_is_dropped_and_a_new_one_kept():
    rng = np.random.default_rng(8)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera)
    discovery = DiscoveryParams()
    # faces at y = 1 and y = 3 on the wall; a known task already looks at y = 1
    face_one = _face_at(points, [3.0, 1.0, 1.0])
    face_three = _face_at(points, [3.0, 3.0, 1.0])
    vertices = np.vstack([points[face_one], points[face_three]])
    known = np.array([[2.0, 1.0, 1.0, 1.0, 0.0, 0.0]])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2], [3, 4, 5]], camera, existing=known)
    assert len(result.final) == 1 and result.redundant == 1
    assert result.final[0, 1] == pytest.approx(3.0, abs=0.1)
    # the brute-force reason: the dropped view adds under 30 % of its footprint to the known one's
    cells = (np.unique(np.floor(points / 0.1), axis=0) + 0.5) * 0.1
    first = np.array([2.0, 1.0, 1.0, 1, 0, 0])
    again = _sees(first, cells, discovery) & ~_sees(known[0], cells, discovery)
    assert again.sum() < 0.3 * _sees(first, cells, discovery).sum()


def test_a_face_at_the_top_of_the_wall_that_no_view_holds_gets_its_view_though_it_adds_a_strip():
    # the wall of _low_and_high_faces, up to the surface at z = 2; a known task looks at it level from
    # 1 m at z = 1.35, so its frame reaches z = 1.35 + tan(27.05 deg) = 1.86 on the wall. A face at the
    # top (about z = 1.93) has its viewpoint lifted to 1.65 at most (the surface's 35 cm clearance): that
    # view's new cells are the strip over 1.86, under 30 % of its footprint, but the face is in no view
    rng = np.random.default_rng(21)
    points, camera, _, _ = _low_and_high_faces(rng)
    discovery = DiscoveryParams()
    params = MapAwareParams(surface_z=2.0)
    robot_map = _map_of(points, np.arange(len(points)), camera, params)
    vertices = points[_face_at(points, [3.0, 3.0, 1.95])]
    face = vertices.mean(axis=0)
    known = np.array([[2.0, 3.0, 1.35, 1.0, 0.0, 0.0]])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2]], camera, existing=known)
    assert len(result.final) == 1 and result.lifted == 1
    top = result.final[0]
    assert 1.55 <= top[2] <= 1.65 + 1e-9
    # brute force: the strip is under min_new_fraction of the view's footprint, the face outside the
    # known view and inside the new one
    cells = (np.unique(np.floor(points / 0.1), axis=0) + 0.5) * 0.1
    footprint = _sees(top, cells, discovery)
    strip = footprint & ~_sees(known[0], cells, discovery)
    assert params.min_new_points <= strip.sum() < params.min_new_fraction * footprint.sum()
    assert not _sees(known[0], face[None], discovery)[0] and _sees(top, face[None], discovery)[0]
    # a known view that holds the face leaves out the view of the strip it still adds: all but a repeat
    higher = np.array([[2.0, 3.0, 1.45, 1.0, 0.0, 0.0]])
    assert _sees(higher[0], face[None], discovery)[0]
    still_new = footprint & ~_sees(higher[0], cells, discovery)
    assert params.min_new_points <= still_new.sum() < params.min_new_fraction * footprint.sum()
    again = discover_on_map(robot_map, vertices, [[0, 1, 2]], camera, existing=higher)
    assert len(again.final) == 0 and again.redundant == 1


def test_a_view_the_views_taken_cover_is_retired_and_one_they_miss_kept():
    """views_left_to_take against brute force: a view next to one taken leaves fewer than min_new_points
    of the map's cells to see; one 2 m along, and one over the top strip a taken view stops short of,
    leave more (the strip under min_new_fraction of its footprint: the share is not asked)."""
    rng = np.random.default_rng(8)
    points, ids, camera = _wall_scene(rng)
    params = MapAwareParams()
    robot_map = _map_of(points, ids, camera, params)
    discovery = DiscoveryParams()
    taken = np.array([[2.0, 1.0, 1.0, 1.0, 0.0, 0.0]])
    rows = np.array([[2.0, 1.05, 1.0, 1.0, 0.0, 0.0], [2.0, 3.0, 1.0, 1.0, 0.0, 0.0]])
    left = views_left_to_take(robot_map, rows, taken, discovery)
    cells = (np.unique(np.floor(points / 0.1), axis=0) + 0.5) * 0.1
    unseen = [(_sees(row, cells, discovery) & ~_sees(taken[0], cells, discovery)).sum() for row in rows]
    assert unseen[0] < params.min_new_points <= unseen[1]
    assert left.tolist() == [False, True]
    # nothing taken: every view is left
    assert views_left_to_take(robot_map, rows, np.zeros((0, 6)), discovery).all()
    # the top of a wall: the strip over a level view's frame is left to take
    points, camera, _, _ = _low_and_high_faces(rng)
    robot_map = _map_of(points, np.arange(len(points)), camera, MapAwareParams(surface_z=2.0))
    level, top = np.array([[2.0, 3.0, 1.35, 1.0, 0.0, 0.0]]), np.array([[2.0, 3.0, 1.6, 1.0, 0.0, 0.0]])
    cells = (np.unique(np.floor(points / 0.1), axis=0) + 0.5) * 0.1
    strip = _sees(top[0], cells, discovery) & ~_sees(level[0], cells, discovery)
    footprint = _sees(top[0], cells, discovery).sum()
    assert params.min_new_points <= strip.sum() < params.min_new_fraction * footprint
    assert views_left_to_take(robot_map, top, level, discovery).tolist() == [True]
    below = (_sees(level[0], cells, discovery) & ~_sees(top[0], cells, discovery)).sum()
    assert views_left_to_take(robot_map, level, top, discovery).tolist() == [below >= params.min_new_points]


def _repeated_by_hand(rows, row_keys, known, known_keys, cells, params, discovery):
    """views_repeated written out: a view is a repeat when one known view of lower key, from another
    finder (key >> 16), holds its face and all but under min_new_fraction (or min_new_points) of its
    cells; a view of under min_new_points cells is never one."""
    out = []
    for row, key in zip(rows, row_keys, strict=True):
        sees = _sees(row, cells, discovery)
        face = row[:3] + discovery.standoff * row[3:]
        verdict = False
        if sees.sum() >= params.min_new_points:
            for other, other_key in zip(known, known_keys, strict=True):
                if other_key >= key or other_key >> 16 == key >> 16:
                    continue
                if not _sees(other, face[None], discovery)[0]:
                    continue
                new = int((sees & ~_sees(other, cells, discovery)).sum())
                if new < params.min_new_points or new < params.min_new_fraction * sees.sum():
                    verdict = True
        out.append(verdict)
    return out


def test_a_teammates_view_of_the_same_wall_retires_the_one_of_higher_key():
    """views_repeated: of two robots' views of one stretch of wall only the higher key is a repeat; a
    view the same robot found, or one of another stretch, is not; against brute force on random views."""
    rng = np.random.default_rng(12)
    points, ids, camera = _wall_scene(rng)
    params = MapAwareParams()
    robot_map = _map_of(points, ids, camera, params)
    discovery = DiscoveryParams()

    def cells_of(mapped):  # rule 5's cells, the 0.1 m voxels that hold landmarks
        return (np.unique(np.floor(mapped / 0.1), axis=0) + 0.5) * 0.1

    first = np.array([[2.0, 1.0, 1.0, 1.0, 0.0, 0.0]])  # robot 0's fourth task
    again = np.array([[2.0, 1.08, 1.02, 1.0, 0.0, 0.0]])  # robot 1's first, a few cm off
    zero, one = (0 << 16) | 3, (1 << 16) | 0
    assert views_repeated(robot_map, again, [one], first, [zero], discovery).tolist() == [True]
    assert views_repeated(robot_map, first, [zero], again, [one], discovery).tolist() == [False]
    # the same finder's own view: rule 5 judged it already, when it was found
    assert views_repeated(robot_map, again, [zero + 1], first, [zero], discovery).tolist() == [False]
    # 2 m along the wall: a view of its own
    along = np.array([[2.0, 3.0, 1.0, 1.0, 0.0, 0.0]])
    assert views_repeated(robot_map, along, [one], first, [zero], discovery).tolist() == [False]
    # nothing known, or an empty map: nothing is a repeat
    assert not views_repeated(robot_map, again, [one], np.zeros((0, 6)), [], discovery).any()
    assert not views_repeated(RobotMap(params), again, [one], first, [zero], discovery).any()
    with pytest.raises(ValueError, match="one key per view"):
        views_repeated(robot_map, again, [one, zero], first, [zero], discovery)
    # the end of a wall (nothing mapped beyond y = 2.7): a teammate's view holds all but a strip of a view
    # of the end, under 30 % of it, but not its face: no repeat (rule 5's exception)
    end_map = _map_of(points[points[:, 1] <= 2.7], ids[points[:, 1] <= 2.7], camera, params)
    end_cells = cells_of(points[points[:, 1] <= 2.7])
    end, short = np.array([[2.0, 3.0, 1.0, 1.0, 0.0, 0.0]]), np.array([[2.0, 1.8, 1.0, 1.0, 0.0, 0.0]])
    footprint = _sees(end[0], end_cells, discovery)
    strip = footprint & ~_sees(short[0], end_cells, discovery)
    face = end[0, :3] + discovery.standoff * end[0, 3:]
    assert params.min_new_points <= strip.sum() < params.min_new_fraction * footprint.sum()
    assert not _sees(short[0], face[None], discovery)[0]
    assert views_repeated(end_map, end, [one], short, [zero], discovery).tolist() == [False]
    # random views of the wall from both robots, against the rule written out
    cells = cells_of(points)
    views = np.column_stack(
        [
            rng.uniform(1.8, 2.2, 24),
            rng.uniform(0.5, 3.5, 24),
            rng.uniform(0.6, 1.4, 24),
            np.ones(24),
            np.zeros(24),
            np.zeros(24),
        ]
    )
    yaw = np.radians(rng.uniform(-30, 30, 24))
    views[:, 3], views[:, 4] = np.cos(yaw), np.sin(yaw)
    keys = np.array([(i % 2) << 16 | i for i in range(24)], np.int64)
    got = views_repeated(robot_map, views, keys, views, keys, discovery)
    expected = _repeated_by_hand(views, keys, views, keys, cells, params, discovery)
    assert got.tolist() == expected
    assert 0 < sum(expected) < 24  # the draw holds repeats and views of their own


def test_two_candidates_on_one_patch_give_one_task():
    rng = np.random.default_rng(9)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera)
    faces_at = [_face_at(points, [3.0, y, 1.0]) for y in (2.0, 2.1)]
    vertices = np.vstack([points[f] for f in faces_at])
    result = discover_on_map(robot_map, vertices, [[0, 1, 2], [3, 4, 5]], camera)
    assert len(result.final) == 1 and result.redundant == 1


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="support_radius_m"):
        MapAwareParams(support_radius_m=0.0)
    with pytest.raises(ValueError, match="min_new_fraction"):
        MapAwareParams(min_new_fraction=1.5)
    with pytest.raises(ValueError, match="surface_z"):
        MapAwareParams(surface_z=float("nan"))
    with pytest.raises(ValueError, match="refit_iterations"):
        MapAwareParams(refit_iterations=-1)
    with pytest.raises(ValueError, match="refit_iterations"):
        MapAwareParams(refit_iterations=1.5)
    with pytest.raises(ValueError, match="min_band_concentration"):
        MapAwareParams(min_band_concentration=1.5)
    with pytest.raises(ValueError, match="region_radius_m"):
        MapAwareParams(region_radius_m=0.0)
    with pytest.raises(ValueError, match="region_centre"):
        MapAwareParams(region_centre=(0.0, float("nan"), 0.0))


def test_a_lost_pose_or_nan_landmarks_carve_nothing_and_are_skipped():
    robot_map = RobotMap()
    robot_map.add_keyframe([np.nan, 0, 0], [1], [[1.0, 0, 0]])
    assert not robot_map.free_voxels and not robot_map.landmarks
    robot_map.add_keyframe([0, 0, 0], [1, 2], [[1.0, 0, 0], [np.nan, 0, 0]])
    assert list(robot_map.landmarks) == [1] and robot_map.free_voxels


def test_a_teammate_in_view_is_no_structure():
    rng = np.random.default_rng(11)
    points, _, camera = _wall_scene(rng)
    # a teammate's hull, a 0.5 m box of landmarks at (2, 1, 1), in the camera's view
    hull = rng.uniform([1.75, 0.75, 0.85], [2.25, 1.25, 1.15], (120, 3))
    everything = np.vstack([points, hull])
    heard = np.array([[2.0, 1.0, 1.0, 0.0]])  # its last message, just now
    robot_map = RobotMap()
    robot_map.add_keyframe(camera, np.arange(len(everything)), everything, teammates=heard)
    assert len(robot_map.landmarks) == len(points)  # the hull's landmarks are left out
    # a face on the hull finds no support, and no task
    face = hull[np.argsort(np.linalg.norm(hull - [1.75, 1.0, 1.0], axis=1))[:3]]
    result = discover_on_map(robot_map, face, [[0, 1, 2]], camera, teammates=heard)
    assert result.no_support == 1 and len(result.final) == 0
    # a message 2 s old: the teammate may have moved 0.5 m, and the radius grows with it (to the cap)
    params = MapAwareParams()
    probe = np.array([[2.0, 1.0 + 0.8, 1.0]])
    assert not near_teammates(probe, heard, params)[0]
    assert near_teammates(probe, [[2.0, 1.0, 1.0, 2.0]], params)[0]
    assert not near_teammates(probe + [0, 0.5, 0], [[2.0, 1.0, 1.0, 60.0]], params)[0]


def test_the_water_in_view_before_the_mesh_is_carved_and_none_beyond_it():
    from types import SimpleNamespace

    # a camera at the origin looking along +x (optical frame: x right = -y world, y down = -z world,
    # z forward = +x world) at a wall meshed as two triangles at x = 2, 2 m wide and 1.2 m high
    rotation = np.column_stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]]).astype(float)
    intrinsics = SimpleNamespace(fx=196.0, fy=196.0, cx=160.0, cy=100.0, width=320, height=200)
    corners = np.array([[2.0, -1.0, -0.6], [2.0, 1.0, -0.6], [2.0, 1.0, 0.6], [2.0, -1.0, 0.6]])
    params = MapAwareParams()
    robot_map = RobotMap(params)
    carved = robot_map.carve_view([0, 0, 0], rotation, intrinsics, corners, [[0, 1, 2], [0, 2, 3]])
    assert carved > 50
    rng = np.random.default_rng(12)
    probes = rng.uniform([0.2, -1.2, -0.8], [3.0, 1.2, 0.8], (2000, 3))
    free = robot_map.seen_free(probes)
    # brute force, from the written geometry: the probe's voxel centre lies in the camera's view, its
    # ray meets the wall's rectangle, and it is nearer than the wall by the ray's stop (to a voxel's
    # width, the depth image's cells and its faces drawn at their nearest corner's depth)
    centres = (np.floor(probes / params.voxel_m) + 0.5) * params.voxel_m
    x = centres[:, 0]
    hit = centres[:, 1:] * (2.0 / np.maximum(x, 1e-9))[:, None]  # where the ray meets x = 2
    in_view = (x > 0) & (np.abs(centres[:, 1] / x) < 160 / 196) & (np.abs(centres[:, 2] / x) < 100 / 196)
    on_wall = (np.abs(hit[:, 0]) < 1.0) & (np.abs(hit[:, 1]) < 0.6)
    surely_free = in_view & on_wall & (x < 2.0 - params.ray_stop_m - params.voxel_m)
    surely_not = ~in_view | ~on_wall | (x > 2.0 - params.ray_stop_m)
    margin = (np.abs(hit) > [0.85, 0.45]).any(axis=1)  # the edge cells of the depth image
    assert free[surely_free & ~margin].all()
    assert not free[surely_not].any()
    assert free[surely_free].mean() > 0.8


# ----- views the team can fly; candidates from the dense depth; the water surface ----------------------


def test_a_view_steeper_than_the_team_can_pitch_is_dropped_and_counted():
    # faces on the floor give views looking straight down; faces on the wall give level ones
    rng = np.random.default_rng(11)
    points, ids, camera = _wall_scene(rng)
    faces_at = [_face_at(points, centre) for centre in ([3.0, 2.0, 1.0], [2.0, 1.0, 0.0])]
    vertices = np.vstack([points[f] for f in faces_at])
    triangles = [[0, 1, 2], [3, 4, 5]]
    free = discover_on_map(_map_of(points, ids, camera), vertices, triangles, camera)
    # without a limit both are candidates past rule 3, and the floor's view looks down
    assert free.too_steep == 0
    pitches = []
    for limit in (55.0, 85.0):
        robot_map = _map_of(points, ids, camera, MapAwareParams(max_view_pitch_deg=limit))
        result = discover_on_map(robot_map, vertices, triangles, camera)
        pitches.append(result.too_steep)
        # the rows that are left are no steeper than the limit (the written floor normal is +z: -90 deg)
        elevation = np.degrees(np.arcsin(np.abs(result.final[:, 5]))) if len(result.final) else np.zeros(0)
        assert (elevation <= limit + 1e-9).all()
        assert result.counts()["too_steep"] == result.too_steep
    assert pitches == [1, 1]  # the floor's view is some 90 deg down: past either limit
    # a robot that cannot pitch, judged within 10 deg, flies a wall's level view
    level = _map_of(points, ids, camera, MapAwareParams(max_view_pitch_deg=10.0))
    kept = discover_on_map(level, vertices[:3], [[0, 1, 2]], camera)
    assert kept.too_steep == 0 and len(kept.final) == 1
    with pytest.raises(ValueError, match="max_view_pitch_deg"):
        MapAwareParams(max_view_pitch_deg=120.0)


def test_dense_points_give_candidates_where_the_mesh_has_no_face():
    # the keypoint mesh has one face, high on the wall at y = 1; the dense depth covers the whole wall
    rng = np.random.default_rng(12)
    points, ids, camera = _wall_scene(rng)
    face = _face_at(points, [3.0, 1.0, 1.5])
    dense = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.05, rng)
    found = {}
    for size in (0.0, 0.25):
        robot_map = _map_of(points, ids, camera, MapAwareParams(dense_candidates_m=size))
        robot_map.add_surface(camera, dense)
        result = discover_on_map(robot_map, points[face], [[0, 1, 2]], camera, surface_points=dense)
        found[size] = result
    assert found[0.0].candidates == 1 and len(found[0.0].final) == 1
    many = found[0.25]
    # one candidate per 25 cm cell of the dense points (counted here by hand) and the mesh's face
    cells = {tuple(np.floor(p / 0.25).astype(int)) for p in dense}
    assert many.candidates == 1 + len(cells)
    # the wall's far end (y > 2.5), which the face's view does not reach, is now looked at
    assert len(many.final) > 1
    for row in many.final:
        assert row[3] > 0.95  # at the wall, along +x (a fit near the floor tilts a little)
        assert abs(row[0] - 2.0) < 0.1  # the 1 m standoff from x = 3
    assert many.final[:, 1].max() > 2.5
    # NaN rows among the dense points are skipped, and none at all is the mesh alone
    robot_map = _map_of(points, ids, camera, MapAwareParams(dense_candidates_m=0.25))
    with_nan = np.vstack([dense[:5], np.full((2, 3), np.nan)])
    assert (
        discover_on_map(robot_map, points[face], [[0, 1, 2]], camera, surface_points=with_nan).candidates <= 6
    )
    assert discover_on_map(robot_map, points[face], [[0, 1, 2]], camera, surface_points=None).candidates == 1
    assert (
        discover_on_map(
            robot_map, points[face], [[0, 1, 2]], camera, surface_points=np.zeros((0, 3))
        ).candidates
        == 1
    )


def _in_level_view(view: np.ndarray, points: np.ndarray, far_m: float = 2.0) -> np.ndarray:
    """Which ``points`` a level view looking along +x sees, written out by hand: in front of it within
    ``far_m``, and within half the OAK-D's field of view (78.5 x 54.1 deg) each way."""
    depth = points[:, 0] - view[0]
    half_h, half_v = math.radians(78.5 / 2), math.radians(54.1 / 2)
    return (
        (depth > 0)
        & (depth <= far_m)
        & (np.abs(points[:, 1] - view[1]) <= depth * math.tan(half_h))
        & (np.abs(points[:, 2] - view[2]) <= depth * math.tan(half_v))
    )


def test_the_gaps_of_a_map_get_views_where_no_known_view_looks():
    """The wall at x = 3 mapped by dense depth alone (no mesh face anywhere), and one known task looking at
    its end near y = 1: the gap views all look at the wall along +x from the 1 m standoff, none repeats
    the known view, and the known view and the gap views together see nearly all the wall's 10 cm cells
    at mid-height (checked by a frustum written out by hand, as level views). None with
    gap_candidates_m 0, or on a map without dense points."""
    rng = np.random.default_rng(21)
    points, ids, camera = _wall_scene(rng)
    dense = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.05, rng)
    known = np.array([[2.0, 1.0, 1.0, 1.0, 0.0, 0.0]])
    found = {}
    for size in (0.0, 0.25):
        robot_map = _map_of(points, ids, camera, MapAwareParams(gap_candidates_m=size))
        robot_map.add_surface(camera, dense)
        found[size] = gap_views(robot_map, camera, known)
    assert len(found[0.0].final) == 0 and found[0.0].candidates == 0
    gaps = found[0.25].final
    cells = {tuple(np.floor(p / 0.25).astype(int)) for p in dense}
    assert found[0.25].candidates == len(cells)  # one per 25 cm cell of the dense points, by hand
    assert len(gaps) >= 1
    for row in gaps:
        assert row[3] > 0.95 and abs(row[0] - 2.0) < 0.1
        assert np.linalg.norm(row[:3] - known[0, :3]) > 0.4  # not the known view again
    wall_cells = np.unique(np.floor(dense / 0.1), axis=0) * 0.1 + 0.05
    reach = wall_cells[(wall_cells[:, 2] > 0.55) & (wall_cells[:, 2] < 1.45)]  # what a level view reaches
    seen = np.zeros(len(reach), bool)
    for view in np.vstack([known, gaps]):
        seen |= _in_level_view(view, reach)
    assert seen.mean() > 0.9
    assert _in_level_view(known[0], reach).mean() < 0.5  # the known view alone does not
    # the known views count as covered: with three more of them along the wall's middle, fewer gaps
    more = np.array([[2.0, y, 1.0, 1.0, 0.0, 0.0] for y in (1.0, 2.0, 3.0)])
    robot_map = _map_of(points, ids, camera, MapAwareParams())
    robot_map.add_surface(camera, dense)
    assert len(gap_views(robot_map, camera, more).final) < len(gap_views(robot_map, camera, None).final)
    bare = _map_of(points, ids, camera, MapAwareParams())  # landmarks, no dense points
    assert len(gap_views(bare, camera, known).final) == 0


def test_the_water_surface_seen_from_below_is_no_structure():
    # dense depth on the water surface (z = 2.0, the depth sensor's datum) and on a wall below it
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    camera = np.array([1.0, 2.0, 1.0])
    xs, ys = np.meshgrid(np.arange(1.2, 2.8, 0.1), np.arange(1.0, 3.0, 0.1))
    surface = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.97)])
    wall = np.column_stack([np.full(10, 3.0), np.full(10, 2.0), np.linspace(0.5, 1.84, 10)])
    taken = robot_map.add_surface(camera, np.vstack([surface, wall]))
    kept = robot_map.points()
    assert len(kept) == 10 and (kept[:, 2] < 2.0 - 0.15).all()  # the wall's points, none of the surface
    np.testing.assert_array_equal(taken, wall)  # and what discovery is handed as the keyframe's structure
    # without a datum nothing is dropped
    unknown = RobotMap(MapAwareParams())
    unknown.add_surface(camera, np.vstack([surface, wall]))
    assert len(unknown.points()) > 10


def test_the_top_of_a_wall_that_rises_into_the_surface_band_stays_in_the_map():
    # dense depth of a wall at x = 3 (jittered 4 cm across it) up to the datum z = 2.0; of the surface
    # from below at z = 1.97 over open water 0.2 m and more from the wall; of the surface at the wall's
    # foot, 5 cm from it (the lip a 10 cm reach keeps); and of the surface's mirror image over the datum
    rng = np.random.default_rng(5)
    ys, zs = np.meshgrid(np.arange(0.0, 2.0, 0.05), np.arange(1.0, 1.99, 0.05))
    wall = np.column_stack([3.0 + rng.uniform(-0.04, 0.04, ys.size), ys.ravel(), zs.ravel()])
    xs, ys2 = np.meshgrid(np.arange(1.0, 2.81, 0.1), np.arange(0.0, 2.0, 0.1))
    surface = np.column_stack([xs.ravel(), ys2.ravel(), np.full(xs.size, 1.97)])
    lip = np.column_stack([np.full(5, 2.95), np.linspace(0.2, 1.8, 5), np.full(5, 1.98)])
    mirror = np.column_stack([np.full(5, 3.0), np.linspace(0.2, 1.8, 5), np.full(5, 2.05)])
    points = np.vstack([wall, surface, lip, mirror])
    dropped = water_surface(points, 2.0, wall_reach_m=0.1)
    assert (wall[:, 2] >= 1.85).sum() == 3 * 40  # the wall's top 15 cm: z 1.85 to 1.95 ...
    assert not dropped[: len(wall)].any()  # ... kept, with all the rest of it
    assert dropped[len(wall) : len(wall) + len(surface)].all()
    assert not dropped[len(wall) + len(surface) : -5].any()  # the lip, within reach
    assert dropped[-5:].all()  # over the datum, though right over the wall
    # no reach: the whole band goes, as before
    assert np.array_equal(water_surface(points, 2.0, wall_reach_m=0.0), points[:, 2] >= 1.85)
    # a wall that stops 20 cm under the band gives the band no support
    low = wall[wall[:, 2] <= 1.65]
    assert water_surface(np.vstack([low, lip]), 2.0, wall_reach_m=0.1)[len(low) :].all()
    # through the map: the wall's top is kept, the surface is not
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    taken = robot_map.add_surface(np.array([1.0, 1.0, 1.0]), np.vstack([wall, surface, mirror]))
    np.testing.assert_array_equal(taken, wall)


# ----- rule 4's lift: a viewpoint moved up or down into water the robot can hold --------------------------


def test_the_lifts_are_tried_smallest_first_up_before_down_within_the_view():
    # the OAK-D's 54.1 deg vertical field at the 1 m standoff: half-height tan(27.05 deg) = 0.5107 m, three
    # quarters of it 0.383 m, so 5 cm steps up to 35 cm, written out
    offsets = lift_offsets(MapAwareParams(), DiscoveryParams())
    expected = [0.05, -0.05, 0.1, -0.1, 0.15, -0.15, 0.2, -0.2, 0.25, -0.25, 0.3, -0.3, 0.35, -0.35]
    assert np.allclose(offsets, expected)
    assert len(lift_offsets(MapAwareParams(max_lift_fraction=0.0), DiscoveryParams())) == 0
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="max_lift_fraction"):
            MapAwareParams(max_lift_fraction=bad)
    with pytest.raises(ValueError, match="lift_step_m"):
        MapAwareParams(lift_step_m=0.0)


def _low_and_high_faces(rng):
    """A wall at x = 3 (4 m wide, up to the surface at z = 2) and a floor at z = 0 whose landmarks stop
    0.6 m short of the wall (a grazing view leaves few there), seen from (1, 2, 1); faces on the wall at
    z = 0.25 and z = 1.85, whose 1 m viewpoints lie 25 cm over the floor's landmarks and 15 cm under the
    surface."""
    wall = _plane_points([3, 0, 0], [0, 1, 0], [0, 0, 1], 4.0, 2.0, 0.1, rng)
    floor = _plane_points([0.6, 0, 0], [1, 0, 0], [0, 1, 0], 1.8, 4.0, 0.1, rng)
    points = np.vstack([wall, floor])
    camera = np.array([1.0, 2.0, 1.0])
    faces = [_face_at(points, [3.0, y, z]) for y, z in ((1.0, 0.25), (3.0, 1.85))]
    return points, camera, np.vstack([points[f] for f in faces]), [[0, 1, 2], [3, 4, 5]]


def _in_view(row, point, discovery):
    # the point inside the row's frustum, by angles from its axis (the row looks level along +x here)
    offset = np.asarray(point, float) - row[:3]
    depth = offset @ row[3:]
    return 0 < depth <= discovery.far_range and abs(offset[2]) / depth <= math.tan(
        math.radians(discovery.vfov_deg / 2)
    )


def test_a_face_near_the_floor_or_the_surface_is_viewed_from_the_nearest_height_the_robot_can_hold():
    rng = np.random.default_rng(21)
    points, camera, vertices, triangles = _low_and_high_faces(rng)
    discovery = DiscoveryParams()
    params = MapAwareParams(surface_z=2.0, min_new_fraction=0.0, min_new_points=1)
    unlifted = discover_on_map(
        _map_of(points, np.arange(len(points)), camera, replace(params, max_lift_fraction=0.0)),
        vertices,
        triangles,
        camera,
    )
    # without the lift both viewpoints are refused: too near the floor, too near the surface
    assert unlifted.not_free == 2 and len(unlifted.final) == 0 and unlifted.lifted == 0
    robot_map = _map_of(points, np.arange(len(points)), camera, params)
    lifted = discover_on_map(robot_map, vertices, triangles, camera)
    assert lifted.lifted == 2 and lifted.not_free == 0 and len(lifted.final) == 2
    low, high = sorted(lifted.final, key=lambda row: row[2])
    # straight up and straight down, still 1 m from the wall and looking level at it
    assert np.allclose(low[[0, 1]], [2.0, 1.0], atol=0.05)
    assert np.allclose(high[[0, 1]], [2.0, 3.0], atol=0.05)
    assert low[3] > 0.99 and high[3] > 0.99
    # both the clearance from every landmark (brute force), the high one under the surface by it too
    for row in (low, high):
        assert np.linalg.norm(points - row[:3], axis=1).min() >= params.clearance_m
    assert high[2] <= 2.0 - params.clearance_m + 1e-9
    # moved from the faces' heights (the centroid's, to the few mm that the plane fit's tilt makes over the
    # 1 m standoff) by a whole number of 5 cm steps, by no more than three quarters of the view's half-height
    for row, z in ((low, vertices[:3, 2].mean()), (high, vertices[3:, 2].mean())):
        steps = (row[2] - z) / 0.05
        assert abs(steps - round(steps)) < 0.1 and abs(row[2] - z) <= 0.39
        # the smallest such move: one step less is refused
        back = row.copy()
        back[2] -= np.sign(row[2] - z) * 0.05
        assert not reachable_on_map(robot_map, back[None], 1.0)[0]
        # and the face is still in the view
        assert _in_view(row, [3.0, row[1], z], discovery)
    # a lift capped at 10 cm cannot reach the heights the robot can hold
    capped = discover_on_map(
        _map_of(points, np.arange(len(points)), camera, replace(params, max_lift_fraction=0.2)),
        vertices,
        triangles,
        camera,
    )
    assert capped.not_free == 2 and capped.lifted == 0


def test_a_lift_does_not_take_a_viewpoint_through_a_wall():
    rng = np.random.default_rng(22)
    points, ids, camera = _wall_scene(rng)
    robot_map = _map_of(points, ids, camera, MapAwareParams(surface_z=2.0))
    rows = np.array(
        [
            [2.0, 2.0, 1.0, 1, 0, 0],  # fine where it is: not moved
            [4.0, 2.0, 1.0, -1, 0, 0],  # behind the wall: no height is in seen water
            [2.0, 2.0, 0.2, 1, 0, 0],  # 20 cm over the floor: moved up
        ]
    )
    moved, free, lifted = lift_into_free(robot_map, rows, DiscoveryParams())
    assert free.tolist() == [True, False, True] and lifted == 1
    assert np.array_equal(moved[:2], rows[:2])
    assert np.array_equal(moved[2, [0, 1, 3, 4, 5]], rows[2, [0, 1, 3, 4, 5]]) and 0.35 <= moved[2, 2] <= 0.55


def test_rule_5s_cells_are_every_occupied_cell_once_in_order():
    # against a literal set of floor(point / size), negative coordinates and repeats included
    rng = np.random.default_rng(4)
    points = np.vstack([rng.uniform(-3.0, 3.0, (400, 3)), rng.uniform(-0.2, 0.2, (50, 3))])
    params = MapAwareParams()
    size = params.coverage_voxel_m
    literal = sorted({tuple(int(v) for v in np.floor(p / size)) for p in points})
    np.testing.assert_allclose(coverage_cells(points, params), (np.array(literal) + 0.5) * size)
    assert coverage_cells(np.zeros((0, 3)), params).shape == (0, 3)
