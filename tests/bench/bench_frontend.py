"""Benchmark the stereo front end's stages so far (detection, matching, triangulation) per frame, as a
ratio to rendering the stereo pair in the same process (issue [perception]'s goal: the whole front end
at most 1.5x the render).

    python tests/bench/bench_frontend.py [--frames N]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from envs.simulation import Simulation
from maptidal.perception.stereo import DETECTORS, StereoParams, detect_keypoints, match_stereo, triangulate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10, help="frames per measurement")
    args = parser.parse_args()
    sim = Simulation()
    sim.reset(seed=0)
    K = np.array(sim.intrinsics()["K"])
    baseline = sim.intrinsics()["baseline_m"]
    left, right = sim.render_stereo("rov0")
    start = time.perf_counter()
    for _ in range(args.frames):
        sim.render_stereo("rov0")
    render = (time.perf_counter() - start) / args.frames
    print(f"stereo render (640x400, water model): {1000 * render:.1f} ms")
    print("| detector | detect ms | match ms | triangulate ms | total / render |\n|---|---|---|---|---|")
    for detector in DETECTORS:
        params = StereoParams(detector=detector)
        times = np.zeros(3)
        for _ in range(args.frames):
            t0 = time.perf_counter()
            keypoints = detect_keypoints(left, params)
            t1 = time.perf_counter()
            disparity = match_stereo(left, right, keypoints, params)
            t2 = time.perf_counter()
            triangulate(keypoints, disparity, K[0, 0], K[1, 1], K[0, 2], K[1, 2], baseline, params)
            times += [t1 - t0, t2 - t1, time.perf_counter() - t2]
        times /= args.frames
        ms = " | ".join(f"{1000 * t:.1f}" for t in times)
        print(f"| {detector} | {ms} | {times.sum() / render:.2f} |")


if __name__ == "__main__":
    main()
