"""PNG figures of coverage results: the paper's Fig. 7 (voxels) and Fig. 8 (histogram),
and heatmaps of a parameter sweep (the layout of Table I)."""

from __future__ import annotations

import io
import os

import matplotlib

matplotlib.use("Agg")  # headless: never needs a display

import matplotlib.pyplot as plt
import numpy as np

from maptidal.coverage import CoverageReport
from maptidal.files import atomic_write_bytes

METHOD_COLOURS = {"maptidal": "tab:green", "voronoi": "tab:blue", "boustrophedon": "tab:orange"}


def _save(figure, path: str | os.PathLike) -> None:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    plt.close(figure)
    atomic_write_bytes(path, buffer.getvalue())


def plot_histograms(reports: dict[str, CoverageReport], path: str | os.PathLike, title: str = "") -> None:
    """Normalised views per voxel of each method beside the ideal gamma bins (Fig. 8)."""
    last_bin = max(len(r.histogram) for r in reports.values()) - 1
    last_shown = min(last_bin, max(12, max(int(np.ceil(r.mean_views * 2)) for r in reports.values())))
    bins = np.arange(last_shown + 1)
    width = 0.8 / max(len(reports), 1)
    figure, axes = plt.subplots(figsize=(8, 4.2))
    for k, (name, report) in enumerate(reports.items()):
        values = np.zeros(last_shown + 1)
        shown = min(len(report.histogram), last_shown + 1)
        values[:shown] = report.histogram[:shown]
        label = f"{name}: {report.n_viewpoints} tasks, MAD {report.mad:.3f}"
        axes.bar(bins - 0.4 + (k + 0.5) * width, values, width, label=label, color=METHOD_COLOURS.get(name))
    ideal = next(iter(reports.values())).ideal
    axes.plot(bins, ideal[: last_shown + 1], "k.-", label="ideal gamma (alpha 4, beta 2/3)")
    axes.set_xlabel("views per voxel")
    axes.set_ylabel("fraction of voxels")
    axes.set_xticks(bins[:: max(1, len(bins) // 16)])
    axes.set_title(title or "Views per voxel against the ideal distribution")
    axes.legend(fontsize=8)
    figure.tight_layout()
    _save(figure, path)


def plot_voxel_views(
    voxels: np.ndarray,
    views: np.ndarray,
    viewpoints: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
) -> None:
    """Voxels coloured by their view count, with the viewpoints as arrows (Fig. 7)."""
    figure = plt.figure(figsize=(8, 6))
    axes = figure.add_subplot(projection="3d")
    unseen = views == 0
    vmax = max(4, int(np.percentile(views, 99))) if len(views) else 4
    points = axes.scatter(
        *voxels[~unseen].T, c=views[~unseen], cmap="Reds", vmin=0, vmax=vmax, s=3, depthshade=False
    )
    if unseen.any():
        axes.scatter(*voxels[unseen].T, c="0.25", s=3, depthshade=False, label="never viewed")
    if len(viewpoints):
        axes.quiver(
            *viewpoints[:, :3].T, *viewpoints[:, 3:6].T, length=0.35, color="tab:blue", label="viewpoints"
        )
    figure.colorbar(points, ax=axes, shrink=0.6, label="views per voxel")
    everything = np.vstack([voxels, viewpoints[:, :3]]) if len(viewpoints) else voxels
    low, high = everything.min(axis=0), everything.max(axis=0)
    axes.set_box_aspect(np.maximum(high - low, 0.1))
    axes.view_init(elev=30, azim=200)  # from inside the tank, facing the end wall
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.set_zlabel("z (m)")
    axes.set_title(title)
    axes.legend(loc="upper left", fontsize=8)
    figure.tight_layout()
    _save(figure, path)


def plot_sweep_heatmaps(rows: list[dict], path: str | os.PathLike) -> None:
    """Heatmaps over threshold x r_ex, one column per theta_ex: uninspected, mean views, tasks."""
    thresholds = sorted({r["t"] for r in rows})
    radii = sorted({r["r_ex"] for r in rows})
    angles = sorted({r["theta_ex"] for r in rows})
    metrics = (
        ("pct_uninspected", "% uninspected", "Reds"),
        ("mean_views", "mean views", "Purples"),
        ("tasks", "tasks", "Greens"),
        ("mad", "MAD", "Oranges"),
    )
    figure, grid = plt.subplots(
        len(metrics), len(angles), figsize=(3.6 * len(angles) + 1, 2.6 * len(metrics)), squeeze=False
    )
    lookup = {(r["t"], r["r_ex"], r["theta_ex"]): r for r in rows}
    for j, angle in enumerate(angles):
        for i, (key, label, cmap) in enumerate(metrics):
            values = np.array([[lookup[(t, r, angle)][key] for r in radii] for t in thresholds], dtype=float)
            axes = grid[i, j]
            image = axes.imshow(values, cmap=cmap, aspect="auto")
            for a in range(len(thresholds)):
                for b in range(len(radii)):
                    text = f"{values[a, b]:.0f}" if key == "tasks" else f"{values[a, b]:.2f}"
                    if key == "mad":
                        text = f"{values[a, b]:.3f}"
                    axes.text(b, a, text, ha="center", va="center", fontsize=7)
            axes.set_xticks(range(len(radii)), [f"{r:g}" for r in radii])
            axes.set_yticks(range(len(thresholds)), [f"{t:g}" for t in thresholds])
            axes.set_xlabel("r_ex (m)")
            axes.set_ylabel("t")
            axes.set_title(f"{label}, theta_ex = {angle:g}", fontsize=9)
            figure.colorbar(image, ax=axes, shrink=0.8)
    figure.tight_layout()
    _save(figure, path)
