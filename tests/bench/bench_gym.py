"""Benchmark the Gymnasium environments: env.step against the Simulation.step and sensor reads it wraps
(same process, same number of physics steps), with and without images, and an async vector of two.

    python tests/bench/bench_gym.py [--steps N]
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium
import numpy as np

import envs  # noqa: F401

os.environ.setdefault("MUJOCO_GL", "egl")


def env_rate(env_id: str, steps: int, **options) -> float:
    env = gymnasium.make(env_id, **options)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    for _ in range(10):  # warm-up: the first steps pay one-off costs (renderer, caches)
        env.step(action)
    start = time.perf_counter()
    for _ in range(steps):
        *_, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def bare_rate(env_id: str, steps: int, images: bool = False) -> float:
    """What one env step wraps, done by hand: its Simulation.step and sensor reads (and the stereo
    render, with images)."""
    env = gymnasium.make(env_id)
    env.reset(seed=0)
    inner = env.unwrapped
    sim, robot = inner.sim, inner.robot
    command = {robot: np.zeros(6)}
    for _ in range(10):
        sim.step(command)
        if images:
            sim.render_stereo(robot)
    start = time.perf_counter()
    for _ in range(steps):
        for _ in range(inner.substeps):
            sim.step(command)
            sim.sensors(robot)
        if images:
            sim.render_stereo(robot)
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def team_rate(steps: int) -> float:
    env = gymnasium.make("MapTidal/TeamInspection-v0")
    env.reset(seed=0)
    action = {name: np.zeros(6, np.float32) for name in env.unwrapped.agents}
    start = time.perf_counter()
    for _ in range(steps):
        *_, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def vector_rate(num_envs: int, steps: int) -> float:
    vec = gymnasium.make_vec("MapTidal/GoToPose-v0", num_envs=num_envs, vectorization_mode="async")
    vec.reset(seed=0)
    actions = np.zeros((num_envs, 6), np.float32)
    start = time.perf_counter()
    for _ in range(steps):
        vec.step(actions)
    rate = num_envs * steps / (time.perf_counter() - start)
    vec.close()
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="env steps per measurement")
    args = parser.parse_args()
    print("| environment | images | env steps/s | wrapped work, steps/s | overhead (goal <= 1.3 / 1.1) |")
    print("|---|---|---|---|---|")
    steps = max(10, args.steps // 10)
    for env_id in ("MapTidal/GoToPose-v0", "MapTidal/StationKeeping-v0", "MapTidal/TankInspection-v0"):
        ours, bare = env_rate(env_id, args.steps), bare_rate(env_id, args.steps)
        print(f"| {env_id} | none | {ours:.0f} | {bare:.0f} | {bare / ours:.2f} |")
        ours = env_rate(env_id, steps, obs_images="stereo", image_size=(400, 640))
        bare = bare_rate(env_id, steps, images=True)
        print(f"| {env_id} | stereo 640x400 | {ours:.1f} | {bare:.1f} | {bare / ours:.2f} |")
    print(f"\nMapTidal/TeamInspection-v0, 2 robots: {team_rate(args.steps):.0f} steps/s")
    one, two = vector_rate(1, args.steps), vector_rate(2, args.steps)
    print(f"\nasync vector: 1 env {one:.0f} steps/s, 2 envs {two:.0f} steps/s", end=", ")
    print(f"ratio {two / one:.2f} (goal >= 1.6)")


if __name__ == "__main__":
    main()
