"""Frontier exploration on a robot's own map (issue [loop]): where to look next when no task is left.

Map-aware discovery (:mod:`maptidal.map_discovery`) proposes a view only of structure the robot has seen
with the water in front of it seen too. A robot that only sweeps its camera where it starts, then flies
the tasks that sweep gave, never looks at what lay outside that sweep. This module picks the robot's next
look: the classic frontier method (Yamauchi 1997, "A frontier-based approach for autonomous exploration"),
with the next-best-view gain of counting the unknown volume a view would see (Connolly 1985; Bircher et
al. 2016, "Receding horizon next-best-view planner for 3D exploration").

On the robot's own :class:`~maptidal.map_discovery.RobotMap`, on its voxel grid:

- **free**: a voxel its cameras have seen water through (space carving);
- **looked**: a voxel its cameras looked at, within their useful range, without meeting a surface there
  (:attr:`~maptidal.map_discovery.RobotMap.looked_voxels`): open water, or a surface too bare to map.
  Not known to be free, but nothing more is to be seen there;
- **occupied**: within ``wall_margin_voxels`` of a map landmark. The margin closes the gaps between the
  landmarks of a textured surface, so that a ray does not count the dark behind a wall as unseen water;
- **outside**: above the water surface (the depth sensor's datum, ``surface_z``), beyond
  ``explore_radius_m`` of the robot's launch point, or outside the box ``explore_box`` (the region it was
  sent to inspect: in the loop, the box the structure lies in grown by the water its views stand in);
- **unknown**: anything else.

Only unknown voxels inside ``gain_box`` count (in the loop, the box the structure to inspect lies in,
grown by map-aware discovery's plane tolerance): water outside it may be flown through and stood in, but
holds nothing the robot was sent to inspect, so revealing it is worth nothing. Without the box, every
unknown voxel counts.

A **frontier** is a free or looked voxel beside a counted unknown one. Each frontier stands for a candidate
look, made from where the vehicle's centre can stand: the free voxel nearest the frontier whose every voxel
within ``free_margin_m`` is free too (water the robot has seen through, not looked-at water, which may hide a
bare surface), with free water ``floor_clearance_m`` beneath it (the floor, seen at a grazing angle, has few
landmarks), ``clearance_m`` from every landmark (the hull, whichever way it turns) and from the surface, one
per ``cell_m`` cell, looking along one of ``yaws`` headings, at one of ``pitches_deg`` (level, and, in the
loop, for a robot with a DVL that can pitch, pitched down and up: see below). A look's **gain** is the
unknown volume its rays reach (the camera's field of view, ``view_range_m`` deep, each ray ending at the first
occupied or outside voxel), its **utility** that gain discounted by the distance to fly, ``gain *
exp(-distance / distance_scale_m)`` (Gonzalez-Banos and Latombe 2002). Looks near a teammate (where its last
message put it) or near a place this robot surveyed already are left out: the simplest coordination, which
needs nothing the team does not already send. Looks that reveal less than ``min_gain_m3`` are not worth a
trip; a robot with none left has explored.

**Pitched looks.** A level camera standing 1 m or more up sees the foot of a wall only at a grazing
angle, from afar, and a look's stand needs seen water beneath it: in a shallow tank (1.6 m, the launch
1 to 1.2 m up) the water before the bottom half metre of the end wall stayed unknown, yet no level look
from the stands the map allowed (0.8 to 1 m up) reached enough of it to be worth a trip, and the robots
declared themselves explored with a fifth of the walls never seen. A vehicle that pitches for its views
(the Heavy) can point its camera down or up there: each look may also be pitched by ``pitches_deg``
(nose down +, the vehicle's convention), by default none. The loop gives a robot with a DVL that can
pitch looks pitched down and up as far as it pitches for a view (45 deg for the Heavy), never beyond the
camera's vertical field of view (54 deg for the OAK-D), so that a pitched view still overlaps the level
one. A robot without a DVL looks level: pitched at the bare floor or the surface it loses the visual
fixes it holds its position by. Level and pitched looks are weighed together, by their gain; of equal
gains the level look wins. Weighing the pitched ones only once no level look was worth a trip kept the
missions as they were until then, and added surveys at their end: on five tanks (seeds 0-9) it left as
much of the walls uninspected (2.7 % on the mean of the four where level looks reach the walls' foot,
against 2.8 %) and finished 40 s later (docs/mission.md, "Exploring the map's frontier").

Pure numpy and scipy, with no tank model and no simulator truth: it runs on a real robot's map as well.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from maptidal.camera import OAKD_HFOV_DEG, OAKD_VFOV_DEG
from maptidal.map_discovery import RobotMap, check_box, unpack_voxels

__all__ = ["Exploration", "FrontierParams", "explore", "explore_views", "voxel_states"]

UNKNOWN, FREE, LOOKED, OCCUPIED, OUTSIDE = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class FrontierParams:
    """The exploration's settings (module docstring). Lengths in metres."""

    # how deep a look is counted: the loop's 320 px images (f = 196 px, 7.5 cm baseline, 0.25 px disparity
    # noise) give one observation a depth error of z^2 x 0.25 / (196 x 0.075) = 15 cm at 2.9 m, the depth
    # beyond which a landmark is too rough for the 10 cm plane tolerance of map-aware discovery
    view_range_m: float = 3.0
    # the rays of a look across the OAK-D's field of view (78.5 x 54.1 deg): 9 x 5 rays are 10 and 14 deg
    # apart, 0.5 m and 0.7 m apart at 3 m, a few voxels, so that a doorway-sized gap is not missed
    rays_across: int = 9
    rays_up: int = 5
    hfov_deg: float = OAKD_HFOV_DEG
    vfov_deg: float = OAKD_VFOV_DEG
    # eight headings: 45 deg apart, under the camera's 78.5 deg field of view, so that every direction is
    # inside some heading's view
    yaws: int = 8
    # the pitches a look may take (deg, nose down +, the vehicle's convention: maptidal.mission.
    # verification.view_pitch): level alone by default; the loop adds as much as a robot pitches for a
    # view, down and up (module docstring, "Pitched looks")
    pitches_deg: tuple[float, ...] = (0.0,)
    # one candidate look per cell: about the vehicle's length (0.457 m) and a half, so that two looks in
    # one cell are all but the same place
    cell_m: float = 0.6
    max_candidates: int = 60
    # a look worth a trip reveals at least the water in front of a 0.55 m x 0.55 m patch of surface at
    # the 1 m task standoff (a pyramid of 0.55^2 x 1 / 3 = 0.1 m^3): a patch large enough for a view of
    # its own. Smaller pockets are the map's noise
    min_gain_m3: float = 0.1
    # the distance at which a look's utility falls by e: about a third of a tank's length, so that a
    # near look wins unless a far one reveals several times as much (our choice)
    distance_scale_m: float = 3.0
    # the map's landmarks are dilated this many voxels (0.15 m each) into a surface
    wall_margin_voxels: int = 1
    # where the vehicle's centre stands for a look: this far from every landmark and from the surface.
    # The BlueROV2 Heavy's hull (0.457 x 0.575 x 0.254 m, Blue Robotics' technical details) reaches 0.39 m
    # from its centre, whichever way it turns; with the loop's 15 cm position tolerance, 0.55 m
    clearance_m: float = 0.55
    # free water this far beneath the stand (the loop's reach margin, MapAwareParams.clearance_m)
    floor_clearance_m: float = 0.35
    # a look stands where the water a voxel about it was seen through: the vehicle's half-height (0.127
    # m) and a voxel's half-width are under it, so that the hull is in water seen, not guessed
    free_margin_m: float = 0.15
    # a teammate's vicinity is left to it: the loop's keeping-clear distance (MissionParams.clearance_m),
    # inside which a robot could only wait for the teammate to go
    teammate_exclusion_m: float = 1.0
    # a place surveyed already is not surveyed again: within the vehicle's length and a half
    visited_exclusion_m: float = 0.7
    # the region to explore: within this of the launch point (None: everywhere). The team is launched in
    # front of the structure it is to inspect, within its cameras' useful range (view_range_m): the
    # structure lies within about that of the launch, and looking further finds structure nobody asked
    # to inspect. Bounding exploration so is standard (Bircher et al. 2016's exploration box)
    explore_radius_m: float | None = 3.0
    # ... and within this box, lowest and highest corners (None: no box)
    explore_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    # the unknown volume a look's gain counts, and the frontier borders: inside this box, lowest and
    # highest corners (None: everywhere). In the loop, the box to inspect: unknown water in the box grown
    # for the views' stands (explore_box) but outside the structure's box has nothing to inspect in it;
    # counted, it sent robots looking away from the structure into the open tank, two surveys in three of
    # session 31's default missions (docs/mission.md, "Exploring the map's frontier")
    gain_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    max_views: int = 5

    def __post_init__(self) -> None:
        for name in (
            "view_range_m",
            "hfov_deg",
            "vfov_deg",
            "cell_m",
            "min_gain_m3",
            "distance_scale_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"exploration {name} must be a positive number, got {value!r}")
        for name in (
            "clearance_m",
            "floor_clearance_m",
            "free_margin_m",
            "teammate_exclusion_m",
            "visited_exclusion_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"exploration {name} must be a non-negative number, got {value!r}")
        if self.explore_radius_m is not None and not (
            math.isfinite(self.explore_radius_m) and self.explore_radius_m > 0
        ):
            raise ValueError(
                f"exploration explore_radius_m must be positive or None, got {self.explore_radius_m!r}"
            )
        for name in ("explore_box", "gain_box"):
            if getattr(self, name) is not None:
                check_box(getattr(self, name), f"exploration {name}")
        if self.hfov_deg >= 180 or self.vfov_deg >= 180:
            raise ValueError("exploration fields of view must be under 180 deg")
        for name in ("rays_across", "rays_up", "yaws", "max_candidates", "max_views"):
            value = getattr(self, name)
            if not (isinstance(value, int) and value >= 1):
                raise ValueError(f"exploration {name} must be a positive integer, got {value!r}")
        pitches = self.pitches_deg
        if not (
            isinstance(pitches, tuple)
            and pitches
            and all(isinstance(p, int | float) and math.isfinite(p) and abs(p) < 90 for p in pitches)
        ):
            raise ValueError(
                f"exploration pitches_deg must be a non-empty tuple of angles within 90 deg, got {pitches!r}"
            )
        if not (isinstance(self.wall_margin_voxels, int) and self.wall_margin_voxels >= 0):
            raise ValueError(
                f"exploration wall_margin_voxels must be a whole number >= 0, got {self.wall_margin_voxels!r}"
            )


@dataclass
class VoxelStates:
    """The map's voxels on a dense grid: ``states[i, j, k]`` is UNKNOWN, FREE, LOOKED, OCCUPIED or OUTSIDE
    for the voxel of integer key ``origin + (i, j, k)``, of ``size`` m. An unknown voxel counts towards a
    look's gain and the frontier only when its centre lies in ``gain_box`` (None: every one)."""

    states: np.ndarray
    origin: np.ndarray
    size: float
    gain_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None

    def centres(self, index: np.ndarray) -> np.ndarray:
        """The world centres of grid cells ``index`` ``(N, 3)``."""
        return (np.asarray(index) + self.origin + 0.5) * self.size

    def axes(self, pad: int = 0) -> list[np.ndarray]:
        """The world centres of the cells along each axis of the grid padded by ``pad`` cells each way."""
        return [
            (np.arange(n + 2 * pad) - pad + self.origin[d] + 0.5) * self.size
            for d, n in enumerate(self.states.shape)
        ]

    def counted(self, pad: int = 0) -> np.ndarray:
        """Which cells of the grid, padded by ``pad`` cells each way, have their centre in ``gain_box``
        (all, without one): a boolean array of the padded grid's shape."""
        if self.gain_box is None:
            return np.ones(tuple(n + 2 * pad for n in self.states.shape), bool)
        return _in_box(self.axes(pad), self.gain_box)


def _in_box(axes: list[np.ndarray], box) -> np.ndarray:
    """Which cells of the grid whose cell centres lie at ``axes`` along each axis are in ``box`` (lowest
    and highest corners): the test is separable by axis."""
    low, high = (np.asarray(corner, float) for corner in box)
    x, y, z = ((axis >= low[d]) & (axis <= high[d]) for d, axis in enumerate(axes))
    return x[:, None, None] & y[None, :, None] & z[None, None, :]


def voxel_states(
    robot_map: RobotMap, params: FrontierParams, launch: np.ndarray | None = None, pad_m: float = 0.0
) -> VoxelStates:
    """The map's voxels classified (module docstring) on a dense grid covering the free voxels, padded by
    ``pad_m`` and a voxel; ``launch`` centres the region to explore (``explore_radius_m``)."""
    size = robot_map.params.voxel_m
    free = unpack_voxels(robot_map.free_voxels)
    looked = unpack_voxels(robot_map.looked_voxels - robot_map.free_voxels)
    points = robot_map.points()
    landmarks = np.floor(points / size).astype(np.int64) if len(points) else np.zeros((0, 3), np.int64)
    pad = math.ceil(pad_m / size) + 1 + params.wall_margin_voxels
    low = free.min(axis=0) - pad
    high = free.max(axis=0) + pad
    shape = tuple(int(v) for v in high - low + 1)
    states = np.zeros(shape, np.int8)
    looked = looked[np.all((looked >= low) & (looked <= high), axis=1)]
    states[tuple((looked - low).T)] = LOOKED
    states[tuple((free - low).T)] = FREE
    margin = params.wall_margin_voxels
    inside = np.all((landmarks >= low - margin) & (landmarks <= high + margin), axis=1)
    for offset in np.ndindex(2 * margin + 1, 2 * margin + 1, 2 * margin + 1):
        cells = landmarks[inside] + np.array(offset) - margin - low
        keep = np.all((cells >= 0) & (cells < shape), axis=1)
        states[tuple(cells[keep].T)] = OCCUPIED
    grid = VoxelStates(states, low, size, params.gain_box)
    # the grid's axes in the world: the tests below are separable by axis
    axes = grid.axes()
    outside = np.zeros(shape, bool)
    surface = robot_map.params.surface_z
    if surface is not None:
        outside |= (axes[2] > surface)[None, None, :]
    if params.explore_radius_m is not None and launch is not None:
        x, y, z = ((axis - centre) ** 2 for axis, centre in zip(axes, np.asarray(launch, float), strict=True))
        outside |= x[:, None, None] + y[None, :, None] + z[None, None, :] > params.explore_radius_m**2
    if params.explore_box is not None:
        outside |= ~_in_box(axes, params.explore_box)
    states[outside & (states != OCCUPIED)] = OUTSIDE
    return grid


def _frontier(grid: VoxelStates) -> np.ndarray:
    """The grid indices ``(N, 3)`` of free or looked voxels with a face neighbour unknown and counted
    (off the grid, a voxel is unknown)."""
    states = grid.states
    padded = np.where(grid.counted(pad=1), np.pad(states, 1, constant_values=UNKNOWN), OUTSIDE)
    beside = np.zeros(states.shape, bool)
    n0, n1, n2 = states.shape
    for axis in range(3):
        for step in (-1, 1):
            shift = [slice(1, n0 + 1), slice(1, n1 + 1), slice(1, n2 + 1)]
            shift[axis] = slice(1 + step, [n0, n1, n2][axis] + 1 + step)
            beside |= padded[tuple(shift)] == UNKNOWN
    return np.argwhere(((states == FREE) | (states == LOOKED)) & beside)


def _clear_of_unseen(grid: VoxelStates, radius_m: float) -> np.ndarray:
    """Which voxels have every voxel within ``radius_m`` (centre to centre) free: water seen through, all
    round."""
    free = grid.states == FREE
    reach = math.floor(radius_m / grid.size + 1e-9)
    if reach == 0:
        return free
    padded = np.pad(free, reach, constant_values=False)
    clear = free.copy()
    n0, n1, n2 = free.shape
    for offset in np.ndindex(2 * reach + 1, 2 * reach + 1, 2 * reach + 1):
        delta = np.array(offset) - reach
        if delta @ delta * grid.size**2 > radius_m**2 + 1e-12:
            continue
        a, b, c = reach + delta
        clear &= padded[a : a + n0, b : b + n1, c : c + n2]
    return clear


def _ray_directions(params: FrontierParams, pitch: float = 0.0) -> np.ndarray:
    """Unit rays ``(R, 3)`` across the field of view of a camera looking along +x (x forward, y left, z
    up), pitched by ``pitch`` (rad, nose down +)."""
    across = np.tan(np.radians(params.hfov_deg) / 2) * np.linspace(-1, 1, params.rays_across)
    up = np.tan(np.radians(params.vfov_deg) / 2) * np.linspace(-1, 1, params.rays_up)
    a, u = np.meshgrid(across, up, indexing="ij")
    rays = np.stack([np.ones_like(a), a, u], axis=-1).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    # nose down by pitch: the camera's forward axis turns from +x towards -z, about y
    cos, sin = math.cos(pitch), math.sin(pitch)
    return np.column_stack(
        [cos * rays[:, 0] + sin * rays[:, 2], rays[:, 1], cos * rays[:, 2] - sin * rays[:, 0]]
    )


def look_gains(
    grid: VoxelStates, positions: np.ndarray, yaws: np.ndarray, params: FrontierParams, pitch: float = 0.0
) -> np.ndarray:
    """The unknown volume (m^3) each look sees: ``positions`` ``(N, 3)`` by ``yaws`` ``(Y,)`` gives
    ``(N, Y)``, each look pitched by ``pitch`` (rad, nose down +). Each ray is sampled every voxel, from
    half a voxel out, to ``view_range_m``, and ends at its first occupied or outside voxel; an unknown
    voxel counts, if in the grid's ``gain_box``, once per look however many rays reach it."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    yaws = np.asarray(yaws, float).reshape(-1)
    if len(positions) == 0:
        return np.zeros((0, len(yaws)))
    rays = _ray_directions(params, pitch)
    cos, sin = np.cos(yaws), np.sin(yaws)
    # each heading's rays in the world: rotate about z
    world = np.stack(
        [
            cos[:, None] * rays[None, :, 0] - sin[:, None] * rays[None, :, 1],
            sin[:, None] * rays[None, :, 0] + cos[:, None] * rays[None, :, 1],
            np.broadcast_to(rays[None, :, 2], (len(yaws), len(rays))),
        ],
        axis=-1,
    )  # (Y, R, 3)
    # in grid units, with float32 (a few mm at most, on a grid of 15 cm voxels): a ray is sampled every
    # voxel; the grid is padded by the view's range, and samples off it are clipped to its edge
    shape = np.array(grid.states.shape)
    start = (positions / grid.size - grid.origin).astype(np.float32)
    depths = np.arange(0.5, params.view_range_m / grid.size + 1e-9, 1.0, dtype=np.float32)  # (S,)
    samples = (
        start[:, None, None, None, :]
        + depths[None, None, None, :, None] * world.astype(np.float32)[None, :, :, None, :]
    )  # (N, Y, R, S, 3)
    index = np.clip(np.floor(samples).astype(np.int64), 0, shape - 1)
    flat = (index[..., 0] * shape[1] + index[..., 1]) * shape[2] + index[..., 2]
    states = grid.states.ravel()[flat]
    blocked = np.maximum.accumulate(states >= OCCUPIED, axis=-1)  # occupied or outside
    seen_unknown = (states == UNKNOWN) & ~blocked
    if grid.gain_box is not None:
        seen_unknown &= grid.counted().ravel()[flat]
    looks = len(positions) * len(yaws)
    look = np.broadcast_to(np.arange(looks).reshape(len(positions), len(yaws), 1, 1), states.shape)
    # distinct voxels per look: one integer per (look, voxel), then count the unique ones by look
    cells = int(np.prod(shape))
    keys = np.sort(look[seen_unknown] * cells + flat[seen_unknown])
    unique = keys[np.r_[True, keys[1:] != keys[:-1]]] if len(keys) else keys
    counts = np.bincount(unique // cells, minlength=looks)
    return counts.reshape(len(positions), len(yaws)) * grid.size**3


@dataclass(frozen=True)
class Exploration:
    """What one next-look search found (:func:`explore`), and, with no look worth a trip, why.

    views: the looks, rows as :func:`explore_views` returns them; frontier_voxels: the unknown voxels
    bordering seen water in the counted box; stands: the places a look could stand, after every rule;
    best_gain_m3: the largest gain of any look weighed, worth a trip or not (0 when none was weighed);
    why: "" with looks, else what ran out first: "no water seen", "no position" (not finite), "no
    frontier", "no stand" (none clear of the map, the surface, the floor, the teammates and the places
    surveyed), "no stand near the frontier" (none within a cell of it), or "too little to see" (every
    look's gain under ``min_gain_m3``)."""

    views: np.ndarray
    frontier_voxels: int = 0
    stands: int = 0
    best_gain_m3: float = 0.0
    why: str = ""

    def summary(self) -> dict:
        """The search's numbers, for an event or a report (no views)."""
        return {
            "why": self.why,
            "frontier_voxels": self.frontier_voxels,
            "stands": self.stands,
            "best_gain_m3": round(self.best_gain_m3, 4),
        }


def explore_views(
    robot_map: RobotMap,
    position: np.ndarray,
    params: FrontierParams | None = None,
    launch: np.ndarray | None = None,
    teammates: np.ndarray | None = None,
    visited: np.ndarray | None = None,
) -> np.ndarray:
    """The robot's best next looks, best first: rows ``(x, y, z, yaw, pitch, gain_m3, utility)`` (where
    the vehicle's centre stands, the heading to look along and the pitch, rad, nose down +; the gain is
    counted from the centre, a little behind the camera), at most
    ``max_views``, each revealing at least ``min_gain_m3`` (module docstring). ``position`` is the robot's
    own; ``launch`` its launch point (the centre of the region to explore); ``teammates`` rows ``(x, y, z,
    ...)`` where teammates' last messages put them; ``visited`` ``(M, 3)`` the places it surveyed. No row:
    nothing worth a trip is left (:func:`explore` says why)."""
    return explore(robot_map, position, params, launch, teammates, visited).views


def explore(
    robot_map: RobotMap,
    position: np.ndarray,
    params: FrontierParams | None = None,
    launch: np.ndarray | None = None,
    teammates: np.ndarray | None = None,
    visited: np.ndarray | None = None,
) -> Exploration:
    """:func:`explore_views`'s looks, with the numbers that say why there are none (:class:`Exploration`):
    a robot that has explored says what it saw no more of."""
    params = params or FrontierParams()
    empty = np.zeros((0, 7))
    if not robot_map.free_voxels:
        return Exploration(empty, why="no water seen")
    position = np.asarray(position, float).reshape(3)
    if not np.all(np.isfinite(position)):
        return Exploration(empty, why="no position")  # a robot that does not know where it is
    grid = voxel_states(robot_map, params, launch, pad_m=params.view_range_m)
    frontier = grid.centres(_frontier(grid))
    if len(frontier) == 0:
        return Exploration(empty, why="no frontier")
    # where a look could stand: seen water all round, clear of the map and below the surface
    free_index = np.argwhere(_clear_of_unseen(grid, params.free_margin_m))
    stands = grid.centres(free_index)
    points = robot_map.points()
    ok = np.ones(len(stands), bool)
    if len(points):
        nearest, _ = cKDTree(points).query(stands, k=1)
        ok &= nearest >= params.clearance_m
    surface = robot_map.params.surface_z
    if surface is not None:
        ok &= stands[:, 2] <= surface - params.clearance_m
    if params.floor_clearance_m > 0:
        ok &= robot_map.seen_free(stands - [0.0, 0.0, params.floor_clearance_m])
    for others, radius in ((teammates, params.teammate_exclusion_m), (visited, params.visited_exclusion_m)):
        if others is not None and radius > 0:
            rows = np.asarray(others, float)
            if rows.size:
                rows = rows.reshape(len(rows), -1)[:, :3]
                ok &= cKDTree(rows).query(stands, k=1)[0] > radius
    stands = stands[ok]
    found = {"frontier_voxels": len(frontier), "stands": len(stands)}
    if len(stands) == 0:
        return Exploration(empty, **found, why="no stand")
    # each frontier voxel's nearest stand, within a cell; one stand per cell, those beside the most
    # frontier first
    distance, nearest = cKDTree(stands).query(frontier, k=1, distance_upper_bound=params.cell_m)
    nearest = nearest[np.isfinite(distance)]
    if len(nearest) == 0:
        return Exploration(empty, **found, why="no stand near the frontier")
    chosen, votes = np.unique(nearest, return_counts=True)
    cells = np.floor(stands[chosen] / params.cell_m).astype(np.int64)
    order = np.argsort(-votes, kind="stable")
    _, first = np.unique(cells[order], axis=0, return_index=True)
    picked = order[first]
    picked = picked[np.argsort(-votes[picked], kind="stable")][: params.max_candidates]
    candidates = stands[chosen[picked]]
    yaws = np.arange(params.yaws) * (2 * math.pi / params.yaws)
    pitches = np.radians(np.asarray(params.pitches_deg, float))
    # (N, P x Y): pitch by pitch, each with every heading; the first of equal gains wins (level first)
    gains = np.hstack([look_gains(grid, candidates, yaws, params, pitch) for pitch in pitches])
    best = np.argmax(gains, axis=1)
    gain = gains[np.arange(len(candidates)), best]
    utility = gain * np.exp(-np.linalg.norm(candidates - position, axis=1) / params.distance_scale_m)
    worth = gain >= params.min_gain_m3
    heading = np.remainder(yaws[best % len(yaws)] + math.pi, 2 * math.pi) - math.pi
    rows = np.column_stack([candidates, heading, pitches[best // len(yaws)], gain, utility])
    rows = rows[worth]
    rows = rows[np.argsort(-rows[:, 6], kind="stable")]
    best_gain = float(gain.max()) if len(gain) else 0.0
    return Exploration(
        rows[: params.max_views],
        **found,
        best_gain_m3=best_gain,
        why="" if len(rows) else "too little to see",
    )
