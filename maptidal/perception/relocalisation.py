"""Relocalisation against the robot's own map (issue [truthful-loop]): what keeps a robot without a DVL
localised for a whole mission, where frame-to-frame odometry drifts without bound.

- **Anchors.** The map is a set of world-frame *anchor* points, each with the descriptor of the
  keypoint it was made from (upright SIFT over a window scaled by the keypoint's stereo depth, so that
  it covers the same patch of wall, ``support_m``, seen from near or far) and the standard deviation of
  the frame's position when it was made. An anchor is made from a keypoint whose stereo point lies
  between ``min_depth_m`` and ``max_depth_m`` (farther, the stereo depth error grows past a few cm:
  ``z^2 sigma_d / (f b)``), at the frame's pose, where no anchor projects within ``spacing_px``, or
  where every one that does is much less sure (it takes their place). Anchors never move: the map keeps
  where the robot first put a place, so that revisiting it brings the estimate back to that moment's
  error instead of carrying the drift on: the relocalisation of ORB-SLAM, or Kimera's loop closure, in
  its simplest form. Its error is the error of the frames that made the anchors.
- **Matching.** The anchors are projected with the frame's predicted pose; each keypoint takes the
  anchor of the nearest descriptor (Euclidean distance) among those projected within
  ``search_radius_px`` of it, when that distance is at most ``max_distance`` and passes Lowe's ratio
  test, one keypoint per anchor.
- **The fix.** The attitude is the autopilot's (gravity and the compass hold it within a degree), so
  only the camera centre is unknown, and each match says that the anchor lies on the keypoint's ray:
  ``(I - b b^T)(X - c) = 0`` for the ray's unit world bearing ``b``. Two matches fix the centre; RANSAC
  over pairs keeps the matches that reproject within ``reprojection_px``, and the centre is the least
  squares solution over them, ``c = (sum P_i)^-1 sum P_i X_i`` with ``P_i = I - b_i b_i^T`` (tested
  against a brute-force search). Every hypothesis is solved and scored at once, the pairs drawn one at a
  time, so that a random stream gives the same fix as hypothesis by hypothesis. A planar wall, which
  lets six-degree-of-freedom PnP trade rotation for translation, cannot fool a solve that knows the
  rotation.
- **Refusals.** A fix needs ``min_inliers`` inliers, a well-conditioned geometry (the rays' spread,
  ``min_ray_spread``), a centre within ``max_correction_m`` of the prediction and, as a Kalman filter
  gates an innovation, within ``gate`` standard deviations of it (the prediction's and the fix's
  together, horizontally); otherwise the frame goes without one (and counts why). The bound in metres
  stays however unsure the prediction: a wrong fix let through by a bound of three standard
  deviations alone once threw a robot's estimate 18 m off.
- **Lost.** A robot whose prediction has grown unsure past ``global_sigma_m`` (it has gone long
  without a fix, or a wrong one put it far off) and finds no fix near it searches: the guided match
  from predictions moved over a horizontal grid (``global_step_m``, out to
  ``max_global_correction_m``), and the fix with the most inliers, at least ``global_min_inliers``. A
  descriptor match against the whole map instead found 0 to 3 matches a frame in the painted tank (a
  near twin for nearly every keypoint fails Lowe's test), and a robot 90 cm off stayed so. A robot
  still lost widens the search one ring of the grid per search, out to ``max_lost_search_m``, then
  starts over: a robot without a DVL pushed while in contact runs its motion model on while blocked, and
  ends farther off than the first search reaches, and than its standard deviation says. A search
  works out each keypoint's descriptor distance to every anchor once, for its whole grid, and matches
  each prediction from those at once: the same matches as keypoint by keypoint, to the bit.

OpenCV (SIFT descriptors), numpy and scipy only.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections import Counter
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from maptidal.perception.recording import CameraIntrinsics, CameraPose


@dataclass(frozen=True)
class RelocalisationParams:
    """Matching, fix and map settings (module docstring)."""

    enabled: bool = True
    # the surface patch a descriptor's window scale stands for: 2 cm, a 4 px SIFT scale at 1 m and
    # f = 196 px (its histogram window is some six scales across: 12 cm of wall)
    support_m: float = 0.02
    # the search radius: three of the prediction's standard deviations seen at 1 m, within these bounds
    min_search_radius_px: float = 15.0
    max_search_radius_px: float = 80.0
    # a fix's own error beside its anchors' (the mean of their variances): 2 cm
    fix_sigma_m: float = 0.02
    max_distance: float = 250.0  # SIFT descriptors have norm 512
    ratio: float = 0.9
    reprojection_px: float = 4.0  # 4 px at f = 196 px and 1 m: a 2 cm error in an anchor
    min_inliers: int = 8
    min_inlier_ratio: float = 0.3
    ransac_iterations: int = 64
    min_ray_spread: float = 0.15  # rad: the rays' angular spread, below it the centre is ill-fixed
    max_correction_m: float = 0.6
    # a robot this unsure of its position that finds no fix near its prediction searches a grid of
    # predictions about it, and takes the fix with the most inliers, at least global_min_inliers
    # (Kimera's 20 for PnP)
    global_sigma_m: float = 0.3
    global_min_inliers: int = 20
    global_step_m: float = 0.3  # the guided search at each point covers some 80 px, 0.4 m at 1 m
    max_global_correction_m: float = 1.2
    # a robot still lost after that search widens it: each further search tries one more square ring of
    # global_step_m beyond it, out to this far, then starts over. Not out to three of its standard
    # deviations: a robot without a DVL pushed while in contact runs its motion model on while blocked,
    # and its standard deviation does not know it. In the default mission (seed 0, dense candidates)
    # one ended 1.3 to 2 m off believing itself within 9 cm, and stayed lost for 360 s
    max_lost_search_m: float = 2.4
    # the search (80 guided matches) runs on one frame in this many: on every frame it slowed a mission
    # whose robot was lost for long from 14x to 5.6x real time
    search_every_frames: int = 3
    # the innovation gate, in standard deviations of the fix's difference from the prediction: 3.03 is
    # chi-square's 99 % for two degrees of freedom (the horizontal position), as sqrt(9.21)
    gate: float = 3.03
    min_depth_m: float = 0.3
    max_depth_m: float = 2.0
    spacing_px: float = 8.0
    # a frame makes anchors only while its position is this sure: a map made from drifted frames would
    # hold the robot to its drift
    max_anchor_sigma_m: float = 0.05
    max_anchors: int = 40000

    def __post_init__(self) -> None:
        checks = {
            "support_m": self.support_m > 0,
            "search radius": 0 < self.min_search_radius_px <= self.max_search_radius_px,
            "fix_sigma_m": self.fix_sigma_m > 0,
            "max_distance": self.max_distance > 0,
            "ratio": 0 < self.ratio <= 1,
            "reprojection_px": self.reprojection_px > 0,
            "min_inliers": self.min_inliers >= 3,
            "min_inlier_ratio": 0 <= self.min_inlier_ratio <= 1,
            "ransac_iterations": self.ransac_iterations >= 1,
            "min_ray_spread": self.min_ray_spread >= 0,
            "max_correction_m": self.max_correction_m > 0,
            "gate": self.gate > 0,
            "global search": self.global_sigma_m > 0
            and self.global_min_inliers >= self.min_inliers
            and self.global_step_m > 0
            and self.search_every_frames >= 1
            and self.max_global_correction_m >= self.global_step_m
            and self.max_lost_search_m >= self.max_global_correction_m,
            "depth band": 0 < self.min_depth_m < self.max_depth_m,
            "spacing_px": self.spacing_px >= 0,
            "max_anchor_sigma_m": self.max_anchor_sigma_m > 0,
            "max_anchors": self.max_anchors >= 0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ValueError(f"relocalisation: out of range: {', '.join(bad)}")


@dataclass(frozen=True)
class Fix:
    """A relocalisation: the camera centre (world, m), its standard deviation (m: the inlier anchors'
    and the fix's own, module docstring), the inlier matches' count and the anchors they matched."""

    centre: np.ndarray
    sigma_m: float
    inliers: int
    anchors: np.ndarray


def describe(
    gray: np.ndarray, pixels: np.ndarray, depths: np.ndarray, intrinsics: CameraIntrinsics, support_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Upright SIFT descriptors ``(N, 128)`` of ``gray`` at ``pixels`` ``(N, 2)``, each over a window
    scaled to the keypoint's stereo depth (``depths``, m) so that it covers the same ``support_m`` of the
    surface from near and far, and which keypoints have one ``(N,)`` (none without a depth)."""
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    depths = np.asarray(depths, float).reshape(-1)
    descriptors = np.zeros((len(pixels), 128), np.float32)
    valid = np.zeros(len(pixels), bool)
    rows = np.flatnonzero(np.isfinite(depths) & (depths > 0))
    if not len(rows):
        return descriptors, valid
    sizes = np.clip(intrinsics.fx * support_m / depths[rows], 1.5, 24.0)
    keypoints = [
        cv2.KeyPoint(float(pixels[row, 0]), float(pixels[row, 1]), float(size), 0.0, 0, 0, int(row))
        for row, size in zip(rows.tolist(), sizes.tolist(), strict=True)
    ]
    kept, computed = _SIFT.compute(gray, keypoints)
    if computed is not None and len(kept):
        found = np.array([k.class_id for k in kept], int)
        descriptors[found], valid[found] = computed, True
    return descriptors, valid


_SIFT = cv2.SIFT_create()


def descriptor_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distances of descriptor rows ``a`` ``(N, 128)`` to ``b`` ``(1 or N, 128)``."""
    return np.linalg.norm(np.asarray(a, np.float32) - np.asarray(b, np.float32), axis=-1)


def bearings(pixels: np.ndarray, rotation: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Unit world-frame rays ``(N, 3)`` through ``pixels`` of a camera with optical-to-world ``rotation``."""
    pixels = np.asarray(pixels, float).reshape(-1, 2)
    rays = np.column_stack(
        [
            (pixels[:, 0] - intrinsics.cx) / intrinsics.fx,
            (pixels[:, 1] - intrinsics.cy) / intrinsics.fy,
            np.ones(len(pixels)),
        ]
    )
    rays = rays @ np.asarray(rotation, float).T
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def centre_from_rays(points: np.ndarray, rays: np.ndarray) -> np.ndarray | None:
    """The point nearest, in least squares, to every line through ``points[i]`` along unit ``rays[i]``
    (module docstring); None when the lines are (nearly) parallel."""
    projectors = np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]
    normal = projectors.sum(axis=0)
    if np.linalg.cond(normal) > 1e8:
        return None
    return np.linalg.solve(normal, np.einsum("nij,nj->i", projectors, points))


def project(
    points: np.ndarray, centre: np.ndarray, rotation: np.ndarray, intrinsics: CameraIntrinsics
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 2)`` and depths ``(N,)`` of world ``points`` seen by a camera at ``centre`` with
    optical-to-world ``rotation``."""
    camera = (np.asarray(points, float).reshape(-1, 3) - centre) @ np.asarray(rotation, float)
    depth = camera[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * camera[:, 0] / depth + intrinsics.cx
        v = intrinsics.fy * camera[:, 1] / depth + intrinsics.cy
    return np.column_stack([u, v]), depth


def locate(
    points: np.ndarray,
    pixels: np.ndarray,
    rotation: np.ndarray,
    intrinsics: CameraIntrinsics,
    params: RelocalisationParams,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The camera centre from world ``points`` ``(N, 3)`` seen at ``pixels`` ``(N, 2)`` with a known
    ``rotation``, by RANSAC over pairs (module docstring): (centre, inlier mask), or None."""
    n = len(points)
    if n < max(params.min_inliers, 2):
        return None
    rays = bearings(pixels, rotation, intrinsics)
    # every hypothesis at once (the pairs drawn as one at a time, so that the same random stream gives
    # the same pairs): the same centres, inliers and choice as hypothesis by hypothesis, to the bit
    pairs = np.array([rng.choice(n, 2, replace=False) for _ in range(params.ransac_iterations)])
    paired = rays[pairs]  # (hypotheses, 2, 3)
    projectors = np.eye(3)[None, None] - paired[..., :, None] * paired[..., None, :]
    normals = projectors.sum(axis=1)
    fixed = np.flatnonzero(~(np.linalg.cond(normals) > 1e8))  # centre_from_rays' refusal
    best: np.ndarray | None = None
    if len(fixed):
        right = np.einsum("bnij,bnj->bi", projectors[fixed], points[pairs[fixed]])
        centres = np.linalg.solve(normals[fixed], right[..., None])[..., 0]
        inliers = _inliers_of_each(points, pixels, centres, rotation, intrinsics, params.reprojection_px)
        best = inliers[int(np.argmax(inliers.sum(axis=1)))]  # the first of the most inliers
    if best is None or best.sum() < max(params.min_inliers, params.min_inlier_ratio * n):
        return None
    centre = None
    for _ in range(2):  # least squares on the inliers, then once more on the inliers of that
        centre = centre_from_rays(points[best], rays[best])
        if centre is None:
            return None
        refined = _inliers(points, pixels, centre, rotation, intrinsics, params.reprojection_px)
        if refined.sum() < params.min_inliers:
            return None
        best = refined
    return centre, best


def _inliers(points, pixels, centre, rotation, intrinsics, threshold_px: float) -> np.ndarray:
    """Which ``points`` a camera at ``centre`` sees in front of it within ``threshold_px`` of their
    ``pixels``."""
    return _inliers_of_each(
        points, pixels, np.asarray(centre, float)[None], rotation, intrinsics, threshold_px
    )[0]


def _inliers_of_each(points, pixels, centres, rotation, intrinsics, threshold_px: float) -> np.ndarray:
    """:func:`_inliers` of each of ``centres`` ``(B, 3)``: a mask ``(B, N)``, every centre at once."""
    pixels = np.asarray(pixels, float)
    camera = (np.asarray(points, float)[None] - centres[:, None]) @ np.asarray(rotation, float)
    depth = camera[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * camera[..., 0] / depth + intrinsics.cx
        v = intrinsics.fy * camera[..., 1] / depth + intrinsics.cy
    error = np.linalg.norm(np.stack([u, v], axis=-1) - pixels[None], axis=2)
    return (depth > 0) & (error <= threshold_px)


def ray_spread(rays: np.ndarray) -> float:
    """The rays' angular spread (rad): the root-mean-square angle from their mean direction."""
    mean = rays.mean(axis=0)
    mean /= np.linalg.norm(mean)
    return float(np.sqrt(np.mean(np.arccos(np.clip(rays @ mean, -1.0, 1.0)) ** 2)))


def _nearest_matches(
    rows: np.ndarray, neighbours, visible: np.ndarray, distances: np.ndarray, params: RelocalisationParams
) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`AnchorMap.match`'s choice, for every keypoint at once, from the descriptor distances of
    every keypoint to every anchor (:meth:`AnchorMap.all_distances`): keypoint row ``rows[i]`` takes,
    among its candidate anchors ``visible[neighbours[i]]``, the nearest (the first such candidate on a
    tie), when that distance is at most ``max_distance`` and under ``ratio`` times the second nearest;
    an anchor taken by several keypoints keeps the nearest (the earlier row on a tie). The same answer
    as the per-keypoint loop (a test checks it on random ties), without a Python step per keypoint."""
    empty = np.zeros(0, int), np.zeros(0, int)
    counts = np.fromiter((len(near) for near in neighbours), int, len(rows))
    owners = np.flatnonzero(counts)
    if not len(owners):
        return empty
    candidates = visible[np.fromiter(itertools.chain.from_iterable(neighbours), int, int(counts.sum()))]
    group = np.repeat(np.arange(len(owners)), counts[owners])
    pair = distances[rows[owners][group], candidates]
    starts = np.r_[0, np.cumsum(counts[owners])[:-1]]
    first = np.minimum.reduceat(pair, starts)
    at_minimum = np.flatnonzero(pair == first[group])
    _, first_of_group = np.unique(group[at_minimum], return_index=True)
    nearest = at_minimum[first_of_group]  # each keypoint's first candidate at its minimum
    rest = pair.copy()
    rest[nearest] = np.inf
    second = np.minimum.reduceat(rest, starts)  # inf for a keypoint with one candidate
    first64, second64 = first.astype(np.float64), second.astype(np.float64)  # compared as Python floats
    ambiguous = (counts[owners] > 1) & (first64 >= params.ratio * second64)
    passed = (first64 <= params.max_distance) & ~ambiguous
    if not passed.any():
        return empty
    keypoints, anchors, score = rows[owners][passed], candidates[nearest][passed], first64[passed]
    order = np.lexsort((keypoints, score, anchors))  # by anchor, then nearest, then the earlier row
    anchors, keypoints = anchors[order], keypoints[order]
    keep = np.r_[True, anchors[1:] != anchors[:-1]]
    return keypoints[keep], anchors[keep]


class AnchorMap:
    """The robot's own map of anchors, and relocalisation against it (module docstring)."""

    def __init__(self, intrinsics: CameraIntrinsics, params: RelocalisationParams | None = None) -> None:
        self.intrinsics = intrinsics
        self.params = params or RelocalisationParams()
        self.points = np.zeros((0, 3))
        self.descriptors = np.zeros((0, 128), np.float32)
        self.sigmas = np.zeros(0)  # each anchor's position standard deviation: its frame's, when made
        self.fixes = 0
        self._unsure_frames = 0  # frames in a row that have needed the search
        self._ring = 0  # the search's ring: 0 the whole square out to max_global_correction_m
        self.global_fixes = 0  # of those, found by the search of a lost robot
        self.refused: Counter = Counter()  # frames with matches but no fix, by reason
        self._rng = np.random.default_rng(0)  # a fixed seed: the same frames give the same fixes

    def __len__(self) -> int:
        return len(self.points)

    def search_radius_px(self, sigma_m: float) -> float:
        """How far from its predicted pixel an anchor is looked for, with a prediction of horizontal
        standard deviation ``sigma_m``."""
        p = self.params
        return float(
            np.clip(3.0 * sigma_m * self.intrinsics.fx, p.min_search_radius_px, p.max_search_radius_px)
        )

    def match(
        self,
        pose: CameraPose,
        pixels: np.ndarray,
        descriptors: np.ndarray,
        valid: np.ndarray,
        sigma_m: float = 0.0,
        distances: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Keypoint rows and the anchors they match, one keypoint per anchor (module docstring), under
        the predicted ``pose`` of horizontal standard deviation ``sigma_m``. ``distances``, when given,
        holds each keypoint's descriptor distance to every anchor (:meth:`all_distances`), for a search
        that matches one frame from many predictions."""
        p = self.params
        radius = self.search_radius_px(sigma_m)
        empty = np.zeros(0, int), np.zeros(0, int)
        if not len(self.points) or not valid.any():
            return empty
        projected, depth = project(self.points, pose.position, pose.rotation, self.intrinsics)
        k = self.intrinsics
        visible = np.flatnonzero(
            (depth > p.min_depth_m * 0.5)
            & (depth < p.max_depth_m * 2.0)
            & (projected[:, 0] > -radius)
            & (projected[:, 0] < k.width + radius)
            & (projected[:, 1] > -radius)
            & (projected[:, 1] < k.height + radius)
        )
        if not len(visible):
            return empty
        tree = cKDTree(projected[visible])
        rows = np.flatnonzero(valid)
        neighbours = tree.query_ball_point(pixels[rows], radius)
        if distances is not None:
            return _nearest_matches(rows, neighbours, visible, distances, p)
        best_anchor: dict[int, tuple[float, int]] = {}  # anchor -> (distance, keypoint row)
        for row, near in zip(rows.tolist(), neighbours, strict=True):
            if not near:
                continue
            anchors = visible[np.asarray(near, int)]
            found = descriptor_distances(self.descriptors[anchors], descriptors[row][None])
            order = np.argsort(found, kind="stable")
            first = float(found[order[0]])
            if first > p.max_distance:
                continue
            if len(order) > 1 and first >= p.ratio * float(found[order[1]]):
                continue
            anchor = int(anchors[order[0]])
            if anchor not in best_anchor or first < best_anchor[anchor][0]:
                best_anchor[anchor] = (first, row)
        if not best_anchor:
            return empty
        anchors = np.array(sorted(best_anchor), int)
        keypoints = np.array([best_anchor[a][1] for a in anchors.tolist()], int)
        return keypoints, anchors

    def all_distances(self, descriptors: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """The descriptor distance ``(N, A)`` of each ``valid`` keypoint to every anchor (rows of keypoints
        without a descriptor left at zero): what :meth:`match` would work out pair by pair, the same
        numbers, once for a search's many predictions."""
        distances = np.zeros((len(descriptors), len(self.points)), np.float32)
        for row in np.flatnonzero(valid).tolist():
            distances[row] = descriptor_distances(self.descriptors, descriptors[row][None])
        return distances

    def relocalise(
        self,
        pose: CameraPose,
        pixels: np.ndarray,
        descriptors: np.ndarray,
        valid: np.ndarray,
        sigma_m: float = 0.0,
    ) -> tuple[Fix | None, np.ndarray]:
        """A fix of the camera centre for a frame whose predicted pose is ``pose``, of horizontal standard
        deviation ``sigma_m`` (None when refused), and the keypoint rows matched to anchors (inliers of
        the fix, or every match without one). A prediction unsure past ``global_sigma_m`` that finds no
        fix near itself is tried against the whole map (:meth:`match_globally`), on stronger evidence:
        ``global_min_inliers`` inliers, anywhere within ``max_global_correction_m``."""
        keypoints, anchors = self.match(pose, pixels, descriptors, valid, sigma_m)
        fix, matched = self._attempt(pose, pixels, keypoints, anchors, sigma_m, self.params.min_inliers)
        searching = fix is None and sigma_m >= self.params.global_sigma_m
        self._unsure_frames = self._unsure_frames + 1 if searching else 0
        if searching and (self._unsure_frames - 1) % self.params.search_every_frames == 0:
            found = self._search(pose, pixels, descriptors, valid, *self._next_search())
            if found is not None:
                self._ring = 0
                self.fixes += 1
                self.global_fixes += 1
                return found
        elif not searching:
            self._ring = 0
        self.fixes += fix is not None
        return fix, matched

    def _next_search(self) -> tuple[np.ndarray, float]:
        """The horizontal offsets ``(K, 2)`` this search tries, and how far its fix may be from the
        prediction: the whole grid of ``global_step_m`` out to ``max_global_correction_m`` first (a fix
        within that), then one square ring of the grid beyond it per search, out to
        ``max_lost_search_m`` (a fix within the ring's corners and a step), then over again."""
        p = self.params
        rings = math.floor((p.max_lost_search_m - p.max_global_correction_m) / p.global_step_m + 1e-9)
        ring = self._ring if self._ring <= rings else 0
        self._ring = ring + 1 if ring < rings else 0
        inner = p.max_global_correction_m + (ring - 1) * p.global_step_m if ring else -1.0
        outer = p.max_global_correction_m + ring * p.global_step_m
        count = math.floor(outer / p.global_step_m + 1e-9)
        steps = np.arange(-count, count + 1) * p.global_step_m
        dx, dy = (grid.ravel() for grid in np.meshgrid(steps, steps, indexing="ij"))
        chebyshev = np.maximum(np.abs(dx), np.abs(dy))
        keep = (chebyshev > inner + 1e-9) & (chebyshev > 0)  # the prediction itself was tried
        bound = outer if ring == 0 else math.sqrt(2.0) * outer + p.global_step_m
        return np.column_stack([dx[keep], dy[keep]]), bound

    def _search(
        self,
        pose: CameraPose,
        pixels: np.ndarray,
        descriptors: np.ndarray,
        valid: np.ndarray,
        offsets: np.ndarray,
        bound: float,
    ) -> tuple[Fix, np.ndarray] | None:
        """The fix with the most inliers among guided matches from predictions moved by each horizontal
        offset (:meth:`_next_search`; a descriptor match against the whole map fails on a tank's
        repeated texture: Lowe's ratio test finds a near twin for nearly every keypoint), each needing
        ``global_min_inliers`` and lying within ``bound`` of the prediction; None when none has them."""
        p = self.params
        best: tuple[Fix, np.ndarray] | None = None
        distances = self.all_distances(descriptors, valid)  # once for the whole grid
        for dx, dy in offsets.tolist():
            moved = CameraPose(pose.position + np.array([dx, dy, 0.0]), pose.rotation)
            keypoints, anchors = self.match(moved, pixels, descriptors, valid, p.global_step_m, distances)
            if len(keypoints) < p.global_min_inliers:
                continue
            fix, matched = self._attempt(
                pose, pixels, keypoints, anchors, p.global_step_m, p.global_min_inliers, bound=bound
            )
            if fix is not None and (best is None or fix.inliers > best[0].inliers):
                best = (fix, matched)
        return best

    def _attempt(
        self,
        pose: CameraPose,
        pixels: np.ndarray,
        keypoints: np.ndarray,
        anchors: np.ndarray,
        sigma_m: float,
        min_inliers: int,
        bound: float | None = None,
    ) -> tuple[Fix | None, np.ndarray]:
        """One fix from matched ``keypoints`` and ``anchors`` (module docstring's refusals; one of the
        search is bounded by ``bound``, the search's reach, instead of the gate)."""
        p = self.params
        if len(keypoints) < min_inliers:
            return None, keypoints
        params = p if min_inliers == p.min_inliers else dataclasses.replace(p, min_inliers=min_inliers)
        found = locate(
            self.points[anchors], pixels[keypoints], pose.rotation, self.intrinsics, params, self._rng
        )
        if found is None:
            self.refused["inliers"] += 1
            return None, keypoints
        centre, inliers = found
        rays = bearings(pixels[keypoints[inliers]], pose.rotation, self.intrinsics)
        if ray_spread(rays) < p.min_ray_spread:
            self.refused["geometry"] += 1
            return None, keypoints
        jump = float(np.linalg.norm(centre - pose.position))
        globally = bound is not None
        if jump > (bound if globally else p.max_correction_m):
            self.refused["jump"] += 1
            return None, keypoints
        used = anchors[inliers]
        sigma = float(np.sqrt(np.mean(self.sigmas[used] ** 2) + p.fix_sigma_m**2))
        # the innovation gate of a Kalman filter: a fix farther from the prediction than gate standard
        # deviations of their difference is a wrong one (a repeated structure: the ladder's rungs)
        innovation = float(np.linalg.norm((centre - pose.position)[:2]))
        if not globally and innovation > p.gate * math.hypot(sigma_m, sigma):
            self.refused["gate"] += 1
            return None, keypoints
        return Fix(centre, sigma, int(inliers.sum()), used), keypoints[inliers]

    def add(
        self,
        pose: CameraPose,
        pixels: np.ndarray,
        points_camera: np.ndarray,
        descriptors: np.ndarray,
        usable: np.ndarray,
        sigma_m: float,
    ) -> int:
        """Make anchors of the ``usable`` keypoints (rows with a stereo point ``points_camera`` and a
        descriptor) that lie in the depth band, at ``pose`` of horizontal standard deviation ``sigma_m``;
        returns how many were made. Where anchors already project within ``spacing_px`` a keypoint makes
        none, unless all of those are less sure by far (a standard deviation over twice this frame's and
        1 cm more): then it takes their place, so the map grows surer where the robot is surer."""
        p = self.params
        rows = np.flatnonzero(usable)
        if not len(rows):
            return 0
        depth = points_camera[rows, 2]
        rows = rows[(depth >= p.min_depth_m) & (depth <= p.max_depth_m)]
        drop = np.zeros(len(self.points), bool)
        if len(self.points) and len(rows) and p.spacing_px > 0:
            projected, anchor_depth = project(self.points, pose.position, pose.rotation, self.intrinsics)
            ahead = np.flatnonzero(anchor_depth > 0)
            if len(ahead):
                near = cKDTree(projected[ahead]).query_ball_point(pixels[rows], p.spacing_px)
                worse = self.sigmas[ahead] > 2.0 * sigma_m + 0.01
                keep = []
                for row, close in zip(rows.tolist(), near, strict=True):
                    if not close:
                        keep.append(row)
                    elif worse[close].all():
                        keep.append(row)
                        drop[ahead[close]] = True
                rows = np.array(keep, int)
        room = p.max_anchors - int((~drop).sum())
        rows = rows[: max(room, 0)]
        if drop.any():
            self.points, self.descriptors, self.sigmas = (
                self.points[~drop],
                self.descriptors[~drop],
                self.sigmas[~drop],
            )
        if len(rows):
            self.points = np.vstack([self.points, pose.to_world(points_camera[rows])])
            self.descriptors = np.vstack([self.descriptors, descriptors[rows]])
            self.sigmas = np.concatenate([self.sigmas, np.full(len(rows), float(sigma_m))])
        return len(rows)
