"""Frontier exploration on a robot's own map (issue [loop], maptidal.exploration): the frontier, the gain of a
look and the clearance of where it stands against literal per-voxel and per-ray constructions, and the
choice of the next look in rooms built by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from maptidal.exploration import (
    FREE,
    LOOKED,
    OCCUPIED,
    OUTSIDE,
    UNKNOWN,
    FrontierParams,
    VoxelStates,
    _clear_of_unseen,
    _frontier,
    explore,
    explore_views,
    look_gains,
    voxel_states,
)
from maptidal.map_discovery import MapAwareParams, RobotMap, _packed, voxel_keys

VOXEL = 0.15


def _random_grid(seed: int, shape=(9, 8, 7), gain_box=None) -> VoxelStates:
    rng = np.random.default_rng(seed)
    states = rng.choice([UNKNOWN, FREE, FREE, FREE, LOOKED, OCCUPIED, OUTSIDE], size=shape).astype(np.int8)
    return VoxelStates(states, np.array([-4, 3, -2]), VOXEL, gain_box)


def _in_gain_box(grid: VoxelStates, cell) -> bool:
    """Whether grid cell ``cell`` (on or off the grid) has its centre in the grid's gain box, literally."""
    if grid.gain_box is None:
        return True
    centre = [(cell[d] + grid.origin[d] + 0.5) * grid.size for d in range(3)]
    return all(grid.gain_box[0][d] <= centre[d] <= grid.gain_box[1][d] for d in range(3))


# a box that cuts the random grid (world x -0.6 to 0.75, y 0.45 to 1.65, z -0.3 to 0.75) on every axis
GAIN_BOX = ((-0.3, 0.7, -0.2), (0.4, 1.5, 0.8))


@pytest.mark.parametrize("gain_box", [None, GAIN_BOX])
@pytest.mark.parametrize("seed", range(3))
def test_the_frontier_is_every_free_or_looked_voxel_beside_a_counted_unknown_one(seed, gain_box):
    grid = _random_grid(seed, gain_box=gain_box)
    states = grid.states
    expected = set()
    for i, j, k in np.ndindex(*states.shape):
        if states[i, j, k] not in (FREE, LOOKED):
            continue
        for d in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
            a, b, c = i + d[0], j + d[1], k + d[2]
            inside = 0 <= a < states.shape[0] and 0 <= b < states.shape[1] and 0 <= c < states.shape[2]
            unknown = not inside or states[a, b, c] == UNKNOWN  # off the grid is unknown
            if unknown and _in_gain_box(grid, (a, b, c)):
                expected.add((i, j, k))
                break
    assert {tuple(row) for row in _frontier(grid).tolist()} == expected
    if gain_box is not None:  # the box leaves some of the frontier out
        assert len(expected) < len(_frontier(_random_grid(seed)))


@pytest.mark.parametrize("radius", [0.1, 0.2, 0.35])
def test_a_stand_is_clear_when_every_voxel_within_the_radius_is_free(radius):
    grid = _random_grid(7, shape=(8, 8, 8))
    # mostly free, with occupied and looked-at voxels scattered: looked-at water may hide a bare surface
    grid.states[(grid.states != OCCUPIED) & (grid.states != LOOKED)] = FREE
    clear = _clear_of_unseen(grid, radius)
    states = grid.states
    for i, j, k in np.ndindex(*states.shape):
        ok = states[i, j, k] == FREE
        for a, b, c in np.ndindex(*states.shape):
            if ok and ((a - i) ** 2 + (b - j) ** 2 + (c - k) ** 2) * VOXEL**2 <= radius**2 + 1e-12:
                ok = states[a, b, c] == FREE
        # a voxel near the grid's edge has neighbours off it, which are not free
        reach = int(radius / VOXEL + 1e-9)
        if min(i, j, k) < reach or max(i, j, k) > 7 - reach:
            ok = False
        assert clear[i, j, k] == ok, (i, j, k)


def _literal_gain(grid: VoxelStates, position, yaw, params: FrontierParams, pitch: float = 0.0) -> float:
    """One look's unknown volume, ray by ray and sample by sample, as the docstring says; the camera's
    axes written out for a heading ``yaw`` and a pitch ``pitch`` (nose down +)."""
    seen = set()
    tan_h = math.tan(math.radians(params.hfov_deg) / 2)
    tan_v = math.tan(math.radians(params.vfov_deg) / 2)
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    forward = np.array([cp * cy, cp * sy, -sp])
    left = np.array([-sy, cy, 0.0])
    up = np.array([sp * cy, sp * sy, cp])
    for a in np.linspace(-tan_h, tan_h, params.rays_across):
        for u in np.linspace(-tan_v, tan_v, params.rays_up):
            ray = forward + a * left + u * up
            ray /= np.linalg.norm(ray)
            depth = 0.5 * grid.size
            while depth <= params.view_range_m + 1e-9:
                point = np.asarray(position) + depth * ray
                cell = np.floor(point / grid.size).astype(int) - grid.origin
                cell = np.clip(cell, 0, np.array(grid.states.shape) - 1)
                state = grid.states[tuple(cell)]
                if state in (OCCUPIED, OUTSIDE):
                    break
                if state == UNKNOWN and _in_gain_box(grid, cell):
                    seen.add(tuple(cell))
                depth += grid.size
    return len(seen) * grid.size**3


@pytest.mark.parametrize("pitch_deg", [0.0, 27.0, -40.0])
@pytest.mark.parametrize("gain_box", [None, ((-1.0, -0.5, -2.0), (1.5, 2.5, 0.5))])
@pytest.mark.parametrize("seed", range(3))
def test_a_looks_gain_is_the_unknown_volume_its_rays_reach_before_a_surface(seed, gain_box, pitch_deg):
    rng = np.random.default_rng(seed)
    states = rng.choice([UNKNOWN, FREE, LOOKED, OCCUPIED], p=[0.45, 0.35, 0.15, 0.05], size=(30, 30, 20))
    grid = VoxelStates(states.astype(np.int8), np.array([-15, -15, -10]), VOXEL, gain_box)
    params = FrontierParams(view_range_m=1.5, rays_across=4, rays_up=3)
    positions = rng.uniform(-0.8, 0.8, size=(3, 3))
    yaws = np.array([0.3, 2.0, -2.5])
    pitch = math.radians(pitch_deg)
    gains = look_gains(grid, positions, yaws, params, pitch)
    for n, position in enumerate(positions):
        for y, yaw in enumerate(yaws):
            assert gains[n, y] == pytest.approx(_literal_gain(grid, position, yaw, params, pitch), rel=1e-9)
    if gain_box is not None:  # the box leaves some unknown voxels out
        everywhere = look_gains(dataclasses.replace(grid, gain_box=None), positions, yaws, params, pitch)
        assert (gains <= everywhere).all() and (gains < everywhere).any()


def _room() -> np.ndarray:
    """Landmarks every 0.1 m on the walls and floor of a closed room 4 x 4 m, 2 m deep, centred on 0."""
    g, h = np.arange(-2, 2.001, 0.1), np.arange(0, 2.001, 0.1)
    walls = [[s * 2, y, z] for s in (-1, 1) for y in g for z in h]
    walls += [[x, s * 2, z] for s in (-1, 1) for x in g for z in h]
    walls += [[x, y, 0.0] for x in g for y in g]
    return np.array(walls, float)


def _look(robot_map: RobotMap, camera, yaw_deg: float, walls: np.ndarray) -> None:
    """Fold into the map what a level camera at ``camera`` facing ``yaw_deg`` sees of ``walls``: the
    landmarks in its field of view, and the water up to them (rays), as a keyframe does."""
    offsets = walls - camera
    bearing = np.degrees(np.arctan2(offsets[:, 1], offsets[:, 0])) - yaw_deg
    bearing = (bearing + 180) % 360 - 180
    elevation = np.degrees(np.arctan2(offsets[:, 2], np.hypot(offsets[:, 0], offsets[:, 1])))
    seen = (np.abs(bearing) < 39) & (np.abs(elevation) < 27)
    robot_map.add_keyframe(np.asarray(camera, float), np.flatnonzero(seen), walls[seen])


def test_a_robot_that_looked_one_way_is_sent_to_look_the_other_way():
    walls = _room()
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    camera = np.array([-0.5, 0.0, 1.0])
    _look(robot_map, camera, 0.0, walls)  # it has seen the +x half of the room
    views = explore_views(robot_map, camera, launch=camera)
    assert len(views) >= 1
    best = views[0]
    facing = np.array([math.cos(best[3]), math.sin(best[3])])
    assert facing[0] < -0.5, best  # towards the half it has not seen
    assert best[5] >= FrontierParams().min_gain_m3
    assert (views[:, 4] == 0).all()  # level looks alone by default
    # utility is the gain discounted by the distance to fly; the rows are best first
    distance = np.linalg.norm(views[:, :3] - camera, axis=1)
    assert views[:, 6] == pytest.approx(views[:, 5] * np.exp(-distance / FrontierParams().distance_scale_m))
    assert np.all(np.diff(views[:, 6]) <= 1e-12)
    # every look stands in water the robot has seen, clear of the map and of the surface
    assert robot_map.seen_free(views[:, :3]).all()
    nearest = np.min(np.linalg.norm(views[:, None, :3] - robot_map.points()[None], axis=2), axis=1)
    assert np.all(nearest >= FrontierParams().clearance_m)
    assert np.all(views[:, 2] <= 2.0 - FrontierParams().clearance_m)


def test_a_room_seen_all_round_leaves_nothing_to_explore():
    walls = _room()
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    for x in (-1.0, 0.0, 1.0):
        for y in (-1.0, 0.0, 1.0):
            for z in (0.4, 1.0, 1.6):
                for yaw in range(0, 360, 30):
                    _look(robot_map, np.array([x, y, z]), yaw, walls)
    assert len(explore_views(robot_map, np.zeros(3) + [0, 0, 1], launch=np.array([0.0, 0.0, 1.0]))) == 0


def test_a_mapped_wall_stops_the_rays_and_an_unmapped_one_does_not():
    # a robot in a corridor of seen water, facing a wall 1 m ahead: with the wall's landmarks mapped
    # there is nothing to see that way; without them the water beyond counts as unknown
    robot_map = RobotMap(MapAwareParams())
    camera = np.array([0.0, 0.0, 1.0])
    ys, zs = np.meshgrid(np.arange(-1.5, 1.51, 0.1), np.arange(0.0, 2.01, 0.1))
    wall = np.column_stack([np.full(ys.size, 1.0), ys.ravel(), zs.ravel()])
    robot_map.add_keyframe(camera, np.arange(len(wall)), wall)
    params = FrontierParams(explore_radius_m=None)
    grid = voxel_states(robot_map, params, pad_m=params.view_range_m)
    mapped = look_gains(grid, camera[None], np.array([0.0]), params)[0, 0]
    bare = RobotMap(MapAwareParams())
    bare.free_voxels = set(robot_map.free_voxels)  # the same water seen, the wall not mapped
    bare_grid = voxel_states(bare, params, pad_m=params.view_range_m)
    unmapped = look_gains(bare_grid, camera[None], np.array([0.0]), params)[0, 0]
    assert mapped < 0.02 and unmapped > 0.5, (mapped, unmapped)


def test_looked_at_water_is_not_unknown():
    # open water the camera looked at without meeting a surface is not worth a trip
    robot_map = RobotMap(MapAwareParams())
    camera = np.array([0.0, 0.0, 1.0])
    wall = np.array([[1.0, y, z] for y in np.arange(-0.3, 0.31, 0.1) for z in np.arange(0.7, 1.31, 0.1)])
    robot_map.add_keyframe(camera, np.arange(len(wall)), wall)
    params = FrontierParams(explore_radius_m=None)
    grid = voxel_states(robot_map, params, pad_m=params.view_range_m)
    before = look_gains(grid, camera[None], np.array([math.pi]), params)[0, 0]
    behind = np.array(
        [
            [-x, y, z]
            for x in np.arange(0.3, 3.0, VOXEL)
            for y in np.arange(-3, 3, VOXEL)
            for z in np.arange(-2, 4, VOXEL)
        ]
    )
    robot_map.looked_voxels = set(_packed(voxel_keys(behind, VOXEL)).tolist())
    grid = voxel_states(robot_map, params, pad_m=params.view_range_m)
    after = look_gains(grid, camera[None], np.array([math.pi]), params)[0, 0]
    assert before > 1.0 and after < 0.1 * before, (before, after)


def test_teammates_places_surveyed_and_the_region_bound_the_looks():
    walls = _room()
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    camera = np.array([-0.5, 0.0, 1.0])
    _look(robot_map, camera, 0.0, walls)
    params = FrontierParams()
    views = explore_views(robot_map, camera, params, launch=camera)
    best = views[0, :3]
    # a teammate there: no look within the exclusion of it
    teammate = np.array([[*best, 3.0]])
    others = explore_views(robot_map, camera, params, launch=camera, teammates=teammate)
    assert np.all(np.linalg.norm(others[:, :3] - best, axis=1) > params.teammate_exclusion_m)
    # a place surveyed already is not surveyed again
    again = explore_views(robot_map, camera, params, launch=camera, visited=best[None])
    assert np.all(np.linalg.norm(again[:, :3] - best, axis=1) > params.visited_exclusion_m)
    # a region of 0.5 m about the launch holds almost no unknown water: no look is worth a trip
    small = FrontierParams(explore_radius_m=0.5)
    assert len(explore_views(robot_map, camera, small, launch=camera)) == 0
    # ... nor does a box about the camera of 0.5 m each way; the box's voxels are outside beyond it
    box = tuple(tuple(float(v) for v in camera + side) for side in (-0.5, 0.5))
    boxed = FrontierParams(explore_radius_m=None, explore_box=box)
    assert len(explore_views(robot_map, camera, boxed)) == 0
    grid = voxel_states(robot_map, boxed)
    centres = grid.centres(np.argwhere(grid.states != OCCUPIED))
    beyond = np.any((centres < camera - 0.5) | (centres > camera + 0.5), axis=1)
    states = grid.states[tuple(np.argwhere(grid.states != OCCUPIED).T)]
    assert beyond.any() and (states[beyond] == OUTSIDE).all() and not (states[~beyond] == OUTSIDE).all()


def test_a_look_is_worth_only_what_it_reveals_of_the_gain_box():
    # a robot at the middle of a closed room has looked at one wall (+x). Counting every unknown voxel,
    # its best look turns round, to the room's unseen half; counting only the box against that wall (the
    # structure it was sent to inspect), every look reveals a corner of that box left out of the first
    robot_map = RobotMap()
    camera = np.array([-0.5, 0.0, 1.0])
    walls = _room()
    _look(robot_map, camera, 0.0, walls)
    everywhere = explore_views(robot_map, camera, FrontierParams(), launch=camera)
    assert math.cos(everywhere[0, 3]) < 0
    box = ((1.0, -2.0, 0.0), (2.0, 2.0, 2.0))
    params = FrontierParams(gain_box=box)
    views = explore_views(robot_map, camera, params, launch=camera)
    assert len(views) and (np.cos(views[:, 3]) > -1e-9).all()
    grid = voxel_states(robot_map, params, camera, pad_m=params.view_range_m)
    for x, y, z, yaw, _pitch, gain, _ in views:
        # within two voxels: the gain's rays are sampled in float32, and a sample may fall on a voxel's face
        assert gain == pytest.approx(_literal_gain(grid, (x, y, z), yaw, params), abs=2 * VOXEL**3)
        assert params.min_gain_m3 <= gain < everywhere[0, 5]


def test_an_empty_or_lost_map_gives_no_look():
    assert explore_views(RobotMap(), np.zeros(3)).shape == (0, 7)
    robot_map = RobotMap()
    _look(robot_map, np.array([-0.5, 0.0, 1.0]), 0.0, _room())
    assert explore_views(robot_map, np.array([np.nan, 0.0, 1.0])).shape == (0, 7)


@pytest.mark.parametrize(
    "bad",
    [
        {"view_range_m": 0.0},
        {"min_gain_m3": -1.0},
        {"clearance_m": math.nan},
        {"explore_radius_m": 0.0},
        {"yaws": 0},
        {"rays_across": 2.5},
        {"hfov_deg": 200.0},
        {"wall_margin_voxels": -1},
        {"explore_box": ((0, 0, 0), (1, 1, float("nan")))},
        {"gain_box": ((0, 0, 0), (1, -1, 1))},
    ],
)
def test_bad_exploration_settings_are_refused(bad):
    with pytest.raises(ValueError, match="exploration"):
        FrontierParams(**bad)


def test_a_look_stands_over_water_seen_beneath_it_where_the_floor_has_few_landmarks():
    # dense walls, a floor with a landmark only every 1.2 m, seen from 0.8 m up at a grazing angle: the
    # water just above the floor is crossed by rays to the floor's few landmarks, but a stand there has
    # no water seen 35 cm beneath it
    g, h = np.arange(-2, 2.001, 0.1), np.arange(0, 2.001, 0.1)
    walls = [[s * 2, y, z] for s in (-1, 1) for y in g for z in h]
    walls += [[x, s * 2, z] for s in (-1, 1) for x in g for z in h]
    xs, ys = np.meshgrid(np.arange(-1.8, 2.0, 1.2), np.arange(-1.8, 2.0, 1.2))
    floor = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    landmarks = np.vstack([walls, floor])
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    for yaw in range(0, 360, 45):
        _look(robot_map, np.array([0.0, 0.0, 0.8]), yaw, landmarks)
    params = FrontierParams(explore_radius_m=None, min_gain_m3=1e-3, max_views=1000, max_candidates=1000)
    views = explore_views(robot_map, np.array([0.0, 0.0, 0.8]), params)
    assert len(views)
    assert np.all(views[:, 2] >= params.floor_clearance_m), views[:, 2].min()
    without = dataclasses.replace(params, floor_clearance_m=0.0)
    low = explore_views(robot_map, np.array([0.0, 0.0, 0.8]), without)
    assert views[:, 2].min() > low[:, 2].min()  # without the rule, looks stand lower


def _shallow_room_seen_level(camera: np.ndarray) -> RobotMap:
    """A room 4 x 4 m, 1.6 m deep, walls mapped every 0.1 m from 0.5 m up, the floor and the walls'
    foot bare (no landmark, as a bland concrete floor at a grazing angle), seen from ``camera`` with a
    level camera all round: the water before the walls' foot is never looked at."""
    g, h = np.arange(-2, 2.001, 0.1), np.arange(0.5, 1.601, 0.1)
    walls = [[s * 2, y, z] for s in (-1, 1) for y in g for z in h]
    walls += [[x, s * 2, z] for s in (-1, 1) for x in g for z in h]
    robot_map = RobotMap(MapAwareParams(surface_z=1.6))
    for yaw in range(0, 360, 45):
        _look(robot_map, camera, yaw, np.array(walls, float))
    return robot_map


def test_a_pitched_look_reveals_more_of_the_water_before_a_walls_foot_than_any_level_look():
    # a robot 1 m up in a shallow room has looked level all round; the water before the walls' foot,
    # within the box of the +x wall it was sent to inspect, is unknown. The stands its map allows are
    # about its own height, where a level look sees that water at a grazing angle or not at all; one
    # pitched down sees much more of it
    camera = np.array([0.0, 0.0, 1.0])
    robot_map = _shallow_room_seen_level(camera)
    box = ((1.4, -2.0, 0.0), (2.1, 2.0, 1.6))
    level = FrontierParams(gain_box=box, explore_radius_m=None, min_gain_m3=1e-6, max_views=100)
    pitched = dataclasses.replace(level, pitches_deg=(0.0, 27.0, -27.0))
    level_views = explore_views(robot_map, camera, level)
    pitched_views = explore_views(robot_map, camera, pitched)
    assert len(pitched_views)
    best = pitched_views[0]
    assert best[4] == pytest.approx(math.radians(27.0)), best  # nose down
    assert math.cos(best[3]) > 0.5  # towards the +x wall
    best_level = level_views[:, 5].max() if len(level_views) else 0.0
    assert best[5] > 1.5 * best_level, (best[5], best_level)
    # its gain is the literal count of its pitched rays
    grid = voxel_states(robot_map, pitched, None, pad_m=pitched.view_range_m)
    x, y, z, yaw, pitch, gain, _ = best
    assert gain == pytest.approx(_literal_gain(grid, (x, y, z), yaw, pitched, pitch), abs=2 * VOXEL**3)
    # of equal gains the level look comes first: in a room seen all round at its own height, with only
    # level looks' worth left, the default keeps to level
    assert (level_views[:, 4] == 0).all()


@pytest.mark.parametrize("bad", [(), (90.0,), (float("nan"),), [0.0, 27.0]])
def test_bad_look_pitches_are_refused(bad):
    with pytest.raises(ValueError, match="pitches_deg"):
        FrontierParams(pitches_deg=bad)


def test_a_search_with_no_look_says_what_ran_out_first():
    """explore: the looks explore_views gives, and, with none, why: no water seen, no stand (a teammate
    everywhere), or too little to see, with the best look's gain the same search gives when every look
    counts (min_gain_m3 next to 0, max_views large enough for all)."""
    walls = _room()
    camera = np.array([-0.5, 0.0, 1.0])
    assert explore(RobotMap(MapAwareParams()), camera).why == "no water seen"
    robot_map = RobotMap(MapAwareParams(surface_z=2.0))
    _look(robot_map, camera, 0.0, walls)
    assert explore(robot_map, camera + [np.nan, 0.0, 0.0], launch=camera).why == "no position"
    found = explore(robot_map, camera, launch=camera)
    assert found.why == "" and len(found.views) and found.stands > 0 and found.frontier_voxels > 0
    np.testing.assert_array_equal(found.views, explore_views(robot_map, camera, launch=camera))
    every = explore_views(
        robot_map, camera, FrontierParams(min_gain_m3=1e-9, max_views=10_000), launch=camera
    )
    assert found.best_gain_m3 == pytest.approx(every[:, 5].max())
    demanding = FrontierParams(min_gain_m3=every[:, 5].max() + 0.01)
    short = explore(robot_map, camera, demanding, launch=camera)
    assert len(short.views) == 0 and short.why == "too little to see"
    assert short.best_gain_m3 == pytest.approx(every[:, 5].max()) and short.stands == found.stands
    crowded = explore(robot_map, camera, FrontierParams(teammate_exclusion_m=50.0), camera, camera[None])
    assert len(crowded.views) == 0 and crowded.why == "no stand" and crowded.stands == 0
    assert crowded.summary() == {
        "why": "no stand",
        "frontier_voxels": found.frontier_voxels,
        "stands": 0,
        "best_gain_m3": 0.0,
    }
