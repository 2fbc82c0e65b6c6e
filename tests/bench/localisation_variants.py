"""Missions over seeds with variants of the front end of the robot without a DVL, run in parallel, for
its horizontal localisation error (median, p90, max) and the tasks verified (issue [truthful-loop]).

    python tests/bench/localisation_variants.py --variants base,pyr5,hz2 --seeds 0,1,2 --duration 600
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import time
from pathlib import Path

# base: the defaults; nopred: tracking unaided by the camera's motion (FrontEndParams.predict_tracks);
# hz2: the robot without a DVL at 2 frames/s; gate25: the odometry's gate at 0.25 m; yaw4/6/8: every
# robot turning at most 4, 6 or 8 deg/s (12 by default); oneside: keeping clear as before message
# version 4, a robot giving way only to lower-indexed teammates. Names combine: yaw6nopred
VARIANTS = ("base", "nopred", "hz2", "gate25", "yaw4", "yaw6", "yaw8", "oneside")


def closest_approach(folder: Path) -> float:
    """The smallest true centre-to-centre distance between any two robots in a mission's
    trajectories.csv (sampled as written, once a second)."""
    import csv
    import math
    from collections import defaultdict

    by_time: dict[str, list[tuple[float, ...]]] = defaultdict(list)
    with open(folder / "trajectories.csv") as stream:
        for row in csv.DictReader(stream):
            by_time[row["time_s"]].append(tuple(float(row[f"true_{k}"]) for k in "xyz"))
    pairs = ((a, b) for points in by_time.values() for i, a in enumerate(points) for b in points[i + 1 :])
    return min((math.dist(a, b) for a, b in pairs), default=math.inf)


def run_one(job: tuple[str, int, float, str]) -> dict:
    """One mission of one variant and seed; its localisation errors and counts."""
    variant, seed, duration, out = job
    from maptidal.mission import run as run_module
    from maptidal.mission.config import prepare_mission
    from maptidal.perception.frontend import FrontEnd

    def front_end(intrinsics, pose_source, params):
        tracker, odometry = params.tracker, params.odometry
        if "gate25" in variant:
            odometry = dataclasses.replace(odometry, max_disagreement_m=0.25)
        if "nopred" in variant:
            params = dataclasses.replace(params, predict_tracks=False)
        return FrontEnd(
            intrinsics, pose_source, dataclasses.replace(params, tracker=tracker, odometry=odometry)
        )

    run_module.FrontEnd = front_end
    if "oneside" in variant:
        keep_clear = run_module.Mission._keep_clear

        def one_sided(self, robot, reference, now):
            agent = self.auction.agents[robot.index]
            for peer in agent.peer_positions:
                if peer > robot.index:
                    agent.peer_giving_way[peer] = True  # never give way to a higher index
            return keep_clear(self, robot, reference, now)

        run_module.Mission._keep_clear = one_sided
    scenario, params = prepare_mission(None, None, duration, None, seed)
    params = dataclasses.replace(params, perception_process=False)
    if "hz2" in variant:
        params = dataclasses.replace(params, frame_rate_no_dvl_hz=2.0)
    if "turnall" in variant:
        params = dataclasses.replace(params, turn_first="all")
    elif "turn" in variant:
        params = dataclasses.replace(params, turn_first="no-dvl")
    for rate in (4, 6, 8):
        if f"yaw{rate}nd" in variant:
            params = dataclasses.replace(params, yaw_rate_no_dvl_deg_s=float(rate))
        elif f"yaw{rate}" in variant:
            params = dataclasses.replace(
                params, yaw_rate_deg_s=float(rate), yaw_rate_no_dvl_deg_s=float(rate)
            )
    start = time.perf_counter()
    folder = Path(f"{out}/{variant}-{seed}")
    document = run_module.Mission(scenario, params, folder).run()
    verified = sum(r["verified"] for r in document["done_by_robot"].values())
    return {
        "variant": variant,
        "seed": seed,
        "wall_s": round(time.perf_counter() - start, 1),
        "localisation": document["localisation"],
        "done_by_robot": document["done_by_robot"],
        "verified": verified,
        "found": len(document["tasks"]),
        "closest_m": round(closest_approach(folder), 3),
    }


def main() -> None:
    """Run the grid and print one line per mission and the medians per variant."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", default="base,pyr5,hz2")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--jobs", type=int, default=multiprocessing.cpu_count())
    parser.add_argument("--out", default="/tmp/variants", help="the missions' folders")
    parser.add_argument("--results", default=None, help="the results' JSON (default: OUT/results.json)")
    args = parser.parse_args()
    jobs = [
        (v, int(s), args.duration, args.out) for v in args.variants.split(",") for s in args.seeds.split(",")
    ]
    Path(args.out).mkdir(parents=True, exist_ok=True)
    results = []
    # a fresh process per mission: a variant patches the mission class in the process it runs in
    with multiprocessing.get_context("spawn").Pool(min(args.jobs, len(jobs)), maxtasksperchild=1) as pool:
        for result in pool.imap_unordered(run_one, jobs):
            rov0, rov1 = (result["localisation"].get(name, {}) for name in ("rov0", "rov1"))
            median = 100 * rov1.get("median_m", 0)
            print(
                f"{result['variant']:8s} seed {result['seed']}: rov1 median {median:.1f} "
                f"p90 {100 * rov1.get('p90_m', 0):.1f} max {100 * rov1.get('max_m', 0):.1f} cm, "
                f"rov0 median {100 * rov0.get('median_m', 0):.1f} cm; closest {result['closest_m']} m; "
                f"verified {result['verified']} of {result['found']} ({result['wall_s']} s)",
                flush=True,
            )
            results.append(result)
            Path(args.results or Path(args.out) / "results.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
