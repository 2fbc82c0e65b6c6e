"""Train Stable-Baselines3 PPO on MapTidal/GoToPose-v1, report the success rate, and plot the learning
curve.

    pip install -e .[rl]          # stable-baselines3 and torch 2.13.0 (CPU), outside the default install
    python examples/train_ppo.py --timesteps 200000 --envs 2 --out runs/ppo

Writes ``learning_curve.png`` (mean episode return and success rate against environment steps) and
``result.json`` (the curve, the evaluation's success rate and the settings) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium
import numpy as np

import maptidal.envs  # noqa: F401  (registers MapTidal/)
from maptidal.files import atomic_write_bytes
from maptidal.progress import ProgressBar

ENV_ID = "MapTidal/GoToPose-v1"


def make_env(seed: int):
    """A factory of one flat-observation GoToPose environment, monitored for returns and success."""
    from stable_baselines3.common.monitor import Monitor

    def build():
        made = gymnasium.make(ENV_ID, flat_obs=True, max_episode_steps=120)  # 12 s episodes
        env = Monitor(made, info_keywords=("is_success",))
        env.reset(seed=seed)
        return env

    return build


def evaluate(model, episodes: int, seed: int) -> float:
    """Share of new episodes in which the deterministic policy reaches the pose (within tolerance)."""
    env = gymnasium.make(ENV_ID, flat_obs=True, max_episode_steps=120)
    reached = 0
    for k in range(episodes):
        observation, _ = env.reset(seed=seed + k)
        done, success = False, False
        while not done:
            action, _ = model.predict(observation, deterministic=True)
            observation, _, terminated, truncated, info = env.step(action)
            success |= info["is_success"]
            done = terminated or truncated
        reached += success
    env.close()
    return reached / episodes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=200_000, help="environment steps to train")
    parser.add_argument("--envs", type=int, default=2, help="parallel environments (subprocesses)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path("runs/ppo"))
    args = parser.parse_args()
    try:
        from stable_baselines3 import PPO
        from stable_baselines3.common.callbacks import BaseCallback
        from stable_baselines3.common.vec_env import SubprocVecEnv
    except ImportError:
        print("examples/train_ppo.py needs the rl extra: pip install -e .[rl]", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)

    class Curve(BaseCallback):
        """Episode returns and successes as they finish, and a progress bar."""

        def __init__(self) -> None:
            super().__init__()
            self.points: list[tuple[int, float, float]] = []
            self.bar = ProgressBar(args.timesteps, "PPO")

        def _on_step(self) -> bool:
            for info in self.locals["infos"]:
                if "episode" in info:
                    self.points.append(
                        (self.num_timesteps, float(info["episode"]["r"]), float(info["is_success"]))
                    )
            self.bar.advance(self.training_env.num_envs)
            return True

    vec = SubprocVecEnv([make_env(args.seed + k) for k in range(args.envs)])
    model = PPO("MlpPolicy", vec, n_steps=1024, batch_size=256, gamma=0.99, seed=args.seed, verbose=0)
    curve = Curve()
    model.learn(total_timesteps=args.timesteps, callback=curve)
    vec.close()
    success = evaluate(model, args.eval_episodes, 10_000)
    points = np.array(curve.points) if curve.points else np.zeros((0, 3))
    result = {
        "env": ENV_ID,
        "timesteps": args.timesteps,
        "envs": args.envs,
        "seed": args.seed,
        "eval_episodes": args.eval_episodes,
        "eval_success_rate": success,
        "curve": [{"step": int(s), "return": r, "success": bool(k)} for s, r, k in points],
    }
    atomic_write_bytes(args.out / "result.json", json.dumps(result, indent=2).encode())
    plot(points, success, args.out / "learning_curve.png")
    print(
        f"success rate over {args.eval_episodes} new episodes: {success:.0%}; {args.out}/learning_curve.png"
    )
    return 0


def plot(points: np.ndarray, success: float, path: Path) -> None:
    """Mean return and success rate over a sliding window of 20 episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, left = plt.subplots(figsize=(7, 4), dpi=120)
    if len(points):
        window = max(1, min(20, len(points) // 5))
        kernel = np.ones(window) / window
        steps = points[window - 1 :, 0]
        left.plot(steps, np.convolve(points[:, 1], kernel, "valid"), color="tab:blue", label="return")
        right = left.twinx()
        right.plot(steps, np.convolve(points[:, 2], kernel, "valid"), color="tab:green", label="success")
        right.set_ylim(-0.05, 1.05)
        right.set_ylabel(f"success rate ({window}-episode mean)")
    left.set_xlabel("environment steps")
    left.set_ylabel("episode return")
    left.set_title(f"PPO on {ENV_ID}: evaluation success {success:.0%}")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
