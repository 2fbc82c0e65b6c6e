"""``maptidal run`` and ``maptidal report``: the closed-loop Map-TIDAL mission, and its report rebuilt from
the event log."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from maptidal.cli.common import (
    add_executor_args,
    add_output_folder,
    check_executor_args,
    jobs_for,
    positive_float,
    positive_int,
)

POSE_HELP = (
    "where each robot's pose comes from, to mesh on and to fly on: vo (the default), its visual odometry "
    "and relocalisation against its own map, weighed against its DVL or motion model; dr, its dead "
    "reckoning alone (a robot without a DVL flies blind); truth, the simulator's true pose, a frame at a "
    "time (an oracle localisation, to see what localisation costs)"
)


def register(commands) -> None:
    """Add the ``run``, ``report`` and ``batch`` subcommands."""
    run = commands.add_parser(
        "run",
        help="fly the closed-loop mission: see, map, discover, auction, fly, inspect (what `make run` runs)",
        description="Run the headless closed-loop Map-TIDAL mission: robots explore, render stereo "
        "frames, mesh keyframes, discover tasks, auction them with CBBA over the acoustic channel, fly "
        "to them with go-to-pose on their own estimates and capture an image at each. Writes "
        "events.jsonl, trajectories.csv, images/, mission.json (snapshots and final), plots and "
        "report.md to --out as it goes. `make run` runs this.",
    )
    run.add_argument(
        "scenario_path",
        nargs="?",
        metavar="SCENARIO",
        help="mission scenario TOML, as `maptidal batch` takes it (default: assets/scenarios/mission.toml)",
    )
    run.add_argument("--scenario", metavar="FILE", help="the same, named (give one or the other)")
    run.add_argument(
        "--robots", type=positive_int, metavar="N", help="use the first N robots of the scenario"
    )
    run.add_argument(
        "--duration",
        type=positive_float,
        metavar="S",
        help="the most simulated seconds: the mission ends sooner when its work is done (default: the "
        "scenario's, else 600)",
    )
    run.add_argument("--seed", type=int, default=0, help="seed of the sensor and camera noise (default 0)")
    run.add_argument("--pose", choices=("truth", "dr", "vo"), help=POSE_HELP)
    run.add_argument(
        "--planner",
        choices=("maptidal", "voronoi", "boustrophedon"),
        help="where the tasks come from (default: the scenario's, else maptidal): maptidal discovers them "
        "on the robots' own meshes as they fly; voronoi and boustrophedon are the paper's baselines, "
        "whose viewpoints are planned a priori from the tank model and known to every robot from the "
        "start, flown with the same robots, controllers, channel and CBBA (a viewpoint above or below "
        "the heights a robot can hold is flown at their edge, still level)",
    )
    run.add_argument(
        "--discovery",
        choices=("map-aware", "paper"),
        help="how the maptidal planner discovers tasks in the loop (default: the scenario's, else "
        "map-aware): map-aware works on each robot's own fused map and free space and reads no tank "
        "model; paper runs the paper's Algorithms 1-3 on each keyframe's mesh, its tasks then kept where "
        "the tank model's water is free",
    )
    run.add_argument(
        "--no-explore",
        action="store_true",
        help="map-aware robots with no task left do not fly to their own map's frontier to look there "
        "(default: they do, within the scenario's explore_radius_m of where each was launched)",
    )
    run.add_argument(
        "--video",
        action="store_true",
        help="also write mission.mp4: a camera behind the team with each robot's view inset, two frames "
        "per simulated second played at 20 fps",
    )
    run.add_argument(
        "--no-plots",
        action="store_true",
        help="leave out the PNG plots at the end (some 3 s); `maptidal report DIR` draws them later",
    )
    add_output_folder(run, "runs/mission")
    run.set_defaults(handler=run_mission)

    report = commands.add_parser(
        "report",
        help="rebuild a mission's mission.json, plots and report.md from its event log",
        description="Rebuild mission.json, the plots and report.md of a mission folder from events.jsonl "
        "(and the last mission.json snapshot), as after a mission that was killed midway.",
    )
    report.add_argument("mission_dir", metavar="DIR", help="a mission's output folder")
    report.add_argument(
        "--scenario",
        metavar="FILE",
        help="the mission's scenario, for its tank (default: the tank the event log says the mission was "
        "flown in; for a log that does not say, the default mission's)",
    )
    report.set_defaults(handler=run_report)

    batch = commands.add_parser(
        "batch",
        help="Monte-Carlo missions over seeds, locally or on a Ray cluster, aggregated",
        description="Fly the mission once per seed, in local processes or on a Ray cluster, and aggregate "
        "the metrics (coverage, tasks found and done, completion time, messages and bytes sent): "
        "batch.csv (a row per seed, written as runs land), batch.json (rows, mean, std, min, max), "
        "batch.md and batch.png; each mission's own outputs go to seed_NNN/ under --out. The same "
        "seeds give the same numbers on either executor.",
    )
    batch.add_argument(
        "scenario", nargs="?", metavar="SCENARIO", help="mission scenario TOML (default: mission.toml)"
    )
    batch.add_argument(
        "--scenario",
        dest="scenario_file",
        metavar="FILE",
        help="the same, named as `maptidal run` names it (give one or the other)",
    )
    batch.add_argument(
        "--seeds", default="1-10", metavar="SEEDS", help="N, N-M or a comma list (default %(default)s)"
    )
    batch.add_argument(
        "--robots", type=positive_int, metavar="N", help="use the first N robots of the scenario"
    )
    batch.add_argument(
        "--duration", type=positive_float, metavar="S", help="simulated seconds of each mission"
    )
    batch.add_argument("--pose", choices=("truth", "dr", "vo"), help=POSE_HELP)
    batch.add_argument(
        "--planners",
        metavar="LIST",
        help="fly each seed with each planner: all, or a comma list of maptidal, voronoi and "
        "boustrophedon (default: the scenario's planner); batch.md then compares them",
    )
    batch.add_argument(
        "--discovery",
        choices=("map-aware", "paper"),
        help="the maptidal planner's discovery mode (default: the scenario's, else map-aware)",
    )
    batch.add_argument(
        "--no-explore",
        action="store_true",
        help="map-aware robots with no task left do not explore their map's frontier (as run's)",
    )
    batch.add_argument(
        "--no-plots",
        action="store_true",
        help="leave out each mission's own PNG plots (the batch still draws its figures); `maptidal "
        "report` on a seed's folder draws them later",
    )
    add_executor_args(batch, "missions")
    add_output_folder(batch, "runs/batch")
    batch.set_defaults(handler=run_batch_command)

    compare = commands.add_parser(
        "compare-batches",
        help="two batches of the same seeds side by side: which differences are more than the seeds' noise",
        description="Pair two `maptidal batch` folders by planner and seed and give, for each metric (finish "
        "time, walls uninspected, tasks, path, energy, contact, time surveying and lost, bytes), the "
        "means, the mean difference AFTER - BEFORE with its 95 % confidence interval (Student's t on the "
        "seeds' differences), and on how many seeds AFTER is lower and higher. A mission is chaotic, so "
        "a difference whose interval holds 0 is the seeds' noise. Writes compare.md, compare.json and "
        "compare.png (each seed a line from BEFORE to AFTER) to --out.",
    )
    compare.add_argument("before", metavar="BEFORE", help="a batch folder (batch.json or batch.csv)")
    compare.add_argument("after", metavar="AFTER", help="another batch folder, of the same seeds")
    add_output_folder(compare, "runs/compare")
    compare.set_defaults(handler=run_compare_batches)


def one_scenario(positional: str | None, named: str | None) -> str | None:
    """The scenario file a mission command was given, as ``SCENARIO`` or ``--scenario FILE`` (None: the
    default); both, naming different files, is an error."""
    if positional is not None and named is not None and positional != named:
        raise ValueError(f"two scenarios given ({positional}, --scenario {named}): give one")
    return named if named is not None else positional


def run_mission(args: argparse.Namespace) -> int:
    """Handler of ``maptidal run``."""
    from maptidal.mission.config import prepare_mission
    from maptidal.mission.outputs import summary_table
    from maptidal.mission.run import Mission
    from maptidal.progress import ProgressBar

    scenario, params = prepare_mission(
        one_scenario(args.scenario_path, args.scenario),
        args.robots,
        args.duration,
        args.pose,
        args.seed,
        planner=args.planner,
        discovery=args.discovery,
        explore=False if args.no_explore else None,
    )
    if args.video:
        params = dataclasses.replace(params, video=True)
    if args.no_plots:
        params = dataclasses.replace(params, plots=False)
    mission = Mission(scenario, params, args.out)
    if mission.writer.cleared:
        print(
            f"maptidal run: note: {args.out} held an earlier mission; its {mission.writer.cleared} files "
            "were removed",
            file=sys.stderr,
        )
    bar = ProgressBar(100, "mission")
    state = {"shown": 0}

    def progress(now: float, found: int, done: int, total: float, inspected: float) -> None:
        percent = int(100 * now / total)
        if percent > state["shown"]:
            note = f"{now:.0f}/{total:.0f} s, tasks {done}/{found} done, {inspected:.0f} % inspected"
            bar.advance(percent - state["shown"], note)
            state["shown"] = percent

    document = mission.run(progress)
    if state["shown"] < 100:  # it ended before its cap (its work done, as a rule): the bar is full
        ended = "finished" if document["finished"] else "ended"
        bar.advance(100 - state["shown"], f"{ended} at {document['sim_time_s']:.0f} s, before the cap")
    print(summary_table(document))
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0


def run_report(args: argparse.Namespace) -> int:
    """Handler of ``maptidal report``."""
    from maptidal.mission.config import load_mission
    from maptidal.mission.outputs import EVENTS, flown_tank, rebuild, summary_table

    tank = None
    if args.scenario is None and (Path(args.mission_dir) / EVENTS).is_file():
        tank = flown_tank(args.mission_dir)  # the tank the mission was flown in, as its log says
    document = rebuild(args.mission_dir, load_mission(args.scenario)[0].tank if tank is None else tank)
    if args.scenario is None and tank is None:  # said once the log is known to be readable
        print(
            "maptidal report: the event log does not name its tank; used the default mission's "
            "(--scenario names the mission's own)",
            file=sys.stderr,
        )
    print(summary_table(document))
    print(f"report: {Path(args.mission_dir) / 'report.md'}")
    return 0


def run_batch_command(args: argparse.Namespace) -> int:
    """Handler of ``maptidal batch``."""
    from maptidal.mission.batch import (
        batch_markdown,
        parse_planners,
        parse_seeds,
        planners_markdown,
        run_batch,
    )

    check_executor_args(args)
    scenario = one_scenario(args.scenario, args.scenario_file)
    seeds = parse_seeds(args.seeds)
    planners = parse_planners(args.planners) if args.planners else None
    jobs = jobs_for(args, len(seeds) * len(planners or [None]), "batch")
    rows, summary = run_batch(
        scenario,
        seeds,
        args.out,
        executor=args.executor,
        jobs=jobs,
        ray_address=args.ray_address,
        robots=args.robots,
        duration_s=args.duration,
        pose_source=args.pose,
        planners=planners,
        discovery=args.discovery,
        plots=not args.no_plots,
        explore=False if args.no_explore else None,
    )
    several = planners is not None and len(planners) > 1
    print(
        planners_markdown(summary, len(seeds), rows=rows) if several else batch_markdown(summary, len(rows))
    )
    print(f"files in {args.out}: batch.csv, batch.json, batch.md, batch.png, coverage_time.png, seed_NNN/")
    return 0


def run_compare_batches(args: argparse.Namespace) -> int:
    """Handler of ``maptidal compare-batches``."""
    from maptidal.mission.batch_compare import write_comparison

    _, markdown = write_comparison(args.before, args.after, args.out)
    print(markdown, end="")
    print(f"files in {args.out}: compare.md, compare.json, compare.png")
    return 0
