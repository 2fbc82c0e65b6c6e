"""``maptidal allocate``: decentralised CBBA allocation over a simulated acoustic channel."""

from __future__ import annotations

import argparse
import json

from maptidal.cli.common import JSON_FILE, PNG_FILE
from maptidal.progress import ProgressBar


def register(commands) -> None:
    """Add the ``allocate`` subcommand."""
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
    allocate.add_argument("--plot", type=PNG_FILE, metavar="PNG", help="draw robots, tasks and paths")
    allocate.add_argument(
        "--out", type=JSON_FILE, metavar="RESULT.json", help="also write the JSON result (atomically)"
    )
    allocate.add_argument("--quiet", action="store_true", help="no progress bar")
    allocate.set_defaults(handler=run_allocate)


def run_allocate(args: argparse.Namespace) -> int:
    """Handler of ``maptidal allocate``."""
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
