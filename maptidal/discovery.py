"""Map-TIDAL task discovery: the paper's Algorithms 1-3, exact and vectorised.

Ruediger & Banerjee, "Mapping-Guided Task Discovery and Allocation for Cooperative
Robotic Inspection of Underwater Structures", Section III.B and Algorithms 1-3
(Ruediger & Banerjee; docs/references.md). Discovery runs once per keyframe mesh:

1. **Generate Points** (Alg. 3): one candidate inspection point (CIP) per mesh face,
   at ``centroid + L_i * n`` looking along ``-n``, where ``n`` is the unit face
   normal from the winding ``(v1 - v0) x (v2 - v0)``. Zero-area faces are skipped.
2. **Prune** (Alg. 2): against the existing tasks (``n = 0``), or against itself
   with thresholds shrunk by ``p_s`` (``n = 2``) when there are no existing tasks
   or none lies within ``r_ex`` of any CIP.
3. **Calculate Scores** (Alg. 3): the fraction of keypoints inside each CIP's camera
   frustum. CIPs with ``S >= t`` are confirmed; the others remain, in order.
4. **Final pruning**: ``Prune(remains, confirmed, 1)``, i.e. the confirmed tasks
   followed by the remains not excluded by a confirmed or earlier kept task.

A viewpoint row is ``(x, y, z, dx, dy, dz)``. The pruning rule is: X is excluded
by Y when ``|X - Y| < r_ex`` and ``arccos(dX . dY) < theta_ex`` (both strict).
Pruning is order dependent; the fast path below keeps that order exactly: it
walks the candidates in order and lets every kept one suppress the later ones
it excludes, so the Python loop runs once per *kept* candidate, not once per
candidate pair. Neighbours within r_ex, and keypoints near a frustum, come from
maptidal.geometry.SpatialGrid rather than scipy's cKDTree: the tree returns
Python lists, and converting them cost more than the whole search (measured
0.19 s against 0.06 s at 10k faces). tests/bench/literal_discovery.py is a
line-by-line transcription used as the oracle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from maptidal.camera import OAKD_HFOV_DEG, OAKD_VFOV_DEG
from maptidal.geometry import (
    MAX_DISTANCE_M,
    CameraModel,
    SpatialGrid,
    count_in_frustums,
    frustum_count_bounds,
    view_angles,
)

__all__ = [
    "DiscoveryInputError",
    "DiscoveryParams",
    "DiscoveryResult",
    "calculate_scores",
    "confirm",
    "discover",
    "generate_points",
    "prune",
    "validate_mesh",
    "validate_viewpoints",
]


# Neighbour look-ups use a radius a hair larger than r_ex, then the exact strict
# test d < r_ex decides, so rounding in the look-up can never drop a pair.
_QUERY_SLACK = 1.0 + 1e-9

# Rebuild the neighbour grid once 1/_REBUILD_FRACTION of its points are blocked.
_REBUILD_FRACTION = 2
# Candidate-other pairs tested at once when pruning against a fixed set (bounds the memory).
_PAIR_BLOCK = 262_144

_MODE_NAMES = {0: "existing", 1: "final", 2: "self"}


class DiscoveryInputError(ValueError):
    """Raised when a mesh, keypoint set or task list cannot be used for discovery."""


@dataclass(frozen=True)
class DiscoveryParams:
    """Map-TIDAL discovery parameters.

    Defaults are the paper's best values (Section IV.D and Table I): L_i = 1.0 m,
    r_ex = 1.7 m, theta_ex = 0.25 rad, t = 75 %, p_s = 70 % (Section III.B), and the
    OAK-D stereo pair's field of view, 78.5 x 54.1 deg (:mod:`maptidal.camera`). ``range_m``
    (the frustum's far plane) defaults to ``2 * standoff``.
    """

    standoff: float = 1.0
    r_ex: float = 1.7
    theta_ex: float = 0.25
    threshold: float = 0.75
    p_s: float = 0.7
    hfov_deg: float = OAKD_HFOV_DEG
    vfov_deg: float = OAKD_VFOV_DEG
    range_m: float | None = None

    def __post_init__(self) -> None:
        positive = {
            "standoff": self.standoff,
            "r_ex": self.r_ex,
            "theta_ex": self.theta_ex,
            "p_s": self.p_s,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0.0):
                raise DiscoveryInputError(f"{name} must be a positive finite number, got {value!r}")
        for name in ("standoff", "r_ex"):
            if getattr(self, name) > MAX_DISTANCE_M:
                raise DiscoveryInputError(
                    f"{name} must be at most {MAX_DISTANCE_M:g} m (a camera under water sees a few metres), "
                    f"got {getattr(self, name)!r}"
                )
        if not self.theta_ex <= math.pi:
            raise DiscoveryInputError(f"theta_ex must be at most pi rad, got {self.theta_ex!r}")
        if not self.p_s <= 1.0:
            raise DiscoveryInputError(f"p_s must be in (0, 1], got {self.p_s!r}")
        if not (math.isfinite(self.threshold) and 0.0 <= self.threshold <= 1.0):
            raise DiscoveryInputError(f"threshold must be in [0, 1], got {self.threshold!r}")
        try:
            self.camera  # noqa: B018 - validates the field of view and range
        except ValueError as err:
            raise DiscoveryInputError(str(err)) from err

    @property
    def far_range(self) -> float:
        """The frustum's far-plane distance: ``range_m`` or ``2 * standoff``."""
        return 2.0 * self.standoff if self.range_m is None else self.range_m

    @property
    def camera(self) -> CameraModel:
        """The scoring camera's frustum model."""
        return CameraModel(self.hfov_deg, self.vfov_deg, self.far_range)

    def to_dict(self) -> dict[str, float]:
        """Parameters as plain numbers named with their units, with the resolved ``range_m``."""
        return {
            "standoff_m": self.standoff,
            "r_ex_m": self.r_ex,
            "theta_ex_rad": self.theta_ex,
            "threshold": self.threshold,
            "p_s": self.p_s,
            "hfov_deg": self.hfov_deg,
            "vfov_deg": self.vfov_deg,
            "range_m": self.far_range,
        }


@dataclass
class DiscoveryResult:
    """Every stage of one discovery run, as in the paper's Fig. 4.

    Each array is ``(N, 6)`` viewpoint rows. ``final`` is the new task list
    (confirmed first, then the kept remains); it never contains existing tasks.
    """

    cips: np.ndarray
    after_prune: np.ndarray
    confirmed: np.ndarray
    remains: np.ndarray
    final: np.ndarray
    pruning_mode: str
    params: DiscoveryParams = field(default_factory=DiscoveryParams)
    keypoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    _scores: np.ndarray | None = field(default=None, repr=False)

    @property
    def scores(self) -> np.ndarray:
        """Alg. 3's score of each pruned CIP, exact (computed on first use: discovery itself only needs
        to know which side of the threshold each score lies, which bounds decide for most CIPs)."""
        if self._scores is None:
            self._scores = calculate_scores(self.after_prune, self.keypoints, self.params.camera)
        return self._scores

    @property
    def counts(self) -> dict[str, int]:
        """Stage sizes: CIPs -> after pruning -> confirmed (/ remains) -> final."""
        return {
            "cips": len(self.cips),
            "after_prune": len(self.after_prune),
            "confirmed": len(self.confirmed),
            "final": len(self.final),
        }

    def to_json_dict(self) -> dict:
        """The ``maptidal discover --json`` document: counts, tasks and params."""
        return {
            "counts": self.counts,
            "tasks": tasks_to_json_list(self.final),
            "params": self.params.to_dict(),
        }


def tasks_to_json_list(rows: np.ndarray) -> list[dict[str, list[float]]]:
    """Viewpoint rows ``(N, 6)`` as ``[{"position": [...], "direction": [...]}, ...]``."""
    return [
        {"position": [float(v) for v in row[:3]], "direction": [float(v) for v in row[3:6]]}
        for row in np.asarray(rows, dtype=float).reshape(-1, 6)
    ]


def _as_float_array(values: object, name: str) -> np.ndarray:
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError) as err:
        raise DiscoveryInputError(f"{name} must be numeric: {err}") from err


def validate_mesh(vertices: object, faces: object) -> tuple[np.ndarray, np.ndarray]:
    """Check a triangle mesh and return it as ``(V, 3)`` floats and ``(F, 3)`` ints.

    Raises DiscoveryInputError for an empty mesh, non-finite vertices, faces that
    are not triangles or index outside the vertex array.
    """
    vertices = _as_float_array(vertices, "vertices")
    faces_raw = np.asarray(faces)
    if vertices.size == 0 or faces_raw.size == 0:
        raise DiscoveryInputError("the mesh is empty: it needs at least one vertex and one face")
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise DiscoveryInputError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces_raw.ndim != 2 or faces_raw.shape[1] != 3:
        raise DiscoveryInputError(f"faces must be triangles of shape (F, 3), got {faces_raw.shape}")
    if not np.issubdtype(faces_raw.dtype, np.integer):
        as_float = faces_raw.astype(float)
        if not np.all(np.isfinite(as_float)) or np.any(as_float != np.round(as_float)):
            raise DiscoveryInputError("face indices must be integers")
    faces = faces_raw.astype(np.int64)
    bad_vertices = ~np.all(np.isfinite(vertices), axis=1)
    if bad_vertices.any():
        first = int(np.flatnonzero(bad_vertices)[0])
        raise DiscoveryInputError(
            f"{int(bad_vertices.sum())} vertices are NaN or infinite (first: vertex {first})"
        )
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise DiscoveryInputError(
            f"face indices must lie in [0, {len(vertices) - 1}], found [{faces.min()}, {faces.max()}]"
        )
    return vertices, faces


def validate_viewpoints(rows: object, name: str = "tasks", tolerance: float = 1e-3) -> np.ndarray:
    """Check viewpoint rows ``(N, 6)``: finite, with unit directions (to ``tolerance``).

    Directions within the tolerance are renormalised; others raise DiscoveryInputError.
    """
    rows = _as_float_array(rows, name)
    if rows.size == 0:
        return np.empty((0, 6))
    if rows.ndim != 2 or rows.shape[1] != 6:
        raise DiscoveryInputError(f"{name} must have shape (N, 6), got {rows.shape}")
    if not np.all(np.isfinite(rows)):
        raise DiscoveryInputError(f"{name} contain NaN or infinite values")
    lengths = np.linalg.norm(rows[:, 3:], axis=1)
    off = np.abs(lengths - 1.0) > tolerance
    if off.any():
        first = int(np.flatnonzero(off)[0])
        raise DiscoveryInputError(
            f"{name}[{first}] has a view direction of length {lengths[first]:.6g}; "
            f"directions must be unit vectors (tolerance {tolerance})"
        )
    rows = rows.copy()
    rows[:, 3:] /= lengths[:, None]
    return rows


def generate_points(vertices: np.ndarray, faces: np.ndarray, standoff: float) -> np.ndarray:
    """Alg. 3, Generate Points: one CIP per non-degenerate face, in face order.

    The CIP sits ``standoff`` along the unit winding normal from the face centroid
    and looks back along ``-normal``.
    """
    v0, v1, v2 = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    normals = np.cross(v1 - v0, v2 - v0)
    lengths = np.sqrt(np.sum(normals * normals, axis=1))
    keep = lengths > 0.0
    normals = normals[keep] / lengths[keep, None]
    centroids = (v0[keep] + v1[keep] + v2[keep]) / 3.0
    return np.hstack([centroids + standoff * normals, -normals])


def _suppress_sequentially(
    candidates: np.ndarray, blocked: np.ndarray, r_ex: float, theta_ex: float
) -> np.ndarray:
    """Indices of the candidates kept by sequential pruning, in order.

    Walks the candidates in order: the first one not yet blocked is kept and
    blocks every later candidate within both ``r_ex`` and ``theta_ex`` of it. This
    equals comparing each candidate against the growing list of kept ones, with a
    Python step per kept candidate only.
    """
    blocked = blocked.copy()
    kept: list[int] = []
    positions, directions = candidates[:, :3], candidates[:, 3:]
    cell = r_ex * _QUERY_SLACK
    # A slightly widened squared-distance test discards most neighbours cheaply;
    # the exact strict tests then decide on the few that remain.
    coarse_r2 = cell**2
    live = np.flatnonzero(~blocked)
    grid = SpatialGrid(positions[live], cell)
    blocked_in_grid = 0
    index, count = 0, len(candidates)
    while index < count:
        if blocked[index]:
            # Jump to the next unblocked candidate without a Python step per blocked one.
            step = int(np.argmin(blocked[index:]))
            if blocked[index + step]:
                break
            index += step
        kept.append(index)
        local, columns = grid.near(positions[index])
        px, py, pz = positions[index]
        dx, dy, dz = columns[0] - px, columns[1] - py, columns[2] - pz
        # Summed left to right like the literal sqrt(dx*dx + dy*dy + dz*dz).
        squared = dx * dx + dy * dy + dz * dz
        close = squared < coarse_r2
        near, squared = live[local[close]], squared[close]
        is_later = (near > index) & ~blocked[near]
        later = near[is_later]
        if len(later):
            distances = np.sqrt(squared[is_later])
            angles = view_angles(directions[index], directions[later])
            newly = later[(distances < r_ex) & (angles < theta_ex)]
            blocked[newly] = True
            blocked_in_grid += len(newly)
        index += 1
        if blocked_in_grid * _REBUILD_FRACTION > len(live):
            # Rebuild over the live candidates only, so later look-ups skip the blocked ones.
            live = index + np.flatnonzero(~blocked[index:])
            grid = SpatialGrid(positions[live], cell)
            blocked_in_grid = 0
    return np.asarray(kept, dtype=np.int64)


def _blocked_by(
    candidates: np.ndarray, others: np.ndarray, r_ex: float, theta_ex: float
) -> tuple[np.ndarray, bool]:
    """Mark candidates excluded by any row of ``others`` (a fixed set, e.g. existing tasks).

    Also says whether any candidate-other pair is within ``r_ex`` at all, which is
    Algorithm 2's "precheck". Every candidate-other pair is tested at once, a block of
    others at a time, after dropping the others too far from every candidate to matter.
    """
    blocked = np.zeros(len(candidates), dtype=bool)
    positions = candidates[:, :3]
    reach = r_ex * _QUERY_SLACK
    low, high = positions.min(axis=0) - reach, positions.max(axis=0) + reach
    others = others[np.all((others[:, :3] >= low) & (others[:, :3] <= high), axis=1)]
    if len(others) == 0:
        return blocked, False
    any_within = False
    cx, cy, cz = positions[:, 0, None], positions[:, 1, None], positions[:, 2, None]
    block = max(1, _PAIR_BLOCK // len(candidates))
    for start in range(0, len(others), block):
        rows = others[start : start + block]
        # candidate minus task, summed left to right as in the literal distance
        dx, dy, dz = cx - rows[:, 0], cy - rows[:, 1], cz - rows[:, 2]
        within = np.sqrt(dx * dx + dy * dy + dz * dz) < r_ex
        if not within.any():
            continue
        any_within = True
        candidate, other = np.nonzero(within)
        near, far = candidates[candidate], rows[other]
        # the literal dot product, left to right, then its clipped arccos
        dots = near[:, 3] * far[:, 3] + near[:, 4] * far[:, 4] + near[:, 5] * far[:, 5]
        blocked[candidate[np.arccos(np.clip(dots, -1.0, 1.0)) < theta_ex]] = True
    return blocked, any_within


def prune(
    candidates: np.ndarray, compare: np.ndarray, mode: int, params: DiscoveryParams
) -> tuple[np.ndarray, str]:
    """Alg. 2, ``Prune(C, C_comp, n)``. Returns the pruned rows and the mode applied.

    - ``mode=0``: keep the candidates not excluded by any row of ``compare``; if no
      pair at all is within ``r_ex`` ("precheck" stays true), return
      ``Prune(C, [], 2)`` instead (mode string ``"self(precheck)"``).
    - ``mode=1``: start from ``compare`` and append each kept candidate to both the
      output and the comparison set.
    - ``mode=2``: start from ``C[0]`` and compare ``C`` with itself using
      ``r_ex * p_s`` and ``theta_ex * p_s``.
    """
    candidates = np.asarray(candidates, dtype=float).reshape(-1, 6)
    compare = np.asarray(compare, dtype=float).reshape(-1, 6)
    if mode not in (0, 1, 2):
        raise ValueError(f"prune mode must be 0, 1 or 2, got {mode!r}")
    if len(candidates) == 0:
        return (compare.copy() if mode == 1 else np.empty((0, 6))), _MODE_NAMES[mode]

    r_ex, theta_ex = params.r_ex, params.theta_ex
    if mode == 2:
        r_ex, theta_ex = r_ex * params.p_s, theta_ex * params.p_s
    if mode == 0:
        blocked, any_within = _blocked_by(candidates, compare, r_ex, theta_ex)
        if not any_within:
            return prune(candidates, np.empty((0, 6)), 2, params)[0], "self(precheck)"
        return candidates[~blocked], "existing"

    if mode == 1:
        blocked = np.zeros(len(candidates), dtype=bool)
        if len(compare):
            blocked, _ = _blocked_by(candidates, compare, r_ex, theta_ex)
        kept = _suppress_sequentially(candidates, blocked, r_ex, theta_ex)
        return np.vstack([compare, candidates[kept]]), "final"

    # mode 2: C[0] seeds the output; the loop then visits C[0] again, which its own
    # seed excludes (distance 0, angle 0), so the walk below keeps index 0 once.
    no_blocks = np.zeros(len(candidates), dtype=bool)
    kept = _suppress_sequentially(candidates, no_blocks, r_ex, theta_ex)
    return candidates[kept], "self"


def calculate_scores(candidates: np.ndarray, keypoints: np.ndarray, camera: CameraModel) -> np.ndarray:
    """Alg. 3, Calculate Scores: the fraction of keypoints inside each CIP's frustum."""
    keypoints = np.asarray(keypoints, dtype=float).reshape(-1, 3)
    if len(keypoints) == 0:
        raise DiscoveryInputError("there are no keypoints to score against")
    return count_in_frustums(candidates, keypoints, camera) / len(keypoints)


def confirm(
    candidates: np.ndarray, keypoints: np.ndarray, camera: CameraModel, threshold: float
) -> tuple[np.ndarray, np.ndarray | None]:
    """Alg. 1's test S >= t for every candidate, exactly as calculate_scores would decide it.

    Count bounds from a grid of keypoint cells (geometry.frustum_count_bounds) settle most candidates:
    an upper bound below t*K rejects, a lower bound at or above it confirms. Only the rest are counted
    point by point. Returns the mask and, when every candidate had to be counted, the exact scores
    (else None: DiscoveryResult computes them when asked)."""
    keypoints = np.asarray(keypoints, dtype=float).reshape(-1, 3)
    if len(keypoints) == 0:
        raise DiscoveryInputError("there are no keypoints to score against")
    total = len(keypoints)
    lower, upper = frustum_count_bounds(candidates, keypoints, camera)
    # compare as calculate_scores does (count / K >= t), so rounding decides alike
    confirmed = lower / total >= threshold
    undecided = np.flatnonzero(~confirmed & (upper / total >= threshold))
    if len(undecided) == len(candidates):
        scores = count_in_frustums(candidates, keypoints, camera) / total
        return scores >= threshold, scores
    if len(undecided):
        confirmed[undecided] = (
            count_in_frustums(candidates[undecided], keypoints, camera) / total >= threshold
        )
    return confirmed, None


def discover(
    vertices: object,
    faces: object,
    existing: object | None = None,
    keypoints: object | None = None,
    params: DiscoveryParams | None = None,
) -> DiscoveryResult:
    """Alg. 1: discover new inspection tasks on one keyframe mesh.

    ``existing`` is the task list ``T_e`` (``(N, 6)`` rows); ``keypoints`` default to
    the mesh vertices, which are the landmarks in a Kimera mesh. Raises
    DiscoveryInputError on unusable input.
    """
    params = params or DiscoveryParams()
    vertices, faces = validate_mesh(vertices, faces)
    existing_rows = validate_viewpoints([] if existing is None else existing, "existing tasks")
    if keypoints is None:
        keypoint_array = vertices
    else:
        keypoint_array = _as_float_array(keypoints, "keypoints")
        if keypoint_array.ndim != 2 or keypoint_array.shape[1] != 3 or len(keypoint_array) == 0:
            raise DiscoveryInputError(f"keypoints must have shape (K>0, 3), got {keypoint_array.shape}")
        if not np.all(np.isfinite(keypoint_array)):
            raise DiscoveryInputError("keypoints contain NaN or infinite values")

    cips = generate_points(vertices, faces, params.standoff)
    if len(cips) == 0:
        raise DiscoveryInputError("every face of the mesh has zero area: no candidate points")

    if len(existing_rows) == 0:
        after_prune, mode = prune(cips, existing_rows, 2, params)
    else:
        after_prune, mode = prune(cips, existing_rows, 0, params)

    is_confirmed, scores = confirm(after_prune, keypoint_array, params.camera, params.threshold)
    confirmed, remains = after_prune[is_confirmed], after_prune[~is_confirmed]
    final, _ = prune(remains, confirmed, 1, params)
    return DiscoveryResult(
        cips=cips,
        after_prune=after_prune,
        confirmed=confirmed,
        remains=remains,
        final=final,
        pruning_mode=mode,
        params=params,
        keypoints=keypoint_array,
        _scores=scores,
    )
