"""The ``maptidal`` command line.

Subcommands:
  discover  Map-TIDAL task discovery on one mesh (PLY, OBJ or STL)
  demo      discovery over a pass of synthetic keyframes; what `make run` runs

Every subcommand has ``--help``. Bad input ends with a one-line error and exit
status 2; nothing half-written is left behind.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from maptidal.discovery import DiscoveryInputError, DiscoveryParams

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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``maptidal`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except DiscoveryInputError as err:
        print(f"maptidal {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
