"""PNG figures of discovery results, in the style of the paper's Fig. 3, 4 and 9."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # headless: never needs a display

import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from maptidal.discovery import DiscoveryResult
from maptidal.files import save_png

ARROW_LENGTH_M = 0.3


def _arrows(axes, rows: np.ndarray, colour: str, label: str) -> None:
    if len(rows) == 0:
        return
    axes.quiver(
        rows[:, 0],
        rows[:, 1],
        rows[:, 2],
        rows[:, 3],
        rows[:, 4],
        rows[:, 5],
        length=ARROW_LENGTH_M,
        color=colour,
        linewidth=1.4,
        label=label,
    )


def _equal_axes(axes, points: np.ndarray) -> None:
    low, high = points.min(axis=0), points.max(axis=0)
    centre, half = (low + high) / 2, max(float((high - low).max()) / 2, 0.5)
    axes.set_xlim(centre[0] - half, centre[0] + half)
    axes.set_ylim(centre[1] - half, centre[1] + half)
    axes.set_zlim(centre[2] - half, centre[2] + half)


def plot_discovery(
    result: DiscoveryResult,
    vertices: np.ndarray,
    faces: np.ndarray,
    path: str | os.PathLike,
    existing: np.ndarray | None = None,
    title: str = "Map-TIDAL task discovery",
) -> Path:
    """Draw the mesh, the CIPs and the tasks (arrows) in 3D and save a PNG.

    Two panels: left, the mesh with every CIP and the CIPs kept by the first
    pruning; right, the existing tasks (black), the confirmed tasks (green) and
    the remains kept by the final pruning (light green), as in the paper's Fig. 9.
    """
    existing = np.empty((0, 6)) if existing is None else np.asarray(existing).reshape(-1, 6)
    figure = plt.figure(figsize=(13, 6))
    counts = result.counts
    everything = np.vstack([vertices, result.cips[:, :3], existing[:, :3]])
    for panel in (1, 2):
        axes = figure.add_subplot(1, 2, panel, projection="3d")
        mesh = Poly3DCollection(
            vertices[faces], facecolor="0.75", edgecolor="0.55", linewidth=0.2, alpha=0.35
        )
        axes.add_collection3d(mesh)
        if panel == 1:
            axes.scatter(*result.cips[:, :3].T, s=4, c="tab:cyan", label=f"CIPs ({counts['cips']})")
            axes.scatter(
                *result.after_prune[:, :3].T,
                s=14,
                c="tab:blue",
                label=f"after pruning ({counts['after_prune']}, {result.pruning_mode})",
            )
            axes.set_title("Candidate inspection points (CIPs) and those kept by pruning")
        else:
            kept_remains = result.final[len(result.confirmed) :]
            _arrows(axes, existing, "black", f"existing tasks ({len(existing)})")
            _arrows(axes, result.confirmed, "tab:green", f"confirmed, S >= t ({counts['confirmed']})")
            _arrows(axes, kept_remains, "yellowgreen", f"kept by final pruning ({len(kept_remains)})")
            if len(result.remains):
                axes.scatter(*result.remains[:, :3].T, s=6, c="tab:red", alpha=0.5, label="scored below t")
            axes.set_title(f"Keypoint scores and final pruning: {counts['final']} new tasks")
        axes.set_xlabel("x (m)")
        axes.set_ylabel("y (m)")
        axes.zaxis.set_rotate_label(False)  # matplotlib otherwise turns it to read "(m) z"
        axes.set_zlabel("z (m)", rotation=90, labelpad=6)
        _equal_axes(axes, everything)
        axes.view_init(elev=18, azim=-150)
        axes.legend(loc="upper left", fontsize=8)
    figure.suptitle(title)
    figure.subplots_adjust(left=0.02, right=0.96, bottom=0.04, top=0.9, wspace=0.08)
    return save_png(figure, path)
