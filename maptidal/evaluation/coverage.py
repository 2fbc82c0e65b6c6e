"""Coverage evaluation: views per voxel, the ideal gamma distribution and MAD.

This is the paper's evaluation (Section IV.B-IV.D): the evaluated surface is
voxelised, every viewpoint's camera frustum (the same pyramid as discovery uses)
counts the voxel centres inside it, and the distribution of views per voxel is
compared with a discretised gamma distribution.

Definitions, used everywhere in maptidal:

- *views* of a voxel: the number of viewpoints whose frustum contains its centre;
- *% uninspected*: 100 x the fraction of voxels with 0 views;
- *histogram*: the fraction of voxels with k views, for k = 0..K, where
  ``K = max(10, largest observed count)``; it sums to 1;
- *ideal*: gamma with shape alpha = 4 and scale beta = 2/3 (peak at 2 views,
  paper Sec. IV.C), in integer-centred bins: bin 0 = CDF(0.5), bin k = CDF(k + 0.5)
  - CDF(k - 0.5); it sums to slightly less than 1 (the tail beyond K + 0.5);
- *MAD*: the mean of |histogram - ideal| over **fixed bins**: 0, 1, .., 10 views and one tail bin for
  11 or more (12 bins, whatever the data). The ideal is the gamma's bins 0..10 renormalised to sum to 1,
  and 0 in the tail: more than 10 views is over-coverage, never ideal (the gamma puts 1.1e-4 of its
  mass there). So every voxel beyond 10 views counts as a full error, and adding over-covered voxels
  never lowers MAD. The paper (Sec. IV.C, Fig. 8) compares the histogram with the gamma but does not
  say over which bins; over bins 0..K with K the largest count (``mad_legacy``, our earlier reading),
  a method that over-covers spreads its error over more bins and scores better the more it over-covers.

The paper's count ignores occlusion: a voxel seen through another wall still
counts. ``occlusion=True`` counts a voxel only when the straight ray from the
viewpoint reaches it unblocked by the scene; the paper does not do this.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass

import numpy as np
import trimesh
from scipy.stats import gamma

from maptidal.camera import OAKD_HFOV_DEG, OAKD_VFOV_DEG
from maptidal.geometry import CameraModel, _inside_local, frustum_masks, view_frame
from maptidal.raycast import Occluders, visible_from
from maptidal.tank import TankModel

# Paper Sec. IV.C: peak at 2 views with alpha = 4 gives beta = 2 / (alpha - 1) = 2/3.
IDEAL_GAMMA_ALPHA = 4.0
IDEAL_GAMMA_BETA = 2.0 / 3.0
MIN_HISTOGRAM_BINS = 10


@dataclass(frozen=True)
class CoverageParams:
    """Voxel size and camera of the evaluation; defaults follow the paper and issue [coverage]."""

    voxel_m: float = 0.05
    far_m: float = 2.0
    hfov_deg: float = OAKD_HFOV_DEG
    vfov_deg: float = OAKD_VFOV_DEG
    occlusion: bool = False

    def __post_init__(self) -> None:
        if not (np.isfinite(self.voxel_m) and self.voxel_m > 0.0):
            raise ValueError(f"voxel size must be positive, got {self.voxel_m!r}")
        self.camera  # noqa: B018 - validates the angles and the far plane

    @property
    def camera(self) -> CameraModel:
        """The frustum used to count views (validates the angles and range)."""
        return CameraModel(self.hfov_deg, self.vfov_deg, self.far_m)


# Voxelising costs about 600 bytes a voxel at its peak: a million voxels stay under a gigabyte.
MAX_VOXELS = 1_000_000
# Fewer voxels than this cannot tell the walls' parts apart (on the OSB tank's 11 m^2 it is a 33 cm
# voxel, a sixth of the water's depth); nearly any set of views then scores as full coverage.
MIN_VOXELS = 100


def voxel_centres(surface: trimesh.Trimesh, voxel_m: float) -> np.ndarray:
    """Centres ``(V, 3)`` of the surface voxels of a mesh (trimesh subdivision voxeliser).

    Raises ValueError, before any work, when the surface would need more than :data:`MAX_VOXELS`, or fewer
    than :data:`MIN_VOXELS`.
    """
    estimate = float(surface.area) / voxel_m**2
    if estimate > MAX_VOXELS:
        smallest = math.sqrt(float(surface.area) / MAX_VOXELS)
        raise ValueError(
            f"a voxel of {voxel_m:g} m gives about {estimate:,.0f} voxels on this surface "
            f"({surface.area:.1f} m^2); at most {MAX_VOXELS:,} are allowed, so use a voxel of at least "
            f"{smallest * 1000:.1f} mm"
        )
    if estimate < MIN_VOXELS:
        largest = math.sqrt(float(surface.area) / MIN_VOXELS)
        raise ValueError(
            f"a voxel of {voxel_m:g} m gives about {estimate:,.0f} voxels on this surface "
            f"({surface.area:.1f} m^2); at least {MIN_VOXELS} are needed to tell its parts apart, so use a "
            f"voxel of at most {largest * 1000:.0f} mm"
        )
    longest = float(surface.edges_unique_length.max()) if len(surface.faces) else 0.0
    # Each subdivision halves the edges; the voxeliser stops when edges < pitch / 2.
    iterations = max(1, int(np.ceil(np.log2(max(longest, voxel_m) / (voxel_m / 2.0)))) + 1)
    grid = surface.voxelized(pitch=voxel_m, method="subdivide", max_iter=iterations)
    return np.asarray(grid.points, dtype=float)


def views_per_point(
    viewpoints: np.ndarray,
    points: np.ndarray,
    camera: CameraModel,
    occluders: np.ndarray | Occluders | None = None,
    tolerance: float = 0.0,
) -> np.ndarray:
    """For each point, the number of viewpoints whose frustum contains it.

    With ``occluders`` (triangles ``(T, 3, 3)``, or :class:`maptidal.raycast.Occluders`), a point
    counts for a viewpoint only when the ray to it is not blocked more than ``tolerance`` m before it.
    """
    viewpoints = np.asarray(viewpoints, float).reshape(-1, 6)
    points = np.asarray(points, float).reshape(-1, 3)
    counts = np.zeros(len(points), dtype=np.int64)
    if len(viewpoints) == 0 or len(points) == 0:
        return counts
    if occluders is not None and not isinstance(occluders, Occluders):
        occluders = Occluders.of(occluders)  # prepared once for every viewpoint
    for viewpoint, inside in zip(viewpoints, frustum_masks(viewpoints, points, camera), strict=True):
        if occluders is not None and inside.any():
            seen = np.flatnonzero(inside)
            inside[seen] = visible_from(viewpoint, points[seen], occluders, tolerance)
        counts += inside
    return counts


def ideal_gamma_bins(
    last_bin: int, alpha: float = IDEAL_GAMMA_ALPHA, beta: float = IDEAL_GAMMA_BETA
) -> np.ndarray:
    """The ideal distribution over integer-centred bins 0..last_bin (paper Sec. IV.C)."""
    edges = np.arange(last_bin + 1) + 0.5
    cdf = gamma.cdf(edges, a=alpha, scale=beta)
    return np.diff(np.concatenate([[0.0], cdf]))


def views_histogram(views: np.ndarray, last_bin: int) -> np.ndarray:
    """Fraction of voxels with k views, k = 0..last_bin (sums to 1 when last_bin >= max)."""
    views = np.asarray(views, dtype=np.int64)
    if len(views) == 0:
        return np.zeros(last_bin + 1)
    return np.bincount(views, minlength=last_bin + 1)[: last_bin + 1] / len(views)


MAD_LAST_BIN = 10  # fixed MAD bins: 0..10 views, then one tail bin for 11 or more


def fixed_bins(views: np.ndarray) -> np.ndarray:
    """Fraction of voxels with 0, 1, .., 10 views and with 11 or more: ``(12,)``, sums to 1."""
    views = np.asarray(views, dtype=np.int64)
    counts = np.bincount(np.minimum(views, MAD_LAST_BIN + 1), minlength=MAD_LAST_BIN + 2)
    return counts / max(len(views), 1)


def ideal_fixed_bins() -> np.ndarray:
    """The ideal over the fixed MAD bins: the gamma's bins 0..10 renormalised, and 0 in the tail."""
    ideal = ideal_gamma_bins(MAD_LAST_BIN)
    return np.append(ideal / ideal.sum(), 0.0)


def mad(views: np.ndarray) -> float:
    """MAD over the fixed bins (module docstring)."""
    return mean_absolute_difference(fixed_bins(views), ideal_fixed_bins())


def mean_absolute_difference(histogram: np.ndarray, ideal: np.ndarray) -> float:
    """MAD: the mean of |histogram - ideal| over the bins both cover."""
    return float(np.mean(np.abs(np.asarray(histogram) - np.asarray(ideal))))


@dataclass(frozen=True)
class CoverageReport:
    """The paper's coverage metrics for one set of viewpoints."""

    n_viewpoints: int
    n_voxels: int
    pct_uninspected: float
    mean_views: float
    max_views: int
    histogram: list[float]
    ideal: list[float]
    mad: float
    occlusion: bool
    mad_legacy: float = 0.0  # over bins 0..K (module docstring): reported beside MAD as a note only

    def to_dict(self) -> dict:
        """A JSON-ready dict of every field."""
        return asdict(self)


def coverage_report(views: np.ndarray, n_viewpoints: int, occlusion: bool = False) -> CoverageReport:
    """Summarise views per voxel into the paper's metrics (definitions in the module doc)."""
    views = np.asarray(views, dtype=np.int64)
    if len(views) == 0:
        raise ValueError("no voxels to evaluate: the surface is empty")
    max_views = int(views.max())
    last_bin = max(MIN_HISTOGRAM_BINS, max_views)
    histogram = views_histogram(views, last_bin)
    ideal = ideal_gamma_bins(last_bin)
    return CoverageReport(
        n_viewpoints=int(n_viewpoints),
        n_voxels=len(views),
        pct_uninspected=100.0 * float(np.mean(views == 0)),
        mean_views=float(views.mean()),
        max_views=max_views,
        histogram=histogram.tolist(),
        ideal=ideal.tolist(),
        mad=mad(views),
        mad_legacy=mean_absolute_difference(histogram, ideal),
        occlusion=occlusion,
    )


@dataclass
class CoverageModel:
    """A voxelised evaluated surface, ready to score sets of viewpoints.

    Built once per tank and voxel size, then reused for every method and every
    parameter set, so that all are judged on the same voxels.
    """

    voxels: np.ndarray
    params: CoverageParams
    occluders: np.ndarray | None = None

    @classmethod
    def from_tank(cls, tank: TankModel, params: CoverageParams | None = None) -> CoverageModel:
        """Voxelise a :class:`maptidal.tank.TankModel`'s evaluated surface."""
        params = params or CoverageParams()
        occluders = tank.scene_triangles() if params.occlusion else None
        return cls(voxel_centres(tank.evaluated_surface(), params.voxel_m), params, occluders)

    @functools.cached_property
    def _prepared_occluders(self) -> Occluders | None:
        return None if self.occluders is None else Occluders.of(self.occluders)

    def views(self, viewpoints: np.ndarray) -> np.ndarray:
        """Views per voxel for viewpoint rows ``(N, 6)``."""
        # A voxel centre lies up to half a diagonal off its surface; allow that much.
        tolerance = float(np.sqrt(3.0) * self.params.voxel_m)
        return views_per_point(
            viewpoints, self.voxels, self.params.camera, self._prepared_occluders, tolerance
        )

    def evaluate(self, viewpoints: np.ndarray) -> tuple[CoverageReport, np.ndarray]:
        """The report and the views per voxel for viewpoint rows ``(N, 6)``."""
        viewpoints = np.asarray(viewpoints, float).reshape(-1, 6)
        views = self.views(viewpoints)
        return coverage_report(views, len(viewpoints), self.params.occlusion), views


class SeenVoxels:
    """Which voxels of a :class:`CoverageModel` any viewpoint has seen so far, counted incrementally: each
    new viewpoint is tested (frustum, then occlusion) only against the voxels not seen yet, kept as a
    compact array, so a camera looking at what it has seen casts no rays and copies nothing. The result
    equals ``model.views(all viewpoints so far) > 0`` (tests/test_gym.py checks it on a flown
    trajectory)."""

    def __init__(self, model: CoverageModel) -> None:
        self.model = model
        self._columns = np.ascontiguousarray(model.voxels.T)
        self._tolerance = float(np.sqrt(3.0) * model.params.voxel_m)
        self.reset()

    def reset(self) -> None:
        """Nothing seen."""
        self.restore(np.zeros(len(self.model.voxels), bool))

    def restore(self, seen: np.ndarray) -> None:
        """Take up from a copy of an earlier ``seen`` (one flag per voxel), as if those had been seen."""
        seen = np.array(seen, bool)
        if seen.shape != (len(self.model.voxels),):
            raise ValueError(
                f"seen must hold one flag per voxel ({len(self.model.voxels)}), got {seen.shape}"
            )
        self.seen = seen
        self._unseen = np.flatnonzero(~seen)
        self._unseen_columns = np.ascontiguousarray(self._columns[:, self._unseen])

    def look(self, viewpoints: np.ndarray) -> int:
        """Add what the viewpoints ``(N, 6)`` see; returns the number of voxels newly seen."""
        camera = self.model.params.camera
        newly = 0
        for viewpoint in np.asarray(viewpoints, float).reshape(-1, 6):
            if not len(self._unseen):
                break
            local = view_frame(viewpoint) @ (self._unseen_columns - viewpoint[:3, None])
            inside = np.flatnonzero(_inside_local(local[0], local[1], local[2], camera))
            if len(inside) and self.model.occluders is not None:
                points = self._unseen_columns[:, inside].T
                inside = inside[
                    visible_from(viewpoint, points, self.model._prepared_occluders, self._tolerance)
                ]
            if len(inside):
                self.seen[self._unseen[inside]] = True
                keep = np.ones(len(self._unseen), bool)
                keep[inside] = False
                self._unseen = self._unseen[keep]
                self._unseen_columns = np.ascontiguousarray(self._unseen_columns[:, keep])
                newly += len(inside)
        return newly
