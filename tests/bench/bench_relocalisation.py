"""Benchmark relocalisation (maptidal.perception.relocalisation): the front end's time per frame and its
absolute trajectory error with relocalisation on, as a ratio to the same front end with it off, in the
same process, on the same recording (the exploration sweep, a Heavy without a DVL, at the mission's
320 x 200).

    python tests/bench/bench_relocalisation.py
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from maptidal.camera import StereoCameraParams
from maptidal.envs.scenario import load_scenario
from maptidal.mission.capture import CaptureParams, capture
from maptidal.perception.frontend import FrontEndParams, absolute_trajectory_error, run_frontend
from maptidal.perception.relocalisation import RelocalisationParams


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="runs of each, the fastest kept (default 2)")
    args = parser.parse_args()
    base = load_scenario()
    robots = tuple(
        dataclasses.replace(r, sensors=tuple(s for s in r.sensors if s != "dvl")) for r in base.robots
    )
    scenario = dataclasses.replace(base, robots=robots)
    with tempfile.TemporaryDirectory() as scratch:
        recording = capture(
            scratch,
            scenario,
            CaptureParams(path="sweep"),
            seed=0,
            camera=StereoCameraParams(width=320, height=200),
        )
        truth = [frame.poses["truth"] for frame in recording.frames]
        rows = {}
        for enabled in (False, True):
            params = FrontEndParams(relocalisation=RelocalisationParams(enabled=enabled))
            best = float("inf")
            for _ in range(args.repeats):
                start = time.perf_counter()
                run = run_frontend(recording, "vo", params)
                best = min(best, time.perf_counter() - start)
            ate = absolute_trajectory_error([record.pose for record in run.frames], truth[: len(run.frames)])
            fixes = sum(record.relocalised for record in run.frames)
            rows[enabled] = (best / len(run.frames), ate, fixes, len(run.frames))
    print("| relocalisation | frames | fixes | ms per frame | ATE (cm) |\n|---|---|---|---|---|")
    for enabled, (per_frame, ate, fixes, count) in rows.items():
        print(
            f"| {'on' if enabled else 'off'} | {count} | {fixes} | {1000 * per_frame:.1f} | {100 * ate:.2f} |"
        )
    print(
        f"\ntime ratio on / off: {rows[True][0] / rows[False][0]:.2f}; "
        f"ATE ratio on / off: {rows[True][1] / rows[False][1]:.2f}"
    )


if __name__ == "__main__":
    main()
