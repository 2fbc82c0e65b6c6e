"""Two batches of missions side by side, seed by seed (``maptidal compare-batches``): does a change make a
difference, or is it the seeds?

A mission is chaotic: a change anywhere (a rule, a threshold, the order of two events) sends every seed's
mission down another course, so one seed's finish time moves by a minute or two either way, and a mean
over ten seeds moves by some 15 s (the seeds' spread over the square root of their number) with no
change for the better or the worse. Two batches of the same seeds are therefore compared in pairs: for
each metric, each planner and each seed both batches flew, the difference ``after - before``; then the
mean difference and its 95 % confidence interval from Student's t with ``n - 1`` degrees of freedom
(``mean +- t(0.975, n - 1) * s / sqrt(n)``, ``s`` the differences' sample standard deviation). An
interval that holds 0 says the two batches do not differ on that metric at these seeds, whatever the
means say. The pairing takes out what a seed fixes for both batches (where the tank's features fall
under the cameras' first sweep); it cannot take out the chaos, which only more seeds do.

The batches are read from their folders: ``batch.json`` (the rows as the batch wrote them) or, for a batch
that was stopped before it ended, ``batch.csv``. Pure numpy and scipy: no simulator.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats

from maptidal.files import atomic_write_json, atomic_write_text, save_png

__all__ = [
    "COMPARED",
    "PairedDifference",
    "between_planners",
    "compare_batches",
    "comparison_markdown",
    "difference_table",
    "paired_difference",
    "planners_pairs_markdown",
    "plot_comparison",
    "read_batch",
    "write_comparison",
]

# the metrics compared, in table order, with their short names for the table and the plot
COMPARED = {
    "completion_time_s": "finish time (s)",
    "pct_uninspected": "walls uninspected (%)",
    "tasks_found": "tasks found",
    "tasks_done": "tasks done",
    "time_to_95_s": "time to 95 % inspected (s)",
    "path_m": "team's path (m)",
    "thruster_energy_kj": "thruster energy (kJ)",
    "contact_s": "contact (robot-s)",
    "surveying_s": "surveying (robot-s)",
    "fruitless_survey_s": "surveys finding no task (robot-s)",
    "lost_s": "lost (robot-s)",
    "bytes": "bytes sent",
}
# the plot's panels: what a reader asks first of a change
PLOTTED = ("completion_time_s", "pct_uninspected", "tasks_found", "contact_s")
CONFIDENCE = 0.95


@dataclass(frozen=True)
class PairedDifference:
    """One metric of one planner in two batches, over the seeds both flew (and both have the metric for):
    the values ``before`` and ``after`` seed by seed, and the confidence interval (``low``, ``high``; None
    with fewer than two seeds) of their mean difference ``after - before``."""

    metric: str
    planner: str
    seeds: tuple[int, ...]
    before: tuple[float, ...]
    after: tuple[float, ...]
    low: float | None
    high: float | None

    @property
    def mean_before(self) -> float:
        """The first batch's mean over the paired seeds."""
        return float(np.mean(self.before))

    @property
    def mean_after(self) -> float:
        """The second batch's mean over the paired seeds."""
        return float(np.mean(self.after))

    @property
    def mean_difference(self) -> float:
        """The mean of the seeds' differences ``after - before``."""
        return float(np.mean(np.subtract(self.after, self.before)))

    @property
    def interval(self) -> str:
        """The interval as the tables and plots print it, `` [low, high]``, or nothing without one."""
        return "" if self.low is None else f" [{_figure(self.low)}, {_figure(self.high)}]"

    @property
    def lower_in(self) -> int:
        """How many seeds the later batch has lower."""
        return sum(a < b for a, b in zip(self.after, self.before, strict=True))

    @property
    def higher_in(self) -> int:
        """How many seeds the later batch has higher."""
        return sum(a > b for a, b in zip(self.after, self.before, strict=True))

    @property
    def within_noise(self) -> bool | None:
        """Whether the interval holds 0 (None without an interval)."""
        if self.low is None or self.high is None:
            return None
        return self.low <= 0.0 <= self.high

    def as_dict(self) -> dict:
        """The figures as plain numbers (``compare.json``)."""
        return {
            "metric": self.metric,
            "planner": self.planner,
            "seeds": list(self.seeds),
            "before": list(self.before),
            "after": list(self.after),
            "mean_before": self.mean_before,
            "mean_after": self.mean_after,
            "mean_difference": self.mean_difference,
            "ci_low": self.low,
            "ci_high": self.high,
            "confidence": CONFIDENCE,
            "lower_in": self.lower_in,
            "higher_in": self.higher_in,
            "within_noise": self.within_noise,
        }


def _number(text: str) -> float | None:
    """A CSV cell as a number (None for an empty cell or a word)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return value


def read_batch(folder: str | Path) -> list[dict]:
    """The rows of the batch in ``folder``: ``batch.json``'s, or ``batch.csv``'s with its numbers parsed.
    A row without a planner (a batch of one planner before planners were recorded) counts as
    ``maptidal``. Raises ValueError, in one line, for a folder with neither file, with no row, or with a
    planner's seed twice."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such batch folder")
    json_path, csv_path = folder / "batch.json", folder / "batch.csv"
    if json_path.is_file():
        try:
            rows = json.loads(json_path.read_text())["rows"]
        except (json.JSONDecodeError, KeyError, TypeError) as err:
            raise ValueError(f"{json_path}: not a batch's batch.json ({err})") from None
    elif csv_path.is_file():
        with csv_path.open(newline="") as handle:
            rows = [
                {
                    key: (value if key in ("planner", "folder", "finished") else _number(value))
                    for key, value in row.items()
                }
                for row in csv.DictReader(handle)
            ]
    else:
        raise ValueError(f"{folder}: neither batch.json nor batch.csv (is it a `maptidal batch` folder?)")
    if not isinstance(rows, list) or not rows:
        raise ValueError(f"{folder}: the batch has no mission in it")
    seen = set()
    for row in rows:
        if not isinstance(row, dict) or _number(row.get("seed")) is None:
            raise ValueError(f"{folder}: a row without a seed")
        row["seed"] = int(_number(row["seed"]))
        row["planner"] = row.get("planner") or "maptidal"
        if (row["planner"], row["seed"]) in seen:  # two missions of one seed: which to pair is unknown
            raise ValueError(f"{folder}: seed {row['seed']} of {row['planner']} is there twice")
        seen.add((row["planner"], row["seed"]))
    return rows


def _values(rows: list[dict], metric: str, planner: str) -> dict[int, float]:
    """Seed -> the metric's finite value, for the planner's rows."""
    values = {}
    for row in rows:
        if row["planner"] != planner:
            continue
        value = _number(row.get(metric))
        if value is not None and math.isfinite(value):
            values[row["seed"]] = value
    return values


def paired_difference(
    before_rows: list[dict],
    after_rows: list[dict],
    metric: str,
    planner: str,
    after_planner: str | None = None,
) -> PairedDifference | None:
    """``metric`` of ``planner`` paired by seed across two batches' rows (module docstring), or None when
    no seed has it in both. With ``after_planner``, the second rows' planner is that one (two planners of
    one batch, :func:`between_planners`), and the difference is labelled ``after_planner - planner``."""
    second = planner if after_planner is None else after_planner
    before, after = _values(before_rows, metric, planner), _values(after_rows, metric, second)
    seeds = tuple(sorted(set(before) & set(after)))
    if not seeds:
        return None
    b = np.array([before[s] for s in seeds])
    a = np.array([after[s] for s in seeds])
    differences = a - b
    mean = float(differences.mean())
    low = high = None
    if len(seeds) >= 2:
        half = float(
            stats.t.ppf(0.5 + CONFIDENCE / 2, len(seeds) - 1)
            * differences.std(ddof=1)
            / math.sqrt(len(seeds))
        )
        low, high = mean - half, mean + half
    label = planner if after_planner is None else f"{after_planner} - {planner}"
    return PairedDifference(metric, label, seeds, tuple(b.tolist()), tuple(a.tolist()), low, high)


def compare_batches(before_rows: list[dict], after_rows: list[dict]) -> list[PairedDifference]:
    """Every compared metric (``COMPARED``) of every planner both batches flew, paired by seed. Raises
    ValueError when nothing pairs (no planner and seed in common)."""
    found = [
        paired_difference(before_rows, after_rows, metric, planner)
        for planner in dict.fromkeys(row["planner"] for row in before_rows)
        for metric in COMPARED
    ]
    found = [difference for difference in found if difference is not None]
    if not found:
        raise ValueError("the two batches have no planner and seed in common: nothing to pair")
    return found


def _figure(value: float | None) -> str:
    """A number for the table: three significant figures, or a dash."""
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"


def difference_table(differences: list[PairedDifference], before_name: str, after_name: str) -> list[str]:
    """Markdown table lines: each metric's means, the mean difference with its interval, on how many seeds
    ``after_name`` is lower and higher, and whether the interval holds 0."""
    lines = [
        f"| metric | {before_name} | {after_name} | difference [{CONFIDENCE:.0%} CI] "
        "| lower / higher on | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for d in differences:
        if d.within_noise is None:
            verdict = "too few seeds"
        elif d.within_noise:
            verdict = "within the seeds' noise"
        else:
            verdict = "lower" if d.high < 0 else "higher"
        lines.append(
            f"| {COMPARED[d.metric]} | {_figure(d.mean_before)} | {_figure(d.mean_after)} | "
            f"{_figure(d.mean_difference)}{d.interval} | "
            f"{d.lower_in} / {d.higher_in} of {len(d.seeds)} | {verdict} |"
        )
    return lines


def _explained(before_name: str, after_name: str) -> str:
    return (
        f"Paired by seed; the difference is {after_name} minus {before_name}, with its {CONFIDENCE:.0%} "
        "confidence interval from Student's t on the seeds' differences. *Within the seeds' noise*: the "
        "interval holds 0, and the two do not differ on that metric at these seeds."
    )


def comparison_markdown(differences: list[PairedDifference], before_name: str, after_name: str) -> str:
    """The comparison of two batches as markdown: a table per planner (:func:`difference_table`)."""
    lines = [f"# {after_name} against {before_name}", "", _explained(before_name, after_name)]
    for planner in dict.fromkeys(d.planner for d in differences):
        mine = [d for d in differences if d.planner == planner]
        seeds = max(len(d.seeds) for d in mine)
        lines += ["", f"## {planner} ({seeds} seeds)", "", *difference_table(mine, before_name, after_name)]
    return "\n".join(lines) + "\n"


def between_planners(rows: list[dict], first: str, second: str) -> list[PairedDifference]:
    """Planner ``second`` against planner ``first`` in one batch's rows, paired by seed (each planner
    flew the same seeds), every compared metric: the differences are ``second - first``."""
    found = [paired_difference(rows, rows, metric, first, second) for metric in COMPARED]
    return [difference for difference in found if difference is not None]


def planners_pairs_markdown(rows: list[dict], reference: str | None = None) -> list[str]:
    """Markdown lines for ``batch.md`` with several planners: every other planner against ``reference``
    (by default Map-TIDAL where it flew, else the first planner), paired by seed
    (:func:`between_planners`); none with a single planner or without the reference."""
    planners = list(dict.fromkeys(row["planner"] for row in rows))
    if reference is None:
        reference = "maptidal" if "maptidal" in planners else planners[0] if planners else ""
    if reference not in planners or len(planners) < 2:
        return []
    lines = [f"## Each planner against {reference}, seed by seed", "", _explained(reference, "the planner")]
    for other in planners:
        if other == reference:
            continue
        differences = between_planners(rows, reference, other)
        if differences:
            lines += ["", f"### {other}", "", *difference_table(differences, reference, other)]
    return [*lines, ""]


def plot_comparison(
    differences: list[PairedDifference], before_name: str, after_name: str, path: Path
) -> None:
    """A panel per plotted metric (``PLOTTED``) and planner: each seed a line from its value in the first
    batch to its value in the second, the means in black, the mean difference and its interval in the
    title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    planners = list(dict.fromkeys(d.planner for d in differences))
    shown = {(d.planner, d.metric): d for d in differences if d.metric in PLOTTED}
    metrics = [m for m in PLOTTED if any((p, m) in shown for p in planners)]
    if not metrics:
        metrics = list(PLOTTED)
    figure, axes = plt.subplots(
        len(planners), len(metrics), figsize=(3.2 * len(metrics), 3.0 * len(planners)), squeeze=False
    )
    for row, planner in enumerate(planners):
        for column, metric in enumerate(metrics):
            axis = axes[row][column]
            d = shown.get((planner, metric))
            if d is None:
                axis.text(0.5, 0.5, "no seed has it", ha="center", va="center", transform=axis.transAxes)
                axis.set_xticks([])
                axis.set_yticks([])
                continue
            for b, a in zip(d.before, d.after, strict=True):
                colour = "tab:green" if a < b else "tab:red" if a > b else "grey"
                axis.plot([0, 1], [b, a], "-o", color=colour, alpha=0.5, ms=3, lw=1)
            axis.plot([0, 1], [d.mean_before, d.mean_after], "-s", color="black", lw=2, ms=5)
            axis.set_title(
                f"{COMPARED[metric]}\n{planner}: {_figure(d.mean_difference)}{d.interval}", fontsize=8
            )
            axis.set_xticks([0, 1], [before_name, after_name], fontsize=8)
            axis.set_xlim(-0.3, 1.3)
            axis.tick_params(labelsize=8)
    figure.suptitle(
        f"{after_name} against {before_name}, seed by seed (green: lower, red: higher; black: the means; "
        f"title: mean difference [{CONFIDENCE:.0%} CI])",
        fontsize=9,
    )
    figure.tight_layout()
    save_png(figure, path)


def write_comparison(
    before: str | Path, after: str | Path, out_dir: str | Path
) -> tuple[list[PairedDifference], str]:
    """Compare the batches in folders ``before`` and ``after`` and write ``compare.md``, ``compare.json``
    and ``compare.png`` to ``out_dir``; returns the differences and the markdown."""
    before, after = Path(before), Path(after)
    before_rows, after_rows = read_batch(before), read_batch(after)
    differences = compare_batches(before_rows, after_rows)
    before_name, after_name = before.resolve().name, after.resolve().name
    if before_name == after_name:
        before_name, after_name = f"{before_name} (1)", f"{after_name} (2)"
    markdown = comparison_markdown(differences, before_name, after_name)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "compare.md", markdown)
    atomic_write_json(
        out / "compare.json",
        {"before": str(before), "after": str(after), "differences": [d.as_dict() for d in differences]},
    )
    plot_comparison(differences, before_name, after_name, out / "compare.png")
    return differences, markdown
