"""Where the robot without a DVL loses its position: a frame-by-frame account of its front end's steps.

Runs a mission (inline perception) and, for each robot without a DVL, records at every frame the true
camera step, the dead reckoning's step, the visual (PnP) step and what the front end did with it (used,
gated, too long, none), and every relocalisation fix. It prints how much each kind of frame added to the
horizontal error, and writes the rows as JSON for a closer look.

    python tests/bench/diag_localisation.py --duration 300 --seed 0 --out /tmp/diag
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from maptidal.mission.config import prepare_mission
from maptidal.mission.run import Mission
from maptidal.perception import frontend as frontend_module
from maptidal.perception import odometry as odometry_module

ROWS: list[dict] = []
FIXES: list[dict] = []
TRUTH: dict[tuple[int, float], np.ndarray] = {}
CLOCK: dict[int, float] = {}
COUNTS: dict[float, tuple] = {}
YAW: dict[tuple[int, float], float] = {}


def instrument() -> None:
    """Wrap the front end's process, the odometry's update and correct to record what they did."""
    process = frontend_module.FrontEnd.process
    update = odometry_module.VisualOdometry.update
    correct = odometry_module.VisualOdometry.correct

    def logged_process(self, index, time_s, left, right, pose):
        CLOCK[id(self.odometry)] = time_s
        record, keyframe = process(self, index, time_s, left, right, pose)
        if not self.odometry.params.has_dvl:
            COUNTS[round(time_s, 3)] = (record.keypoints, record.tracked, record.matched, record.pnp_inliers)
        return record, keyframe

    def logged_update(self, dead_reckoning, motion, dt_s=0.0):
        before = None if self.pose is None else self.pose.position.copy()
        last_dr = None if self._last_dr is None else self._last_dr.position.copy()
        gated_before = self.gated
        visual = None
        if motion is not None and self.pose is not None:
            rotation, translation, _ = motion
            visual = (self.pose.rotation @ (-rotation.T @ translation)).tolist()
        result = update(self, dead_reckoning, motion, dt_s)
        if before is not None and not self.params.has_dvl:
            kind = "none"
            if visual is not None:
                if self.gated > gated_before:
                    kind = "gated"
                elif np.linalg.norm(visual) > self.params.max_step_m:
                    kind = "long"
                else:
                    kind = "used"
            ROWS.append(
                {
                    "vo": id(self),
                    "t": CLOCK.get(id(self)),
                    "dr_step": (dead_reckoning.position - last_dr).tolist(),
                    "visual_step": visual,
                    "kind": kind,
                    "step": (result.position - before).tolist(),
                    "pose": result.position.tolist(),
                    "sigma": self.sigma_m,
                    "inliers": None if motion is None else int(motion[2]),
                }
            )
        return result

    def logged_correct(self, centre, sigma_m):
        before = self.pose.position.copy()
        result = correct(self, centre, sigma_m)
        if not self.params.has_dvl:
            FIXES.append(
                {
                    "vo": id(self),
                    "t": CLOCK.get(id(self)),
                    "shift": (result.position - before).tolist(),
                    "centre": np.asarray(centre, float).tolist(),
                    "fix_sigma": sigma_m,
                }
            )
        return result

    frontend_module.FrontEnd.process = logged_process
    odometry_module.VisualOdometry.update = logged_update
    odometry_module.VisualOdometry.correct = logged_correct


def main() -> None:
    """Run the mission and print the account."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="/tmp/diag_localisation")
    args = parser.parse_args()
    instrument()
    scenario, params = prepare_mission(None, None, args.duration, None, args.seed)
    import dataclasses

    params = dataclasses.replace(params, perception_process=False)
    mission = Mission(scenario, params, args.out)
    see = Mission._see

    def logged_see(robot, now):
        camera = mission._camera_pose(robot, "truth")
        TRUTH[(robot.index, round(now, 3))] = np.array(camera.position, float)
        YAW[(robot.index, round(now, 3))] = float(mission.sim.ground_truth(robot.name)["rpy"][2])
        return see(mission, robot, now)

    mission._see = logged_see
    mission.run()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    truth = [[i, t, *TRUTH[(i, t)].tolist(), YAW[(i, t)]] for (i, t) in sorted(TRUTH)]
    counts = [[t, *c] for t, c in sorted(COUNTS.items())]
    (Path(args.out) / "diag.json").write_text(
        json.dumps({"rows": ROWS, "fixes": FIXES, "truth": truth, "counts": counts})
    )
    summarise(mission)


def summarise(mission: Mission) -> None:
    """Print the per-kind error contributions of the robot(s) without a DVL."""
    robots = [r for r in mission.robots.values() if not r.has_dvl]
    for robot in robots:
        times = sorted(t for (i, t) in TRUTH if i == robot.index)
        truth = {t: TRUTH[(robot.index, t)] for t in times}
        rows = [r for r in ROWS if r["t"] is not None and round(r["t"], 3) in truth]
        print(f"{robot.name}: {len(rows)} frames, {len(FIXES)} fixes")
        by_kind: dict[str, list[float]] = {}
        dr_err, vis_err = [], []
        previous_t = None
        for row in rows:
            t = round(row["t"], 3)
            index = times.index(t)
            if index == 0:
                continue
            true_step = truth[t] - truth[times[index - 1]]
            err = np.linalg.norm((np.array(row["step"]) - true_step)[:2])
            by_kind.setdefault(row["kind"], []).append(err)
            dr_err.append(np.linalg.norm((np.array(row["dr_step"]) - true_step)[:2]))
            if row["visual_step"] is not None:
                vis_err.append(np.linalg.norm((np.array(row["visual_step"]) - true_step)[:2]))
            previous_t = t
        for kind, errs in sorted(by_kind.items()):
            e = np.array(errs)
            median, p90, total = 100 * np.median(e), 100 * np.percentile(e, 90), 100 * e.sum()
            print(
                f"  {kind:6s} n={len(e):4d} step error median {median:.1f} cm, p90 {p90:.1f}, sum {total:.0f}"
            )
        for label, errors in (("dead-reckoning", dr_err), ("visual", vis_err)):
            median, p90 = 100 * np.median(errors), 100 * np.percentile(errors, 90)
            print(f"  {label} step error median {median:.1f} cm p90 {p90:.1f}")
        del previous_t


if __name__ == "__main__":
    main()
