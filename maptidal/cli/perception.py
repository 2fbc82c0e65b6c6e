"""``maptidal capture`` and ``maptidal discover-frames``: stereo recordings from the simulator, and Map-TIDAL
on the keyframe meshes of a recording's rendered (or real) frames."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from maptidal.cli.common import add_discovery_params, add_output_folder, discovery_params_from, positive_int

PATH_CHOICES = ("paper", "sweep")
POSE_CHOICES = ("truth", "dr", "vo")


def _add_capture_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--path",
        choices=PATH_CHOICES,
        default="paper",
        help="scripted path: the paper's slow 0.5 m rise facing the end wall, or the yaw sweeps of the "
        "exploration pass (default %(default)s)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the sensor and camera noise (default 0)")
    parser.add_argument(
        "--frame-rate", type=float, default=5.0, metavar="HZ", help="stereo frames per second (default 5)"
    )


def register(commands) -> None:
    """Add the ``capture`` and ``discover-frames`` subcommands."""
    capture = commands.add_parser(
        "capture",
        help="fly a scripted path in the simulator and record its stereo frames and poses",
        description="Fly one robot of a scenario along a scripted path with the simulator's physics and "
        "go-to-pose on its dead-reckoned state, rendering its stereo pair every frame. Writes a "
        "recording folder: left/ and right/ PNGs, intrinsics.json, poses.json (ground truth and dead "
        "reckoning per frame) and surface.ply (the true tank surfaces).",
    )
    capture.add_argument("--scenario", metavar="FILE", help="scenario TOML (default: the default scenario)")
    _add_capture_options(capture)
    add_output_folder(capture, "runs/recording")
    capture.set_defaults(handler=run_capture)

    frames = commands.add_parser(
        "discover-frames",
        help="Map-TIDAL on the keyframe meshes of a stereo recording (rendered or real)",
        description="Run the stereo front end (keypoints, stereo matching, KLT tracking, landmark fusion, "
        "keyframes, Kimera-style meshes) over a recording folder, or over frames it captures itself "
        "with --scenario, and discover tasks keyframe by keyframe. Writes the keyframe meshes (PLY), "
        "the tasks (the `maptidal discover` format), frames.json and Fig. 4-style overlays "
        "(keypoints, mesh, tasks) per keyframe.",
    )
    frames.add_argument("frames_dir", nargs="?", metavar="FRAMES_DIR", help="a recording folder")
    frames.add_argument("--scenario", metavar="FILE", help="capture the frames from this scenario first")
    _add_capture_options(frames)
    frames.add_argument(
        "--pose",
        choices=POSE_CHOICES,
        default="truth",
        help="where the camera poses come from: ground truth, dead reckoning, or dead reckoning "
        "corrected by stereo visual odometry (default %(default)s)",
    )
    frames.add_argument(
        "--keyframes",
        type=positive_int,
        default=None,
        metavar="N",
        help="use the first N keyframes (default: 7 on the paper path, as the paper did; all on the sweep)",
    )
    frames.add_argument("--no-overlays", action="store_true", help="skip the overlay PNGs")
    frames.add_argument("--json", action="store_true", help="print the result as JSON")
    add_output_folder(frames, "runs/frames")
    add_discovery_params(frames)
    frames.set_defaults(handler=run_discover_frames)


def _capture(args: argparse.Namespace, out: Path):
    from maptidal.mission.capture import CaptureParams, capture
    from maptidal.progress import ProgressBar

    params = CaptureParams(path=args.path, frame_rate_hz=args.frame_rate)
    bar = ProgressBar(100, "capture", enabled=not getattr(args, "json", False))
    state = {"shown": 0}

    def progress(elapsed: float, total: float) -> None:
        percent = int(100 * elapsed / max(total, 1e-9))
        if percent > state["shown"]:
            bar.advance(percent - state["shown"], f"{elapsed:.1f}/{total:.1f} s simulated")
            state["shown"] = percent

    return capture(out, args.scenario, params, seed=args.seed, progress=progress)


def run_capture(args: argparse.Namespace) -> int:
    """Handler of ``maptidal capture``."""
    recording = _capture(args, args.out)
    print(f"{len(recording.frames)} frames, {recording.frames[-1].time_s:.1f} s: {args.out}")
    return 0


def run_discover_frames(args: argparse.Namespace) -> int:
    """Handler of ``maptidal discover-frames``."""
    from maptidal.frame_discovery import discover_on_recording, write_outputs
    from maptidal.perception.frontend import FrontEndParams
    from maptidal.perception.recording import load_recording
    from maptidal.progress import ProgressBar

    if (args.frames_dir is None) == (args.scenario is None):
        raise ValueError("give a recording folder (FRAMES_DIR) or --scenario FILE to capture one, not both")
    discovery = discovery_params_from(args)
    if args.scenario is not None:
        recording = _capture(args, args.out / "recording")
        path = args.path
    else:
        recording = load_recording(args.frames_dir)
        path = recording.metadata.get("path", "sweep")
    limit = args.keyframes if args.keyframes is not None else (7 if path == "paper" else None)
    bar = ProgressBar(len(recording.frames), "front end", enabled=not args.json)
    result = discover_on_recording(
        recording,
        args.pose,
        FrontEndParams(max_keyframes=limit),
        discovery,
        progress=lambda done, total: bar.advance(done - bar.done),
    )
    write_outputs(result, recording, args.out, overlays=not args.no_overlays)
    document = result.to_json()
    if args.json:
        print(json.dumps(document))
        return 0
    counts = document["counts"]
    error = document["mesh_error_median_m"]
    ate = document["ate_m"]
    print(
        f"{document['keyframes']} keyframes of {document['frames']} frames, keypoints "
        f"{document['keypoints_per_keyframe']}, {document['mesh_faces']} mesh faces; median mesh error "
        + (f"{1000 * error:.1f} mm" if error is not None else "unknown (no true surface)")
        + ", ATE "
        + (f"{100 * ate:.1f} cm" if ate is not None else "unknown (no ground truth)")
        + f" ({args.pose})"
    )
    print(f"{counts['cips']} CIPs -> {counts['final']} tasks; outputs: {args.out}")
    return 0
