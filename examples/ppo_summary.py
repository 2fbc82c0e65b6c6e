"""Summarise several runs of ``examples/train_ppo.py`` (one per seed, with and without randomisation):
learning curves as the mean and spread over seeds, and a table of the evaluations.

    python examples/ppo_summary.py runs/ppo-sk-* --out docs/img/ppo_station_keeping_seeds.png

Reads each run's ``result.json``; groups runs by environment and by whether they trained with
randomisation; draws each group's episode return against environment steps (each seed's curve averaged
in 40 bins, then the mean over seeds and a band of one standard deviation); prints a Markdown table of
each group's evaluation per condition (the mean over seeds of each seed's mean return, the spread over
seeds, and the share of episodes that reached the pose), with the scripted controller beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

BINS = 40


def load(paths: list[Path]) -> dict[tuple[str, bool], list[dict]]:
    """The runs' results, grouped by (environment, trained with randomisation)."""
    groups: dict[tuple[str, bool], list[dict]] = {}
    for path in paths:
        result_file = path / "result.json" if path.is_dir() else path
        if result_file.suffix != ".json" or not result_file.exists():
            print(f"skipped {path}: no result.json (still training?)", file=sys.stderr)
            continue
        try:
            result = json.loads(result_file.read_text())
        except (OSError, json.JSONDecodeError) as error:
            print(f"skipped {result_file}: unreadable ({error})", file=sys.stderr)
            continue
        groups.setdefault((result["env"], bool(result["randomized_training"])), []).append(result)
    return groups


def binned_curve(result: dict, edges: np.ndarray) -> np.ndarray:
    """A run's mean episode return in each bin of environment steps (NaN where no episode ended)."""
    steps = np.array([point["step"] for point in result["curve"]], float)
    returns = np.array([point["return"] for point in result["curve"]], float)
    which = np.digitize(steps, edges, right=True) - 1  # bins (a, b]: the last step counts
    return np.array(
        [returns[which == k].mean() if np.any(which == k) else np.nan for k in range(len(edges) - 1)]
    )


def table(groups: dict[tuple[str, bool], list[dict]]) -> str:
    """The evaluations as a Markdown table: one row per policy, one column per condition."""
    conditions = list(next(iter(groups.values()))[0]["evaluations"])
    lines = [
        "| policy | seeds | " + " | ".join(conditions) + " |",
        "|---|---|" + "---|" * len(conditions),
    ]
    scripted_done = set()
    for (env, randomized), runs in sorted(groups.items()):
        rows = [("PPO, randomised training" if randomized else "PPO, nominal training", "ppo")]
        if env not in scripted_done:
            rows.append(("scripted controller", "scripted"))
            scripted_done.add(env)
        for label, policy in rows:
            cells = []
            for condition in conditions:
                means = [run["evaluations"][condition][policy]["return_mean"] for run in runs]
                reached = [run["evaluations"][condition][policy]["success"] for run in runs]
                cells.append(f"{np.mean(means):.1f} +- {np.std(means):.1f}, {np.mean(reached):.0%} reached")
            seeds = ", ".join(str(run["seed"]) for run in runs)
            lines.append(f"| {label} ({env.split('/')[-1]}) | {seeds} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(groups: dict[tuple[str, bool], list[dict]], path: Path) -> None:
    """Each group's learning curve: the mean over seeds and a one-standard-deviation band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axis = plt.subplots(figsize=(7, 4), dpi=120)
    colours = {False: "tab:blue", True: "tab:orange"}
    for (_env, randomized), runs in sorted(groups.items()):
        edges = np.linspace(0, max(run["timesteps"] for run in runs), BINS + 1)
        curves = np.array([binned_curve(run, edges) for run in runs])
        centres = (edges[:-1] + edges[1:]) / 2
        with np.errstate(all="ignore"):
            mean, spread = np.nanmean(curves, axis=0), np.nanstd(curves, axis=0)
        label = f"{'randomised' if randomized else 'nominal'} training ({len(runs)} seeds)"
        axis.plot(centres, mean, color=colours[randomized], label=label)
        axis.fill_between(centres, mean - spread, mean + spread, color=colours[randomized], alpha=0.2)
        scripted = np.mean([run["evaluations"]["nominal"]["scripted"]["return_mean"] for run in runs])
        scripted_label = "scripted controller (nominal vehicle)" if not randomized else None
        axis.axhline(scripted, color="tab:gray", linestyle="--", linewidth=1, label=scripted_label)
    envs = sorted({env for env, _ in groups})
    axis.set_title(f"PPO on {', '.join(envs)}: episode return (training episodes)")
    axis.set_xlabel("environment steps")
    axis.set_ylabel("episode return (mean over seeds, +- std)")
    axis.legend(loc="best")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> int:
    """Read the runs, draw the curves, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run folders of examples/train_ppo.py")
    parser.add_argument("--out", type=Path, required=True, help="the learning curves' PNG")
    args = parser.parse_args()
    groups = load(args.runs)
    if not groups:
        print("no finished runs", file=sys.stderr)
        return 2
    plot(groups, args.out)
    print(table(groups))
    return 0


if __name__ == "__main__":
    sys.exit(main())
