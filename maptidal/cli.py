"""The ``maptidal`` command line.

Subcommands:
  discover  Map-TIDAL task discovery on one mesh (PLY, OBJ or STL)
  coverage  views per voxel of a task list on the tank model (paper Sec. IV.B-D)
  compare   Map-TIDAL against Voronoi and boustrophedon; what `make run` runs
  sweep     Map-TIDAL over a grid of t, r_ex, theta_ex (the layout of Table I)
  demo      discovery over a pass of synthetic keyframes along one wall
  sim       step the MuJoCo world with a constant pilot command
  allocate  decentralised CBBA allocation over a simulated acoustic channel
  export-mjcf  write a scenario's world as MJCF files (Menagerie style)

Every subcommand has ``--help``. Bad input ends with a one-line error and exit
status 2; nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from maptidal.discovery import DiscoveryInputError, DiscoveryParams
from maptidal.files import atomic_write_bytes
from maptidal.progress import ProgressBar
from maptidal.tank import TankConfigError

EXIT_BAD_INPUT = 2


def _add_discovery_params(parser: argparse.ArgumentParser) -> None:
    defaults = DiscoveryParams()
    group = parser.add_argument_group("discovery parameters (defaults: the paper's best values)")
    group.add_argument(
        "--standoff",
        type=float,
        default=defaults.standoff,
        metavar="M",
        help="L_i, CIP distance from the surface (default %(default)s m)",
    )
    group.add_argument(
        "--r-ex",
        type=float,
        default=defaults.r_ex,
        metavar="M",
        help="radius of exclusion (default %(default)s m)",
    )
    group.add_argument(
        "--theta-ex",
        type=float,
        default=defaults.theta_ex,
        metavar="RAD",
        help="angle of exclusion (default %(default)s rad)",
    )
    group.add_argument(
        "--threshold",
        type=float,
        default=defaults.threshold,
        metavar="T",
        help="keypoint score to confirm a CIP, in [0, 1] (default %(default)s)",
    )
    group.add_argument(
        "--p-s",
        type=float,
        default=defaults.p_s,
        metavar="P",
        help="self-pruning scale of r_ex and theta_ex (default %(default)s)",
    )
    group.add_argument(
        "--hfov-deg",
        type=float,
        default=defaults.hfov_deg,
        metavar="DEG",
        help="camera horizontal field of view (default %(default)s deg)",
    )
    group.add_argument(
        "--vfov-deg",
        type=float,
        default=defaults.vfov_deg,
        metavar="DEG",
        help="camera vertical field of view (default %(default)s deg)",
    )
    group.add_argument(
        "--range",
        dest="range_m",
        type=float,
        default=None,
        metavar="M",
        help="frustum far plane (default 2 x standoff)",
    )


def _params_from(args: argparse.Namespace) -> DiscoveryParams:
    return DiscoveryParams(
        standoff=args.standoff,
        r_ex=args.r_ex,
        theta_ex=args.theta_ex,
        threshold=args.threshold,
        p_s=args.p_s,
        hfov_deg=args.hfov_deg,
        vfov_deg=args.vfov_deg,
        range_m=args.range_m,
    )


def _cmd_discover(args: argparse.Namespace) -> int:
    from maptidal.discovery import discover
    from maptidal.files import atomic_write_json, load_keypoints, load_mesh, load_tasks

    params = _params_from(args)
    vertices, faces = load_mesh(args.mesh)
    existing = load_tasks(args.existing) if args.existing else None
    keypoints = load_keypoints(args.keypoints) if args.keypoints else None
    result = discover(vertices, faces, existing=existing, keypoints=keypoints, params=params)
    document = result.to_json_dict()
    if args.out:
        atomic_write_json(args.out, document)
    if args.plot:
        from maptidal.plotting import plot_discovery

        plot_discovery(result, vertices, faces, args.plot, existing=existing, title=f"{Path(args.mesh).name}")
    if args.json:
        print(json.dumps(document))
    else:
        counts = result.counts
        print(
            f"{counts['cips']} CIPs -> {counts['after_prune']} after pruning ({result.pruning_mode}) -> "
            f"{counts['confirmed']} confirmed / {len(result.remains)} remain -> {counts['final']} new tasks"
        )
        for label, path in (("tasks", args.out), ("plot", args.plot)):
            if path:
                print(f"{label}: {path}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from maptidal.demo import DemoConfig, run_demo

    params = _params_from(args)
    run_demo(args.out, DemoConfig(seed=args.seed), params=params, plots=not args.no_plots)
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0


def _add_coverage_args(parser: argparse.ArgumentParser) -> None:
    from maptidal.coverage import CoverageParams

    defaults = CoverageParams()
    group = parser.add_argument_group("coverage model")
    group.add_argument(
        "--tank", metavar="CONFIG", help="tank config TOML (default assets/osb_tank/tank.toml)"
    )
    group.add_argument(
        "--voxel",
        type=float,
        default=defaults.voxel_m,
        metavar="M",
        help="voxel size (default %(default)s m)",
    )
    group.add_argument(
        "--far",
        type=float,
        default=defaults.far_m,
        metavar="M",
        help="frustum far plane (default %(default)s m)",
    )
    group.add_argument(
        "--occlusion",
        action="store_true",
        help="count a voxel only when the ray to it is unblocked (the paper does not)",
    )


def _coverage_params(args: argparse.Namespace, discovery: DiscoveryParams | None = None):
    from maptidal.coverage import CoverageParams

    camera = discovery or DiscoveryParams()
    return CoverageParams(
        voxel_m=args.voxel,
        far_m=args.far,
        hfov_deg=camera.hfov_deg,
        vfov_deg=camera.vfov_deg,
        occlusion=args.occlusion,
    )


def _cmd_coverage(args: argparse.Namespace) -> int:
    from maptidal.coverage import CoverageModel
    from maptidal.files import atomic_write_json, load_tasks
    from maptidal.tank import TankModel, load_tank_config

    tasks = load_tasks(args.tasks)
    tank = TankModel(load_tank_config(args.tank))
    model = CoverageModel.from_tank(tank, _coverage_params(args))
    report, views = model.evaluate(tasks)
    document = {"tank": tank.config.name, **report.to_dict()}
    if args.plot_dir:
        from maptidal.coverage_plots import plot_histograms, plot_voxel_views

        out = Path(args.plot_dir)
        plot_histograms(
            {"tasks": report}, out / "histogram.png", title=f"{Path(args.tasks).name} on {tank.config.name}"
        )
        plot_voxel_views(model.voxels, views, tasks, out / "voxels.png", title=Path(args.tasks).name)
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


def _evaluation_config(args: argparse.Namespace):
    from maptidal.evaluation import EvaluationConfig

    discovery = _params_from(args)
    return EvaluationConfig(
        tank_path=args.tank,
        seed=args.seed,
        coverage=_coverage_params(args, discovery),
        discovery=discovery,
    )


def _cmd_compare(args: argparse.Namespace) -> int:
    from maptidal.evaluation import comparison_table, run_compare

    out = None if args.no_write else args.out
    document = run_compare(out, _evaluation_config(args), plots=not args.no_plots, progress=not args.json)
    if args.json:
        print(json.dumps({"methods": document["methods"]}))
    else:
        print(comparison_table(document["methods"]))
        ordering = ", ".join(f"{k}: {v}" for k, v in document["ordering_as_paper"].items())
        print(f"paper's ordering holds: {ordering}")
        if out:
            print(f"report: {Path(out) / 'report.md'}")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from maptidal.evaluation import parse_grid, run_sweep, sweep_markdown

    grid = parse_grid(args.grid or [])
    if args.jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {args.jobs}")
    rows = run_sweep(args.out, grid, _evaluation_config(args), jobs=args.jobs, plots=not args.no_plots)
    print(sweep_markdown(rows))
    print(f"files: {Path(args.out) / 'sweep.csv'}, sweep.md, sweep.png")
    return 0


def _add_sim_parser(commands) -> None:
    """Register the ``sim`` subcommand on the CLI's subparsers."""
    sim = commands.add_parser(
        "sim",
        help="run the MuJoCo world headless with a constant pilot command",
        description="Load a scenario, hold a normalised 6-DOF pilot command (surge, sway, heave, roll, "
        "pitch, yaw in [-1, 1], ArduSub's meaning) on every robot for the duration, and print the final "
        "ground-truth state of the first robot with the run's speed.",
    )
    sim.add_argument(
        "--scenario", metavar="FILE", help="scenario TOML (default assets/scenarios/default.toml)"
    )
    sim.add_argument(
        "--frame", choices=("heavy", "standard"), help="switch every robot to this BlueROV2 frame"
    )
    sim.add_argument(
        "--command", default="", metavar="AXIS=V,...", help="e.g. surge=1.0,heave=-0.2 (default idle)"
    )
    sim.add_argument(
        "--duration", type=float, default=5.0, metavar="S", help="simulated seconds (default %(default)s)"
    )
    sim.add_argument("--render-dir", metavar="DIR", help="save stereo pairs (PNG) into DIR")
    sim.add_argument(
        "--render-every",
        type=int,
        default=25,
        metavar="N",
        help="control steps between saved pairs (default %(default)s)",
    )
    sim.add_argument(
        "--water-backend",
        choices=("auto", "gl", "cpu"),
        default="auto",
        help="where the underwater image model runs: a GL shader, the CPU, or auto (GL on a GPU, "
        "CPU on a software rasteriser; default %(default)s)",
    )
    sim.add_argument("--seed", type=int, default=0, help="noise seed (default %(default)s)")
    sim.add_argument("--json", action="store_true", help="print the result as JSON")
    sim.set_defaults(handler=_cmd_sim)


def _cmd_sim(args: argparse.Namespace) -> int:
    """Handler of ``maptidal sim``; returns the exit status."""
    import cv2

    from controllers.convention import parse_command
    from envs.scenario import load_scenario, with_frame
    from envs.simulation import Simulation

    if not (math.isfinite(args.duration) and args.duration > 0):
        raise ValueError(f"--duration must be a positive number of seconds, got {args.duration}")
    command = parse_command(args.command)
    scenario = load_scenario(args.scenario)
    if args.frame:
        scenario = with_frame(scenario, args.frame)
    sim = Simulation(scenario, water_backend=args.water_backend)
    sim.reset(seed=args.seed)
    steps = max(1, round(args.duration / (scenario.substeps * scenario.timestep_s)))
    render_dir = Path(args.render_dir) if args.render_dir else None
    if render_dir:
        render_dir.mkdir(parents=True, exist_ok=True)
    commands = {robot: command for robot in sim.robots}
    progress = ProgressBar(steps, "sim", enabled=not args.json)
    start = time.perf_counter()
    for k in range(steps):
        sim.step(commands)
        if render_dir and k % args.render_every == 0:
            for robot in sim.robots:
                left, right = sim.render_stereo(robot)
                _ok, png = cv2.imencode(".png", np.hstack([left, right])[..., ::-1])
                atomic_write_bytes(render_dir / f"{robot}_{k:05d}.png", png.tobytes())
        progress.advance()
    wall = time.perf_counter() - start
    truth = sim.ground_truth(sim.robots[0])
    physics_steps = steps * scenario.substeps
    result = {
        "robot": sim.robots[0],
        "position": truth["position"],
        "velocity_body": truth["velocity_body"],
        "rpy": truth["rpy"],
        "sim_time_s": sim.time,
        "steps_per_s": physics_steps / sim.wall_time_s if sim.wall_time_s > 0 else float("inf"),
        "realtime_factor": sim.time / wall if wall > 0 else float("inf"),
        "hydrodynamics": sim.backend,
    }
    if render_dir:
        result["water_backend"] = sim.water_backend
    if args.json:
        print(json.dumps(result))
    else:
        p, v, rpy = (np.round(result[k], 3).tolist() for k in ("position", "velocity_body", "rpy"))
        print(
            f"{result['robot']} after {result['sim_time_s']:.2f} s: position {p} m, body velocity {v} m/s, "
            f"rpy {np.round(np.degrees(rpy), 1).tolist()} deg"
        )
        print(
            f"{result['steps_per_s']:.0f} physics steps/s, {result['realtime_factor']:.1f}x real time "
            f"({result['hydrodynamics']} hydrodynamics)"
        )
    return 0


def _add_export_parser(commands) -> None:
    export = commands.add_parser(
        "export-mjcf",
        help="write a scenario's world as MJCF files (Menagerie style)",
        description="Write scene.xml (tank and robots), tank.xml, one bluerov2_<frame>.xml per frame, the "
        "procedural textures as PNG and a README into DIR, for MuJoCo's viewer and other tools. The "
        "hydrodynamics and thrust are a callback of maptidal's Simulation and are not in the files.",
    )
    export.add_argument(
        "--scenario", metavar="FILE", help="scenario TOML (default assets/scenarios/default.toml)"
    )
    export.add_argument("--frame", choices=("heavy", "standard"), help="switch every robot to this frame")
    export.add_argument(
        "--out", default="runs/mjcf", metavar="DIR", help="output folder (default %(default)s)"
    )
    export.set_defaults(handler=_cmd_export)


def _cmd_export(args: argparse.Namespace) -> int:
    from envs.export import export_world
    from envs.scenario import load_scenario, with_frame

    scenario = load_scenario(args.scenario)  # a ScenarioError is a ValueError: exit 2
    if args.frame:
        scenario = with_frame(scenario, args.frame)
    for name, path in export_world(scenario, args.out).items():
        print(f"{name}: {path}")
    return 0


def _add_allocate_parser(commands) -> None:
    allocate = commands.add_parser(
        "allocate",
        help="decentralised CBBA task allocation over a simulated acoustic channel",
        description="Run the Map-TIDAL auction (CBBA with bid warping, paper Sec. III.A) for the robots and "
        "tasks of SCENARIO.json over a slow, lossy acoustic channel in simulated time; report paths, "
        "conflicts, traffic and the ratio to a centralised greedy allocation. The scenario format is "
        "documented in maptidal/allocation/scenario.py.",
    )
    allocate.add_argument("scenario", metavar="SCENARIO.json", help="robots, tasks, channel and events")
    allocate.add_argument("--json", action="store_true", help="print the result as JSON")
    allocate.add_argument("--plot", metavar="PNG", help="draw robots, tasks and paths")
    allocate.add_argument("--out", metavar="RESULT.json", help="also write the JSON result (atomically)")
    allocate.add_argument("--quiet", action="store_true", help="no progress bar")
    allocate.set_defaults(handler=_cmd_allocate)


def _cmd_allocate(args: argparse.Namespace) -> int:
    from maptidal.allocation.report import plot_allocation, summarise
    from maptidal.allocation.scenario import load_scenario
    from maptidal.files import atomic_write_json

    scenario = load_scenario(args.scenario)
    simulation = scenario.simulation()
    steps = 100
    bar = ProgressBar(steps, "auction", enabled=not (args.quiet or args.json))
    progress_done = 0

    def progress(time_s: float) -> None:
        nonlocal progress_done
        reached = min(steps - 1, int(steps * time_s / scenario.max_time_s))
        if reached > progress_done:
            bar.advance(reached - progress_done, f"{time_s:.0f} s simulated")
            progress_done = reached

    report = simulation.run(scenario.max_time_s, progress)
    bar.advance(steps - progress_done, f"{simulation.time_s:.0f} s simulated")
    summary = summarise(simulation, report, scenario.task_names)
    if args.out:
        atomic_write_json(args.out, summary)
    if args.plot:
        plot_allocation(simulation, report, summary, args.plot)
    if args.json:
        print(json.dumps(summary))
        return 0
    state = "converged" if report.converged else f"NOT converged within {scenario.max_time_s:.0f} s"
    print(
        f"{state} after {summary['sim_time_s']:.1f} s simulated ({summary['rounds']} TDMA rounds): "
        f"{summary['messages']} messages, {summary['bytes']} bytes "
        f"({summary['bytes_per_message']} per message)"
    )
    for robot, entry in summary["robots"].items():
        print(f"  {robot}: {len(entry['path'])} tasks, {entry['length_m']:.2f} m  {' '.join(entry['path'])}")
    print(
        f"conflicts {summary['conflicts']}, disagreements {summary['disagreements']}, "
        f"unassigned {summary['unassigned'] or 'none'}, greedy ratio {summary['greedy_ratio']:.3f}"
    )
    if summary["failed"]:
        failed = ", ".join(summary["failed"])
        print(f"failed robots: {failed}; infeasible: {summary['infeasible']}; lost: {summary['lost']}")
    if summary["rejected_messages"]:
        print(f"rejected messages: {summary['rejected_messages']}")
    for label, path in (("result", args.out), ("plot", args.plot)):
        if path:
            print(f"{label}: {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``maptidal`` command and its subcommands."""
    parser = argparse.ArgumentParser(
        prog="maptidal",
        description="Map-TIDAL: mapping-guided task discovery and allocation for cooperative "
        "underwater inspection, in a headless MuJoCo testbed.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    discover = commands.add_parser(
        "discover",
        help="discover inspection tasks on one keyframe mesh",
        description="Run Map-TIDAL task discovery (paper Algorithms 1-3) on one mesh. "
        "Chain frames by passing one frame's --out as the next frame's --existing.",
    )
    discover.add_argument("mesh", help="keyframe mesh: .ply, .obj or .stl")
    discover.add_argument("--existing", metavar="TASKS.json", help="existing tasks T_e ({'tasks': [...]})")
    discover.add_argument(
        "--keypoints",
        metavar="FILE",
        help="keypoints as .npy (K x 3) or a .ply point cloud (default: mesh vertices)",
    )
    _add_discovery_params(discover)
    discover.add_argument("--json", action="store_true", help="print the result as JSON")
    discover.add_argument("--out", metavar="TASKS.json", help="write the new tasks (atomically)")
    discover.add_argument("--plot", metavar="PNG", help="draw the mesh, CIPs and tasks")
    discover.set_defaults(handler=_cmd_discover)

    coverage = commands.add_parser(
        "coverage",
        help="views per voxel of a task list on the tank model",
        description="Voxelise the tank's evaluated walls and count, per voxel, the viewpoints whose camera "
        "frustum contains it (paper Sec. IV.B); report %% uninspected, mean views and MAD against the ideal "
        "gamma distribution (alpha 4, beta 2/3).",
    )
    coverage.add_argument("tasks", metavar="TASKS.json", help="viewpoints ({'tasks': [...]})")
    _add_coverage_args(coverage)
    coverage.add_argument("--json", action="store_true", help="print the full report as JSON")
    coverage.add_argument("--plot-dir", metavar="DIR", help="write histogram.png, voxels.png, coverage.json")
    coverage.set_defaults(handler=_cmd_coverage)

    compare = commands.add_parser(
        "compare",
        help="Map-TIDAL vs Voronoi vs boustrophedon on the tank (what `make run` runs)",
        description="Run Map-TIDAL on synthetic exploration keyframes of the tank, and the Voronoi and "
        "boustrophedon baselines, score all three on the same voxels, print the paper's comparison table "
        "and write compare.json, tasks, plots and report.md.",
    )
    _add_coverage_args(compare)
    compare.add_argument(
        "--seed", type=int, default=0, help="seed of keyframes and Voronoi (default %(default)s)"
    )
    compare.add_argument("--json", action="store_true", help='print {"methods": {...}} as JSON')
    compare.add_argument(
        "--out", default="runs/compare", metavar="DIR", help="output folder (default %(default)s)"
    )
    compare.add_argument("--no-write", action="store_true", help="write no files, only print")
    compare.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    _add_discovery_params(compare)
    compare.set_defaults(handler=_cmd_compare)

    sweep = commands.add_parser(
        "sweep",
        help="Map-TIDAL over a grid of t, r_ex and theta_ex (Table I)",
        description="Evaluate Map-TIDAL's coverage for every combination of the grid, in parallel local "
        "processes; writes sweep.csv, sweep.md (Table I's layout) and sweep.png (heatmaps).",
    )
    sweep.add_argument(
        "--grid",
        nargs="+",
        metavar="NAME=V1,V2",
        help="grid values; default t=0.70,0.75,0.80 r_ex=1.5,1.6,1.7,1.8 theta_ex=0.25,0.3",
    )
    sweep.add_argument(
        "--out", default="runs/sweep", metavar="DIR", help="output folder (default %(default)s)"
    )
    sweep.add_argument(
        "--jobs", type=int, default=1, metavar="N", help="local processes (default %(default)s)"
    )
    sweep.add_argument("--seed", type=int, default=0, help="seed of the keyframes (default %(default)s)")
    sweep.add_argument("--no-plots", action="store_true", help="skip the heatmap PNG")
    _add_coverage_args(sweep)
    _add_discovery_params(sweep)
    sweep.set_defaults(handler=_cmd_sweep)

    demo = commands.add_parser(
        "demo",
        help="discovery over a pass of synthetic keyframes (what `make run` runs)",
        description="Discover tasks frame by frame on Kimera-like keyframe meshes of a wall with a "
        "window and a ladder; writes tasks, per-frame plots and a markdown report.",
    )
    demo.add_argument(
        "--out", default="runs/default", metavar="DIR", help="output folder (default %(default)s)"
    )
    demo.add_argument(
        "--seed", type=int, default=0, help="random seed of the keyframes (default %(default)s)"
    )
    demo.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    _add_discovery_params(demo)
    demo.set_defaults(handler=_cmd_demo)
    _add_sim_parser(commands)
    _add_allocate_parser(commands)
    _add_export_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``maptidal`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except (DiscoveryInputError, TankConfigError, ValueError, KeyError) as err:
        print(f"maptidal {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
