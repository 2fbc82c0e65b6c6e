"""The paper's Table I beside our sweep: its 24 cells, its colour classes, and rank correlations.

The values and printed colours live in ``assets/paper/table1.toml`` (transcribed from the paper, Sec.
IV.D). :func:`colour_class` is the paper's colour rule as its text states it; :func:`side_by_side`
puts our sweep rows next to the paper's cells, and :func:`rank_correlations` gives, for each column
(avg, num, %), the Spearman rank correlation of ours with the paper's across the 24 cells.
"""

from __future__ import annotations

import math
import tomllib
from functools import cache

import numpy as np
from scipy.stats import spearmanr

from maptidal.paths import asset

PAPER_GRID = {"t": (0.70, 0.75, 0.80), "r_ex": (1.5, 1.6, 1.7, 1.8), "theta_ex": (0.25, 0.30)}
COLUMNS = {"avg": "mean_views", "num": "tasks", "pct": "pct_uninspected"}  # paper name -> our row key


@cache
def paper_cells() -> tuple[dict, ...]:
    """The 24 cells of Table I (t, r_ex, theta_ex, avg, num, pct and the printed colours)."""
    document = tomllib.loads(asset("paper", "table1.toml").read_text())
    cells = []
    for cell in document["cells"]:
        for key in ("avg", "num", "pct"):
            cell.setdefault(f"{key}_colour", "none")
        cells.append(cell)
    return tuple(cells)


def colour_class(avg: float, num: int, pct: float) -> dict[str, str]:
    """The paper's colour rule (Sec. IV.D, as its text states it) for one cell's three values.

    Only cells under 5 % uninspected are coloured: their % is green; 15 to 25 tasks and an average under
    2.5 are green; otherwise under 30 tasks, or an average up to 3.5, is yellow; an average over 3.5 is
    red (and 30 tasks or more, red too)."""
    if not pct < 5.0:
        return {"avg": "none", "num": "none", "pct": "none"}
    avg_class = "green" if avg < 2.5 else ("yellow" if avg <= 3.5 else "red")
    num_class = "green" if 15 <= num <= 25 else ("yellow" if num < 30 else "red")
    return {"avg": avg_class, "num": num_class, "pct": "green"}


def _key(t: float, r_ex: float, theta_ex: float) -> tuple[float, float, float]:
    return round(t, 4), round(r_ex, 4), round(theta_ex, 4)


def side_by_side(rows: list[dict]) -> list[dict]:
    """Our sweep rows (:func:`maptidal.evaluation.comparison.run_sweep`) beside the paper's cells, in the
    paper's order; raises ValueError if a cell of the paper's grid is missing."""
    ours = {_key(r["t"], r["r_ex"], r["theta_ex"]): r for r in rows}
    cells = []
    for cell in paper_cells():
        key = _key(cell["t"], cell["r_ex"], cell["theta_ex"])
        if key not in ours:
            raise ValueError(f"the sweep lacks the paper's cell t={key[0]}, r_ex={key[1]}, theta_ex={key[2]}")
        row = ours[key]
        mine = {"avg": row["mean_views"], "num": row["tasks"], "pct": row["pct_uninspected"]}
        cells.append(
            {
                "t": cell["t"],
                "r_ex": cell["r_ex"],
                "theta_ex": cell["theta_ex"],
                "ours": {**mine, "classes": colour_class(mine["avg"], mine["num"], mine["pct"])},
                "paper": {
                    "avg": cell["avg"],
                    "num": cell["num"],
                    "pct": cell["pct"],
                    "classes": {k: cell[f"{k}_colour"] for k in ("avg", "num", "pct")},
                },
            }
        )
    return cells


def rank_correlations(cells: list[dict]) -> dict[str, float | None]:
    """Spearman's rank correlation of ours with the paper's, per column (None when ours is constant)."""
    out: dict[str, float | None] = {}
    for column in ("avg", "num", "pct"):
        mine = np.array([c["ours"][column] for c in cells], float)
        theirs = np.array([c["paper"][column] for c in cells], float)
        if np.ptp(mine) == 0 or np.ptp(theirs) == 0:
            out[column] = None
            continue
        rho = float(spearmanr(mine, theirs).statistic)
        out[column] = None if math.isnan(rho) else rho
    return out


def trends(cells: list[dict], which: str = "ours") -> dict[str, bool]:
    """The paper's stated trends (Sec. IV.D: lower r_ex and theta_ex give more tasks, better coverage and
    a higher average), each as: the Spearman correlation with the parameter has the stated sign."""
    names = {"num": "more_tasks", "pct": "better_coverage", "avg": "higher_average"}
    out = {}
    for parameter in ("r_ex", "theta_ex"):
        values = np.array([c[parameter] for c in cells])
        # lower parameter -> more tasks, fewer uninspected, higher average: negative, positive, negative
        for column, sign in (("num", -1), ("pct", 1), ("avg", -1)):
            data = np.array([c[which][column] for c in cells], float)
            rho = float(spearmanr(values, data).statistic) if np.ptp(data) > 0 else 0.0
            out[f"lower_{parameter}_{names[column]}"] = bool(sign * rho > 0)
    return out


def table_markdown(cells: list[dict], correlations: dict) -> str:
    """Ours beside the paper's, one line per cell, each value marked with its colour class."""
    mark = {"green": "🟢", "yellow": "🟡", "red": "🔴", "none": ""}
    lines = [
        "# Table I side by side: ours / the paper's",
        "",
        "Each value is marked with the paper's colour class (green, yellow, red; unmarked: uncoloured).",
        "",
        "| t | r_ex (m) | theta_ex (rad) | avg | num | % uninspected |",
        "|---|---|---|---|---|---|",
    ]
    for c in cells:
        o, p = c["ours"], c["paper"]
        values = [
            f"{o['avg']:.2f}{mark[o['classes']['avg']]} / {p['avg']:.2f}{mark[p['classes']['avg']]}",
            f"{o['num']}{mark[o['classes']['num']]} / {p['num']}{mark[p['classes']['num']]}",
            f"{o['pct']:.2f}{mark[o['classes']['pct']]} / {p['pct']:.2f}{mark[p['classes']['pct']]}",
        ]
        lines.append(f"| {c['t']:.0%} | {c['r_ex']:g} | {c['theta_ex']:g} | " + " | ".join(values) + " |")
    rho = ", ".join(f"{k} {'n/a' if v is None else f'{v:+.2f}'}" for k, v in correlations.items())
    lines += ["", f"Spearman rank correlation of ours with the paper's, per column: {rho}.", ""]
    return "\n".join(lines)
