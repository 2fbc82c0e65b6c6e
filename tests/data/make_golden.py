"""Regenerate the golden regression data of the front end on purpose (``make golden``), and say what changed.

    python tests/data/make_golden.py [--check]

Captures :data:`GOLDEN_FRAMES` stereo frames of the default scenario on the paper's path (camera noise off
and the CPU water model, so that the frames depend only on the world, the physics and the rasteriser),
stores them in grey in
``tests/data/golden_frames/`` with their intrinsics, poses and the true surface, runs the front end and
discovery on them, and writes ``golden.json``: per-frame keypoint counts, per-keyframe mesh sizes and the
tasks. ``tests/test_golden.py`` checks the committed frames and outputs against a fresh run. With
``--check`` nothing is written: it only prints what a regeneration would change.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

HERE = Path(__file__).resolve().parent
GOLDEN_DIR = HERE / "golden_frames"
GOLDEN_FRAMES = 4
CAPTURE = {"path": "paper", "frame_rate_hz": 0.5, "max_frames": GOLDEN_FRAMES}  # 10 cm apart: each a keyframe


def golden_scenario():
    """The default scenario with the camera noise off."""
    from maptidal.envs.scenario import load_scenario

    scenario = load_scenario()
    return dataclasses.replace(scenario, water=dataclasses.replace(scenario.water, noise_sigma=0.0))


def capture_golden(out_dir: Path):
    """Capture the golden frames into ``out_dir`` (grey PNGs) and return the loaded recording."""
    from maptidal.mission.capture import CaptureParams, capture
    from maptidal.perception.recording import RecordingWriter, load_recording

    with tempfile.TemporaryDirectory() as scratch:
        # the CPU water model on every machine: a GPU's water shader is the same model, not the same pixels
        colour = capture(scratch, golden_scenario(), CaptureParams(**CAPTURE), seed=0, water_backend="cpu")
        writer = RecordingWriter(out_dir, colour.intrinsics, colour.metadata)
        (out_dir / colour.metadata["surface"]).write_bytes(
            (colour.root / colour.metadata["surface"]).read_bytes()
        )
        for frame in colour.frames:
            left, right = colour.images(frame)
            gray = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) for image in (left, right)]
            writer.add(frame.time_s, *gray, frame.poses)
    return load_recording(out_dir)


def golden_outputs(recording) -> dict:
    """What the front end and discovery give on ``recording``: the golden.json document."""
    from maptidal.frame_discovery import discover_on_recording

    result = discover_on_recording(recording, "truth")
    document = result.to_json()
    return {
        "frames": document["frames"],
        "keypoints_per_frame": [record.keypoints for record in result.run.frames],
        "matched_per_frame": [record.matched for record in result.run.frames],
        "keyframes": document["keyframes"],
        "mesh_faces_per_keyframe": [len(k.keyframe.mesh.faces) for k in result.run.keyframes],
        "mesh_error_median_m": document["mesh_error_median_m"],
        "tasks": document["tasks"],
    }


def _changes(old: dict, new: dict) -> list[str]:
    lines = []
    for key in ("keypoints_per_frame", "matched_per_frame", "keyframes", "mesh_faces_per_keyframe"):
        if old.get(key) != new.get(key):
            lines.append(f"{key}: {old.get(key)} -> {new.get(key)}")
    if len(old.get("tasks", [])) != len(new["tasks"]):
        lines.append(f"tasks: {len(old.get('tasks', []))} -> {len(new['tasks'])}")
    elif old.get("tasks") != new["tasks"]:
        lines.append("tasks: same count, moved")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only print what would change")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE.parents[1]))
    with tempfile.TemporaryDirectory() as scratch:
        fresh_dir = Path(scratch) / "golden_frames"
        fresh = capture_golden(fresh_dir)
        outputs = golden_outputs(fresh)
        old_path = GOLDEN_DIR / "golden.json"
        if old_path.is_file():
            old = json.loads(old_path.read_text())
            for frame in fresh.frames:
                for side in ("left", "right"):
                    name = f"{side}/{frame.index:06d}.png"
                    before = cv2.imread(str(GOLDEN_DIR / name), cv2.IMREAD_GRAYSCALE)
                    after = cv2.imread(str(fresh_dir / name), cv2.IMREAD_GRAYSCALE)
                    if before is None or before.shape != after.shape:
                        print(f"{name}: new")
                    else:
                        diff = np.abs(before.astype(int) - after.astype(int))
                        print(f"{name}: mean |diff| {diff.mean():.3f} levels, max {diff.max()}")
            changes = _changes(old, outputs)
            print("\n".join(changes) if changes else "outputs: unchanged")
        else:
            print("no golden data yet: writing it")
        if args.check:
            return 0
        GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
        for stale in GOLDEN_DIR.rglob("*"):
            if stale.is_file():
                stale.unlink()
        for path in fresh_dir.rglob("*"):
            if path.is_file():
                target = GOLDEN_DIR / path.relative_to(fresh_dir)
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(path.read_bytes())
        (GOLDEN_DIR / "golden.json").write_text(json.dumps(outputs, indent=1) + "\n")
        size = sum(p.stat().st_size for p in GOLDEN_DIR.rglob("*") if p.is_file())
        print(f"wrote {GOLDEN_DIR} ({size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
