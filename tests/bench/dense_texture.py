"""The dense depth's texture test on rendered frames (issue [loop]): from random poses in the default tank
and the two held-out variants (tests/bench/tanks/), the dense points against the renderer's own depth
buffer, with the texture test off and on. A point is accurate within 10 cm (or 5 % of its depth) of the
rendered depth, wrong beyond 30 cm; "far clip" marks wrong points whose pixel sees nothing within 40 m
(the water surface from below, or down the tank). Writes a markdown table to stdout.

    python tests/bench/dense_texture.py [--poses N]
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

from maptidal.camera import StereoCameraParams
from maptidal.envs.scenario import load_scenario
from maptidal.envs.simulation import Simulation
from maptidal.perception.dense import DenseDepthParams, dense_points
from maptidal.perception.recording import CameraIntrinsics

ROOT = Path(__file__).resolve().parents[2]
TANKS = {
    "default": ROOT / "assets/scenarios/mission.toml",
    "variant A": ROOT / "tests/bench/tanks/variant_a/mission.toml",
    "variant B": ROOT / "tests/bench/tanks/variant_b/mission.toml",
}
FAR_CLIP_M = 40.0


def classify(points: np.ndarray, depth: np.ndarray, k: CameraIntrinsics) -> dict:
    """Counts of a frame's dense points (:func:`dense_points` in the camera's own frame): accurate, wrong,
    and wrong where the pixel sees nothing near, each against the renderer's depth at its pixel."""
    u = np.round(points[:, 0] / points[:, 2] * k.fx + k.cx).astype(int)
    v = np.round(points[:, 1] / points[:, 2] * k.fy + k.cy).astype(int)
    truth = depth[v, u].astype(float)
    error = np.abs(points[:, 2] - truth)
    return {
        "points": len(points),
        "accurate": int((error < np.maximum(0.1, 0.05 * truth)).sum()),
        "wrong": int((error > 0.3).sum()),
        "far clip": int(((error > 0.3) & (truth > FAR_CLIP_M)).sum()),
    }


def measure(path: Path, poses: int, seed: int = 1) -> dict[str, dict[str, int]]:
    """The counts over ``poses`` random poses in the scenario's tank, the test off and on."""
    scenario = load_scenario(path)
    tank = scenario.tank.config
    sim = Simulation(scenario, camera=StereoCameraParams(width=320, height=200), water_backend="prefer-gl")
    sim.reset(seed=0)
    calibration = sim.intrinsics()
    matrix = calibration["K"]
    k = CameraIntrinsics(
        calibration["width"],
        calibration["height"],
        matrix[0][0],
        matrix[1][1],
        matrix[0][2],
        matrix[1][2],
        calibration["baseline_m"],
    )
    robot, *others = sim.robots
    for index, other in enumerate(others):
        sim.place(other, [-5.5, 0.5 * index, 0.3])  # down the tank, out of view
    settings = {
        "off": DenseDepthParams(pixel_noise_sigma=scenario.water.noise_sigma, texture_confidence=0.0),
        "on": DenseDepthParams(pixel_noise_sigma=scenario.water.noise_sigma),
    }
    totals = {name: dict.fromkeys(("points", "accurate", "wrong", "far clip"), 0) for name in settings}
    rng = np.random.default_rng(seed)
    half_width = tank.end_wall_width / 2 - 0.2
    try:
        for _ in range(poses):
            position = [
                rng.uniform(-2.2, -0.6),
                rng.uniform(-half_width, half_width),
                rng.uniform(0.4, tank.water_depth - 0.3),
            ]
            sim.place(robot, position, yaw_rad=rng.uniform(-math.radians(115), math.radians(115)))
            left, right, depth, _ = sim.render_stereo(robot, depth=True)
            for name, params in settings.items():
                points = dense_points(left, right, k, np.zeros(3), np.eye(3), params)
                counts = classify(points, depth, k)
                for key, value in counts.items():
                    totals[name][key] += value
    finally:
        sim.close()
    return totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--poses", type=int, default=40, help="random poses per tank (default 40)")
    args = parser.parse_args()
    print("| tank | texture test | points | accurate | wrong (> 30 cm) | of them at the far clip |")
    print("|---|---|---|---|---|---|")
    for tank, path in TANKS.items():
        totals = measure(path, args.poses)
        for name, counts in totals.items():
            print(
                f"| {tank} | {name} | {counts['points']} | {counts['accurate']} | {counts['wrong']} |"
                f" {counts['far clip']} |"
            )


if __name__ == "__main__":
    main()
