"""Benchmark the batched vector environment (``make_vec(..., vectorization_mode="vector_entry_point")``)
against a ``SyncVectorEnv`` of the same number of one-robot environments, and against bare MuJoCo
(``mj_step`` on each robot's model and data for the same physics time), in alternating blocks in one
process so that a busy moment on a shared machine hits every side alike (median block times).

    python tests/bench/bench_batched.py [--envs 16] [--steps 400] [--env-id MapTidal/GoToPose-v1]

Goals (issue [rl], part 6): batched >= 3x SyncVectorEnv at N = 16; the batched env.step <= 1.5x bare
mj_step for the same physics time.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium
import mujoco
import numpy as np

import maptidal.envs  # noqa: F401  (registers MapTidal/)


def measure(env_id: str, n: int, steps: int, block: int = 20) -> dict[str, float]:
    """Steps per second (robot steps: vector steps times N) of each side, and the ratios."""
    batched = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    sync = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="sync")
    bare = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
    for vec in (batched, sync, bare):
        vec.reset(seed=0)
    sims = [env.sim for env in bare.envs]
    physics_steps = bare.periods_per_step * bare.substeps_per_period
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, (n, *batched.single_action_space.shape)).astype(np.float32)

    def run_batched() -> None:
        batched.step(actions)

    def run_sync() -> None:
        sync.step(actions)

    def run_bare() -> None:
        for sim in sims:
            mujoco.mj_step(sim.model, sim.data, nstep=physics_steps)

    sides = {"batched": run_batched, "sync": run_sync, "bare mj_step": run_bare}
    for run in sides.values():  # warm-up
        for _ in range(3):
            run()
    times: dict[str, list[float]] = {name: [] for name in sides}
    for _ in range(max(1, steps // block)):
        for name, run in sides.items():
            start = time.perf_counter()
            for _ in range(block):
                run()
            times[name].append(time.perf_counter() - start)
    for vec in (batched, sync, bare):
        vec.close()
    rate = {name: n * block / float(np.median(values)) for name, values in times.items()}
    return {
        **{f"{name} robot-steps/s": value for name, value in rate.items()},
        "batched / sync": rate["batched"] / rate["sync"],
        "batched step / bare mj_step (time)": rate["bare mj_step"] / rate["batched"],
        "sync step / bare mj_step (time)": rate["bare mj_step"] / rate["sync"],
    }


def main() -> None:
    """Print the measurements."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[16])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--env-id", default="MapTidal/GoToPose-v1")
    args = parser.parse_args()
    for n in args.envs:
        result = measure(args.env_id, n, args.steps)
        print(f"{args.env_id}, N = {n}:")
        for key, value in result.items():
            print(f"  {key}: {value:.2f}")


if __name__ == "__main__":
    main()
