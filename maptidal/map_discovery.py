"""Map-aware task discovery for the closed loop (issue [loop]): candidates from the robot's own fused map.

The paper's discovery (:mod:`maptidal.discovery`, Algorithms 1-3, kept exact for ``maptidal discover``)
runs on one keyframe's raw mesh. In the loop that yields tasks from faces that bridge two surfaces, tasks
behind walls or under the floor, and hundreds of near-duplicates of views the team already holds. This
mode keeps the paper's idea (a candidate viewpoint ``standoff`` in front of each mesh face, looking back at
it) and adds five rules, each with its reason:

1. **The robot's own fused map.** :class:`RobotMap` accumulates, keyframe after keyframe, every fused
   landmark of the keyframe (the front end's information-form fusion, so a landmark seen ten times sits
   where its ten observations agree) and the water the camera saw through, and, with ``dense_depth``,
   the keyframe's dense stereo depth (:meth:`RobotMap.add_surface`): a bare wall gives the front end's
   keypoints few landmarks, and the dense depth maps it all the same. Discovery reads that map, not
   one keyframe's faces alone: one keyframe sees a strip of wall; the map holds the wall. A teammate is
   no structure: landmarks and faces about where its last acoustic message put it are left out. Nor is
   the water surface, which the dense depth maps from below: dense points within ``SURFACE_BAND_M``
   (15 cm, the stereo depth error at the 3 m the dense depth reaches) of the depth sensor's datum
   ``surface_z``, or above it, are left out, but for the top of a wall that rises into that band: a
   band point with a point of the 15 cm beneath the band within ``wall_reach_m`` of it horizontally
   is a wall's (:func:`water_surface`). Nor is structure beyond the region the robot was sent to
   inspect: faces farther than ``region_radius_m`` from ``region_centre`` (in the loop, the robot's
   launch point and its exploration radius), or outside the box ``region_box`` (in the loop, the box the
   structure to inspect lies in, the mission's ``inspect_box``) grown by ``plane_tolerance_m`` (the
   map's scatter across a wall), yield no candidate; a glimpse down a long wall is not a task.
2. **Normals from local surface fits.** A face's normal is the smallest principal axis of the map points
   within ``support_radius_m`` of its centroid (the least-squares plane, as in Hoppe et al. 1992,
   "Surface reconstruction from unorganized points"), turned to face the camera that saw the face. One
   face's normal comes from three noisy landmarks; a plane through dozens is steadier. A centroid with
   fewer than ``min_support`` points nearby has no fit and yields no candidate.
3. **No candidates on faces that bridge surfaces.** The fit must be planar: its surface variation
   ``lambda_0 / (lambda_0 + lambda_1 + lambda_2)`` (Pauly et al. 2002, "Efficient simplification of point-
   sampled surfaces") at most ``max_surface_variation``, which a flat patch meets under stereo noise and
   the crease between a wall and the floor does not. And the face itself must lie on that plane: each
   vertex and the centroid within ``plane_tolerance_m`` of it. A face spanning a wall and the floor, or a
   near wall and a far one, has its centroid in open water, off every plane. A face whose ball is not
   planar is fitted again on its own plane (:func:`refit_on_faces`): the support points within
   ``plane_tolerance_m`` of the face's plane, refitted ``refit_iterations`` times to the plane of those
   points, as an iteratively reweighted fit with a hard cut does (Huber 1981, "Robust statistics"). A
   face on a wall within the support radius of the floor, of a ladder or of a window shares its ball
   with them, fails the fit over the whole ball, and has its wall back this way. The refitted plane
   must hold what a surface under stereo noise gives: its points (those within ``plane_tolerance_m``)
   spanning it both ways (middle principal variance at least ``plane_tolerance_m`` squared), and
   gathered near it (``min_band_concentration`` of them within half the tolerance), where the plane of
   a face that bridges a crease cuts both surfaces at an angle and holds their points evenly across the
   band. A face off the plane of a planar ball bridges two surfaces of that ball, and is not retried.
4. **A view the team can fly, in water the robot has seen.** A view steeper than ``max_view_pitch_deg``
   (up or down from level; the mission sets its robots' largest pitch for a view plus the tolerance a
   view is judged by) is dropped: a robot declines a view it cannot pitch to, so such a task would only
   cost the team a round of the auction. A viewpoint is kept only where the robot has seen water:
   its voxel lies between one of its cameras and the keyframe mesh that camera saw (space carving:
   :meth:`RobotMap.carve_view` draws the mesh into a depth image; nothing behind a wall or under the
   floor is ever carved), and so is the voxel ``clearance_m`` beneath it (the floor, seen at a grazing
   angle, has sparse landmarks: a viewpoint a few cm above it can be far from all of them), no landmark
   lies within ``clearance_m`` of it, it is ``clearance_m`` below the
   surface (the depth sensor's datum, ``surface_z``), and no landmark lies on its line of sight to the
   face. No tank model and no simulator truth is read. Water the robot has not yet seen is not free: a
   face seen at a grazing angle waits until the robot has seen the water in front of it. A viewpoint
   that fails is moved straight up or down, its view unchanged, to the nearest height that passes, by
   up to ``max_lift_fraction`` of the view's half-height at the standoff (:func:`lift_into_free`): a
   face near the floor or the water surface has its viewpoint there, where no robot holds station, and
   is looked at from the edge of the water the robot can hold, the face still in the picture.
5. **Views that add little are dropped.** Each candidate sees a set of map points (those in its
   frustum, on a voxel grid of ``coverage_voxel_m``). A greedy cover (the standard greedy algorithm for
   set cover, Chvatal 1979) takes the candidate that sees the most points no view yet covers, the views
   of every task the robot knows (planned, captured or assigned, its own or a teammate's) counting as
   covered, until no candidate adds ``min_new_fraction`` of its own view and ``min_new_points`` points.
   The 0.3 mirrors the paper's confirmation threshold: there a view that holds 75 % of a keyframe's
   keypoints stands for it; here a view that adds under 30 % of its footprint is all but a repeat.
   But not when its own face (the point it looks at from the standoff) is in no view yet, the known
   tasks' or those the cover took: then ``min_new_points`` suffice. A face at the top or the foot of a
   wall has its view lifted away from it (rule 4), and adds only the strip its neighbours' frames stop
   short of, a small share of its footprint; yet no other view holds that face.
   Occlusion is not modelled in this count. Only cells in the region to inspect count (rule 1's box).

Candidates come from the keyframe mesh's faces and, with ``dense_candidates_m`` above 0 (off by
default), from the keyframe's dense depth as well, one per cell of that size, each taken as a face shrunk
to its point: a bare stretch of wall gives the keypoint mesh no face, so no candidate, however well the
dense depth maps it. Since rule 4's lift it leaves no less of the walls uninspected than the default,
for more than twice the tasks (docs/mission.md), so it is off by default.

**A view the team has since taken is retired** (:func:`views_left_to_take`). Rule 5 judges a candidate
against the views the robot knows when it finds it, on the map it has then. By the time a robot comes
to fly a task, the team may have taken views that hold all of it: a teammate's task heard late, or the
robot's own views, each wider in the water than on the map it was planned on. A task whose view holds
fewer than ``min_new_points`` cells of the robot's map (now) that no view taken since covers is retired
before it is flown: it is marked done in the auction, with a ``retired`` event, and no image. Only views
taken count, never those planned, so two open tasks cannot retire each other; and only the cell count,
not rule 5's share, since a view at the top of a wall adds only a strip (rule 5's exception), which the
share would take for a repeat. The mission does this only when asked (``retire_taken``, off by default):
on the map, where occlusion is not counted, the views taken claim more than their images show.

**A repeat of a task found first is retired** (:func:`views_repeated`). Two robots that map the same
stretch of wall before either hears of the other's tasks each find a view of it, and both would be flown:
rule 5 could not count a view the robot did not know. Once a robot knows both, a view is a repeat when a
view a teammate found, of lower key, holds its face and all but under ``min_new_fraction`` of its cells
on the robot's map now (or all but under ``min_new_points``): rule 5's test, against that one view. It
is retired (as above) when the robot comes to it. Keys are ordered (the finder's index, then its own
count), so of two views that repeat each other only the higher is ever dropped, by whichever robot judges
it, and no robot needs to know when a teammate found a task. Views one robot found are not judged
against each other: rule 5 judged each against the robot's own earlier ones when it was found. The
mission does this only when asked (``retire_repeats``, off by default): in the loop the views it retired
held a part of the walls their images would have shown.

Every number is a parameter of :class:`MapAwareParams`; the defaults are chosen by the reasoning given
beside them, not fitted to a tank. Pure numpy and scipy: it runs on a real robot's landmarks as well.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from maptidal.discovery import DiscoveryParams, validate_viewpoints
from maptidal.geometry import frustum_masks

__all__ = [
    "MapAwareParams",
    "MapAwareResult",
    "PointTable",
    "RobotMap",
    "discover_on_map",
    "fit_planes",
    "lift_into_free",
    "lift_offsets",
    "near_teammates",
    "reachable_on_map",
    "refit_on_faces",
    "unpack_voxels",
    "voxel_keys",
    "water_surface",
]


@dataclass(frozen=True)
class MapAwareParams:
    """The map-aware rules' settings (module docstring). Lengths in metres."""

    # The stereo noise sets these. The loop's 320 px images with the OAK-D's 78.5 deg field of view have
    # f = 160 / tan(39.25 deg) = 196 px; with its 7.5 cm baseline and 0.25 px disparity noise
    # (FusionParams) one observation's depth error is z^2 0.25 / (196 x 0.075) = 3.8 cm at 1.5 m and
    # 6.8 cm at 2 m (maptidal.perception.landmarks).
    # - the plane fit's support: a ball of 0.5 m, whose in-plane spread (r^2 / 4 = 0.0625 m^2 per axis on
    #   a disc) makes a flat wall's surface variation 0.0015 / 0.127 = 0.011 at 1.5 m and 0.036 at 2 m,
    #   while a right-angle crease split between its two planes gives about 0.1 at any size (a 0.3 m ball
    #   would give a flat wall 0.09 at 2 m: no longer told from a crease)
    support_radius_m: float = 0.5
    min_support: int = 8
    max_surface_variation: float = 0.05
    # a face's vertices and centroid within 2.5 sigma of one observation's depth noise at 1.5 m
    plane_tolerance_m: float = 0.1
    # space carving: a voxel near the vehicle's half-length (BlueROV2 Heavy, 0.457 m long); rays stop this
    # far short of the landmark they end on, so that the surface's own voxel is not called free
    voxel_m: float = 0.15
    ray_stop_m: float = 0.15
    # how close a viewpoint may come to a mapped surface or the water surface: the loop's reach margin
    clearance_m: float = 0.35
    # a landmark this close to the line of sight blocks it, but for its last stretch at the face
    line_of_sight_radius_m: float = 0.05
    line_of_sight_end_m: float = 0.2
    # rule 5's cover
    coverage_voxel_m: float = 0.1
    min_new_fraction: float = 0.3
    min_new_points: int = 8
    # the water surface's height in the world frame, from the depth sensor's datum (None: not checked)
    surface_z: float | None = None
    # the region the robot was sent to inspect: faces farther than region_radius_m from region_centre
    # (the world frame) yield no candidate (None: everywhere). The mission sets the robot's launch point
    # and its exploration radius (maptidal.exploration.FrontierParams.explore_radius_m), so that the
    # robot inspects the structure it explores, and not what it glimpses beyond
    region_centre: tuple[float, float, float] | None = None
    region_radius_m: float | None = None
    # ... and the box the structure to inspect lies in, as its lowest and highest corners (None: no box):
    # what an operator states of the job, as the baselines are given the walls themselves
    region_box: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    # a teammate is not structure: landmarks and faces within this of where its last message put it are
    # left out, the radius growing by ``teammate_speed_m_s`` for each second the message is old. 0.39 m
    # is half the BlueROV2 Heavy's diagonal (0.457 x 0.575 x 0.254 m, Blue Robotics' technical details);
    # 0.25 m/s is the loop's cruise speed (MissionParams.speed_m_s). The growth stops at
    # ``teammate_max_radius_m`` (our choice): a message ten seconds old would otherwise blank 2.9 m of the
    # map, and the teammate, once it has moved on, shows only as a few faces in the water
    teammate_radius_m: float = 0.39
    teammate_speed_m_s: float = 0.25
    teammate_max_radius_m: float = 1.0
    # how far a camera looking at open water is taken to have looked (RobotMap.looked_voxels): the depth
    # at which one observation's depth error reaches 15 cm (z^2 x 0.25 / (196 x 0.075), 2.9 m), beyond
    # which a surface would give landmarks too rough to map. Where a ray meets no surface this close, the
    # water there was looked at and held nothing to see
    look_range_m: float = 3.0
    # fold each keyframe's dense stereo depth into the map (maptidal.perception.dense; the OAK-D computes
    # it on the camera), so that bare walls, with few keypoints, are mapped too
    dense_depth: bool = True
    # candidates from the keyframe's dense depth as well as from its mesh's faces: one per cell of this
    # size (0: none). A bare stretch of wall gives the keypoint mesh no face, and so no candidate, however
    # well the dense depth maps it; a quarter of the camera's footprint height at the 1 m standoff
    # (2 x 1 m x tan(27 deg) = 1.0 m) gives the greedy cover (rule 5) views to choose from at that grain
    dense_candidates_m: float = 0.0
    # when the robot has no look left worth a trip, candidates from all its map's dense points, one per
    # cell of this size, judged by rules 2 to 5 as a keyframe's are (:func:`gap_views`; 0: none). A wall
    # the dense depth mapped from afar, where the keypoint mesh had no face, has no task otherwise, and,
    # mapped, is worth no look: in the default tank's seeds 7, 8 and 10 a side wall's evaluated strip,
    # held in both robots' maps, was left 5 to 7 points of the walls uninspected so
    gap_candidates_m: float = 0.25
    # rule 3's second try for a face the whole ball's fit refuses (refit_on_faces): how many times the
    # plane is refitted to the support points within plane_tolerance_m of it, starting from the face's
    # own plane (0: no second try). A face's three landmarks, a few cm off each, tilt its plane by some
    # 10 deg; each refit on the points it keeps brings it to their plane, and three are enough for the
    # walls built by hand in the tests to come back within a degree
    refit_iterations: int = 3
    # ... and the refitted plane must hold its points near it: at least this share of the points within
    # plane_tolerance_m of it lie within half that. Stereo noise of up to half the tolerance (5 cm, an
    # observation's depth error at 1.8 m) leaves 0.68 or more there; a band that cuts a surface at an
    # angle (a bridging face's plane across a crease), or a cloud, is filled evenly, 0.5
    min_band_concentration: float = 2.0 / 3.0
    # how near, horizontally, a dense point in the water surface's band must lie to one in the 15 cm
    # beneath the band to be taken for a wall's top (water_surface): the dense depth's scatter across a
    # wall seen at 2 m, its depth error there (6.8 cm, above), fits within it. Along the walls' tops a
    # lip of the surface this wide is kept too (0: the whole band left out)
    wall_reach_m: float = 0.1
    # the steepest view the team can fly, in degrees up or down from level (None: not checked): the
    # mission sets its robots' largest pitch for a view plus the direction tolerance a view is judged
    # by, since a robot declines a view it cannot pitch to (maptidal.mission.verification.pitch_to_fly)
    max_view_pitch_deg: float | None = None
    # a viewpoint that is not in free water (rule 4) may be moved straight up or down, its view unchanged,
    # by up to this fraction of the view's half-height at the standoff (1 m x tan(27 deg) = 0.51 m for the
    # OAK-D: up to 0.38 m), the face then still a quarter of the half-image from the frame's edge. A face
    # near the floor or the water surface has its viewpoint there, closer than ``clearance_m`` to them;
    # moved to where the robot can hold station, the level view still holds the face, as the paper's
    # baselines' top and bottom lanes are flown (0: not moved)
    max_lift_fraction: float = 0.75
    # the lift is tried in steps of this size, smallest first, up before down at each size
    lift_step_m: float = 0.05

    def __post_init__(self) -> None:
        for name in (
            "support_radius_m",
            "max_surface_variation",
            "plane_tolerance_m",
            "voxel_m",
            "coverage_voxel_m",
            "look_range_m",
            "lift_step_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"map-aware {name} must be a positive number, got {value!r}")
        for name in (
            "ray_stop_m",
            "clearance_m",
            "line_of_sight_radius_m",
            "line_of_sight_end_m",
            "teammate_radius_m",
            "teammate_speed_m_s",
            "teammate_max_radius_m",
            "dense_candidates_m",
            "gap_candidates_m",
            "wall_reach_m",
        ):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"map-aware {name} must be a non-negative number, got {value!r}")
        if not (isinstance(self.max_lift_fraction, int | float) and 0.0 <= self.max_lift_fraction <= 1.0):
            raise ValueError(f"map-aware max_lift_fraction must be in [0, 1], got {self.max_lift_fraction!r}")
        if not 0.0 <= self.min_band_concentration <= 1.0:
            raise ValueError(
                f"map-aware min_band_concentration must be in [0, 1], got {self.min_band_concentration!r}"
            )
        if not 0.0 <= self.min_new_fraction <= 1.0:
            raise ValueError(f"map-aware min_new_fraction must be in [0, 1], got {self.min_new_fraction!r}")
        if not (isinstance(self.refit_iterations, int) and self.refit_iterations >= 0):
            raise ValueError(
                f"map-aware refit_iterations must be a whole number >= 0, got {self.refit_iterations!r}"
            )
        if self.min_support < 3 or self.min_new_points < 1:
            raise ValueError("map-aware min_support must be at least 3 and min_new_points at least 1")
        if self.region_radius_m is not None and not (
            isinstance(self.region_radius_m, int | float)
            and math.isfinite(self.region_radius_m)
            and self.region_radius_m > 0
        ):
            raise ValueError(
                f"map-aware region_radius_m must be positive or None, got {self.region_radius_m!r}"
            )
        if self.region_centre is not None and not (
            len(self.region_centre) == 3 and all(math.isfinite(float(c)) for c in self.region_centre)
        ):
            raise ValueError(
                f"map-aware region_centre must be three finite numbers or None, got {self.region_centre!r}"
            )
        if self.region_box is not None:
            check_box(self.region_box, "map-aware region_box")
        if self.surface_z is not None and not math.isfinite(self.surface_z):
            raise ValueError(f"map-aware surface_z must be finite or None, got {self.surface_z!r}")
        if self.max_view_pitch_deg is not None and not 0.0 <= self.max_view_pitch_deg <= 90.0:
            raise ValueError(
                f"map-aware max_view_pitch_deg must be in [0, 90] or None, got {self.max_view_pitch_deg!r}"
            )


SURFACE_BAND_M = 0.15


def check_box(box, name: str) -> None:
    """Check a box given as its lowest and highest corners: two rows of three finite numbers, the first
    no higher than the second on any axis (raises ValueError naming ``name`` otherwise)."""
    try:
        corners = np.asarray(box, float)
    except (TypeError, ValueError):
        corners = np.zeros(0)
    if corners.shape != (2, 3) or not np.isfinite(corners).all() or (corners[0] > corners[1]).any():
        raise ValueError(f"{name} must be [[x, y, z], [x, y, z]], the lowest corner first, got {box!r}")


def in_box(points: np.ndarray, box, margin_m: float = 0.0) -> np.ndarray:
    """Which ``points`` ``(N, 3)`` lie in the ``box`` (lowest and highest corners) grown by ``margin_m``."""
    low, high = (np.asarray(corner, float) for corner in box)
    points = np.asarray(points, float).reshape(-1, 3)
    return np.all((points >= low - margin_m) & (points <= high + margin_m), axis=1)


def water_surface(points: np.ndarray, surface_z: float, wall_reach_m: float) -> np.ndarray:
    """Which of the dense depth's ``points`` ``(N, 3)`` are the water surface seen from below: those
    within ``SURFACE_BAND_M`` of ``surface_z`` (the depth error at the 3 m the dense depth reaches) or
    above it, but for those on a wall that rises into the band. A wall goes on below the band; the
    surface has open water beneath it. So a band point under the datum with one of the same points in
    the ``SURFACE_BAND_M`` just below the band within ``wall_reach_m`` of it horizontally is a wall's,
    and kept: the top 15 cm of the walls, which the band would otherwise leave out of the map, and so
    out of rule 5's count of what is still to be seen. Points over the datum are the surface's mirror
    image of the tank, never structure."""
    points = np.asarray(points, float).reshape(-1, 3)
    band = points[:, 2] >= surface_z - SURFACE_BAND_M
    maybe_wall = np.flatnonzero(band & (points[:, 2] < surface_z))
    beneath = points[~band & (points[:, 2] >= surface_z - 2.0 * SURFACE_BAND_M)]
    if len(maybe_wall) == 0 or len(beneath) == 0 or wall_reach_m <= 0:
        return band
    nearest, _ = cKDTree(beneath[:, :2]).query(points[maybe_wall, :2], distance_upper_bound=wall_reach_m)
    surface = band.copy()
    surface[maybe_wall[np.isfinite(nearest)]] = False  # no neighbour in reach: an infinite distance
    return surface


def voxel_keys(points: np.ndarray, size: float) -> np.ndarray:
    """Integer voxel coordinates ``(N, 3)`` of ``points`` on a grid of ``size`` m."""
    return np.floor(np.asarray(points, float).reshape(-1, 3) / size).astype(np.int64)


def _packed(keys: np.ndarray) -> np.ndarray:
    # one int64 per voxel (21 bits an axis, +-1M voxels): set operations on a 1-D array
    shifted = keys + (1 << 20)
    return (shifted[:, 0] << 42) | (shifted[:, 1] << 21) | shifted[:, 2]


def unpack_voxels(packed) -> np.ndarray:
    """The integer voxel coordinates ``(N, 3)`` of packed voxel keys (as in :attr:`RobotMap.free_voxels`),
    in ascending key order."""
    return _unpacked(np.sort(np.fromiter(packed, np.int64, len(packed))))


def _unpacked(keys: np.ndarray) -> np.ndarray:
    # the integer voxel coordinates (N, 3) of packed keys (_packed), in their order
    mask = (1 << 21) - 1
    return np.column_stack([(keys >> 42) & mask, (keys >> 21) & mask, keys & mask]) - (1 << 20)


# a plane is fitted on at most this many of its ball's points, taken evenly through the ball (every k-th
# in the k-d tree's order, which walks the ball cell by cell): a plane through 256 points under 4 cm of
# noise across a 0.5 m ball is tilted by well under a degree, and the dense depth puts some thousand
# points in a ball, whose moments would take most of a keyframe's discovery time
FIT_POINTS = 256


def _thinned(found: list[int]) -> list[int]:
    """At most FIT_POINTS of a ball's neighbour list, every k-th."""
    return found[:: -(-len(found) // FIT_POINTS)] if len(found) > FIT_POINTS else found


def _group_moments(
    owner: np.ndarray, offsets: np.ndarray, groups: int, weight: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The (weighted) mean ``(G, 3)`` and covariance ``(G, 3, 3)`` of the ``offsets`` of each group,
    ``owner`` giving each row's group: every group at once, by bincount. A group of no weight gets a
    zero mean and covariance."""
    weight = np.ones(len(owner)) if weight is None else np.asarray(weight, float)
    total = np.maximum(np.bincount(owner, weight, groups), 1e-300)
    mean = np.stack([np.bincount(owner, weight * offsets[:, k], groups) for k in range(3)], axis=1)
    mean /= total[:, None]
    covariance = np.empty((groups, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            moment = np.bincount(owner, weight * offsets[:, i] * offsets[:, j], groups) / total
            covariance[:, i, j] = covariance[:, j, i] = moment - mean[:, i] * mean[:, j]
    return mean, covariance


def fit_planes(
    map_points: np.ndarray,
    centres: np.ndarray,
    radius: float,
    min_support: int,
    tree: cKDTree | None = None,
    balls: list | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The least-squares plane of the ``map_points`` within ``radius`` of each of ``centres`` ``(M, 3)``.

    Returns each fit's centroid ``(M, 3)``, unit normal ``(M, 3)`` (the smallest principal axis, sign
    arbitrary), surface variation ``(M,)`` and support count ``(M,)``. A centre with fewer than
    ``min_support`` points has NaN centroid, normal and variation. A ball of more than
    :data:`FIT_POINTS` points is fitted on that many of them, taken evenly through it. ``balls``, the
    neighbour lists of ``tree.query_ball_point(centres, radius)`` when the caller has them already,
    saves the search."""
    map_points = np.asarray(map_points, float).reshape(-1, 3)
    centres = np.asarray(centres, float).reshape(-1, 3)
    out_centroid = np.full((len(centres), 3), np.nan)
    out_normal = np.full((len(centres), 3), np.nan)
    out_variation = np.full(len(centres), np.nan)
    support = np.zeros(len(centres), int)
    if len(map_points) == 0 or len(centres) == 0:
        return out_centroid, out_normal, out_variation, support
    if balls is None:
        balls = (tree or cKDTree(map_points)).query_ball_point(centres, radius, return_sorted=False)
    support[:] = [len(found) for found in balls]
    neighbours = [_thinned(found) for found in balls]
    rows = np.flatnonzero(support >= min_support)
    if len(rows) == 0:
        return out_centroid, out_normal, out_variation, support
    # every fit at once: each neighbour tagged with its fit, its offset from that fit's centre (small
    # numbers, so the moments lose no precision), then the moments by bincount and one stacked eigh
    fitted = np.array([len(neighbours[row]) for row in rows], int)
    owner = np.repeat(np.arange(len(rows)), fitted)
    index = np.concatenate([neighbours[row] for row in rows]).astype(np.intp)
    offsets = map_points[index] - centres[rows][owner]
    mean, covariance = _group_moments(owner, offsets, len(rows))
    values, vectors = np.linalg.eigh(covariance)
    total = values.sum(axis=1)
    out_centroid[rows] = centres[rows] + mean
    out_normal[rows] = vectors[:, :, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        out_variation[rows] = np.where(total > 0, np.maximum(values[:, 0], 0.0) / total, np.nan)
    return out_centroid, out_normal, out_variation, support


def refit_on_faces(
    map_points: np.ndarray,
    triangles: np.ndarray,
    params: MapAwareParams,
    tree: cKDTree | None = None,
    balls: list | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rule 3's second try (module docstring): the plane of each face's own support.

    For each face of ``triangles`` ``(M, 3, 3)``, start from the face's plane, keep the ``map_points``
    within ``support_radius_m`` of its centroid and within ``plane_tolerance_m`` of the plane, and fit
    the plane of those points; ``refit_iterations`` times. Returns each fit's centroid ``(M, 3)``, unit
    normal ``(M, 3)`` (sign arbitrary) and whether it holds ``(M,)``: at least ``min_support`` points
    kept, spanning the plane both ways (middle principal variance at least ``plane_tolerance_m``
    squared), gathered near it (``min_band_concentration`` of them within half the tolerance), and the
    face's corners and centroid within ``plane_tolerance_m`` of it. A face shrunk to a point (a dense
    candidate) starts from the plane of its ``min_support`` nearest map points; a line, or a face with
    NaNs, does not hold. ``balls``, each face centroid's neighbour list
    within ``support_radius_m`` when the caller has them already (:func:`fit_planes`), saves the search."""
    map_points = np.asarray(map_points, float).reshape(-1, 3)
    triangles = np.asarray(triangles, float).reshape(-1, 3, 3)
    centroid_out, normal_out = np.full((len(triangles), 3), np.nan), np.full((len(triangles), 3), np.nan)
    holds = np.zeros(len(triangles), bool)
    if len(triangles) == 0 or len(map_points) < params.min_support or params.refit_iterations <= 0:
        return centroid_out, normal_out, holds
    tolerance = params.plane_tolerance_m
    centres = triangles.mean(axis=1)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    length = np.linalg.norm(cross, axis=1)
    start = np.full((len(triangles), 3), np.nan)  # each face's plane to start from: its own normal
    flat = np.isfinite(cross).all(axis=1) & (length > 1e-12)
    start[flat] = cross[flat] / length[flat, None]
    # a face shrunk to a point (a dense-depth candidate) has no plane of its own: it starts from the
    # plane of its nearest min_support map points, which lie on its own surface however near a crease
    point = np.isfinite(triangles).all(axis=(1, 2)) & (np.ptp(triangles, axis=1).max(axis=1) == 0.0)
    if point.any() and len(map_points) >= params.min_support:
        tree = tree or cKDTree(map_points)
        _, nearest = tree.query(centres[point], k=params.min_support)
        local = map_points[nearest] - map_points[nearest].mean(axis=1, keepdims=True)
        start[point] = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]
    usable = np.flatnonzero(np.isfinite(start).all(axis=1))
    # each ball thinned to FIT_POINTS, as for the first fit
    if balls is None:
        tree = tree or cKDTree(map_points)
        found_in = tree.query_ball_point(centres[usable], params.support_radius_m, return_sorted=False)
    else:
        found_in = [balls[row] for row in usable]
    neighbours = [_thinned(found) for found in found_in]
    sizes = np.array([len(found) for found in neighbours], int)
    rows = usable[sizes >= params.min_support]
    if len(rows) == 0:
        return centroid_out, normal_out, holds
    # every face's ball at once, as in fit_planes: each point tagged with its face, as an offset from
    # the face's centroid
    fits = len(rows)
    owner = np.repeat(np.arange(fits), sizes[sizes >= params.min_support])
    index = np.concatenate([found for found in neighbours if len(found) >= params.min_support])
    offsets = map_points[index.astype(np.intp)] - centres[rows][owner]
    centre = np.zeros((fits, 3))  # each plane's point, in those offsets
    normal = start[rows]
    alive = np.ones(fits, bool)

    def band(plane_centre, plane_normal):
        distance = np.abs(np.einsum("ij,ij->i", offsets - plane_centre[owner], plane_normal[owner]))
        kept = (distance <= tolerance) & alive[owner]
        count = np.bincount(owner, kept, fits)
        return distance, kept, count

    def moments(kept):
        mean, covariance = _group_moments(owner, offsets, fits, kept)
        covariance[~alive] = np.eye(3)  # no fit: kept out of the eigen-solve's way
        return mean, covariance

    for _ in range(params.refit_iterations):
        _, kept, count = band(centre, normal)
        alive &= count >= params.min_support
        centre, covariance = moments(kept)
        normal = np.linalg.eigh(covariance)[1][:, :, 0]
    distance, kept, count = band(centre, normal)
    alive &= count >= params.min_support
    centre, covariance = moments(kept)
    values = np.linalg.eigvalsh(covariance)
    inner = np.bincount(owner, kept & (distance <= 0.5 * tolerance), fits) / np.maximum(count, 1.0)
    corners = np.concatenate([triangles[rows], centres[rows, None]], axis=1) - centres[rows, None]
    on_plane = np.abs(np.einsum("nkj,nj->nk", corners - centre[:, None], normal)).max(axis=1) <= tolerance
    good = alive & (values[:, 1] >= tolerance**2) & (inner >= params.min_band_concentration) & on_plane
    centroid_out[rows[good]] = centres[rows[good]] + centre[good]
    normal_out[rows[good]] = normal[good]
    holds[rows[good]] = True
    return centroid_out, normal_out, holds


def near_teammates(points: np.ndarray, teammates: np.ndarray | None, params: MapAwareParams) -> np.ndarray:
    """Which ``points`` ``(N, 3)`` lie on or about a teammate: ``teammates`` rows ``(x, y, z, age_s)`` are
    where each teammate's last message put it and how old that message is."""
    points = np.asarray(points, float).reshape(-1, 3)
    near = np.zeros(len(points), bool)
    if teammates is None:
        return near
    for x, y, z, age in np.asarray(teammates, float).reshape(-1, 4):
        grown = params.teammate_radius_m + params.teammate_speed_m_s * max(age, 0.0)
        radius = min(grown, max(params.teammate_max_radius_m, params.teammate_radius_m))
        near |= np.linalg.norm(points - [x, y, z], axis=1) <= radius
    return near


class PointTable(Mapping[int, np.ndarray]):
    """Points by integer key, kept as the rows of one growing array: a new key takes the next row, a
    known key keeps its row (as a dict keeps a key's first place), so :meth:`rows` lists the points in
    the order a dict's values would, and reads them as one slice rather than thousands of small arrays.
    Read-only as a mapping; :meth:`put` adds or moves a point."""

    def __init__(self, points: Mapping[int, np.ndarray] | None = None) -> None:
        self._row: dict[int, int] = {}
        self._array = np.zeros((256, 3))
        for key, point in (points or {}).items():
            self.put(key, point)

    def put(self, key: int, point: np.ndarray) -> None:
        """Set ``key``'s point (a copy is kept)."""
        row = self._row.setdefault(key, len(self._row))
        if row == len(self._array):
            self._array = np.concatenate([self._array, np.zeros_like(self._array)])
        self._array[row] = point

    def rows(self) -> np.ndarray:
        """The points ``(N, 3)``, a view valid until the next :meth:`put`."""
        return self._array[: len(self._row)]

    def __getitem__(self, key: int) -> np.ndarray:
        return self._array[self._row[key]].copy()

    def __iter__(self):
        return iter(self._row)

    def __len__(self) -> int:
        return len(self._row)


@dataclass
class RobotMap:
    """One robot's own map: fused landmarks by id, the voxels its cameras have seen through, and the
    voxels they have looked at without meeting a surface.

    :meth:`add_keyframe` folds in a keyframe: the fused positions of the landmarks seen there (a landmark
    seen again moves to its newer, better-fused position) and the rays from the camera to them;
    :meth:`carve_view` carves the water between the camera and the keyframe's mesh, and marks as looked
    at the water in its view, within ``look_range_m``, where no face of the mesh lies (open water, or a
    surface too bare to map: not known to be free, but nothing more to see from there; exploration
    uses it, :mod:`maptidal.exploration`)."""

    params: MapAwareParams = field(default_factory=MapAwareParams)
    landmarks: PointTable = field(default_factory=PointTable)
    free_voxels: set[int] = field(default_factory=set)
    looked_voxels: set[int] = field(default_factory=set)
    # dense stereo depth (maptidal.perception.dense): one point per coverage_voxel_m cell, the latest
    surface: PointTable = field(default_factory=PointTable)
    # points() joined once per change of the map: discovery and exploration ask for it several times a frame
    _stacked: np.ndarray | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # points given as plain mappings are kept as tables
        self.landmarks, self.surface = PointTable(self.landmarks), PointTable(self.surface)

    def add_keyframe(
        self,
        camera_position: np.ndarray,
        seen_ids: np.ndarray,
        seen_points: np.ndarray,
        teammates: np.ndarray | None = None,
    ) -> None:
        """Carve the rays from ``camera_position`` to ``seen_points`` ``(N, 3)`` (the fused positions of
        the landmarks ``seen_ids`` seen at this keyframe) and store those positions. Rows with NaNs are
        skipped, and so are the landmarks on a teammate (``teammates``: :func:`near_teammates`), which is
        no structure."""
        camera = np.asarray(camera_position, float).reshape(3)
        if not np.all(np.isfinite(camera)):
            return  # a lost pose carves nothing rather than carving the wrong water
        seen_points = np.asarray(seen_points, float).reshape(-1, 3)
        seen_ids = np.asarray(seen_ids, int).reshape(-1)
        finite = np.isfinite(seen_points).all(axis=1)
        self._carve(camera, seen_points[finite])
        on_teammate = near_teammates(seen_points, teammates, self.params)
        self._stacked = None
        for landmark, point, skip in zip(seen_ids.tolist(), seen_points, on_teammate.tolist(), strict=True):
            if np.all(np.isfinite(point)) and not skip:
                self.landmarks.put(landmark, point)

    def add_surface(
        self, camera_position: np.ndarray, points: np.ndarray, teammates: np.ndarray | None = None
    ) -> np.ndarray:
        """Fold in a keyframe's dense stereo depth (:func:`maptidal.perception.dense.dense_points`): carve
        the rays from ``camera_position`` to ``points`` ``(N, 3)`` as for landmarks, and keep one point per
        ``coverage_voxel_m`` cell (the latest), so that a bare wall, which gives the front end few
        landmarks, is in the map too. Rows with NaNs, points on a teammate and the water surface (within
        ``SURFACE_BAND_M`` of ``surface_z``) are skipped. Returns the points taken for structure, before
        the thinning to one a cell: what :func:`discover_on_map` takes as ``surface_points``."""
        camera = np.asarray(camera_position, float).reshape(3)
        if not np.all(np.isfinite(camera)):
            return np.zeros((0, 3))
        points = np.asarray(points, float).reshape(-1, 3)
        points = points[np.isfinite(points).all(axis=1)]
        self._carve(camera, points)
        points = points[~near_teammates(points, teammates, self.params)]
        if self.params.surface_z is not None:
            points = points[~water_surface(points, self.params.surface_z, self.params.wall_reach_m)]
        keys = _packed(voxel_keys(points, self.params.coverage_voxel_m)).tolist()
        self._stacked = None
        for key, point in zip(keys, points, strict=True):
            self.surface.put(key, point)
        return points

    def _carve(self, camera: np.ndarray, targets: np.ndarray) -> None:
        if len(targets) == 0:
            return
        offsets = targets - camera
        lengths = np.linalg.norm(offsets, axis=1)
        step = 0.5 * self.params.voxel_m  # half a voxel: no voxel a ray crosses is skipped by much
        reach = np.maximum(lengths - self.params.ray_stop_m, 0.0)
        count = int(np.ceil(reach.max() / step)) + 1
        fractions = np.arange(count) * step
        samples = fractions[None, :] <= reach[:, None]
        directions = offsets / np.maximum(lengths, 1e-9)[:, None]
        points = camera + fractions[None, :, None] * directions[:, None, :]
        keys = _packed(voxel_keys(points[samples], self.params.voxel_m))
        self.free_voxels.update(np.unique(keys).tolist())

    def carve_view(
        self,
        camera_position: np.ndarray,
        rotation: np.ndarray,
        intrinsics,
        mesh_vertices: np.ndarray,
        mesh_faces: np.ndarray,
        cell_px: int = 8,
    ) -> int:
        """Carve the water a camera saw through to its keyframe mesh: every voxel in its view whose pixel
        falls on a mesh face and that lies nearer than the face (less ``ray_stop_m``). ``rotation`` is the
        camera's optical frame in the world (columns: right, down, forward); ``intrinsics`` has ``fx``,
        ``fy``, ``cx``, ``cy``, ``width`` and ``height``. The mesh is drawn into a depth image of
        ``cell_px`` pixel cells, each face at its nearest vertex's depth (so a face never claims water
        beyond itself), the nearest face winning. The voxels in view within ``look_range_m`` whose pixel
        shows no face are added to :attr:`looked_voxels`. Returns how many voxels were carved."""
        camera = np.asarray(camera_position, float).reshape(3)
        rotation = np.asarray(rotation, float).reshape(3, 3)
        vertices = np.asarray(mesh_vertices, float).reshape(-1, 3)
        faces = np.asarray(mesh_faces, int).reshape(-1, 3)
        if len(faces) == 0 or not (np.all(np.isfinite(camera)) and np.all(np.isfinite(rotation))):
            return 0
        local = (vertices - camera) @ rotation  # optical frame: x right, y down, z forward
        depth = local[:, 2]
        usable = np.isfinite(local).all(axis=1) & (depth > 1e-3)
        faces = faces[usable[faces].all(axis=1)]
        if len(faces) == 0:
            return 0
        k = intrinsics
        with np.errstate(divide="ignore", invalid="ignore"):
            u = k.fx * local[:, 0] / depth + k.cx
            v = k.fy * local[:, 1] / depth + k.cy
        cells_w, cells_h = int(np.ceil(k.width / cell_px)), int(np.ceil(k.height / cell_px))
        image = np.zeros((cells_h, cells_w), np.float32)  # 0: no face seen there
        face_depth = depth[faces].min(axis=1)
        for row in np.argsort(-face_depth):  # far to near: the nearest face wins a cell
            # cell i spans pixels [8i, 8i + 8) and OpenCV puts its centre at i: hence the half cell;
            # corners to 1/16 of a cell (shift 4), so that a cell is filled when its centre is inside
            corners = np.column_stack([u[faces[row]], v[faces[row]]]) / cell_px - 0.5
            fixed = np.round(corners * 16).astype(np.int32)
            cv2.fillConvexPoly(image, fixed, float(face_depth[row]), lineType=cv2.LINE_8, shift=4)
        # a cell on the mesh's rim is only partly covered: a 3 x 3 minimum (erosion) leaves it unknown, and
        # gives every cell the nearest depth about it, so that no voxel is carved beyond the mesh
        image = cv2.erode(image, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0)
        # the voxels of the view's bounding box, tested against the depth image
        far = max(float(face_depth.max()), self.params.look_range_m)
        corners = np.array(
            [
                [x, y, 1.0]
                for x in (-k.cx / k.fx, (k.width - k.cx) / k.fx)
                for y in (-k.cy / k.fy, (k.height - k.cy) / k.fy)
            ]
        )
        box = np.vstack([camera, camera + far * corners @ rotation.T])
        size = self.params.voxel_m
        low, high = np.floor(box.min(axis=0) / size), np.floor(box.max(axis=0) / size)
        axes = [np.arange(a, b + 1) for a, b in zip(low, high, strict=True)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        centres = (grid + 0.5) * size
        inside = (centres - camera) @ rotation
        z = inside[:, 2]
        ahead = z > 1e-3
        column = np.full(len(z), -1)
        line = np.full(len(z), -1)
        column[ahead] = np.floor((k.fx * inside[ahead, 0] / z[ahead] + k.cx) / cell_px).astype(int)
        line[ahead] = np.floor((k.fy * inside[ahead, 1] / z[ahead] + k.cy) / cell_px).astype(int)
        in_view = ahead & (column >= 0) & (column < cells_w) & (line >= 0) & (line < cells_h)
        surface = np.zeros(len(z), np.float32)
        surface[in_view] = image[line[in_view], column[in_view]]
        free = in_view & (surface > 0) & (z < surface - self.params.ray_stop_m)
        self.free_voxels.update(_packed(grid[free].astype(np.int64)).tolist())
        # the whole voxel in view and in range, so that a voxel half beyond the range is not called looked
        looked = in_view & (surface == 0) & (z < self.params.look_range_m - size)
        self.looked_voxels.update(_packed(grid[looked].astype(np.int64)).tolist())
        return int(free.sum())

    def points(self) -> np.ndarray:
        """Every landmark's position and every dense surface point ``(N, 3)``: the map's surface."""
        if self._stacked is None:
            self._stacked = np.concatenate([self.landmarks.rows(), self.surface.rows()])
            self._stacked.flags.writeable = False  # shared by every caller until the map changes
        return self._stacked

    def seen_free(self, positions: np.ndarray) -> np.ndarray:
        """Whether each position's voxel was crossed by a ray of the robot's cameras."""
        keys = _packed(voxel_keys(positions, self.params.voxel_m))
        return np.array([key in self.free_voxels for key in keys.tolist()], bool)


@dataclass
class MapAwareResult:
    """What one keyframe gave, and how many candidates each rule removed, in the order they apply."""

    final: np.ndarray
    candidates: int
    no_support: int
    not_planar: int
    bridging: int
    not_free: int
    redundant: int
    too_steep: int = 0
    lifted: int = 0
    refitted: int = 0
    outside: int = 0

    def counts(self) -> dict[str, int]:
        """The candidate counts by rule, for logs and reports."""
        return {
            "candidates": self.candidates,
            "outside": self.outside,
            "no_support": self.no_support,
            "not_planar": self.not_planar,
            "bridging": self.bridging,
            "refitted": self.refitted,
            "too_steep": self.too_steep,
            "not_free": self.not_free,
            "lifted": self.lifted,
            "redundant": self.redundant,
            "final": len(self.final),
        }


def reachable_on_map(
    robot_map: RobotMap, rows: np.ndarray, standoff: float, tree: cKDTree | None = None
) -> np.ndarray:
    """Rule 4: which viewpoint rows ``(N, 6)`` lie in water the robot has seen, with water seen
    ``clearance_m`` beneath them too, clear of its map and of the surface, with no landmark on the line of
    sight to the face ``standoff`` ahead."""
    params = robot_map.params
    rows = np.asarray(rows, float).reshape(-1, 6)
    if len(rows) == 0:
        return np.zeros(0, bool)
    ok = robot_map.seen_free(rows[:, :3])
    # water seen beneath the hull too: the floor is seen at a grazing angle, its landmarks are sparse,
    # and a viewpoint a few cm above it can lie farther than clearance_m from every one of them
    ok &= robot_map.seen_free(rows[:, :3] - [0.0, 0.0, params.clearance_m])
    if params.surface_z is not None:
        ok &= rows[:, 2] <= params.surface_z - params.clearance_m
    points = robot_map.points()
    if len(points) == 0:
        return ok
    tree = tree or cKDTree(points)
    if params.clearance_m > 0:
        nearest, _ = tree.query(rows[:, :3], k=1)
        ok &= nearest >= params.clearance_m
    sight = max(standoff - params.line_of_sight_end_m, 0.0)
    if params.line_of_sight_radius_m > 0 and sight > 0:
        spacing = params.line_of_sight_radius_m
        steps = np.arange(0.0, sight + 1e-9, spacing)
        for row in np.flatnonzero(ok):
            samples = rows[row, :3] + steps[:, None] * rows[row, 3:]
            hits = tree.query_ball_point(samples, params.line_of_sight_radius_m, return_length=True)
            ok[row] = not np.any(hits)
    return ok


def lift_offsets(params: MapAwareParams, discovery: DiscoveryParams) -> np.ndarray:
    """The vertical moves rule 4 tries on a viewpoint not in free water, in order: smallest first, up
    before down, in ``lift_step_m`` steps up to ``max_lift_fraction`` of the view's half-height at the
    standoff."""
    most = params.max_lift_fraction * discovery.standoff * math.tan(math.radians(discovery.vfov_deg / 2.0))
    sizes = np.arange(1, int(most / params.lift_step_m + 1e-9) + 1) * params.lift_step_m
    return np.column_stack([sizes, -sizes]).ravel()


def lift_into_free(
    robot_map: RobotMap, rows: np.ndarray, discovery: DiscoveryParams, tree: cKDTree | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Rule 4's free water, with the lift: each viewpoint row ``(N, 6)`` that
    :func:`reachable_on_map` refuses is moved straight up or down by the first of :func:`lift_offsets`
    that it accepts, its view direction unchanged. Returns the rows (moved where lifted), which of them are
    free, and how many were lifted."""
    rows = np.array(rows, float).reshape(-1, 6)
    free = reachable_on_map(robot_map, rows, discovery.standoff, tree)
    lifted = 0
    for offset in lift_offsets(robot_map.params, discovery):
        waiting = np.flatnonzero(~free)
        if len(waiting) == 0:
            break
        moved = rows[waiting].copy()
        moved[:, 2] += offset
        now_free = reachable_on_map(robot_map, moved, discovery.standoff, tree)
        rows[waiting[now_free]] = moved[now_free]
        free[waiting[now_free]] = True
        lifted += int(now_free.sum())
    return rows, free, lifted


def coverage_cells(points: np.ndarray, params: MapAwareParams) -> np.ndarray:
    """The centres of the ``coverage_voxel_m`` cells that hold map ``points``, rule 5's count: those in
    the region to inspect (``region_box``, grown as rule 1 grows it), since structure outside it is no
    one's job, and a view is not new for showing it."""
    # unique on the packed keys: the order of np.unique(axis=0), at a fraction of its cost
    keys = _unpacked(np.unique(_packed(voxel_keys(points, params.coverage_voxel_m))))
    cells = (keys + 0.5) * params.coverage_voxel_m
    if params.region_box is not None:
        cells = cells[in_box(cells, params.region_box, params.plane_tolerance_m)]
    return cells


def _covered(rows: np.ndarray, cells: np.ndarray, camera) -> np.ndarray:
    # which coverage cells any of ``rows`` sees
    seen = np.zeros(len(cells), bool)
    for mask in frustum_masks(rows, cells, camera):
        seen |= mask
    return seen


def discover_on_map(
    robot_map: RobotMap,
    vertices: np.ndarray,
    faces: np.ndarray,
    camera_position: np.ndarray,
    existing: np.ndarray | None = None,
    discovery: DiscoveryParams | None = None,
    teammates: np.ndarray | None = None,
    surface_points: np.ndarray | None = None,
    candidate_cell_m: float | None = None,
) -> MapAwareResult:
    """Map-aware discovery (module docstring) on a keyframe mesh ``vertices`` ``(V, 3)``, ``faces``
    ``(F, 3)``, seen from ``camera_position``, with the ``existing`` task rows ``(N, 6)`` the robot knows.
    ``surface_points`` ``(M, 3)``, the keyframe's dense depth as :meth:`RobotMap.add_surface` kept it,
    give candidates too, one per ``dense_candidates_m`` cell, each taken as a face shrunk to the point.
    ``robot_map`` must already hold this keyframe (:meth:`RobotMap.add_keyframe`). The candidate standoff
    and the view's frustum are ``discovery``'s (the paper's ``L_i`` and the OAK-D's field of view). Faces
    on a teammate (``teammates``, :func:`near_teammates`) count as having no support.
    ``candidate_cell_m`` stands in for ``dense_candidates_m`` (:func:`gap_views`)."""
    params = robot_map.params
    cell_m = params.dense_candidates_m if candidate_cell_m is None else candidate_cell_m
    discovery = discovery or DiscoveryParams()
    existing_rows = validate_viewpoints([] if existing is None else existing, "existing tasks")
    vertices = np.asarray(vertices, float).reshape(-1, 3)
    faces = np.asarray(faces, int).reshape(-1, 3)
    triangles = vertices[faces]
    if surface_points is not None and cell_m > 0:
        spots = np.asarray(surface_points, float).reshape(-1, 3)
        spots = spots[np.isfinite(spots).all(axis=1)]  # NaN has no voxel key
        _, first = np.unique(voxel_keys(spots, cell_m), axis=0, return_index=True)
        spots = spots[np.sort(first)]
        triangles = np.concatenate([triangles, np.repeat(spots[:, None, :], 3, axis=1)])
    if len(triangles) == 0:
        return MapAwareResult(np.zeros((0, 6)), 0, 0, 0, 0, 0, 0)
    good = np.isfinite(triangles).all(axis=(1, 2))
    triangles = triangles[good]
    candidates = len(triangles)
    outside = 0
    if params.region_radius_m is not None and params.region_centre is not None:
        # rule 1: only the structure the robot was sent to inspect
        offsets = triangles.mean(axis=1) - np.asarray(params.region_centre, float)
        inside = np.einsum("ij,ij->i", offsets, offsets) <= params.region_radius_m**2
        outside = int((~inside).sum())
        triangles = triangles[inside]
    if params.region_box is not None:
        inside = in_box(triangles.mean(axis=1), params.region_box, params.plane_tolerance_m)
        outside += int((~inside).sum())
        triangles = triangles[inside]
    centres = triangles.mean(axis=1)
    points = robot_map.points()
    if len(points) == 0 or len(triangles) == 0:
        return MapAwareResult(np.zeros((0, 6)), candidates, len(triangles), 0, 0, 0, 0, outside=outside)
    tree = cKDTree(points)
    # rule 2: the local plane at each face
    balls = tree.query_ball_point(centres, params.support_radius_m, return_sorted=False)
    fit_centre, normal, variation, _ = fit_planes(
        points, centres, params.support_radius_m, params.min_support, tree, balls
    )
    supported = np.isfinite(variation) & ~near_teammates(centres, teammates, params)
    # rule 3: planar, and the face on the plane
    planar = supported & (variation <= params.max_surface_variation)
    on_plane = np.zeros(len(triangles), bool)
    rows_planar = np.flatnonzero(planar)
    if len(rows_planar):
        corners = np.concatenate([triangles[rows_planar], centres[rows_planar, None]], axis=1)
        offsets = np.einsum("nkj,nj->nk", corners - fit_centre[rows_planar, None], normal[rows_planar])
        on_plane[rows_planar] = np.abs(offsets).max(axis=1) <= params.plane_tolerance_m
    not_planar = int((supported & ~planar).sum())
    bridging = int((planar & ~on_plane).sum())
    # rule 3's second try: a face in a ball that is not planar, fitted again on its own plane. A face
    # off a planar ball's plane bridges two surfaces that ball holds, and has no second try
    retry = np.flatnonzero(supported & ~planar)
    refit_centre, refit_normal, holds = refit_on_faces(
        points, triangles[retry], params, tree, [balls[row] for row in retry]
    )
    rescued = retry[holds]
    fit_centre[rescued], normal[rescued] = refit_centre[holds], refit_normal[holds]
    on_plane[rescued] = True
    # the normal faces the camera that saw the face
    towards = np.asarray(camera_position, float).reshape(3) - centres
    flip = np.einsum("ij,ij->i", normal, towards) < 0
    normal[flip] *= -1.0
    # the candidate looks at the face's centroid projected onto its plane, from standoff along the normal
    surface = centres - np.einsum("ij,ij->i", centres - fit_centre, normal)[:, None] * normal
    kept = np.flatnonzero(on_plane)
    rows = np.hstack([surface[kept] + discovery.standoff * normal[kept], -normal[kept]])
    # rule 4: a view the team can fly ...
    too_steep = 0
    if params.max_view_pitch_deg is not None:
        flyable = np.abs(rows[:, 5]) <= math.sin(math.radians(params.max_view_pitch_deg)) + 1e-12
        too_steep = int((~flyable).sum())
        rows = rows[flyable]
    # ... in water the robot has seen, moved up or down into it if need be
    # each view's own face: where it looks from the standoff, before the lift moves it
    looked_at = rows[:, :3] + discovery.standoff * rows[:, 3:]
    rows, free, lifted = lift_into_free(robot_map, rows, discovery, tree)
    rows, looked_at = rows[free], looked_at[free]
    # rule 5: a greedy cover of the map's cells, the known tasks' views counting as covered
    redundant_before = len(rows)
    final = np.zeros((0, 6))
    if len(rows):
        cells = coverage_cells(points, params)
        camera = discovery.camera
        covered = _covered(existing_rows, cells, camera) if len(existing_rows) else np.zeros(len(cells), bool)
        sees = np.stack(list(frustum_masks(rows, cells, camera)))
        footprint = sees.sum(axis=1)
        # a face no view holds yet: its candidate is kept for less than min_new_fraction
        face_in_view = np.stack(list(frustum_masks(rows, looked_at, camera)))
        face_seen = np.zeros(len(rows), bool)
        if len(existing_rows):
            face_seen = _covered(existing_rows, looked_at, camera)
        chosen: list[int] = []
        while True:
            new = (sees & ~covered).sum(axis=1)
            fraction = np.where(footprint > 0, new / np.maximum(footprint, 1), 0.0)
            needed = (fraction >= params.min_new_fraction) | ~face_seen
            eligible = (new >= params.min_new_points) & needed
            if not eligible.any():
                break
            best = int(np.argmax(np.where(eligible, new, -1)))
            chosen.append(best)
            covered |= sees[best]
            face_seen |= face_in_view[best]
        final = rows[chosen]
    return MapAwareResult(
        final=final,
        candidates=candidates,
        no_support=int((~supported).sum()),
        not_planar=not_planar - len(rescued),
        bridging=bridging,
        not_free=int((~free).sum()),
        redundant=redundant_before - len(final),
        too_steep=too_steep,
        lifted=lifted,
        refitted=len(rescued),
        outside=outside,
    )


def gap_views(
    robot_map: RobotMap,
    position: np.ndarray,
    existing: np.ndarray | None = None,
    discovery: DiscoveryParams | None = None,
    teammates: np.ndarray | None = None,
) -> MapAwareResult:
    """Views of what the robot's map holds that no known task's view holds: candidates from all the map's
    dense points, one per ``gap_candidates_m`` cell, judged by rules 1 to 5 as a keyframe's faces are
    (:func:`discover_on_map`), the known tasks ``existing`` counting as covered. ``position``, where the
    robot is, turns each plane's normal towards it, as a keyframe's camera does: from inside a tank, every
    wall faces it. Asked once a robot has no look left worth a trip. None with ``gap_candidates_m`` 0."""
    cell_m = robot_map.params.gap_candidates_m
    if cell_m <= 0 or len(robot_map.surface) == 0:
        return MapAwareResult(np.zeros((0, 6)), 0, 0, 0, 0, 0, 0)
    empty = np.zeros((0, 3))
    return discover_on_map(
        robot_map,
        empty,
        empty.astype(int),
        position,
        existing,
        discovery,
        teammates=teammates,
        surface_points=robot_map.surface.rows(),
        candidate_cell_m=cell_m,
    )


def views_left_to_take(
    robot_map: RobotMap, rows: np.ndarray, taken: np.ndarray, discovery: DiscoveryParams | None = None
) -> np.ndarray:
    """Which of the views ``rows`` ``(N, 6)`` still hold at least ``min_new_points`` cells of the robot's
    map (on the ``coverage_voxel_m`` grid, as rule 5 counts them) that none of the views ``taken``
    ``(K, 6)`` holds (module docstring, "A view the team has since taken is retired"). On an empty map,
    every view is left to take: nothing says it is not."""
    params = robot_map.params
    discovery = discovery or DiscoveryParams()
    rows = validate_viewpoints(rows, "views to review").reshape(-1, 6)
    taken = validate_viewpoints(taken, "views taken").reshape(-1, 6)
    points = robot_map.points()
    if len(rows) == 0 or len(taken) == 0 or len(points) == 0:
        return np.ones(len(rows), bool)
    cells = coverage_cells(points, params)
    covered = _covered(taken, cells, discovery.camera)
    left = np.array([int((sees & ~covered).sum()) for sees in frustum_masks(rows, cells, discovery.camera)])
    return left >= params.min_new_points


def views_repeated(
    robot_map: RobotMap,
    rows: np.ndarray,
    row_keys: np.ndarray,
    known: np.ndarray,
    known_keys: np.ndarray,
    discovery: DiscoveryParams | None = None,
) -> np.ndarray:
    """Which of the views ``rows`` ``(N, 6)``, keyed ``row_keys``, repeat one of the views ``known``
    ``(K, 6)`` that a teammate found and that has a lower key (``known_keys``; a key's finder is
    :func:`maptidal.allocation.tasks.task_key`'s origin, its bits above the 16th): that view holds the
    view's own face (where it looks at from the standoff) and all but under ``min_new_fraction`` of its
    cells on the robot's map now, or all but under ``min_new_points`` of them. Rule 5 would have dropped
    it for that one view, had its finder known it (module docstring, "A repeat of a task found first is
    retired"). Only the lower key stands for the other, so of two views that repeat each other only one
    is ever dropped, whichever robot judges them. A view that holds under ``min_new_points`` cells of the
    map now is not judged: nothing on the map says it is a repeat."""
    params = robot_map.params
    discovery = discovery or DiscoveryParams()
    rows = validate_viewpoints(rows, "views to review").reshape(-1, 6)
    known = validate_viewpoints(known, "known views").reshape(-1, 6)
    row_keys = np.asarray(row_keys, np.int64).reshape(-1)
    known_keys = np.asarray(known_keys, np.int64).reshape(-1)
    if len(row_keys) != len(rows) or len(known_keys) != len(known):
        raise ValueError("views_repeated: one key per view")
    repeated = np.zeros(len(rows), bool)
    points = robot_map.points()
    if len(rows) == 0 or len(known) == 0 or len(points) == 0:
        return repeated
    cells = coverage_cells(points, params)
    if len(cells) == 0:
        return repeated
    camera = discovery.camera
    # which known view may stand for which view: found by another robot, with a lower key
    finder, row_finder = known_keys >> 16, row_keys >> 16
    stands_for = (known_keys[:, None] < row_keys[None, :]) & (finder[:, None] != row_finder[None, :])
    if not stands_for.any():
        return repeated
    faces = rows[:, :3] + discovery.standoff * rows[:, 3:]
    face_in_known = np.stack(list(frustum_masks(known, faces, camera)))  # (K, N)
    stands_for &= face_in_known
    if not stands_for.any():
        return repeated
    known_sees = np.stack(list(frustum_masks(known, cells, camera)))  # (K, cells)
    for i, row_sees in enumerate(frustum_masks(rows, cells, camera)):
        footprint = int(row_sees.sum())
        if footprint < params.min_new_points or not stands_for[:, i].any():
            continue
        new = (row_sees[None, :] & ~known_sees[stands_for[:, i]]).sum(axis=1)
        little = (new < params.min_new_points) | (new < params.min_new_fraction * footprint)
        repeated[i] = bool(little.any())
    return repeated
