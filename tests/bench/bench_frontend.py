"""Benchmark the stereo front end stage by stage, per frame, as a ratio to rendering the stereo pair in the
same process (issue [perception]'s goal: the whole front end at most 1.5x the render).

Captures the paper's path (5 frames/s), renders each recorded pose again to time the render, then runs
the front end and discovery over the recording with each pose source and each detector.

    python tests/bench/bench_frontend.py [--keyframes N]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from maptidal.envs.simulation import Simulation
from maptidal.frame_discovery import discover_on_recording
from maptidal.mission.capture import CaptureParams, capture, place_camera
from maptidal.perception.frontend import FrontEndParams
from maptidal.perception.stereo import DETECTORS, StereoParams, detect_keypoints, match_stereo

STAGES = (
    "detection",
    "tracking",
    "matching",
    "triangulation",
    "localisation",
    "fusion",
    "meshing",
    "discovery",
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--keyframes", type=int, default=7, help="keyframes to process (default 7, the paper's)"
    )
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        recording = capture(scratch, params=CaptureParams(path="paper"), seed=0)
        sim = Simulation()
        frames = recording.frames[:40]
        start = time.perf_counter()
        for frame in frames:
            place_camera(sim, "rov0", frame.poses["truth"])
            sim.render_stereo("rov0")
        render = (time.perf_counter() - start) / len(frames)
        sim.close()
        print(
            f"stereo render (640x400, water model, {sim.water_backend}): {1000 * render:.1f} ms per frame\n"
        )
        print("| detector | pose | frames | " + " | ".join(STAGES) + " | total ms/frame | total / render |")
        print("|---|---|---|" + "---|" * (len(STAGES) + 2))
        for detector in DETECTORS:
            for source in ("truth", "vo") if detector == "orb" else ("truth",):
                params = FrontEndParams(stereo=StereoParams(detector=detector), max_keyframes=args.keyframes)
                result = discover_on_recording(recording, source, params)
                n = len(result.run.frames)
                per_frame = {stage: result.run.timings.get(stage, 0.0) / n for stage in STAGES}
                total = sum(per_frame.values())
                cells = " | ".join(f"{1000 * per_frame[stage]:.1f}" for stage in STAGES)
                print(
                    f"| {detector} | {source} | {n} | {cells} | {1000 * total:.1f} | {total / render:.2f} |"
                )
        matching_against_the_literal(recording)


def matching_against_the_literal(recording) -> None:
    """Row matching, every keypoint at once, against the literal per-keypoint matchTemplate loop it
    replaced (tests/bench/literal_stereo.py), on the same frames and keypoints."""
    from literal_stereo import literal_match_stereo

    pairs = [recording.images(frame) for frame in recording.frames[:20]]
    keypoints = [detect_keypoints(left) for left, _ in pairs]
    timed = {}
    for name, matcher in (("vectorised", match_stereo), ("literal", literal_match_stereo)):
        start = time.perf_counter()
        for (left, right), points in zip(pairs, keypoints, strict=True):
            matcher(left, right, points)
        timed[name] = (time.perf_counter() - start) / len(pairs)
    count = sum(len(points) for points in keypoints) / len(pairs)
    print(
        f"\nrow matching, {count:.0f} keypoints a frame: {1000 * timed['vectorised']:.1f} ms, the literal "
        f"per-keypoint loop {1000 * timed['literal']:.1f} ms ({timed['vectorised'] / timed['literal']:.2f}x)"
    )


if __name__ == "__main__":
    main()
