"""The tank's unknown dimensions, calibrated from the baselines' published figures (issue [fidelity]).

The paper gives the OSB tank's dimensions only in its Fig. 6, a picture we do not have. Its two baselines
(Sec. IV.E) do not depend on discovery: their figures follow from the geometry and the
baselines' own rules alone. So, with the baselines' rules fixed at our reading of Sec. IV.E, we fit
the dimensions the paper leaves open so that our Voronoi and boustrophedon rows match the paper's:

============== ===== ============== ========== =====
method         tasks % uninspected  mean views MAD
============== ===== ============== ========== =====
Voronoi        20    17.32          1.39       0.100
boustrophedon  30    8.94           1.80       0.081
============== ===== ============== ========== =====

What is fitted (the paper leaves it open): the end wall's width, the angled walls' length, the evaluated
length of each side wall, the share of it in the geometry the baselines lay their points on (the paper's
Fig. 6A draws the generation geometry and the voxelised region apart), the water depth, and the
window's width and height. What is fixed by the paper
and not fitted: 20 Voronoi seeds, the boustrophedon's 0.1 m lateral overlap and two interpolation points
in sections longer than 1 m, the 1 m standoff, the OAK-D's field of view and the 2 m far plane, and the
paper's coverage count (no occlusion, 5 cm voxels). What is our reading, also not fitted: wall avoidance
as a 0.25 m margin, Lloyd relaxation run to convergence, the lanes' placement and corner viewpoints.

The residuals are scaled by what we take as each figure's resolution (a task, a percentage point of
uninspected walls, a tenth of a view, a hundredth of MAD) and the objective is their sum of squares. The
objective is piecewise constant in places (lane and section counts are integers, voxels are discrete),
so the search is a coarse grid followed by a Nelder-Mead polish from its best points. How well each
dimension is determined is reported as the range, along that dimension alone, over which the objective
stays within 1 of its minimum (one more unit of scaled residual).
"""

from __future__ import annotations

import copy
import itertools
import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from maptidal.evaluation.baselines import (
    BoustrophedonParams,
    VoronoiParams,
    boustrophedon_viewpoints,
    voronoi_viewpoints,
)
from maptidal.evaluation.comparison import PAPER_TABLE
from maptidal.evaluation.coverage import CoverageModel, CoverageParams
from maptidal.files import save_png
from maptidal.paths import asset
from maptidal.tank import TankConfigError, TankModel, tank_config_from_dict

# the paper, Sec. IV.E: the baselines' published figures
PAPER_BASELINES = {method: PAPER_TABLE[method] for method in ("voronoi", "boustrophedon")}
# the resolution each residual is scaled by (module docstring)
SCALES = {"tasks": 1.0, "pct_uninspected": 1.0, "mean_views": 0.1, "mad": 0.01}
# the fitted dimensions: (section, key) in the tank TOML, and the search bounds (m)
DIMENSIONS = {
    "end_width": (("end_wall", "width"), (1.5, 6.0)),
    "angled_length": (("angled_walls", "length"), (0.3, 5.0)),
    "side_evaluated": (("side_walls", "evaluated_length"), (0.2, 5.0)),
    # the part of each side wall the baselines lay points on, as a share of the evaluated part
    # (Fig. 6A draws the generation geometry and the evaluated region apart)
    "side_baseline_share": (("side_walls", "baseline_share"), (0.0, 1.0)),
    "water_depth": (("water_depth",), (1.5, 4.0)),
    "window_width": (("window", "width"), (0.4, 1.4)),
    "window_height": (("window", "height"), (0.3, 1.0)),
}


@dataclass(frozen=True)
class CalibrationParams:
    """How the fit runs: the grid's points per dimension, how many grid points seed the polish, the
    polish's evaluations, and the coverage voxel size (the paper's 5 cm by default)."""

    grid_points: int = 3
    polish_starts: int = 3
    polish_evaluations: int = 120
    voxel_m: float = 0.05
    fit: tuple[str, ...] = tuple(DIMENSIONS)
    # the dimensions the grid spans (the others start at the base tank's values and are only polished):
    # the window changes the evaluated area little, so it is left to the polish
    grid: tuple[str, ...] = (
        "end_width",
        "angled_length",
        "side_evaluated",
        "side_baseline_share",
        "water_depth",
    )
    # Lloyd's cell centroids on a 4 cm sample grid (compare uses 2 cm): four times fewer samples, for a
    # fit that evaluates hundreds of tanks; the best fit's figures are then recomputed at 2 cm
    voronoi: VoronoiParams = field(default_factory=lambda: VoronoiParams(sample_step_m=0.04))
    boustrophedon: BoustrophedonParams = field(default_factory=BoustrophedonParams)

    def __post_init__(self) -> None:
        unknown = (set(self.fit) | set(self.grid)) - set(DIMENSIONS)
        if unknown:
            raise ValueError(f"unknown dimensions {sorted(unknown)}; known: {', '.join(DIMENSIONS)}")
        if self.grid_points < 1 or self.polish_starts < 0 or self.polish_evaluations < 0:
            raise ValueError("grid_points must be >= 1, polish_starts and polish_evaluations >= 0")


def base_document() -> dict:
    """The default tank's TOML document (the starting point every candidate changes)."""
    return tomllib.loads(asset("osb_tank", "tank.toml").read_text())


def tank_document(dimensions: dict[str, float], base: dict | None = None) -> dict:
    """The tank document with ``dimensions`` (names of :data:`DIMENSIONS`) set. The window stays centred
    at its height unless it no longer fits, when it is lowered to fit; the fouling patches and the ladder
    keep their places relative to the end wall's centre."""
    document = copy.deepcopy(base if base is not None else base_document())
    for name, value in dimensions.items():
        path, _ = DIMENSIONS[name]
        table = document
        for key in path[:-1]:
            table = table.setdefault(key, {})
        table[path[-1]] = float(value)
    side = document.setdefault("side_walls", {})
    share = side.pop("baseline_share", None)
    if share is not None:
        side["baseline_length"] = float(share) * float(side["evaluated_length"])
    window = document.get("window", {})
    depth = float(document["water_depth"])
    if window.get("width", 0) > 0:
        half = window["height"] / 2
        window["centre_height"] = min(max(window.get("centre_height", 1.0), half + 0.05), depth - half - 0.05)
    ladder = document.get("ladder", {})
    if ladder.get("rails", 0):
        end_half = document["end_wall"]["width"] / 2
        ladder["centre_offset"] = min(
            ladder.get("centre_offset", 0.75), end_half - ladder["rail_spacing"] / 2 - 0.05
        )
    # fouling patches stay on the strip
    tank = TankModel(tank_config_from_dict({**document, "fouling": []}))
    patches = []
    for patch in document.get("fouling", []):
        s = min(patch["s"], tank.strip_length - patch["radius"])
        z = min(patch["z"], depth - patch["radius"])
        patches.append({**patch, "s": s, "z": z})
    document["fouling"] = patches
    return document


def baseline_figures(tank: TankModel, params: CalibrationParams | None = None) -> dict[str, dict]:
    """The two baselines' tasks, % uninspected, mean views and MAD on ``tank`` (the paper's count)."""
    params = params or CalibrationParams()
    model = CoverageModel.from_tank(tank, CoverageParams(voxel_m=params.voxel_m, occlusion=False))
    figures = {}
    for name, viewpoints in (
        ("voronoi", voronoi_viewpoints(tank, params.voronoi)),
        ("boustrophedon", boustrophedon_viewpoints(tank, params.boustrophedon)),
    ):
        report, _ = model.evaluate(viewpoints)
        figures[name] = {
            "tasks": len(viewpoints),
            "pct_uninspected": report.pct_uninspected,
            "mean_views": report.mean_views,
            "mad": report.mad,
        }
    return figures


def compare_figures(dimensions: dict[str, float], base: dict | None = None) -> dict[str, dict]:
    """The baselines' figures on the tank with ``dimensions``, at ``maptidal compare``'s own settings
    (Lloyd on 2 cm samples; a fit uses coarser ones): what a fitted tank is reported with."""
    tank = TankModel(tank_config_from_dict(tank_document(dimensions, base)))
    return baseline_figures(tank, CalibrationParams(voronoi=VoronoiParams()))


def _figures_or_none(job: tuple[dict[str, float], dict, CalibrationParams]) -> dict | None:
    """The baselines' figures for one candidate (dimensions, base document, params); None where the
    geometry cannot be built."""
    dimensions, base, params = job
    try:
        tank = TankModel(tank_config_from_dict(tank_document(dimensions, base)))
        return baseline_figures(tank, params)
    except (TankConfigError, ValueError):
        return None


def residuals(figures: dict[str, dict], targets: dict[str, dict] = PAPER_BASELINES) -> dict[str, float]:
    """Scaled residuals ``(ours - target) / scale``, keyed ``method.metric``."""
    return {
        f"{method}.{metric}": (figures[method][metric] - target) / SCALES[metric]
        for method, row in targets.items()
        for metric, target in row.items()
    }


@dataclass
class CalibrationResult:
    """The best dimensions, their figures and residuals, the objective, each dimension's determined
    range, and every candidate evaluated (dimensions, objective)."""

    dimensions: dict[str, float]
    figures: dict[str, dict]
    residuals: dict[str, float]
    objective: float
    determined: dict[str, tuple[float, float]]
    evaluations: list[tuple[dict[str, float], float]]

    def to_dict(self) -> dict:
        """JSON-ready."""
        return {
            "dimensions": self.dimensions,
            "figures": self.figures,
            "residuals": self.residuals,
            "objective": self.objective,
            "determined": {k: list(v) for k, v in self.determined.items()},
            "evaluations": len(self.evaluations),
        }


class Calibration:
    """The fit of :data:`DIMENSIONS` to ``targets`` (module docstring). ``base`` is the tank document the
    candidates start from (default: the OSB tank); ``fixed`` holds dimensions kept at given values."""

    def __init__(
        self,
        targets: dict[str, dict] = PAPER_BASELINES,
        params: CalibrationParams | None = None,
        base: dict | None = None,
        fixed: dict[str, float] | None = None,
    ) -> None:
        self.targets = targets
        self.params = params or CalibrationParams()
        self.base = base if base is not None else base_document()
        self.fixed = dict(fixed or {})
        self.names = [n for n in self.params.fit if n not in self.fixed]
        self.evaluations: list[tuple[dict[str, float], float]] = []
        self._cache: dict[tuple, tuple[float, dict]] = {}

    def _dimensions(self, vector) -> dict[str, float]:
        values = {n: float(np.clip(v, *DIMENSIONS[n][1])) for n, v in zip(self.names, vector, strict=True)}
        return {**self.fixed, **values}

    @staticmethod
    def _key(dimensions: dict[str, float]) -> tuple:
        return tuple(round(dimensions[n], 4) for n in sorted(dimensions))

    def _record(self, dimensions: dict[str, float], figures: dict | None) -> float:
        value = (
            math.inf
            if figures is None
            else float(sum(r * r for r in residuals(figures, self.targets).values()))
        )
        self._cache[self._key(dimensions)] = (value, figures or {})
        self.evaluations.append((dimensions, value))
        return value

    def objective(self, vector) -> float:
        """The sum of squared scaled residuals at ``vector`` (the fitted dimensions in order); a geometry
        that cannot be built (a window wider than its wall) scores infinity."""
        dimensions = self._dimensions(vector)
        key = self._key(dimensions)
        if key not in self._cache:
            return self._record(dimensions, _figures_or_none((dimensions, self.base, self.params)))
        return self._cache[key][0]

    def run(self, progress: Callable[[int, float], None] | None = None, jobs: int = 1) -> CalibrationResult:
        """Grid (in ``jobs`` local processes), then Nelder-Mead from the best grid points; the result
        with each dimension's determined range."""
        from scipy.optimize import minimize

        from maptidal.executors import run_jobs

        p = self.params
        axes = [
            np.linspace(*DIMENSIONS[n][1], p.grid_points) if n in p.grid else [self.base_value(n)]
            for n in self.names
        ]
        vectors = list(itertools.product(*axes))
        candidates = [self._dimensions(v) for v in vectors]
        scored = []
        work = [(c, self.base, self.params) for c in candidates]
        for index, figures in run_jobs(_figures_or_none, work, jobs=jobs):
            scored.append((self._record(candidates[index], figures), vectors[index]))
            if progress is not None:
                progress(len(self.evaluations), min(value for value, _ in scored))
        scored.sort(key=lambda item: (item[0], item[1]))  # ties by position: whatever order runs finish in
        best_value, best = scored[0][0], np.array(scored[0][1], float)
        spans = np.array([DIMENSIONS[n][1][1] - DIMENSIONS[n][1][0] for n in self.names])
        for value, start in scored[: p.polish_starts]:
            if not math.isfinite(value):
                continue
            simplex = [np.array(start, float)] + [
                np.array(start, float) + np.eye(len(start))[k] * spans[k] / max(p.grid_points, 2) / 2
                for k in range(len(start))
            ]
            found = minimize(
                self.objective,
                np.array(start, float),
                method="Nelder-Mead",
                options={"maxfev": p.polish_evaluations, "initial_simplex": np.array(simplex), "xatol": 0.01},
            )
            if found.fun < best_value:
                best_value, best = (
                    float(found.fun),
                    np.clip(found.x, *np.array([DIMENSIONS[n][1] for n in self.names]).T),
                )
            if progress is not None:
                progress(len(self.evaluations), best_value)
        dimensions = self._dimensions(best)
        figures = self._cache[self._key(dimensions)][1]
        return CalibrationResult(
            dimensions,
            figures,
            residuals(figures, self.targets),
            best_value,
            self._determined(best, best_value),
            self.evaluations,
        )

    @property
    def grid_size(self) -> int:
        """How many tanks the grid evaluates."""
        return math.prod(self.params.grid_points for n in self.names if n in self.params.grid)

    def base_value(self, name: str) -> float:
        """The base tank's value of dimension ``name``, clipped into its search bounds."""
        if name == "side_baseline_share":  # not a TOML key: the baseline part over the evaluated part
            side = self.base.get("side_walls", {})
            evaluated = float(side.get("evaluated_length", 0.5))
            return float(side.get("baseline_length", evaluated)) / evaluated if evaluated > 0 else 1.0
        table = self.base
        for key in DIMENSIONS[name][0]:
            table = table[key]
        return float(np.clip(float(table), *DIMENSIONS[name][1]))

    def _determined(self, best: np.ndarray, best_value: float) -> dict[str, tuple[float, float]]:
        """Per dimension, the range along it alone (others at the best) where the objective stays within
        1 of the minimum: probed outwards at 1/64, 1/32, .. 1 of the distance to each bound, up to the
        first probe past it."""
        ranges = {}
        for k, name in enumerate(self.names):
            low, high = DIMENSIONS[name][1]
            lowest = highest = float(best[k])
            for bound in (low, high):
                for fraction in 2.0 ** -np.arange(6, -1, -1):
                    probe = best.copy()
                    probe[k] = best[k] + fraction * (bound - best[k])
                    if self.objective(probe) > best_value + 1.0:
                        break
                    lowest, highest = min(lowest, float(probe[k])), max(highest, float(probe[k]))
            ranges[name] = (lowest, highest)
        return ranges


def calibration_markdown(result: CalibrationResult, base: dict[str, float]) -> str:
    """The fit as markdown: the dimensions (base, fitted, determined range) and the figures beside the
    paper's, with the scaled residuals."""
    lines = [
        "# The tank calibrated from the baselines",
        "",
        "side_baseline_share is a share of the evaluated side-wall length, not metres.",
        "",
        f"Objective (sum of squared scaled residuals): {result.objective:.2f}, "
        f"over {len(result.evaluations)} tanks evaluated.",
        "",
        "| dimension | base (m) | fitted (m) | determined range (m) |",
        "|---|---|---|---|",
    ]
    for name, fitted in result.dimensions.items():
        low, high = result.determined.get(name, (fitted, fitted))
        lines.append(
            f"| {name} | {base.get(name, float('nan')):.2f} | {fitted:.2f} | {low:.2f} to {high:.2f} |"
        )
    lines += ["", "| method | figure | ours | paper | scaled residual |", "|---|---|---|---|---|"]
    for method, row in PAPER_BASELINES.items():
        for metric, target in row.items():
            ours = result.figures.get(method, {}).get(metric, float("nan"))
            residual = result.residuals.get(f"{method}.{metric}", float("nan"))
            lines.append(f"| {method} | {metric} | {ours:.3g} | {target:g} | {residual:+.2f} |")
    lines += ["", "![objective against each dimension](calibration.png)", ""]
    return "\n".join(lines)


def plot_calibration(result: CalibrationResult, path) -> None:
    """Every evaluated tank's objective against each fitted dimension (log scale), the best fit marked
    and its determined range shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(result.dimensions)
    columns = min(3, len(names))
    rows = math.ceil(len(names) / columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4 * columns, 3.2 * rows), squeeze=False)
    finite = [(d, v) for d, v in result.evaluations if math.isfinite(v)]
    for axis, name in zip(axes.flat, names, strict=False):
        axis.semilogy([d[name] for d, _ in finite], [max(v, 1e-3) for _, v in finite], ".", ms=3, alpha=0.5)
        axis.axvline(result.dimensions[name], color="C3", lw=1.5)
        low, high = result.determined.get(name, (result.dimensions[name],) * 2)
        axis.axvspan(low, high, color="C3", alpha=0.15, lw=0)
        axis.set_xlabel(f"{name} ({'share' if name.endswith('share') else 'm'})")
        axis.set_ylabel("objective")
    for axis in list(axes.flat)[len(names) :]:
        axis.set_visible(False)
    figure.suptitle("Tank calibration: every tank evaluated (red: best fit and its determined range)")
    figure.tight_layout()
    save_png(figure, path)
