"""``maptidal run`` and ``maptidal report``: the closed-loop Map-TIDAL mission, and its report rebuilt from
the event log."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from maptidal.cli.common import add_output_folder, positive_float, positive_int


def register(commands) -> None:
    """Add the ``run`` and ``report`` subcommands."""
    run = commands.add_parser(
        "run",
        help="fly the closed-loop mission: see, map, discover, auction, fly, inspect",
        description="Run the headless closed-loop Map-TIDAL mission: robots explore, render stereo "
        "frames, mesh keyframes, discover tasks, auction them with CBBA over the acoustic channel, fly "
        "to them with go-to-pose on their own estimates and capture an image at each. Writes "
        "events.jsonl, trajectories.csv, images/, mission.json (snapshots and final), plots and "
        "report.md to --out as it goes.",
    )
    run.add_argument(
        "--scenario", metavar="FILE", help="mission scenario TOML (default: assets/scenarios/mission.toml)"
    )
    run.add_argument(
        "--robots", type=positive_int, metavar="N", help="use the first N robots of the scenario"
    )
    run.add_argument(
        "--duration",
        type=positive_float,
        metavar="S",
        help="simulated seconds (default: the scenario's, else 240)",
    )
    run.add_argument("--seed", type=int, default=0, help="seed of the sensor and camera noise (default 0)")
    run.add_argument(
        "--pose", choices=("truth", "dr", "vo"), help="pose source of the front end (default dr)"
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
        "--scenario", metavar="FILE", help="the mission's scenario (for the tank; default mission)"
    )
    report.set_defaults(handler=run_report)


def run_mission(args: argparse.Namespace) -> int:
    """Handler of ``maptidal run``."""
    from maptidal.mission.config import load_mission
    from maptidal.mission.outputs import summary_table
    from maptidal.mission.run import Mission, MissionParams
    from maptidal.progress import ProgressBar

    scenario, settings = load_mission(args.scenario)
    if args.robots is not None:
        if args.robots > len(scenario.robots):
            raise ValueError(f"--robots {args.robots}: the scenario has {len(scenario.robots)} robots")
        scenario = dataclasses.replace(scenario, robots=scenario.robots[: args.robots])
    if args.duration is not None:
        settings["duration_s"] = args.duration
    if args.pose is not None:
        settings["pose_source"] = args.pose
    params = MissionParams(seed=args.seed, **settings)
    mission = Mission(scenario, params, args.out)
    bar = ProgressBar(100, "mission")
    state = {"shown": 0}

    def progress(now: float, found: int, done: int, total: float) -> None:
        percent = int(100 * now / total)
        if percent > state["shown"]:
            bar.advance(percent - state["shown"], f"{now:.0f}/{total:.0f} s, tasks {done}/{found} done")
            state["shown"] = percent

    document = mission.run(progress)
    print(summary_table(document))
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0


def run_report(args: argparse.Namespace) -> int:
    """Handler of ``maptidal report``."""
    from maptidal.mission.config import load_mission
    from maptidal.mission.outputs import rebuild, summary_table

    scenario, _ = load_mission(args.scenario)
    document = rebuild(args.mission_dir, scenario.tank)
    print(summary_table(document))
    print(f"report: {Path(args.mission_dir) / 'report.md'}")
    return 0
