"""How honest the front end's uncertainty is for a robot without a DVL (issue [loop]).

The loop calls such a robot lost when its front end holds its horizontal position more than 15 cm
uncertain (``MissionParams.lost_sigma_m``), and the same standard deviation sizes the relocalisation's
search and gate (:mod:`maptidal.perception.relocalisation`). This bench flies missions (perception
inline), samples every 0.5 s the robot's standard deviation and its true horizontal error, and records
each relocalisation fix's normalised innovation squared. It prints, per band of the standard deviation,
the root mean square error, the mean of error^2 / sigma^2 and the share of time lost; the fixes'
innovations; and the drift measured between fixes (the mean squared change of the error over a stretch
without a fix, over its length), against the parameter (``OdometryParams.drift_m2_s_no_dvl``). A plot
of error against standard deviation goes to ``--out``.

    python tests/bench/localisation_calibration.py [SCENARIO] --seeds 0,5 --out /tmp/calibration
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from maptidal.mission import run as run_module
from maptidal.mission.batch import parse_seeds
from maptidal.mission.config import prepare_mission
from maptidal.perception import odometry as odometry_module

SAMPLES: list[list[float]] = []  # time, sigma, error x, error y, lost
FIXES: list[list[float]] = []  # prediction sigma, fix sigma, NIS, drift scale
BANDS_M = (0.0, 0.05, 0.1, 0.15, 0.3, np.inf)


def instrument() -> None:
    """Wrap the odometry's fix and the mission's lost test (run every control period) to record."""
    correct = odometry_module.VisualOdometry.correct
    lost = run_module.Mission._lost

    def logged_correct(self, centre, sigma_m):
        if not self.params.has_dvl:
            innovation = np.asarray(centre, float)[:2] - self.pose.position[:2]
            nis = float(innovation @ innovation) / (self.sigma_m**2 + sigma_m**2)
            FIXES.append([self.sigma_m, float(sigma_m), nis, self.drift_scale])
        return correct(self, centre, sigma_m)

    def logged_lost(self, robot, now):
        answer = lost(self, robot, now)
        if not robot.has_dvl and abs(now * 2.0 - round(now * 2.0)) < 1e-6:
            truth = np.asarray(self.sim.ground_truth(robot.name)["position"])
            error = (self._estimate(robot).position - truth)[:2]
            SAMPLES.append([now, float(robot.position_sigma_m), *map(float, error), float(robot.lost)])
        return answer

    odometry_module.VisualOdometry.correct = logged_correct
    run_module.Mission._lost = logged_lost


def drift_between_fixes(samples: np.ndarray) -> dict[int, float]:
    """Per stretch length (whole seconds): the mean squared change of the horizontal error over stretches
    where the standard deviation only grew (no fix), over the length: the drift rate the fixes hid."""
    changes: dict[int, list[float]] = {}
    start = 0
    for i in range(1, len(samples)):
        if samples[i, 1] < samples[i - 1, 1] - 1e-9 or samples[i, 0] < samples[i - 1, 0]:
            start = i  # a fix (or the next mission)
            continue
        length = samples[i, 0] - samples[start, 0]
        change = samples[i, 2:4] - samples[start, 2:4]
        changes.setdefault(round(length), []).append(float(change @ change))
    return {k: float(np.mean(v)) / k for k, v in sorted(changes.items()) if k > 0 and len(v) >= 5}


def main() -> None:
    """Fly the missions and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=None, help="mission TOML (default: mission.toml)")
    parser.add_argument("--seeds", default="0,5", help="N, N-M or a comma list")
    parser.add_argument("--out", default="/tmp/localisation_calibration", help="folder for missions and plot")
    args = parser.parse_args()
    instrument()
    out = Path(args.out)
    for seed in parse_seeds(args.seeds):
        scenario, params = prepare_mission(args.scenario, None, None, "vo", seed)
        params = dataclasses.replace(params, plots=False, perception_process=False)
        run_module.Mission(scenario, params, out / f"seed_{seed:03d}").run()
    samples, fixes = np.array(SAMPLES), np.array(FIXES)
    sigma, error = samples[:, 1], np.hypot(samples[:, 2], samples[:, 3])
    print("| sigma (m) | samples | RMS error (m) | mean error^2 / sigma^2 | lost |")
    print("|---|---|---|---|---|")
    for low, high in itertools.pairwise(BANDS_M):
        band = (sigma >= low) & (sigma < high) & (sigma > 0)
        if band.any():
            print(
                f"| {low:.2f}-{high:.2f} | {band.sum()} | {np.sqrt(np.mean(error[band] ** 2)):.3f} | "
                f"{np.mean(error[band] ** 2 / sigma[band] ** 2):.2f} | {samples[band, 4].mean():.0%} |"
            )
    if len(fixes):
        print(
            f"\nfixes: {len(fixes)}; NIS median {np.median(fixes[:, 2]):.3f}, 90th percentile "
            f"{np.percentile(fixes[:, 2], 90):.3f} (chi-square, 2 dof: 1.39 and 4.61); drift scale at most "
            f"{fixes[:, 3].max():.1f}"
        )
    rates = drift_between_fixes(samples)
    parameter = odometry_module.OdometryParams().drift_m2_s_no_dvl
    measured = json.dumps({k: round(v, 6) for k, v in rates.items()})
    print(f"\ndrift between fixes by stretch length (s), m^2/s (parameter {parameter:g}): {measured}")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6, 4.5))
    axes.scatter(sigma, error, s=4, c=samples[:, 4], cmap="coolwarm", label="samples (red: lost)")
    top = float(max(sigma.max(), error.max()))
    axes.plot([0, top], [0, top], "k--", lw=1, label="error = sigma")
    axes.axvline(0.15, color="grey", lw=1, label="lost above (lost_sigma_m)")
    axes.set_xlabel("front end's horizontal standard deviation (m)")
    axes.set_ylabel("true horizontal error (m)")
    axes.set_title("Robot without a DVL: uncertainty against error")
    axes.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(out / "calibration.png", dpi=120)
    print(f"\nplot: {out / 'calibration.png'}")


if __name__ == "__main__":
    main()
