"""``maptidal discover`` and ``maptidal demo``: task discovery on one mesh, and on a synthetic pass."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from maptidal.cli.common import (
    JSON_FILE,
    PNG_FILE,
    add_discovery_params,
    add_output_folder,
    discovery_params_from,
)


def register(commands) -> None:
    """Add the ``discover`` and ``demo`` subcommands."""
    discover = commands.add_parser(
        "discover",
        help="discover inspection tasks on one keyframe mesh",
        description="Run Map-TIDAL task discovery (paper Algorithms 1-3) on one mesh. "
        "Chain frames by passing one frame's --out as the next frame's --existing. "
        "`maptidal demo --out DIR` writes sample keyframe meshes (DIR/frameNN.ply) to try it on.",
    )
    discover.add_argument("mesh", help="keyframe mesh: .ply, .obj or .stl")
    discover.add_argument("--existing", metavar="TASKS.json", help="existing tasks T_e ({'tasks': [...]})")
    discover.add_argument(
        "--keypoints",
        metavar="FILE",
        help="keypoints as .npy (K x 3, m) or a .ply point cloud (default: the mesh vertices)",
    )
    add_discovery_params(discover)
    discover.add_argument("--json", action="store_true", help="print the result as JSON")
    discover.add_argument(
        "--out", type=JSON_FILE, metavar="TASKS.json", help="write the new tasks (atomically)"
    )
    discover.add_argument("--plot", type=PNG_FILE, metavar="PNG", help="draw the mesh, CIPs and tasks")
    discover.set_defaults(handler=run_discover)

    demo = commands.add_parser(
        "demo",
        help="discovery over a pass of synthetic keyframes along one wall",
        description="Discover tasks frame by frame on Kimera-like keyframe meshes of a wall with a "
        "window and a ladder; writes each keyframe's mesh (frameNN.ply), its tasks, per-frame plots and "
        "a markdown report. (`make run` runs the closed-loop mission, `maptidal run`, not this.)",
    )
    add_output_folder(demo, "runs/demo")
    demo.add_argument(
        "--seed", type=int, default=0, help="random seed of the keyframes (default %(default)s)"
    )
    demo.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    add_discovery_params(demo)
    demo.set_defaults(handler=run_demo)


def run_discover(args: argparse.Namespace) -> int:
    """Handler of ``maptidal discover``."""
    from maptidal.discovery import discover
    from maptidal.files import atomic_write_json, load_keypoints, load_mesh, load_tasks

    params = discovery_params_from(args)
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
        return 0
    counts = result.counts
    print(
        f"{counts['cips']} CIPs -> {counts['after_prune']} after pruning ({result.pruning_mode}) -> "
        f"{counts['confirmed']} confirmed / {len(result.remains)} remain -> {counts['final']} new tasks"
    )
    for label, path in (("tasks", args.out), ("plot", args.plot)):
        if path:
            print(f"{label}: {path}")
    return 0


def run_demo(args: argparse.Namespace) -> int:
    """Handler of ``maptidal demo``."""
    from maptidal.demo import DemoConfig
    from maptidal.demo import run_demo as demo

    demo(args.out, DemoConfig(seed=args.seed), params=discovery_params_from(args), plots=not args.no_plots)
    print(f"report: {Path(args.out) / 'report.md'}")
    return 0
