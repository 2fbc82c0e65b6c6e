"""The paper's evaluation on our tank: Map-TIDAL against Voronoi and boustrophedon
(Section IV.E, Fig. 7 and 8), and the parameter sweep (Table I).

Every method is scored by the same :class:`maptidal.evaluation.coverage.CoverageModel`, built
once from the tank config. Map-TIDAL runs on the synthetic exploration keyframes
(:mod:`maptidal.keyframes`), frame by frame, each frame's existing tasks being all
the tasks found before it. Outputs are written as they are produced, atomically.
"""

from __future__ import annotations

import csv
import io
import itertools
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.discovery import DiscoveryInputError, DiscoveryParams, DiscoveryResult, discover
from maptidal.evaluation.baselines import (
    BoustrophedonParams,
    VoronoiParams,
    boustrophedon_viewpoints,
    voronoi_viewpoints,
)
from maptidal.evaluation.coverage import CoverageModel, CoverageParams, CoverageReport
from maptidal.evaluation.free_space import free_space_counts, free_space_mask
from maptidal.executors import run_jobs
from maptidal.files import atomic_write_json, atomic_write_text, save_tasks
from maptidal.keyframes import (
    ExplorationParams,
    FeatureParams,
    Keyframe,
    PaperCaptureParams,
    RefinementParams,
    exploration_poses,
    keyframes_at,
    paper_capture_poses,
)
from maptidal.perception.mesher import MesherParams
from maptidal.progress import ProgressBar
from maptidal.tank import TankModel, load_tank_config

# voronoi: Lloyd relaxed to convergence; voronoi_generator: the paper's seed generator as we read it
# (maptidal.evaluation.baselines.VoronoiParams); both are set against the paper's one Voronoi row
METHODS = ("maptidal", "voronoi", "voronoi_generator", "boustrophedon")
CAPTURE_PATHS = ("sweep", "paper")

# Paper, Section IV.E: the comparison on the OSB tank.
PAPER_TABLE = {
    "maptidal": {"pct_uninspected": 3.81, "mean_views": 2.56, "tasks": 20, "mad": 0.029},
    "voronoi": {"pct_uninspected": 17.32, "mean_views": 1.39, "tasks": 20, "mad": 0.100},
    "boustrophedon": {"pct_uninspected": 8.94, "mean_views": 1.80, "tasks": 30, "mad": 0.081},
}
PAPER_TABLE["voronoi_generator"] = PAPER_TABLE["voronoi"]  # both readings set against the one row


@dataclass(frozen=True)
class EvaluationConfig:
    """Everything one comparison depends on; the defaults are the paper's choices."""

    tank_path: str | None = None
    seed: int = 0
    coverage: CoverageParams = field(default_factory=CoverageParams)
    discovery: DiscoveryParams = field(default_factory=DiscoveryParams)
    exploration: ExplorationParams = field(default_factory=ExplorationParams)
    camera: StereoCameraParams = field(default_factory=StereoCameraParams)
    features: FeatureParams | None = None  # None: FeatureParams(seed=seed)
    voronoi: VoronoiParams = field(default_factory=VoronoiParams)
    boustrophedon: BoustrophedonParams = field(default_factory=BoustrophedonParams)
    # drop each keyframe's new tasks that are not in the water or cannot see their target
    # (maptidal.evaluation.free_space); off by default, as the paper has no such check
    free_space: bool = False
    # "paper" (the default): the paper's protocol, 7 keyframes rising 0.5 m in front of the end wall
    # (PaperCaptureParams); "sweep": the two yaw sweeps of ExplorationParams
    capture: str = "paper"
    paper_capture: PaperCaptureParams = field(default_factory=PaperCaptureParams)
    # Kimera-like landmark fusion over the frames they are tracked in (on by default; off: one
    # triangulation per keyframe)
    refinement: RefinementParams = field(default_factory=lambda: RefinementParams(enabled=True))
    # the keyframe mesher's bad-triangle thresholds (Kimera's shipped configs by default)
    mesher: MesherParams = field(default_factory=MesherParams)

    def __post_init__(self) -> None:
        if self.capture not in CAPTURE_PATHS:
            raise ValueError(f"capture must be one of {CAPTURE_PATHS}, got {self.capture!r}")


@dataclass
class MapTidalRun:
    """Tasks found over a keyframe sequence and each frame's stage counts."""

    tasks: np.ndarray
    frames: list[dict]
    # per frame, every stage of its discovery (None where the frame was skipped): for Fig. 4-style pictures
    results: list[DiscoveryResult | None] = field(default_factory=list, repr=False)


def config_keyframes(tank: TankModel, config: EvaluationConfig) -> list[Keyframe]:
    """The keyframes an evaluation config asks for: its capture path's poses."""
    poses = (
        paper_capture_poses(config.paper_capture)
        if config.capture == "paper"
        else exploration_poses(tank, config.exploration)
    )
    return keyframes_at(
        tank,
        poses,
        features=config.features,
        camera=config.camera,
        seed=config.seed,
        refinement=config.refinement,
        mesher=config.mesher,
    )


def landmark_noise_curve(config: EvaluationConfig, levels: tuple[float, ...]) -> list[dict]:
    """Map-TIDAL against the stereo disparity noise (px), with and without landmark refinement: task
    count, share of keyframe faces within theta_ex of a surface normal, and coverage, per level."""
    tank = TankModel(load_tank_config(config.tank_path))
    model = CoverageModel.from_tank(tank, config.coverage)
    rows = []
    for level in levels:
        for refined in (False, True):
            run_config = replace(
                config,
                camera=replace(config.camera, disparity_sigma_px=float(level)),
                refinement=replace(config.refinement, enabled=refined),
            )
            keyframes = config_keyframes(tank, run_config)
            run = discover_over_keyframes(keyframes, config.discovery)
            report, _ = model.evaluate(run.tasks)
            rows.append(
                {
                    "disparity_sigma_px": float(level),
                    "refined": refined,
                    "faces_within_theta_ex": wall_aligned_fraction(
                        tank, keyframes, config.discovery.theta_ex
                    ),
                    **summary_row(report),
                }
            )
    return rows


def surface_looks(tank: TankModel) -> np.ndarray:
    """``(S, 3)``: the direction of looking straight at each wall segment and at the floor."""
    return np.array([-seg.inward_normal for seg in tank.segments] + [np.array([0.0, 0.0, -1.0])])


def surface_aligned_count(tank: TankModel, viewpoints: np.ndarray, angle_rad: float) -> int:
    """How many viewpoints ``(N, 6)`` look within ``angle_rad`` of straight at a wall or the floor: the
    tasks that came from faces lying on one surface, as against faces bridging two (or tilted by noise)."""
    rows = np.asarray(viewpoints, float).reshape(-1, 6)
    if len(rows) == 0:
        return 0
    directions = rows[:, 3:] / np.linalg.norm(rows[:, 3:], axis=1, keepdims=True)
    return int(np.count_nonzero((directions @ surface_looks(tank).T).max(axis=1) > np.cos(angle_rad)))


def wall_aligned_fraction(tank: TankModel, keyframes: list[Keyframe], angle_rad: float) -> float:
    """Fraction of all keyframe faces whose view direction is within ``angle_rad`` of
    looking straight at a wall or the floor.

    A diagnostic of why discovery adds tasks: CIPs are excluded only by tasks
    within theta_ex in direction, so faces off every surface normal (stereo noise,
    triangles bridging the ladder and the wall, the window recess, the floor line)
    each tend to become tasks.
    """
    looks = surface_looks(tank)
    aligned = total = 0
    for keyframe in keyframes:
        v, f = keyframe.mesh.vertices, keyframe.mesh.faces
        if len(f) == 0:
            continue
        normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        lengths = np.linalg.norm(normals, axis=1)
        views = -normals[lengths > 0] / lengths[lengths > 0, None]
        aligned += int(np.count_nonzero((views @ looks.T).max(axis=1) > np.cos(angle_rad)))
        total += len(views)
    return aligned / total if total else 0.0


def discover_over_keyframes(
    keyframes: list[Keyframe], params: DiscoveryParams, free_space_tank: TankModel | None = None
) -> MapTidalRun:
    """Run discovery frame by frame; each frame's existing tasks are all earlier tasks.

    A keyframe whose mesh is empty or only degenerate is skipped and logged in its
    frame record, as a real front end would skip it. With ``free_space_tank``, each frame's new tasks
    that fail :func:`maptidal.evaluation.free_space.free_space_mask` on that tank are dropped (and counted).
    """
    tasks = np.empty((0, 6))
    frames, results = [], []
    for index, keyframe in enumerate(keyframes):
        record: dict = {"frame": index, "faces": len(keyframe.mesh.faces)}
        if len(keyframe.mesh.faces) == 0:
            frames.append({**record, "skipped": "empty mesh"})
            results.append(None)
            continue
        try:
            result = discover(keyframe.mesh.vertices, keyframe.mesh.faces, existing=tasks, params=params)
        except DiscoveryInputError as err:
            frames.append({**record, "skipped": str(err)})
            results.append(None)
            continue
        results.append(result)
        new = result.final
        if free_space_tank is not None and len(new):
            keep = free_space_mask(free_space_tank, new, params.standoff)
            record["dropped_by_free_space"] = int((~keep).sum())
            new = new[keep]
        tasks = np.vstack([tasks, new])
        frames.append({**record, **result.counts, "mode": result.pruning_mode, "total_tasks": len(tasks)})
    return MapTidalRun(tasks, frames, results)


def method_viewpoints(
    tank: TankModel, config: EvaluationConfig, keyframes: list[Keyframe] | None = None
) -> tuple[dict[str, np.ndarray], MapTidalRun]:
    """Viewpoints of each method on ``tank`` (Map-TIDAL, the two Voronoi readings, boustrophedon) and
    the Map-TIDAL run's per-keyframe record."""
    if keyframes is None:
        keyframes = config_keyframes(tank, config)
    run = discover_over_keyframes(keyframes, config.discovery, tank if config.free_space else None)
    viewpoints = {
        "maptidal": run.tasks,
        "voronoi": voronoi_viewpoints(tank, replace(config.voronoi, seed=config.seed)),
        "voronoi_generator": voronoi_viewpoints(
            tank, replace(config.voronoi, seed=config.seed, layout="generator")
        ),
        "boustrophedon": boustrophedon_viewpoints(tank, config.boustrophedon),
    }
    return viewpoints, run


def summary_row(report: CoverageReport) -> dict:
    """The comparison table's columns for one method."""
    return {
        "tasks": report.n_viewpoints,
        "pct_uninspected": report.pct_uninspected,
        "mean_views": report.mean_views,
        "mad": report.mad,
    }


def comparison_table(rows: dict[str, dict]) -> str:
    """The comparison as a markdown table, ours beside the paper's numbers."""
    lines = [
        "| method | tasks | % uninspected | mean views | MAD "
        "| paper: tasks | % uninspected | mean views | MAD |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, row in rows.items():
        paper = PAPER_TABLE.get(name, {})
        lines.append(
            f"| {name} | {row['tasks']} | {row['pct_uninspected']:.2f} | {row['mean_views']:.2f} | "
            f"{row['mad']:.3f} | {paper.get('tasks', '')} | {paper.get('pct_uninspected', '')} | "
            f"{paper.get('mean_views', '')} | {paper.get('mad', '')} |"
        )
    return "\n".join(lines)


def expected_ordering(rows: dict[str, dict]) -> dict[str, bool]:
    """The paper's claims, checked on our numbers: fewest uninspected, lowest MAD, no more tasks."""
    ours, others = rows["maptidal"], [rows[m] for m in METHODS[1:] if m in rows]
    return {
        "fewest_uninspected": all(ours["pct_uninspected"] <= o["pct_uninspected"] for o in others),
        "lowest_mad": all(ours["mad"] <= o["mad"] for o in others),
        "no_more_tasks": all(ours["tasks"] <= o["tasks"] for o in others),
    }


def run_compare(
    out_dir: str | os.PathLike | None,
    config: EvaluationConfig | None = None,
    plots: bool = True,
    progress: bool = True,
    rendered: list[Keyframe] | None = None,
) -> dict:
    """Run the three methods on one voxelised tank; write tasks, JSON, plots and report.md.

    Returns ``{"methods": {name: {tasks, pct_uninspected, mean_views, mad}}, ...}``.
    With ``out_dir`` None nothing is written. With ``rendered`` keyframes (from rendered stereo frames,
    :mod:`maptidal.frame_discovery`), Map-TIDAL also runs on them, reported beside the synthetic
    keyframes' run as ``maptidal_rendered``.
    """
    config = config or EvaluationConfig()
    tank = TankModel(load_tank_config(config.tank_path))
    bar = ProgressBar(4 + (len(METHODS) + 1 if plots and out_dir else 0), "compare", enabled=progress)
    model = CoverageModel.from_tank(tank, config.coverage)
    bar.advance(note=f"{len(model.voxels)} voxels")
    keyframes = config_keyframes(tank, config)
    bar.advance(note=f"{len(keyframes)} keyframes")
    viewpoints, run = method_viewpoints(tank, config, keyframes)
    rendered_run = None
    if rendered is not None:
        rendered_run = discover_over_keyframes(
            rendered, config.discovery, tank if config.free_space else None
        )
        viewpoints["maptidal_rendered"] = rendered_run.tasks
    bar.advance(note="viewpoints")
    reports, views = {}, {}
    for name, rows in viewpoints.items():
        reports[name], views[name] = model.evaluate(rows)
    bar.advance(note="coverage")
    table = {name: summary_row(report) for name, report in reports.items()}
    document = {
        "methods": table,
        "paper": PAPER_TABLE,
        "ordering_as_paper": expected_ordering(table),
        "tank": tank.config.name,
        "n_voxels": len(model.voxels),
        "coverage": {**config.coverage.__dict__},
        "discovery": config.discovery.to_dict(),
        "mesher": {**config.mesher.__dict__},
        "keyframes": run.frames,
        "keyframes_rendered": None if rendered_run is None else rendered_run.frames,
        "faces_within_theta_ex_of_a_surface_normal": wall_aligned_fraction(
            tank, keyframes, config.discovery.theta_ex
        ),
        # of Map-TIDAL's tasks, those looking within theta_ex of straight at a wall or the floor
        "maptidal_tasks_within_theta_ex_of_a_surface_normal": surface_aligned_count(
            tank, viewpoints["maptidal"], config.discovery.theta_ex
        ),
        "reports": {name: report.to_dict() for name, report in reports.items()},
        # where each method's tasks lie (maptidal.evaluation.free_space), whether or not the check was on
        "free_space": {
            "check": config.free_space,
            **{
                name: free_space_counts(tank, rows, config.discovery.standoff)
                for name, rows in viewpoints.items()
            },
        },
    }
    if out_dir is None:
        return document
    out = Path(out_dir)
    for name, rows in viewpoints.items():
        save_tasks(out / f"tasks_{name}.json", rows, method=name)
    atomic_write_json(out / "compare.json", document)
    if plots:
        from maptidal.evaluation.plots import plot_histograms, plot_voxel_views

        plot_histograms(reports, out / "histogram.png", title=f"Views per voxel on {tank.config.name}")
        bar.advance(note="histogram.png")
        for name in viewpoints:
            share = reports[name].pct_uninspected
            title = f"{name}: {len(viewpoints[name])} viewpoints, {share:.1f}% uninspected"
            path = out / f"voxels_{name}.png"
            plot_voxel_views(model.voxels, views[name], viewpoints[name], path, title, tank=tank)
            bar.advance(note=f"voxels_{name}.png")
    atomic_write_text(out / "report.md", compare_report(document, plots))
    return document


def compare_report(document: dict, plots: bool) -> str:
    """The markdown report of a comparison."""
    ordering = document["ordering_as_paper"]
    verdict = ", ".join(f"{k.replace('_', ' ')}: {'yes' if v else 'NO'}" for k, v in ordering.items())
    frames = document["keyframes"]
    lines = [
        f"# Coverage comparison on `{document['tank']}`",
        "",
        f"{document['n_voxels']} voxels of {document['coverage']['voxel_m']} m; frustum far plane "
        f"{document['coverage']['far_m']} m; occlusion "
        f"{'on' if document['coverage']['occlusion'] else 'off (as the paper)'}.",
        f"Map-TIDAL ran on {len(frames)} synthetic keyframes with "
        + ", ".join(f"{k} = {v:g}" for k, v in document["discovery"].items())
        + ".",
        "",
        comparison_table(document["methods"]),
        "",
        f"The paper's ordering on our model: {verdict}.",
        "",
        f"Keyframe faces whose view direction is within theta_ex of a wall or floor normal: "
        f"{100 * document['faces_within_theta_ex_of_a_surface_normal']:.0f}%. Discovery excludes a CIP "
        "only near a task of similar direction, so the other faces tend to add tasks: "
        f"{document['maptidal_tasks_within_theta_ex_of_a_surface_normal']} of the "
        f"{document['methods']['maptidal']['tasks']} Map-TIDAL tasks look within theta_ex of "
        "straight at a surface.",
        "",
        "Where the Map-TIDAL tasks lie (free space check "
        f"{'on: the others were dropped' if document['free_space']['check'] else 'off, as the paper'}): "
        + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in document["free_space"]["maptidal"].items())
        + ".",
        "",
    ]
    if plots:
        lines += ["![histogram](histogram.png)", ""]
        lines += [f"![{m}](voxels_{m}.png)" for m in document["methods"]] + [""]
    lines += [
        "| keyframe | faces | CIPs | after pruning | confirmed | new tasks | total |",
        "|---|---|---|---|---|---|---|",
    ]
    for f in frames:
        if "skipped" in f:
            lines.append(f"| {f['frame']} | {f['faces']} | skipped: {f['skipped']} | | | | |")
        else:
            lines.append(
                f"| {f['frame']} | {f['faces']} | {f['cips']} | {f['after_prune']} ({f['mode']}) | "
                f"{f['confirmed']} | {f['final']} | {f['total_tasks']} |"
            )
    lines += ["", "Files: `compare.json`, `tasks_<method>.json`, the PNGs above.", ""]
    return "\n".join(lines)


# ----- parameter sweep (Table I) --------------------------------------------------------------

DEFAULT_GRID = {"t": (0.70, 0.75, 0.80), "r_ex": (1.5, 1.6, 1.7, 1.8), "theta_ex": (0.25, 0.3)}
GRID_TO_PARAM = {"t": "threshold", "r_ex": "r_ex", "theta_ex": "theta_ex"}

# Per worker process: keyframes and voxels are built once, then reused for every combination.
_WORKER_STATE: dict = {}


def parse_grid(tokens: list[str]) -> dict[str, tuple[float, ...]]:
    """Parse ``["t=0.7,0.75", "r_ex=1.5,1.7"]`` into a grid; missing names keep their defaults."""
    grid = dict(DEFAULT_GRID)
    given: set[str] = set()
    for token in tokens:
        name, sep, values = token.partition("=")
        if sep and name in GRID_TO_PARAM and name in given:
            raise ValueError(f"grid entry {token!r}: {name} is given twice; put all its values in one entry")
        given.add(name)
        if not sep or name not in GRID_TO_PARAM:
            raise ValueError(
                f"bad grid entry {token!r}: use NAME=V1,V2,... with NAME one of {sorted(GRID_TO_PARAM)}"
            )
        try:
            grid[name] = tuple(float(v) for v in values.split(",") if v.strip())
        except ValueError:
            raise ValueError(f"bad grid values in {token!r}: expected numbers separated by commas") from None
        if not grid[name]:
            raise ValueError(f"grid entry {token!r} has no values")
    return grid


def grid_size(grid: dict[str, tuple[float, ...]]) -> int:
    """How many combinations a sweep grid has."""
    return len(grid["t"]) * len(grid["r_ex"]) * len(grid["theta_ex"])


def _worker_setup(config: EvaluationConfig) -> None:
    tank = TankModel(load_tank_config(config.tank_path))
    _WORKER_STATE["config"] = config
    _WORKER_STATE["tank"] = tank
    _WORKER_STATE["model"] = CoverageModel.from_tank(tank, config.coverage)
    _WORKER_STATE["keyframes"] = config_keyframes(tank, config)


def _evaluate_combination(combination: tuple[float, float, float]) -> dict:
    t, r_ex, theta_ex = combination
    config: EvaluationConfig = _WORKER_STATE["config"]
    params = replace(config.discovery, threshold=t, r_ex=r_ex, theta_ex=theta_ex)
    tank = _WORKER_STATE["tank"] if config.free_space else None
    run = discover_over_keyframes(_WORKER_STATE["keyframes"], params, tank)
    report, _ = _WORKER_STATE["model"].evaluate(run.tasks)
    return {"t": t, "r_ex": r_ex, "theta_ex": theta_ex, **summary_row(report)}


def run_sweep(
    out_dir: str | os.PathLike | None,
    grid: dict[str, tuple[float, ...]] | None = None,
    config: EvaluationConfig | None = None,
    jobs: int = 1,
    plots: bool = True,
    progress: bool = True,
    executor: str = "local",
    ray_address: str | None = None,
) -> list[dict]:
    """Evaluate Map-TIDAL over a grid of (t, r_ex, theta_ex); write CSV, markdown and heatmaps.

    Runs in ``jobs`` local processes, or on Ray (:func:`maptidal.executors.run_jobs`); rows come back
    in grid order whatever the finishing order, and the CSV is rewritten (atomically) as each one lands.
    """
    grid = grid or DEFAULT_GRID
    config = config or EvaluationConfig()
    for name, values in grid.items():
        for value in values:
            replace(config.discovery, **{GRID_TO_PARAM[name]: value})  # validates every value up front
    combinations = list(itertools.product(grid["t"], grid["r_ex"], grid["theta_ex"]))
    bar = ProgressBar(len(combinations), "sweep", enabled=progress)
    out = Path(out_dir) if out_dir is not None else None
    results: dict[int, dict] = {}
    outcomes = run_jobs(
        _evaluate_combination,
        combinations,
        executor=executor,
        jobs=jobs,
        ray_address=ray_address,
        initializer=_worker_setup,
        initargs=(config,),
    )
    for index, row in outcomes:
        results[index] = row
        bar.advance(
            note=f"t={row['t']:g} r_ex={row['r_ex']:g} theta_ex={row['theta_ex']:g}: {row['tasks']} tasks"
        )
        if out is not None:
            atomic_write_text(out / "sweep.csv", sweep_csv([results[k] for k in sorted(results)]))
    rows = [results[k] for k in sorted(results)]
    if out is not None:
        atomic_write_text(out / "sweep.md", sweep_markdown(rows))
        if plots:
            from maptidal.evaluation.plots import plot_sweep_heatmaps

            plot_sweep_heatmaps(rows, out / "sweep.png")
    return rows


def sweep_csv(rows: list[dict]) -> str:
    """Sweep rows as CSV text."""
    buffer = io.StringIO()
    writer = csv.DictWriter(
        buffer, fieldnames=["t", "r_ex", "theta_ex", "tasks", "pct_uninspected", "mean_views", "mad"]
    )
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def sweep_markdown(rows: list[dict]) -> str:
    """Sweep rows in the layout of the paper's Table I: rows t x r_ex, columns per theta_ex."""
    angles = sorted({r["theta_ex"] for r in rows})
    lookup = {(r["t"], r["r_ex"], r["theta_ex"]): r for r in rows}
    header = "| t | r_ex (m) | " + " | ".join(f"avg ({a:g}) | num ({a:g}) | % ({a:g})" for a in angles) + " |"
    lines = [
        "# Map-TIDAL parameter sweep (layout of the paper's Table I)",
        "",
        "avg: mean views per voxel; num: tasks; %: voxels never viewed. Columns grouped by theta_ex (rad).",
        "",
        header,
        "|---|---|" + "---|" * (3 * len(angles)),
    ]
    for t in sorted({r["t"] for r in rows}):
        for r_ex in sorted({r["r_ex"] for r in rows}):
            cells = []
            for a in angles:
                row = lookup.get((t, r_ex, a))
                cells += (
                    [f"{row['mean_views']:.2f}", str(row["tasks"]), f"{row['pct_uninspected']:.2f}"]
                    if row
                    else [""] * 3
                )
            lines.append(f"| {t:g} | {r_ex:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
