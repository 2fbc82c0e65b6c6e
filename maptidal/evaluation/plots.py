"""PNG figures of coverage results: the paper's Fig. 7 (voxels) and Fig. 8 (histogram),
and heatmaps of a parameter sweep (the layout of Table I)."""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")  # headless: never needs a display

import matplotlib.pyplot as plt
import numpy as np

from maptidal.evaluation.coverage import CoverageReport
from maptidal.files import save_png
from maptidal.tank import TankModel

METHOD_COLOURS = {
    "maptidal": "tab:green",
    "voronoi": "tab:blue",
    "voronoi_generator": "tab:cyan",
    "boustrophedon": "tab:orange",
}


def _save(figure, path: str | os.PathLike) -> None:
    save_png(figure, path)


def finish_coverage_time(figure, axis, path: str | os.PathLike, legend_size: int = 8) -> None:
    """Finish and save a plot of the walls' inspected share (%) against simulated time: the 95 % mark,
    the labels, 0 to 100 %, the legend."""
    axis.axhline(95.0, color="0.5", ls="--", lw=0.8, label="95 %")
    axis.set_xlabel("simulated time (s)")
    axis.set_ylabel("inspected (%, occlusion on)")
    axis.set_ylim(0, 100)
    axis.legend(fontsize=legend_size, loc="lower right")
    figure.tight_layout()
    save_png(figure, path)


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


# The colour scale of views per voxel stops here (darkest: this many views or more). The paper's ideal
# distribution peaks at 2 views and has almost no mass past 10 (Sec. IV.C), so up to 10 is what matters,
# and one fixed scale lets maps of different methods compare by eye.
VIEWS_COLOUR_TOP = 10
# How far into the water in front of the evaluated walls the voxel maps reach (m): viewpoints stand 1 m off.
OPEN_WATER_SHOWN_M = 1.5


def tank_bounds(tank: TankModel) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (3,) of the water around the evaluated walls, floor to surface, with
    :data:`OPEN_WATER_SHOWN_M` of open water in front of them."""
    ends = [np.r_[seg.start, 0.0] for seg in tank.segments] + [np.r_[tank.segments[-1].end, 0.0]]
    corners = np.vstack(ends)
    low, high = corners.min(axis=0), corners.max(axis=0)
    low[0] -= OPEN_WATER_SHOWN_M
    high[2] = tank.height
    return low, high


def plot_voxel_views(
    voxels: np.ndarray,
    views: np.ndarray,
    viewpoints: np.ndarray,
    path: str | os.PathLike,
    title: str = "",
    tank: TankModel | None = None,
    vmax: int | None = None,
) -> None:
    """Voxels coloured by their view count, with the viewpoints as arrows (Fig. 7).

    ``vmax`` is the top of the colour scale (default :data:`VIEWS_COLOUR_TOP`, the same for every map).
    With ``tank`` the axes are the water around the evaluated walls (:func:`tank_bounds`), and
    viewpoints outside it (behind a wall, under the floor, above the surface) are counted in the legend
    but not drawn.
    """
    figure = plt.figure(figsize=(8.5, 6.2))
    axes = figure.add_subplot(projection="3d")
    unseen = views == 0
    vmax = vmax if vmax is not None else VIEWS_COLOUR_TOP
    points = axes.scatter(
        *voxels[~unseen].T, c=views[~unseen], cmap="Reds", vmin=0, vmax=vmax, s=3, depthshade=False
    )
    if unseen.any():
        axes.scatter(*voxels[unseen].T, c="0.25", s=3, depthshade=False, label="never viewed")
    if tank is not None:
        low, high = tank_bounds(tank)
        margin = 0.05
    else:
        everything = np.vstack([voxels, viewpoints[:, :3]]) if len(viewpoints) else voxels
        low, high, margin = everything.min(axis=0), everything.max(axis=0), 0.0
    inside = np.all((viewpoints[:, :3] >= low - margin) & (viewpoints[:, :3] <= high + margin), axis=1)
    if inside.any():
        label = f"viewpoints ({int(inside.sum())})"
        if not inside.all():
            label += f"; {int((~inside).sum())} outside the water not drawn"
        shown = viewpoints[inside]
        axes.quiver(*shown[:, :3].T, *shown[:, 3:6].T, length=0.35, color="tab:blue", label=label)
    label = f"views per voxel (darkest: {vmax} or more)"
    figure.colorbar(points, ax=axes, shrink=0.6, pad=0.1, extend="max", label=label)
    for set_limits, k in ((axes.set_xlim, 0), (axes.set_ylim, 1), (axes.set_zlim, 2)):
        set_limits(low[k] - margin, high[k] + margin)
    axes.set_box_aspect(np.maximum(high - low, 0.1))
    axes.view_init(elev=30, azim=200)  # from inside the tank, facing the end wall
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    axes.zaxis.set_rotate_label(False)  # matplotlib otherwise turns it to read "(m) z"
    axes.set_zlabel("z (m)", rotation=90, labelpad=6)
    axes.set_title(title)
    axes.legend(loc="upper left", fontsize=8)
    figure.subplots_adjust(left=0.06, right=0.92, bottom=0.02, top=0.95)
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
            low, high = float(values.min()), float(values.max())
            flat = high - low < 1e-12
            if flat:  # one value everywhere (say 0 % uninspected): a scale from 0 that shows where it sits
                low, high = min(0.0, low), max(0.0, high) + 0.1 * max(1.0, abs(high))
            image = axes.imshow(values, cmap=cmap, aspect="auto", vmin=low, vmax=high)
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
            axes.set_title(f"{label}, theta_ex = {angle:g}" + (" (all equal)" if flat else ""), fontsize=9)
            figure.colorbar(image, ax=axes, shrink=0.8)
    figure.tight_layout()
    _save(figure, path)


def plot_noise_curve(rows: list[dict], path: str | os.PathLike, title: str = "") -> None:
    """Task count and the share of keyframe faces within theta_ex of a surface normal against the
    stereo disparity noise, with and without landmark refinement (two panels)."""
    figure, (tasks_axes, faces_axes) = plt.subplots(1, 2, figsize=(9, 3.8))
    for refined, style in ((False, "o-"), (True, "s--")):
        chosen = [r for r in rows if r["refined"] == refined]
        levels = [r["disparity_sigma_px"] for r in chosen]
        label = "refined over tracked frames" if refined else "one triangulation per keyframe"
        tasks_axes.plot(levels, [r["tasks"] for r in chosen], style, label=label)
        faces_axes.plot(levels, [100 * r["faces_within_theta_ex"] for r in chosen], style, label=label)
    tasks_axes.set_xlabel("disparity noise sigma_d (px)")
    tasks_axes.set_ylabel("Map-TIDAL tasks")
    faces_axes.set_xlabel("disparity noise sigma_d (px)")
    faces_axes.set_ylabel("faces within theta_ex of a surface normal (%)")
    tasks_axes.legend(fontsize=8)
    tasks_axes.grid(alpha=0.3)
    faces_axes.grid(alpha=0.3)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    _save(figure, path)
