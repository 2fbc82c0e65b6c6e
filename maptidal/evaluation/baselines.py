"""The paper's comparison baselines: a Voronoi (Lloyd) layout and a boustrophedon sweep.

Both work as the paper built them (Section IV.E): the evaluated walls are unrolled
into a 2D strip (s along the walls, z up), viewpoints are laid out on the strip,
and each is mapped back onto the wall and lifted 1 m off it, looking at the wall
(along minus the inward normal). Both take a :class:`maptidal.tank.TankModel`, so
they work on any tank config.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from maptidal.camera import OAKD_VFOV_DEG
from maptidal.tank import TankModel


def strip_to_viewpoints(tank: TankModel, s: np.ndarray, z: np.ndarray, standoff: float) -> np.ndarray:
    """Viewpoint rows ``(N, 6)``: ``standoff`` m off the wall at (s, z), looking at it."""
    points, normals = tank.strip_to_world(s, z)
    return np.hstack([points + standoff * normals, -normals])


VORONOI_LAYOUTS = ("lloyd", "generator")


@dataclass(frozen=True)
class VoronoiParams:
    """The Voronoi layout on the unrolled strip (paper: 20 seeds with wall avoidance).

    ``layout="lloyd"`` relaxes random seeds until they stop moving (a centroidal Voronoi tessellation).
    ``layout="generator"`` reads the paper's tool as a seed generator: the paper made its points with
    WebSVG's Voronoi editor, whose generator "controls the spread and regularity", not a converged
    relaxation. Seeds start on a jittered grid over the strip (``regularity`` 1: cell centres; 0: anywhere
    in their cell) and take ``lloyd_steps`` Lloyd steps. Both keep seeds ``margin_m`` inside the edges."""

    n_seeds: int = 20
    margin_m: float = 0.25  # wall avoidance: seeds stay this far inside the strip's edges
    tolerance_m: float = 1e-3  # stop when no seed moves more than this
    max_iterations: int = 500
    sample_step_m: float = 0.02  # density samples for the cell centroids
    standoff_m: float = 1.0
    seed: int = 0
    layout: str = "lloyd"
    regularity: float = 0.5  # generator: 1 a regular grid, 0 uniform within each grid cell
    lloyd_steps: int = 2  # generator: relaxation steps after the jittered grid

    def __post_init__(self) -> None:
        if self.n_seeds < 1:
            raise ValueError(f"n_seeds must be >= 1, got {self.n_seeds}")
        if not (self.margin_m >= 0.0 and self.tolerance_m > 0.0 and self.sample_step_m > 0.0):
            raise ValueError("margin_m must be >= 0, tolerance_m and sample_step_m > 0")
        if self.layout not in VORONOI_LAYOUTS:
            raise ValueError(f"layout must be one of {VORONOI_LAYOUTS}, got {self.layout!r}")
        if not (0.0 <= self.regularity <= 1.0 and self.lloyd_steps >= 0):
            raise ValueError("regularity must be in [0, 1] and lloyd_steps >= 0")


@dataclass
class LloydResult:
    """Seeds on the strip ``(N, 2)`` as (s, z), and the quantisation energy per iteration."""

    seeds: np.ndarray
    energies: list[float]
    iterations: int
    converged: bool


def strip_samples(length: float, height: float, step: float) -> np.ndarray:
    """A regular grid of cell-centred samples ``(M, 2)`` over the strip."""

    def centres(extent: float) -> np.ndarray:
        cells = max(1, round(extent / step))
        return (np.arange(cells) + 0.5) * (extent / cells)

    ss, zz = np.meshgrid(centres(length), centres(height), indexing="ij")
    return np.column_stack([ss.ravel(), zz.ravel()])


def quantisation_energy(samples: np.ndarray, seeds: np.ndarray) -> float:
    """Mean squared distance from each sample to its nearest seed: what Lloyd lowers."""
    distances, _ = cKDTree(seeds).query(samples)
    return float(np.mean(distances**2))


def lloyd_relaxation(
    length: float, height: float, params: VoronoiParams | None = None, initial: np.ndarray | None = None
) -> LloydResult:
    """Lloyd's method on the rectangle ``[0, length] x [0, height]``.

    Each iteration assigns the density samples to their nearest seed (the Voronoi
    cells, clipped to the strip), moves each seed to its cell's centroid and clamps
    it into the margin box. The energy never rises: the centroid minimises a cell's
    energy and the clamp is the nearest box point to it.
    """
    params = params or VoronoiParams()
    low = np.array([params.margin_m, params.margin_m])
    high = np.array([length - params.margin_m, height - params.margin_m])
    if np.any(high < low):
        raise ValueError(f"a margin of {params.margin_m} m leaves no room on a {length} x {height} m strip")
    rng = np.random.default_rng(params.seed)
    seeds = rng.uniform(low, high, size=(params.n_seeds, 2)) if initial is None else np.array(initial, float)
    samples = strip_samples(length, height, params.sample_step_m)
    energies: list[float] = []
    for iteration in range(1, params.max_iterations + 1):
        # one nearest-seed query per iteration gives both the cells and the energy of the seeds as they are
        distances, owner = cKDTree(seeds).query(samples)
        energies.append(float(np.mean(distances**2)))
        counts = np.bincount(owner, minlength=len(seeds))
        sums = np.stack(
            [np.bincount(owner, weights=samples[:, k], minlength=len(seeds)) for k in range(2)], 1
        )
        centroids = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], seeds)
        moved = np.clip(centroids, low, high)
        shift = float(np.max(np.linalg.norm(moved - seeds, axis=1)))
        seeds = moved
        if shift < params.tolerance_m:
            return LloydResult(seeds, [*energies, quantisation_energy(samples, seeds)], iteration, True)
    return LloydResult(seeds, [*energies, quantisation_energy(samples, seeds)], params.max_iterations, False)


def jittered_grid_seeds(length: float, height: float, params: VoronoiParams) -> np.ndarray:
    """``params.n_seeds`` seeds ``(N, 2)`` on a jittered grid over the margin box: the grid has about
    square cells (columns / rows as the box's aspect), surplus cells are dropped at random, and each seed
    sits at its cell's centre plus ``(1 - regularity)`` of a uniform offset within the cell."""
    rng = np.random.default_rng(params.seed)
    low = np.array([params.margin_m, params.margin_m])
    size = np.array([length, height]) - 2 * params.margin_m
    if np.any(size < 0):
        raise ValueError(f"a margin of {params.margin_m} m leaves no room on a {length} x {height} m strip")
    n = params.n_seeds
    columns = max(1, round(math.sqrt(n * size[0] / max(size[1], 1e-9))))
    rows = math.ceil(n / columns)
    cells = np.array([(c, r) for r in range(rows) for c in range(columns)], float)
    cells = cells[np.sort(rng.choice(len(cells), n, replace=False))]
    cell = size / np.array([columns, rows])
    jitter = (1.0 - params.regularity) * rng.uniform(-0.5, 0.5, size=(n, 2))
    return low + (cells + 0.5 + jitter) * cell


def voronoi_seeds(length: float, height: float, params: VoronoiParams | None = None) -> np.ndarray:
    """The Voronoi layout's seeds ``(N, 2)`` on a ``length x height`` strip (:class:`VoronoiParams`)."""
    params = params or VoronoiParams()
    if params.layout == "lloyd":
        return lloyd_relaxation(length, height, params).seeds
    start = jittered_grid_seeds(length, height, params)
    if params.lloyd_steps == 0:
        return start
    stepped = replace(params, max_iterations=params.lloyd_steps, tolerance_m=1e-12)
    return lloyd_relaxation(length, height, stepped, initial=start).seeds


def voronoi_viewpoints(tank: TankModel, params: VoronoiParams | None = None) -> np.ndarray:
    """Voronoi baseline: the layout's seeds on the strip of the tank's baseline geometry
    (:meth:`maptidal.tank.TankModel.baseline_geometry`), mapped to viewpoints ``(N, 6)``."""
    params = params or VoronoiParams()
    tank = tank.baseline_geometry()
    seeds = voronoi_seeds(tank.strip_length, tank.height, params)
    return strip_to_viewpoints(tank, seeds[:, 0], seeds[:, 1], params.standoff_m)


@dataclass(frozen=True)
class BoustrophedonParams:
    """Horizontal lanes over the strip (paper: 0.1 m overlap, 2 points in sections > 1 m)."""

    standoff_m: float = 1.0
    overlap_m: float = 0.1
    long_section_m: float = 1.0
    interpolation_points: int = 2
    vfov_deg: float = OAKD_VFOV_DEG

    def lane_spacing(self) -> float:
        """Camera footprint height at the standoff minus the lateral overlap."""
        footprint = 2.0 * self.standoff_m * math.tan(math.radians(self.vfov_deg) / 2.0)
        spacing = footprint - self.overlap_m
        if spacing <= 0.0:
            raise ValueError(
                f"overlap {self.overlap_m} m is not smaller than the {footprint:.3f} m footprint"
            )
        return spacing


def lane_heights(height: float, params: BoustrophedonParams) -> np.ndarray:
    """Heights of the lanes: as few as cover the strip, the band centred on it."""
    spacing = params.lane_spacing()
    footprint = spacing + params.overlap_m
    lanes = max(1, math.ceil((height - params.overlap_m) / spacing))
    band = lanes * spacing + params.overlap_m
    first = (height - band) / 2.0 + footprint / 2.0
    return first + spacing * np.arange(lanes)


def lane_positions(tank: TankModel, params: BoustrophedonParams) -> np.ndarray:
    """Strip positions along one lane: section corners plus interpolation points."""
    corners = tank.corner_s()
    positions = [corners[0]]
    for a, b in itertools.pairwise(corners):
        if b - a > params.long_section_m + 1e-9:  # float sums of section lengths
            k = params.interpolation_points
            positions += list(a + (b - a) * np.arange(1, k + 1) / (k + 1))
        positions.append(b)
    return np.array(positions)


def boustrophedon_viewpoints(tank: TankModel, params: BoustrophedonParams | None = None) -> np.ndarray:
    """Boustrophedon baseline: lanes swept alternately left-right over the strip of the tank's baseline
    geometry, as viewpoints ``(N, 6)``."""
    params = params or BoustrophedonParams()
    tank = tank.baseline_geometry()
    along = lane_positions(tank, params)
    s, z = [], []
    for lane, height in enumerate(lane_heights(tank.height, params)):
        order = along if lane % 2 == 0 else along[::-1]
        s += list(order)
        z += [height] * len(order)
    return strip_to_viewpoints(tank, np.array(s), np.array(z), params.standoff_m)
