"""Benchmark the lost robot's search (maptidal.perception.relocalisation.AnchorMap._search): the guided
match from a grid of predictions with every keypoint's descriptor distances worked out once
(``AnchorMap.all_distances``), against the same search matching keypoint by keypoint at each
prediction (the version before), in the same process, on the searches of a real mission; and the fix's
RANSAC (``locate``), every hypothesis at once, against hypothesis by hypothesis (the version before,
written out below), on the fixes of the same mission.

The searches are those the default mission makes (seed 0, perception inline, where the robot without a
DVL is pushed at 53 s and searches for its map), each taken with the anchor map as it stood; both ways
must give the same fix, to the bit.

    python tests/bench/bench_search.py [--duration S] [--seed N]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import os
import tempfile
import time

os.environ.setdefault("MUJOCO_GL", "egl")

from maptidal.mission.config import prepare_mission
from maptidal.mission.run import Mission
from maptidal.perception import relocalisation


def captured_searches(duration_s: float, seed: int) -> tuple[list, list]:
    """Each search of a mission (a copy of its anchor map, random state included, and its arguments),
    and each of its calls to ``locate`` (the arguments, the random state as it was)."""
    searches, fixes = [], []
    search, locate = relocalisation.AnchorMap._search, relocalisation.locate

    def capture(anchors, *args):
        searches.append((copy.deepcopy(anchors), copy.deepcopy(args)))
        return search(anchors, *args)

    def capture_locate(*args):
        fixes.append(copy.deepcopy(args))
        return locate(*args)

    relocalisation.AnchorMap._search = capture
    relocalisation.locate = capture_locate
    try:
        scenario, params = prepare_mission(None, duration_s=duration_s, seed=seed)
        params = dataclasses.replace(params, perception_process=False, plots=False)
        with tempfile.TemporaryDirectory() as scratch:
            Mission(scenario, params, scratch).run()
    finally:
        relocalisation.AnchorMap._search = search
        relocalisation.locate = locate
    return searches, fixes


def locate_one_at_a_time(points, pixels, rotation, intrinsics, params, rng):
    """``locate`` as it was: each RANSAC hypothesis solved and scored in turn."""
    n = len(points)
    if n < max(params.min_inliers, 2):
        return None
    rays = relocalisation.bearings(pixels, rotation, intrinsics)
    best = None
    for _ in range(params.ransac_iterations):
        pair = rng.choice(n, 2, replace=False)
        centre = relocalisation.centre_from_rays(points[pair], rays[pair])
        if centre is None:
            continue
        inliers = relocalisation._inliers(
            points, pixels, centre, rotation, intrinsics, params.reprojection_px
        )
        if best is None or inliers.sum() > best.sum():
            best = inliers
    if best is None or best.sum() < max(params.min_inliers, params.min_inlier_ratio * n):
        return None
    centre = None
    for _ in range(2):
        centre = relocalisation.centre_from_rays(points[best], rays[best])
        if centre is None:
            return None
        refined = relocalisation._inliers(
            points, pixels, centre, rotation, intrinsics, params.reprojection_px
        )
        if refined.sum() < params.min_inliers:
            return None
        best = refined
    return centre, best


def timed_fixes(fixes: list, function) -> tuple[float, list]:
    """Seconds for every captured ``locate`` call through ``function``, and their answers."""
    total, answers = 0.0, []
    for args in fixes:
        args = copy.deepcopy(args)
        start = time.perf_counter()
        found = function(*args)
        total += time.perf_counter() - start
        answers.append(None if found is None else (found[0].tolist(), found[1].tolist()))
    return total, answers


def timed(searches: list, keypoint_by_keypoint: bool) -> tuple[float, list]:
    """Seconds for every search, and their answers (centre, inliers, matched rows)."""
    total, answers = 0.0, []
    for anchors, args in searches:
        anchors = copy.deepcopy(anchors)
        if keypoint_by_keypoint:  # no distances given: match works them out pair by pair, as before
            anchors.all_distances = lambda descriptors, valid: None
        start = time.perf_counter()
        found = anchors._search(*args)
        total += time.perf_counter() - start
        answers.append(
            None if found is None else (found[0].centre.tolist(), found[0].inliers, found[1].tolist())
        )
    return total, answers


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=150.0, help="simulated seconds (default 150)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    searches, fixes = captured_searches(args.duration, args.seed)
    if not searches:
        print("the mission made no search: try a longer one, or another seed")
        return
    before, old = timed(searches, keypoint_by_keypoint=True)
    after, new = timed(searches, keypoint_by_keypoint=False)
    print(f"{len(searches)} searches of the default mission (seed {args.seed}, {args.duration:g} s)")
    print(f"keypoint by keypoint (before): {1000 * before / len(searches):7.1f} ms a search")
    print(f"distances once (now):          {1000 * after / len(searches):7.1f} ms a search")
    print(f"ratio before / now: {before / after:.2f}; the same fixes: {old == new}")
    before, old = timed_fixes(fixes, locate_one_at_a_time)
    after, new = timed_fixes(fixes, relocalisation.locate)
    print(f"\n{len(fixes)} RANSAC fixes (locate) of the same mission")
    print(f"hypothesis by hypothesis (before): {1000 * before / len(fixes):6.2f} ms a fix")
    print(f"every hypothesis at once (now):    {1000 * after / len(fixes):6.2f} ms a fix")
    print(f"ratio before / now: {before / after:.2f}; the same centres and inliers: {old == new}")


if __name__ == "__main__":
    main()
