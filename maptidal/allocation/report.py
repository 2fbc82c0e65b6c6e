"""What `maptidal allocate` prints and draws: the auction's outcome next to the greedy yardstick."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from maptidal.allocation.auction import AuctionReport, AuctionSimulation
from maptidal.allocation.greedy import sequential_greedy


def _live_tasks(simulation: AuctionSimulation, report: AuctionReport):
    """Tasks the live robots know that are not done, in key order."""
    done = set(report.done)
    tasks = {t.key: t for i in report.alive for t in simulation.agents[i].tasks if t.key not in done}
    return [tasks[k] for k in sorted(tasks)]


def summarise(simulation: AuctionSimulation, report: AuctionReport, task_names: dict[int, str]) -> dict:
    """The JSON document of one auction (issue #5's shape, plus convergence and traffic details).

    greedy_ratio: travel cost of the auction's paths over that of the centralised sequential greedy
    allocation of the same live robots and tasks (1.0 = the same; lower is better)."""
    robots = [simulation.agents[i].robot for i in report.alive]
    greedy = sequential_greedy(robots, _live_tasks(simulation, report), simulation.auction)
    auction_cost = sum(simulation.agents[i].robot.cost_per_m * report.lengths[i] for i in report.alive)
    greedy_cost = greedy.travel_cost(robots)
    ratio = auction_cost / greedy_cost if greedy_cost > 0 else 1.0

    def name(key: int) -> str:
        return task_names.get(key, f"k{key >> 16}.{key & 0xFFFF}")

    messages = max(report.messages, 1)
    return {
        "robots": {
            report.names[i]: {
                "path": [name(k) for k in report.paths[i]],
                "length_m": round(report.lengths[i], 4),
            }
            for i in report.alive
        },
        "conflicts": report.conflicts,
        "unassigned": [name(k) for k in report.unassigned],
        "rounds": report.rounds,
        "messages": report.messages,
        "bytes": report.bytes,
        "sim_time_s": round(report.sim_time_s, 3),
        "greedy_ratio": round(ratio, 6),
        "converged": report.converged,
        "disagreements": report.disagreements,
        "infeasible": [name(k) for k in report.infeasible],
        "lost": [name(k) for k in report.lost],
        "failed": [report.names[i] for i in report.names if i not in report.alive and i in simulation.agents],
        "bytes_per_message": round(report.bytes / messages, 1),
        "max_message_bytes": report.max_message_bytes,
        "end_time_s": round(report.end_time_s, 3),
        "rejected_messages": dict(report.rejected),
        "channel": report.channel,
        "greedy_paths": {report.names[i]: [name(k) for k in greedy.paths[i]] for i in report.alive},
    }


def plot_allocation(
    simulation: AuctionSimulation, report: AuctionReport, summary: dict, path: str | Path
) -> Path:
    """Top and side views of robots, tasks and each robot's path; written atomically as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from maptidal.files import save_png

    figure, axes = plt.subplots(1, 2, figsize=(13, 5.5), gridspec_kw={"width_ratios": [3, 2]})
    colours = plt.get_cmap("tab10")
    tasks = {t.key: t for a in simulation.agents.values() for t in a.tasks}
    done = set(report.done)
    held = {k for path in report.paths.values() for k in path}
    unheld = np.array([t.position for k, t in tasks.items() if k not in held | done]).reshape(-1, 3)
    finished = np.array([tasks[k].position for k in done]).reshape(-1, 3)
    for view, (ax, (u, v), labels) in enumerate(
        zip(axes, ((0, 1), (0, 2)), (("x (m)", "y (m)"), ("x (m)", "z (m)")), strict=True)
    ):
        for points, colour, marker, label in (
            (unheld, "red", "o", "task nobody holds"),
            (finished, "grey", "s", "task done"),
        ):
            if len(points):
                ax.scatter(points[:, u], points[:, v], s=30, c=colour, marker=marker, label=label, zorder=1)
        for n, index in enumerate(sorted(simulation.agents)):
            agent = simulation.agents[index]
            colour = colours(n % 10)
            start = agent.robot.position
            if index not in report.alive:
                ax.scatter(
                    *start[[u, v]], marker="x", s=80, c=[colour], label=f"{report.names[index]} (failed)"
                )
                continue
            points = np.array([start] + [tasks[k].position for k in report.paths[index]])
            ax.plot(points[:, u], points[:, v], "-", c=colour, lw=1.5, zorder=2)
            ax.scatter(points[1:, u], points[1:, v], s=22, c=[colour], zorder=3)
            label = f"{report.names[index]}: {len(points) - 1} tasks, {report.lengths[index]:.1f} m"
            ax.scatter(*start[[u, v]], marker="^", s=110, c=[colour], edgecolors="k", label=label, zorder=4)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        ax.set_title("top view" if view == 0 else "side view")
    axes[0].legend(fontsize=8, loc="best")
    figure.suptitle(
        f"CBBA: {summary['messages']} messages, {summary['bytes']} bytes, converged in "
        f"{summary['sim_time_s']:.1f} s simulated; conflicts {summary['conflicts']}, "
        f"greedy ratio {summary['greedy_ratio']:.3f}",
        fontsize=10,
    )
    figure.tight_layout()
    return save_png(figure, path)
