"""Benchmark the Gymnasium environments: env.step against bare mj_step for the same physics, and
against the Simulation.steps it wraps (same process, same number of physics steps), with and without
images, image observations at their size against 640 x 400 stereo, and an async vector of two.

    python tests/bench/bench_gym.py [--steps N]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is imported: it picks its GL backend then

import gymnasium
import numpy as np
from replay import plain_mj_step, record_periods

import maptidal.envs  # noqa: F401
from maptidal.envs.simulation import step_physics


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
    """What one env step wraps, done by hand: its Simulation.steps (each reads the sensors once and
    updates the estimate the observation reports) and, with images, the stereo render."""
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
        if images:
            sim.render_stereo(robot)
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def interleaved_overhead(env_id: str, steps: int, block: int = 50) -> tuple[float, float, float]:
    """Env steps/s, wrapped-work steps/s and their ratio, measured in alternating blocks of ``block``
    steps on two copies of the environment, so that a busy moment on a shared machine hits both sides
    alike. The ratio is that of the median block times."""
    env = gymnasium.make(env_id)
    bare_env = gymnasium.make(env_id)
    env.reset(seed=0)
    bare_env.reset(seed=0)
    inner = bare_env.unwrapped
    sim, robot = inner.sim, inner.robot
    action = np.zeros(env.action_space.shape, np.float32)
    command = {robot: np.zeros(6)}
    ours, bare = [], []
    for _ in range(max(1, steps // block)):
        start = time.perf_counter()
        for _ in range(block):
            *_, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        ours.append(time.perf_counter() - start)
        start = time.perf_counter()
        for _ in range(block * inner.substeps):
            sim.step(command)  # the physics, the one sensor read and the estimate (track_estimate)
        bare.append(time.perf_counter() - start)
    env.close()
    bare_env.close()
    ours_s, bare_s = float(np.median(ours)), float(np.median(bare))
    return block / ours_s, block / bare_s, ours_s / bare_s


def interleaved_physics_ratio(
    env_id: str, steps: int, block: int = 50, **options
) -> tuple[float, float, float, bool, str]:
    """The time of one ``env.step`` (through ``gymnasium.make``'s wrappers) over that of bare ``mj_step``
    for the same physics time (issue [rl]'s goal: <= 1.5), measured in alternating blocks (median block
    times). The bare side is MuJoCo alone doing the env's very physics: a twin environment, flown first
    one control period at a time to record the controls each period gave (the compiled flight stack flies
    one period at a time as it flies five, bit for bit), replayed into a third copy's model and data with
    ``mj_step`` and nothing else. A fourth copy replays them with ``step_physics``, as the environment
    steps: the sensors computed only in each period's last step, where they are read. Returns (env
    steps/s, bare steps/s, lean bare steps/s, whether all sides ended in the same state, the flight
    stack that ran)."""
    limit = {"max_episode_steps": 10 * (steps + block + 10)}  # no episode ends within the measurement
    measured, recorder, bare_env, lean_env = (gymnasium.make(env_id, **limit, **options) for _ in range(4))
    rng = np.random.default_rng(0)
    total = max(1, steps // block) * block
    actions = rng.uniform(-0.3, 0.3, (total + 10, *measured.action_space.shape)).astype(np.float32)
    for env in (measured, recorder, bare_env, lean_env):
        env.reset(seed=0)
    sim = recorder.unwrapped.sim
    controls = record_periods(sim)  # each period's controls and userdata (its current)
    for action in actions:
        recorder.step(action)
    bare_sim, lean_sim = bare_env.unwrapped.sim, lean_env.unwrapped.sim
    substeps = bare_sim.scenario.substeps
    periods = recorder.unwrapped.substeps

    def replaying(target, step):
        def side(ctrl, userdata):
            target.data.ctrl[:], target.data.userdata[:] = ctrl, userdata
            step(target.model, target.data, substeps)

        return side

    plain, lean = replaying(bare_sim, plain_mj_step), replaying(lean_sim, step_physics)

    for action in actions[:10]:  # warm-up, every side
        measured.step(action)
    for ctrl, userdata in controls[: 10 * periods]:
        plain(ctrl, userdata)
        lean(ctrl, userdata)
    ours, bare, leaner = [], [], []
    for start in range(10, total + 10, block):
        begin = time.perf_counter()
        for action in actions[start : start + block]:
            measured.step(action)
        ours.append(time.perf_counter() - begin)
        replayed = controls[start * periods : (start + block) * periods]
        for side, times in ((plain, bare), (lean, leaner)):
            begin = time.perf_counter()
            for ctrl, userdata in replayed:
                side(ctrl, userdata)
            times.append(time.perf_counter() - begin)
    final = measured.unwrapped.sim.data
    same = all(
        np.array_equal(final.qpos, other.data.qpos)
        and np.array_equal(final.sensordata, other.data.sensordata)
        for other in (bare_sim, lean_sim)
    )
    backend = measured.unwrapped.sim.flight_backend
    for env in (measured, recorder, bare_env, lean_env):
        env.close()
    rates = (block / float(np.median(times)) for times in (ours, bare, leaner))
    return (*rates, same, backend)


def team_rate(steps: int) -> float:
    env = gymnasium.make("MapTidal/TeamInspection-v1")
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


def interleaved_vector_gain(steps: int, block: int = 100) -> tuple[float, float, float]:
    """Steps/s of an async vector of one and of two, measured in alternating blocks (median block
    times), and the ratio of two to one."""
    vectors = {
        n: gymnasium.make_vec("MapTidal/GoToPose-v1", num_envs=n, vectorization_mode="async") for n in (1, 2)
    }
    times: dict[int, list[float]] = {1: [], 2: []}
    for n, vec in vectors.items():
        vec.reset(seed=0)
        for _ in range(10):
            vec.step(np.zeros((n, 6), np.float32))
    for _ in range(max(1, steps // block)):
        for n, vec in vectors.items():
            actions = np.zeros((n, 6), np.float32)
            start = time.perf_counter()
            for _ in range(block):
                vec.step(actions)
            times[n].append(time.perf_counter() - start)
    for vec in vectors.values():
        vec.close()
    one, two = (n * block / float(np.median(times[n])) for n in (1, 2))
    return one, two, two / one


def interleaved_image_gain(steps: int, block: int = 20) -> tuple[float, float, float]:
    """Env steps/s of GoToPose with 84 x 84 left images and with 640 x 400 stereo, measured in
    alternating blocks (median block times), and the ratio of the first to the second (goal >= 5)."""
    envs = {
        "small": gymnasium.make("MapTidal/GoToPose-v1", obs_images="left", image_size=(84, 84)),
        "full": gymnasium.make("MapTidal/GoToPose-v1", obs_images="stereo", image_size=(400, 640)),
    }
    times: dict[str, list[float]] = {name: [] for name in envs}
    action = np.zeros(6, np.float32)
    for env in envs.values():
        env.reset(seed=0)
        for _ in range(5):  # warm-up: the renderer and the water pass are made on the first draws
            env.step(action)
    for _ in range(max(1, steps // block)):
        for name, env in envs.items():
            start = time.perf_counter()
            for _ in range(block):
                *_, terminated, truncated, _ = env.step(action)
                if terminated or truncated:
                    env.reset()
            times[name].append(time.perf_counter() - start)
    for env in envs.values():
        env.close()
    small, full = (block / float(np.median(times[name])) for name in ("small", "full"))
    return small, full, small / full


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300, help="env steps per measurement")
    args = parser.parse_args()
    print(
        "| environment | flight stack | env steps/s | bare mj_step, steps/s | env.step / bare (goal <= 1.5)"
        " | env.step / bare with sensors only where read |"
    )
    print("|---|---|---|---|---|---|")
    for env_id in ("MapTidal/GoToPose-v1", "MapTidal/StationKeeping-v1", "MapTidal/TankInspection-v1"):
        ours, bare, lean, same, backend = interleaved_physics_ratio(env_id, args.steps)
        flown = "" if same else " (the bare sides left the env's trajectory: not comparable)"
        ratios = f"{bare / ours:.2f}{flown} | {lean / ours:.2f}"
        print(f"| {env_id} | {backend} | {ours:.0f} | {bare:.0f} | {ratios} |")
    print()
    print("| environment | images | env steps/s | wrapped work, steps/s | overhead (goal <= 1.3 / 1.1) |")
    print("|---|---|---|---|---|")
    steps = max(10, args.steps // 10)
    for env_id in ("MapTidal/GoToPose-v1", "MapTidal/StationKeeping-v1", "MapTidal/TankInspection-v1"):
        ours, bare, ratio = interleaved_overhead(env_id, args.steps)
        print(f"| {env_id} | none | {ours:.0f} | {bare:.0f} | {ratio:.2f} |")
        ours = env_rate(env_id, steps, obs_images="stereo", image_size=(400, 640))
        bare = bare_rate(env_id, steps, images=True)
        print(f"| {env_id} | stereo 640x400 | {ours:.1f} | {bare:.1f} | {bare / ours:.2f} |")
    small, full, gain = interleaved_image_gain(max(40, args.steps // 3))
    print(f"\nGoToPose images: 84x84 left {small:.0f} steps/s, 640x400 stereo {full:.1f} steps/s, ", end="")
    print(f"ratio {gain:.1f} (goal >= 5)")
    print(f"\nMapTidal/TeamInspection-v1, 2 robots: {team_rate(args.steps):.0f} steps/s")
    one, two, gain = interleaved_vector_gain(args.steps)
    print(f"\nasync vector: 1 env {one:.0f} steps/s, 2 envs {two:.0f} steps/s", end=", ")
    print(f"ratio {gain:.2f} (goal >= 1.6)")


if __name__ == "__main__":
    main()
