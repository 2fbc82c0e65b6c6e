"""Benchmark the batched vector environment (``make_vec(..., vectorization_mode="vector_entry_point")``)
against a ``SyncVectorEnv`` of the same number of one-robot environments, and against bare MuJoCo
(``mj_step`` on each robot's model and data, given the batch's own controls, so the same physics), in
alternating blocks in one
process so that a busy moment on a shared machine hits every side alike (median block times).

    python tests/bench/bench_batched.py [--envs 16] [--steps 400] [--env-id ID] [--threads N]

Goals (issue [rl], part 6): batched >= 3x SyncVectorEnv at N = 16; the batched env.step <= 1.5x bare
mj_step for the same physics time. Where the compiled flight stack runs, the batch flies every robot in
one call of it and SyncVectorEnv's robots fly it one by one.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium
import numpy as np
from replay import plain_mj_step, record_periods

import maptidal.envs  # noqa: F401  (registers MapTidal/)
from maptidal.envs.simulation import step_physics


def measure(env_id: str, n: int, steps: int, block: int = 20, threads: int | None = None) -> dict[str, float]:
    """Robot steps per second of each side, and the ratios. The bare side is MuJoCo alone doing the
    batch's very physics: a second batch reset with the same seed, whose robots get, period by period,
    the controls the batch's robots get (recorded beforehand by one-robot environments with the rows'
    seeds, flown one control period at a time: the compiled flight stack flies a robot alike alone and
    in a batch, and one period at a time as five) and are stepped by ``mj_step`` and nothing else, so
    both sides integrate the same states and contacts. A third batch replays them with ``step_physics``
    (the sensors computed only in each period's last step, where they are read, as the environments
    step). ``threads``: the batch's threads (None: its default)."""
    # no episode ends within the measurement: a batch row that reset would leave its bare twin, which
    # is only stepped, on another trajectory (every side gets the same limit)
    limit = {"max_episode_steps": 10 * (steps + 10)}
    threading = {} if threads is None else {"threads": threads}
    batched = gymnasium.make_vec(
        env_id, num_envs=n, vectorization_mode="vector_entry_point", **limit, **threading
    )
    sync = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="sync", **limit)
    twin = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **limit)
    lean_twin = gymnasium.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **limit)
    for vec in (batched, sync, twin, lean_twin):
        vec.reset(seed=0)
    sims = [env.sim for env in twin.envs]
    lean_sims = [env.sim for env in lean_twin.envs]
    substeps = twin.substeps_per_period
    rng = np.random.default_rng(0)
    actions = rng.uniform(-0.3, 0.3, (n, *batched.single_action_space.shape)).astype(np.float32)
    total_steps = 3 + max(1, steps // block) * block
    recorded = record_controls(env_id, n, actions, total_steps, limit)

    def run_batched() -> None:
        batched.step(actions)

    def run_sync() -> None:
        sync.step(actions)

    def replaying(targets, queue, step):
        def run() -> None:
            for _ in range(batched.periods_per_step):
                for sim, ctrl in zip(targets, queue.pop(0), strict=True):
                    sim.data.ctrl[:] = ctrl
                    step(sim.model, sim.data, substeps)

        return run

    run_bare = replaying(sims, recorded, plain_mj_step)
    run_lean = replaying(lean_sims, list(recorded), step_physics)

    sides = {"batched": run_batched, "sync": run_sync, "bare mj_step": run_bare, "lean bare": run_lean}
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
    # to rounding: the numpy batch sums in another order than the one-robot environments that recorded
    # the controls (the compiled batch matches them bit for bit)
    same = all(
        np.allclose(a.sim.data.qpos, b.sim.data.qpos) and np.allclose(a.sim.data.qpos, c.sim.data.qpos)
        for a, b, c in zip(batched.envs, twin.envs, lean_twin.envs, strict=True)
    )
    for vec in (batched, sync, twin, lean_twin):
        vec.close()
    rate = {name: n * block / float(np.median(values)) for name, values in times.items()}
    return {
        **{f"{name} robot-steps/s": value for name, value in rate.items()},
        "batched / sync": rate["batched"] / rate["sync"],
        "batched step / bare mj_step (time)": rate["bare mj_step"] / rate["batched"],
        "sync step / bare mj_step (time)": rate["bare mj_step"] / rate["sync"],
        "batched step / bare with sensors only where read (time)": rate["lean bare"] / rate["batched"],
        "bare side flew the batch's trajectory (1 = yes)": float(same),
    }


def record_controls(
    env_id: str, n: int, actions: np.ndarray, steps: int, limit: dict
) -> list[list[np.ndarray]]:
    """Each control period's controls of each of ``n`` one-robot environments (seeds 0 to n - 1, as a
    batch reset with seed 0 gives its rows), holding ``actions`` for ``steps`` steps."""
    per_robot = []
    for k in range(n):
        env = gymnasium.make(env_id, **limit)
        env.reset(seed=k)
        record = record_periods(env.unwrapped.sim)
        for _ in range(steps):
            env.step(actions[k])
        per_robot.append([ctrl for ctrl, _ in record])
        env.close()
    return [list(period) for period in zip(*per_robot, strict=True)]


def main() -> None:
    """Print the measurements."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", type=int, nargs="+", default=[16])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--env-id", default="MapTidal/GoToPose-v1")
    parser.add_argument("--threads", type=int, default=None, help="the batch's threads (default: its own)")
    args = parser.parse_args()
    for n in args.envs:
        result = measure(args.env_id, n, args.steps, threads=args.threads)
        print(f"{args.env_id}, N = {n}, threads {args.threads or 'default'}:")
        for key, value in result.items():
            print(f"  {key}: {value:.2f}")


if __name__ == "__main__":
    main()
