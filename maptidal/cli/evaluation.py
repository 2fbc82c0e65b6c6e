"""``maptidal coverage``, ``compare`` and ``sweep``: the paper's coverage evaluation (Sec. IV)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from maptidal.cli.common import (
    add_capture_args,
    add_coverage_args,
    add_discovery_params,
    add_executor_args,
    add_output_folder,
    check_executor_args,
    coverage_params_from,
    discovery_params_from,
    jobs_for,
    output_dir,
    positive_int,
)


def register(commands) -> None:
    """Add the ``coverage``, ``compare``, ``sweep`` and ``calibrate-tank`` subcommands."""
    coverage = commands.add_parser(
        "coverage",
        help="views per voxel of a task list on the tank model",
        description="Voxelise the tank's evaluated walls and count, per voxel, the viewpoints whose camera "
        "frustum contains it (paper Sec. IV.B); report % uninspected, mean views and MAD against the ideal "
        "gamma distribution (alpha 4, beta 2/3).",
    )
    coverage.add_argument("tasks", metavar="TASKS.json", help="viewpoints ({'tasks': [...]}, m)")
    add_coverage_args(coverage)
    coverage.add_argument("--json", action="store_true", help="print the full report as JSON")
    coverage.add_argument(
        "--plot-dir", type=output_dir, metavar="DIR", help="write histogram.png, voxels.png, coverage.json"
    )
    coverage.set_defaults(handler=run_coverage)

    compare = commands.add_parser(
        "compare",
        help="Map-TIDAL vs Voronoi vs boustrophedon on the tank (the paper's Sec. IV.E comparison)",
        description="Run Map-TIDAL on synthetic keyframes of the tank (the paper's capture protocol and "
        "Kimera-like landmark refinement by default), and the Voronoi and boustrophedon baselines, "
        "score them on the same voxels, print the paper's comparison table "
        "and write compare.json, tasks, plots and report.md.",
    )
    add_coverage_args(compare)
    add_capture_args(compare)
    compare.add_argument(
        "--keyframes",
        choices=("synthetic", "rendered"),
        default="synthetic",
        help="synthetic keyframes only (default), or also keyframes from rendered stereo frames: the robot "
        "flies the --capture path in the simulator and the stereo front end meshes its frames; both "
        "Map-TIDAL runs are reported side by side",
    )
    compare.add_argument(
        "--free-space",
        action="store_true",
        help="drop Map-TIDAL tasks outside the water or without a line of sight to their target "
        "(off by default: the paper has no such check)",
    )
    compare.add_argument(
        "--seed", type=int, default=0, help="seed of keyframes and Voronoi (default %(default)s)"
    )
    compare.add_argument("--json", action="store_true", help='print {"methods": {...}} as JSON')
    add_output_folder(compare, "runs/compare")
    compare.add_argument("--no-write", action="store_true", help="write no files, only print")
    compare.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    add_discovery_params(compare)
    compare.set_defaults(handler=run_compare)

    sweep = commands.add_parser(
        "sweep",
        help="Map-TIDAL over a grid of t, r_ex and theta_ex (Table I)",
        description="Evaluate Map-TIDAL's coverage for every combination of the grid, in parallel local "
        "processes or on a Ray cluster; writes sweep.csv, sweep.md (Table I's layout) and sweep.png "
        "(heatmaps).",
    )
    sweep.add_argument(
        "--grid",
        nargs="+",
        metavar="NAME=V1,V2",
        help="grid values (t unitless, r_ex in m, theta_ex in rad); "
        "default t=0.70,0.75,0.80 r_ex=1.5,1.6,1.7,1.8 theta_ex=0.25,0.3",
    )
    add_output_folder(sweep, "runs/sweep")
    add_executor_args(sweep, "grid cells")
    sweep.add_argument("--seed", type=int, default=0, help="seed of the keyframes (default %(default)s)")
    noise = commands.add_parser(
        "noise-curve",
        help="Map-TIDAL's task count against the stereo landmark noise, with and without refinement",
        description="Run Map-TIDAL on the synthetic keyframes at several disparity noise levels, each with "
        "one triangulation per keyframe and with landmarks refined over the frames they are tracked in "
        "(Kimera's back end does this); report the task count, the share of keyframe faces within theta_ex "
        "of a surface normal and the coverage, and plot them (noise_curve.png).",
    )
    noise.add_argument(
        "--levels",
        default="0,0.1,0.25,0.5",
        metavar="PX,...",
        help="disparity noise sigma_d (default %(default)s)",
    )
    noise.add_argument("--seed", type=int, default=0, help="seed of the keyframes (default %(default)s)")
    noise.add_argument("--json", action="store_true", help="print the rows as JSON")
    add_output_folder(noise, "runs/noise_curve")
    add_coverage_args(noise)
    add_capture_args(noise, refinement=False)
    noise.set_defaults(handler=run_noise_curve, free_space=False)
    add_discovery_params(noise)
    sweep.add_argument("--no-plots", action="store_true", help="skip the heatmap PNG")
    sweep.add_argument(
        "--paper-grid",
        action="store_true",
        help="the 24 cells of the paper's Table I, written beside the paper's values with its colour "
        "classes and the rank correlation of each column (paper_table.md, paper_table.json)",
    )
    sweep.add_argument(
        "--json",
        action="store_true",
        help='print the result as JSON ({"cells": [...], "rank_correlation": {...}} with --paper-grid)',
    )
    add_coverage_args(sweep)
    add_capture_args(sweep)
    sweep.add_argument(
        "--free-space",
        action="store_true",
        help="drop Map-TIDAL tasks outside the water or without a line of sight to their target "
        "(off by default: the paper has no such check)",
    )
    add_discovery_params(sweep)
    sweep.set_defaults(handler=run_sweep)

    calibrate = commands.add_parser(
        "calibrate-tank",
        help="fit the tank's unknown dimensions to the paper's Voronoi and boustrophedon figures",
        description="Fit the dimensions the paper leaves open (end-wall width, angled-wall length, "
        "evaluated side-wall length, water depth, window size) so that our Voronoi and boustrophedon "
        "baselines give the paper's tasks, % uninspected, mean views and MAD (Sec. IV.E). A grid over "
        "the walls and the depth, then a Nelder-Mead polish; writes calibration.json, calibration.md, "
        "calibration.png and calibrated_tank.toml to --out.",
    )
    calibrate.add_argument(
        "--grid-points",
        type=positive_int,
        default=3,
        metavar="N",
        help="grid points per gridded dimension (default %(default)s: 243 tanks)",
    )
    calibrate.add_argument(
        "--polish-evaluations",
        type=positive_int,
        default=120,
        metavar="N",
        help="Nelder-Mead evaluations from each of the 3 best grid points (default %(default)s)",
    )
    calibrate.add_argument(
        "--fit",
        metavar="NAME,...",
        help="the dimensions to fit (default all: end_width, angled_length, side_evaluated, "
        "side_baseline_share, water_depth, window_width, window_height); the others keep the default "
        "tank's values",
    )
    calibrate.add_argument(
        "--jobs", type=positive_int, default=1, metavar="N", help="local processes for the grid"
    )
    calibrate.add_argument("--json", action="store_true", help="print the result as JSON")
    add_output_folder(calibrate, "runs/calibration")
    calibrate.set_defaults(handler=run_calibrate_tank)


def run_coverage(args: argparse.Namespace) -> int:
    """Handler of ``maptidal coverage``."""
    from maptidal.evaluation.coverage import CoverageModel
    from maptidal.files import atomic_write_json, load_tasks
    from maptidal.tank import TankModel, load_tank_config

    params = coverage_params_from(args)
    tasks = load_tasks(args.tasks)
    tank = TankModel(load_tank_config(args.tank))
    model = CoverageModel.from_tank(tank, params)
    report, views = model.evaluate(tasks)
    document = {"tank": tank.config.name, **report.to_dict()}
    if args.plot_dir:
        from maptidal.evaluation.plots import plot_histograms, plot_voxel_views

        out = Path(args.plot_dir)
        name = Path(args.tasks).name
        plot_histograms({"tasks": report}, out / "histogram.png", title=f"{name} on {tank.config.name}")
        plot_voxel_views(model.voxels, views, tasks, out / "voxels.png", title=name, tank=tank)
        atomic_write_json(out / "coverage.json", document)
    if args.json:
        print(json.dumps(document))
    else:
        print(
            f"{report.n_viewpoints} viewpoints, {report.n_voxels} voxels: "
            f"{report.pct_uninspected:.2f}% uninspected, "
            f"{report.mean_views:.2f} mean views, MAD {report.mad:.4f}"
        )
    return 0


def run_noise_curve(args: argparse.Namespace) -> int:
    """Handler of ``maptidal noise-curve``."""
    from maptidal.evaluation.comparison import landmark_noise_curve
    from maptidal.evaluation.plots import plot_noise_curve
    from maptidal.files import atomic_write_json

    levels = tuple(float(v) for v in args.levels.split(","))
    if not levels or not all(math.isfinite(v) and 0 <= v <= 5 for v in levels):
        raise ValueError(f"--levels must be disparity noise values in [0, 5] px, got {args.levels!r}")
    config = _evaluation_config(args)
    rows = landmark_noise_curve(config, levels)
    out = Path(args.out)
    atomic_write_json(out / "noise_curve.json", {"capture": config.capture, "rows": rows})
    plot_noise_curve(
        rows, out / "noise_curve.png", title=f"Map-TIDAL against landmark noise ({config.capture} capture)"
    )
    if args.json:
        print(json.dumps({"rows": rows}))
        return 0
    print("| sigma_d (px) | refined | tasks | faces within theta_ex | % uninspected | mean views | MAD |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['disparity_sigma_px']:g} | {'yes' if r['refined'] else 'no'} | {r['tasks']} | "
            f"{100 * r['faces_within_theta_ex']:.0f}% | {r['pct_uninspected']:.2f} | {r['mean_views']:.2f} | "
            f"{r['mad']:.3f} |"
        )
    print(f"files in {out}: noise_curve.json, noise_curve.png")
    return 0


def _evaluation_config(args: argparse.Namespace):
    from maptidal.evaluation.comparison import EvaluationConfig
    from maptidal.keyframes import RefinementParams
    from maptidal.perception.mesher import MesherParams

    discovery = discovery_params_from(args)
    return EvaluationConfig(
        tank_path=args.tank,
        seed=args.seed,
        coverage=coverage_params_from(args, discovery),
        discovery=discovery,
        free_space=args.free_space,
        capture=args.capture,
        refinement=RefinementParams(enabled=getattr(args, "refinement", True)),
        mesher=MesherParams.preset(args.mesher),
    )


def run_compare(args: argparse.Namespace) -> int:
    """Handler of ``maptidal compare``."""
    from maptidal.evaluation.comparison import comparison_table, run_compare

    out = None if args.no_write else args.out
    rendered = _rendered_keyframes(args, out) if args.keyframes == "rendered" else None
    document = run_compare(
        out, _evaluation_config(args), plots=not args.no_plots, progress=not args.json, rendered=rendered
    )
    if args.json:
        print(json.dumps({"methods": document["methods"]}))
        return 0
    print(comparison_table(document["methods"]))
    ordering = ", ".join(f"{k}: {v}" for k, v in document["ordering_as_paper"].items())
    print(f"paper's ordering holds: {ordering}")
    if out:
        print(f"report: {Path(out) / 'report.md'}")
    return 0


def _rendered_keyframes(args: argparse.Namespace, out: Path | None):
    """Fly the --capture path in the simulator (the default scenario), run the front end on its frames
    (ground-truth poses; the first 7 keyframes on the paper path) and return the keyframes."""
    import tempfile

    from maptidal.frame_discovery import discover_on_recording
    from maptidal.mission.capture import CaptureParams, capture
    from maptidal.perception.frontend import FrontEndParams

    if args.tank is not None:
        raise ValueError("--keyframes rendered flies the default scenario's tank; drop --tank")
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(out) / "recording" if out is not None else Path(scratch)
        recording = capture(folder, params=CaptureParams(path=args.capture), seed=args.seed)
        limit = 7 if args.capture == "paper" else None
        result = discover_on_recording(recording, "truth", FrontEndParams(max_keyframes=limit))
        return result.run.discovery_keyframes


def run_sweep(args: argparse.Namespace) -> int:
    """Handler of ``maptidal sweep``."""
    from maptidal.evaluation.comparison import grid_size, parse_grid, run_sweep, sweep_markdown
    from maptidal.evaluation.paper_table import (
        PAPER_GRID,
        rank_correlations,
        side_by_side,
        table_markdown,
        trends,
    )
    from maptidal.files import atomic_write_json, atomic_write_text

    if args.paper_grid and args.grid:
        raise ValueError("--paper-grid is the paper's grid: give it or --grid, not both")
    check_executor_args(args)
    grid = dict(PAPER_GRID) if args.paper_grid else parse_grid(args.grid or [])
    jobs = jobs_for(args, grid_size(grid), "sweep")
    plots = not args.no_plots
    rows = run_sweep(
        args.out,
        grid,
        _evaluation_config(args),
        jobs=jobs,
        plots=plots,
        progress=not args.json,
        executor=args.executor,
        ray_address=args.ray_address,
    )
    files = ["sweep.csv", "sweep.md"] + (["sweep.png"] if plots else [])
    if args.paper_grid:
        cells = side_by_side(rows)
        document = {
            "cells": cells,
            "rank_correlation": rank_correlations(cells),
            "trends": {"ours": trends(cells, "ours"), "paper": trends(cells, "paper")},
        }
        atomic_write_json(Path(args.out) / "paper_table.json", document)
        atomic_write_text(
            Path(args.out) / "paper_table.md", table_markdown(cells, document["rank_correlation"])
        )
        files += ["paper_table.json", "paper_table.md"]
        if args.json:
            print(json.dumps(document))
            return 0
        print(table_markdown(cells, document["rank_correlation"]))
    elif args.json:
        print(json.dumps({"rows": rows}))
        return 0
    else:
        print(sweep_markdown(rows))
    print(f"files in {args.out}: {', '.join(files)}")
    return 0


def run_calibrate_tank(args: argparse.Namespace) -> int:
    """Handler of ``maptidal calibrate-tank``."""
    from maptidal.evaluation.calibration import (
        DIMENSIONS,
        Calibration,
        CalibrationParams,
        calibration_markdown,
        compare_figures,
        plot_calibration,
        residuals,
        tank_document,
    )
    from maptidal.files import atomic_write_json, atomic_write_text
    from maptidal.progress import ProgressBar
    from maptidal.tank import tank_toml

    fit = tuple(DIMENSIONS) if args.fit is None else tuple(n.strip() for n in args.fit.split(","))
    grid = tuple(n for n in CalibrationParams().grid if n in fit)
    params = CalibrationParams(
        grid_points=args.grid_points, polish_evaluations=args.polish_evaluations, fit=fit, grid=grid
    )
    calibration = Calibration(params=params)
    total = calibration.grid_size + params.polish_starts * params.polish_evaluations
    bar = ProgressBar(total, "calibrate", enabled=not args.json)
    state = {"shown": 0}

    def progress(evaluations: int, best: float) -> None:
        step = min(evaluations, total) - state["shown"]
        if step > 0:
            bar.advance(step, f"best objective {best:.2f}")
            state["shown"] += step

    result = calibration.run(progress, jobs=jobs_for(args, calibration.grid_size, "calibrate-tank"))
    # reported at compare's own settings (the fit's Lloyd samples are coarser)
    result.figures = compare_figures(result.dimensions, calibration.base)
    result.residuals = residuals(result.figures)
    out = Path(args.out)
    base = {name: calibration.base_value(name) for name in DIMENSIONS}
    document = {**tank_document(result.dimensions, calibration.base), "name": "osb_tank_calibrated"}
    header = (
        "The OSB tank with the dimensions the paper leaves open fitted to its baselines' figures\n"
        "(maptidal calibrate-tank; the fit, its residuals and ranges: calibration.md beside this file)."
    )
    atomic_write_text(out / "calibrated_tank.toml", tank_toml(document, header))
    atomic_write_json(out / "calibration.json", result.to_dict())
    atomic_write_text(out / "calibration.md", calibration_markdown(result, base))
    plot_calibration(result, out / "calibration.png")
    if args.json:
        print(json.dumps(result.to_dict()))
        return 0
    print(calibration_markdown(result, base))
    print(f"files in {out}: calibrated_tank.toml, calibration.json, calibration.md, calibration.png")
    return 0
