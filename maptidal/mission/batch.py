"""Monte-Carlo missions (``maptidal batch``): one mission per seed, locally or on a Ray cluster
(:mod:`maptidal.executors`), and their metrics aggregated into a table and plots.

Each run writes its own mission folder, ``seed_NNN/``, under the batch folder (on a cluster that needs a
shared file system; the metrics come back to the driver in any case). The driver writes, as each run
lands:

- ``batch.csv``: a row of metrics per seed, rewritten atomically;
- at the end, ``batch.json`` (the rows with each mission's coverage timeline, and the mean, standard
  deviation, minimum and maximum of every metric), ``batch.md`` (the same as a table), ``batch.png`` (a
  panel per metric, every seed a dot) and ``coverage_time.png`` (the walls' inspected share against
  time: the mean over seeds and a band of one standard deviation, each mission held at its last value
  after it ends), and ``time_use.png`` with ``batch.md``'s table of where each robot's time went (the
  mean seconds of each occupation, per planner and robot); ``batch.md`` ends with why each robot
  stopped exploring (the missions per reason, :func:`exploring_ends`).

With several planners (``--planners maptidal,voronoi,boustrophedon`` or ``all``) every planner flies
every seed, each in ``PLANNER/seed_NNN/``; the rows carry the planner, ``batch.json``'s summary is one
aggregate per planner, ``batch.md`` tabulates their means side by side, then each planner against
Map-TIDAL seed by seed (:mod:`maptidal.mission.batch_compare`), and ``batch.png`` draws each planner's
seeds in its own colour.

A mission is a function of its scenario, its settings and its seed alone, so the metrics do not depend on
the executor, except the wall-clock ones (``realtime_factor``, ``wall_time_s``), which are reported but
left out of every comparison.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from maptidal.executors import run_jobs
from maptidal.files import atomic_write_json, atomic_write_text, save_png
from maptidal.mission.batch_compare import planners_pairs_markdown
from maptidal.mission.outputs import mission_metrics
from maptidal.mission.time_use import OCCUPATION_COLOURS, OCCUPATIONS, occupation_table
from maptidal.progress import ProgressBar

# the per-mission metrics, in table order, with their units (``batch.md``, ``batch.png``)
METRICS = {
    "tasks_found": "tasks",
    "tasks_done": "tasks",
    "tasks_verified": "tasks",
    "tasks_retired": "tasks",
    "pct_uninspected": "% of walls, occlusion on",
    "mean_views": "views per voxel",
    "mad": "MAD",
    "completion_time_s": "s (the time limit if unfinished)",
    "time_to_95_s": "s to 95 % of the walls inspected (seeds that reached it)",
    "path_m": "m travelled, the team's",
    "thruster_energy_kj": "kJ drawn by the team's thrusters (T200 power law)",
    "contact_s": "robot-seconds touching the tank or a teammate",
    "surveying_s": "robot-seconds surveying the map's frontier",
    "fruitless_survey_s": "robot-seconds on surveys whose frames found no task",
    "lost_s": "robot-seconds lost (no visual fix, or too unsure)",
    "messages": "messages",
    "bytes": "bytes",
    "lost": "messages lost",
    "tasks_lost": "tasks that died with a failed robot",
}
WALL_CLOCK = ("realtime_factor", "wall_time_s")
# batch.png's panels and their titles
PANELS = {
    "pct_uninspected": "walls uninspected (%, occlusion on)",
    "tasks_found": "tasks found",
    "tasks_done": "tasks done",
    "completion_time_s": "finish time, or the cap (s)",
    "time_to_95_s": "time to 95 % inspected (s)",
    "path_m": "team's path (m)",
    "thruster_energy_kj": "team's thruster energy (kJ)",
    "bytes": "bytes sent",
    "mad": "MAD of views per voxel",
}  # depend on the machine, not on the seed


@dataclass(frozen=True)
class BatchRun:
    """One mission of a batch: the mission file (None: the default), its seed, its output folder, and the
    command line's overrides (:func:`maptidal.mission.config.prepare_mission`)."""

    scenario: str | None
    seed: int
    out_dir: str
    robots: int | None = None
    duration_s: float | None = None
    pose_source: str | None = None
    planner: str | None = None
    discovery: str | None = None
    plots: bool = True
    explore: bool | None = None


def parse_planners(text: str) -> list[str]:
    """Planners from ``"all"`` or a comma list of ``maptidal``, ``voronoi`` and ``boustrophedon``;
    ValueError naming the unknown one otherwise."""
    from maptidal.mission.params import PLANNERS

    if text.strip() == "all":
        return list(PLANNERS)
    names = [part.strip() for part in text.split(",")]
    unknown = [name for name in names if name not in PLANNERS]
    if unknown:
        bad = unknown[0] if unknown else ""
        raise ValueError(f"unknown planner {bad!r} in {text!r}: give all or a comma list of {PLANNERS}")
    if len(set(names)) != len(names):
        raise ValueError(f"planners {text!r} repeat a planner")
    return names


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"1-50"``, ``"3"`` or ``"1,4,9-12"``; ValueError with the bad part otherwise."""
    seeds: list[int] = []
    for part in text.split(","):
        match = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part)
        if match is None or (match[2] is not None and int(match[2]) < int(match[1])):
            raise ValueError(f"bad seeds {part.strip()!r} in {text!r}: give N, N-M or a comma list")
        first = int(match[1])
        seeds.extend(range(first, int(match[2] or first) + 1))
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds {text!r} repeat a seed")
    return seeds


def run_one(run: BatchRun) -> dict:
    """Fly one mission of a batch (in whichever process the executor chose); returns its metrics row."""
    from maptidal.mission.config import prepare_mission
    from maptidal.mission.run import Mission

    scenario, params = prepare_mission(
        run.scenario,
        run.robots,
        run.duration_s,
        run.pose_source,
        run.seed,
        planner=run.planner,
        discovery=run.discovery,
        explore=run.explore,
    )
    if not run.plots:
        params = dataclasses.replace(params, plots=False)
    document = Mission(scenario, params, run.out_dir).run()
    folder = Path(run.out_dir)
    name = folder.name if run.planner is None else f"{folder.parent.name}/{folder.name}"
    return {
        "seed": run.seed,
        "planner": params.planner,
        "folder": name,
        **mission_metrics(document),
        "coverage_timeline": document.get("coverage_timeline", [[0.0, 0.0]]),
        # where each robot's time went, seconds per occupation (maptidal.mission.time_use)
        "time_use": {name: use["seconds"] for name, use in document.get("time_use", {}).items()},
        # why each robot stopped exploring (mission.json's explored; None: it had not)
        "explored": {
            name: None if info is None else info.get("why") or "explored"
            for name, info in (document.get("explored") or {}).items()
        },
    }


def aggregate(rows: list[dict]) -> dict:
    """Mean, standard deviation (population), minimum and maximum of every metric over the rows."""
    summary = {}
    for name in (*METRICS, *WALL_CLOCK):
        values = np.array([row[name] for row in rows if row.get(name) is not None], float)
        values = values[np.isfinite(values)]
        if len(values) == 0:
            summary[name] = {"mean": None, "std": None, "min": None, "max": None, "count": 0}
            continue
        summary[name] = {
            "mean": float(values.mean()),
            "std": float(values.std()),
            "min": float(values.min()),
            "max": float(values.max()),
            "count": len(values),  # the rows that have it (time_to_95_s: the seeds that reached 95 %)
        }
    summary["finished"] = {"count": sum(1 for row in rows if row["finished"]), "of": len(rows)}
    return summary


def time_use_means(rows: list[dict]) -> dict[str, dict[str, dict[str, float]]]:
    """Per planner and robot, the mean seconds of each occupation over the rows that carry a time use (an
    occupation a mission never had counts as 0 s in it)."""
    means: dict[str, dict[str, dict[str, float]]] = {}
    for planner in dict.fromkeys(row.get("planner") for row in rows):
        flown = [row["time_use"] for row in rows if row.get("planner") == planner and row.get("time_use")]
        robots = list(dict.fromkeys(name for use in flown for name in use))
        means[str(planner)] = {
            robot: {
                kind: float(np.mean([use.get(robot, {}).get(kind, 0.0) for use in flown]))
                for kind in OCCUPATIONS
                if any(kind in use.get(robot, {}) for use in flown)
            }
            for robot in robots
        }
    return means


def time_use_markdown(means: dict[str, dict[str, dict[str, float]]]) -> list[str]:
    """``batch.md``'s table of where each robot's time went: mean seconds per occupation, a row per
    planner and robot; none without a time use."""
    rows = [
        (f"{planner}, {robot}", use) for planner, robots in means.items() for robot, use in robots.items()
    ]
    if not rows:
        return []
    return [
        "## Where each robot's time went",
        "",
        "Mean simulated seconds per occupation over the seeds (maptidal/mission/time_use.py).",
        "",
        *occupation_table("planner, robot", rows),
        "",
        "![where each robot's time went](time_use.png)",
        "",
    ]


def exploring_ends(rows: list[dict]) -> dict[str, dict[str, dict[str, int]]]:
    """Per planner and robot, how many missions ended its exploring for each reason (the rows'
    ``explored``, from ``mission.json``: :class:`maptidal.exploration.Exploration`'s ``why``), and how
    many it never ended ("not explored")."""
    ends: dict[str, dict[str, dict[str, int]]] = {}
    for row in rows:
        for robot, why in (row.get("explored") or {}).items():
            counts = ends.setdefault(str(row.get("planner")), {}).setdefault(robot, {})
            reason = why or "not explored"
            counts[reason] = counts.get(reason, 0) + 1
    return ends


def exploring_ends_markdown(ends: dict[str, dict[str, dict[str, int]]]) -> list[str]:
    """``batch.md``'s table of why each robot stopped exploring, a row per planner and robot, the reasons
    most frequent first; none without any."""
    rows = [
        f"| {planner}, {robot} | "
        + ", ".join(f"{why} {n}" for why, n in sorted(counts.items(), key=lambda item: (-item[1], item[0])))
        + " |"
        for planner, robots in ends.items()
        for robot, counts in robots.items()
    ]
    if not rows:
        return []
    return [
        "## Why the robots stopped exploring",
        "",
        "Missions per reason: what each robot's last search for a look ran out of first (the `explored` "
        "event; maptidal/exploration.py).",
        "",
        "| planner, robot | reasons (missions) |",
        "|---|---|",
        *rows,
        "",
    ]


def plot_time_use(means: dict[str, dict[str, dict[str, float]]], path: Path) -> None:
    """Where each robot's time went: a bar per planner and robot, its mean seconds stacked by occupation."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = [
        (f"{planner}, {robot}", use) for planner, robots in means.items() for robot, use in robots.items()
    ]
    figure, axis = plt.subplots(figsize=(8, 1.2 + 0.45 * max(len(pairs), 1)))
    lefts = np.zeros(len(pairs))  # each bar's end so far
    for kind in OCCUPATIONS:
        widths = np.array([use.get(kind, 0.0) for _, use in pairs])
        if widths.any():
            axis.barh(range(len(pairs)), widths, left=lefts, color=OCCUPATION_COLOURS[kind], label=kind)
            lefts += widths
    axis.set_yticks(range(len(pairs)), [label for label, _ in pairs])
    axis.invert_yaxis()
    axis.set_xlabel("mean simulated seconds")
    axis.set_title("Where each robot's time went")
    axis.legend(fontsize=7, ncol=5, loc="upper center", bbox_to_anchor=(0.5, -0.35))
    figure.tight_layout()
    save_png(figure, path)


def batch_csv(rows: list[dict]) -> str:
    """The rows as CSV text, a seed per line."""
    buffer = io.StringIO()
    names = ["planner", "seed", "folder", "finished", *METRICS, *WALL_CLOCK]
    writer = csv.DictWriter(buffer, fieldnames=names, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def batch_markdown(summary: dict, runs: int, time_use: dict | None = None, ends: dict | None = None) -> str:
    """The aggregate as a markdown table: metric, mean, spread, range; then where each robot's time went
    (``time_use``, :func:`time_use_means`) and why each stopped exploring (``ends``,
    :func:`exploring_ends`), when given."""
    lines = [
        f"# Map-TIDAL missions: {runs} seeds",
        "",
        f"Finished before the time limit: {summary['finished']['count']} of {summary['finished']['of']}.",
        "",
        "| metric | unit | mean | std | min | max |",
        "|---|---|---|---|---|---|",
    ]
    for name, unit in {**METRICS, "realtime_factor": "x real time (this machine)"}.items():
        figures = summary[name]
        if figures["mean"] is None:
            lines.append(f"| {name} | {unit} | n/a | n/a | n/a | n/a |")
            continue
        lines.append(
            f"| {name} | {unit} | {figures['mean']:.3g}{_of(figures, runs)} | {figures['std']:.3g} "
            f"| {figures['min']:.3g} | {figures['max']:.3g} |"
        )
    lines += ["", "![every seed](batch.png)", "", "![coverage against time](coverage_time.png)", ""]
    return "\n".join([*lines, *time_use_markdown(time_use or {}), *exploring_ends_markdown(ends or {})])


def _of(figures: dict, runs: int) -> str:
    """The suffix ' (k of n)' when a metric is known for only some of the runs, else nothing."""
    count = figures.get("count", runs)
    return "" if count == runs else f" ({count} of {runs})"


def planners_markdown(
    summaries: dict[str, dict],
    runs: int,
    time_use: dict | None = None,
    rows: list[dict] | None = None,
    ends: dict | None = None,
) -> str:
    """Several planners' aggregates side by side: each metric's mean +- std per planner; then, given the
    ``rows``, each planner against Map-TIDAL seed by seed, with the mean difference's confidence interval
    (:func:`maptidal.mission.batch_compare.planners_pairs_markdown`); then where each robot's time went
    (``time_use``, :func:`time_use_means`) and why each stopped exploring (``ends``, :func:`exploring_ends`),
    when given."""
    planners = list(summaries)
    lines = [
        f"# Planners flown in the loop: {', '.join(planners)}, {runs} seeds each",
        "",
        "Finished before the time limit: "
        + ", ".join(f"{p} {s['finished']['count']} of {s['finished']['of']}" for p, s in summaries.items())
        + ".",
        "",
        "| metric | unit | " + " | ".join(planners) + " |",
        "|---|---|" + "---|" * len(planners),
    ]
    for name, unit in METRICS.items():
        cells = []
        for planner in planners:
            figures = summaries[planner][name]
            spread = (
                "n/a"
                if figures["mean"] is None
                else f"{figures['mean']:.3g} +- {figures['std']:.2g}{_of(figures, runs)}"
            )
            cells.append(spread)
        lines.append(f"| {name} | {unit} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "![every seed of every planner](batch.png)",
        "",
        "![coverage against time, mean and one standard deviation](coverage_time.png)",
        "",
    ]
    pairs = planners_pairs_markdown(rows) if rows else []
    return "\n".join(
        [*lines, *pairs, *time_use_markdown(time_use or {}), *exploring_ends_markdown(ends or {})]
    )


def plot_batch(rows: list[dict], path: Path) -> None:
    """A panel per metric: every seed a dot, the mean a line, one standard deviation a band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    names = tuple(PANELS)
    figure, axes = plt.subplots(3, 3, figsize=(11, 8.5))
    planners = list(dict.fromkeys(row.get("planner") for row in rows))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for axis, name in zip(axes.flat, names, strict=True):
        for k, planner in enumerate(planners):
            mine = [row for row in rows if row.get("planner") == planner]
            seeds = [row["seed"] for row in mine]
            values = np.array([math.nan if row[name] is None else row[name] for row in mine], float)
            colour = colours[k % len(colours)]
            label = planner if len(planners) > 1 else None
            axis.plot(seeds, values, "o", ms=4, color=colour, label=label)
            if np.isfinite(values).any():
                mean, std = np.nanmean(values), np.nanstd(values)
                axis.axhline(mean, color=colour, lw=1)
                axis.axhspan(mean - std, mean + std, color=colour, alpha=0.1, lw=0)
        axis.set_title(PANELS[name], fontsize=9)
        if not any(row.get(name) is not None for row in rows):
            axis.text(0.5, 0.5, "no seed has it", ha="center", va="center", transform=axis.transAxes)
            axis.set_yticks([])
        axis.set_xlabel("seed", fontsize=8)
        axis.xaxis.set_major_locator(MaxNLocator(integer=True))
        axis.tick_params(labelsize=8)
    if len(planners) > 1:
        axes.flat[0].legend(fontsize=8)
    runs = len({row["seed"] for row in rows})
    figure.suptitle(f"{', '.join(map(str, planners))} over {runs} seeds (line: mean, band: one std)")
    figure.tight_layout()
    save_png(figure, path)


def coverage_bands(rows: list[dict], grid: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each planner's inspected share (%) on the time ``grid``: the mean over its seeds and the standard
    deviation. A mission's share is a step function of its timeline, held after its last view and after
    it ends (its inspection is what it is)."""
    bands = {}
    for planner in dict.fromkeys(row.get("planner") for row in rows):
        curves = []
        for row in rows:
            if row.get("planner") != planner:
                continue
            timeline = np.array(row.get("coverage_timeline", [[0.0, 0.0]]), float).reshape(-1, 2)
            index = np.searchsorted(timeline[:, 0], grid, side="right") - 1
            curves.append(timeline[np.clip(index, 0, None), 1])
        curves_array = np.array(curves)
        bands[planner] = (curves_array.mean(axis=0), curves_array.std(axis=0))
    return bands


def plot_coverage_bands(rows: list[dict], path: Path) -> None:
    """Coverage against time, one line (the mean over seeds) and band (one standard deviation) per
    planner, with the 95 % mark."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from maptidal.evaluation.plots import finish_coverage_time

    end = max(float(row["completion_time_s"]) for row in rows)
    grid = np.linspace(0.0, max(end, 1.0), 400)
    figure, axis = plt.subplots(figsize=(8, 4))
    for planner, (mean, std) in coverage_bands(rows, grid).items():
        line = axis.plot(grid, mean, lw=1.5, label=str(planner))[0]
        axis.fill_between(
            grid,
            np.clip(mean - std, 0, 100),
            np.clip(mean + std, 0, 100),
            color=line.get_color(),
            alpha=0.15,
            lw=0,
        )
    runs = len({row["seed"] for row in rows})
    axis.set_title(f"Walls inspected against time, {runs} seeds (line: mean, band: one std)")
    finish_coverage_time(figure, axis, path)


def run_batch(
    scenario: str | None,
    seeds: list[int],
    out_dir: str | Path,
    executor: str = "local",
    jobs: int = 1,
    ray_address: str | None = None,
    robots: int | None = None,
    duration_s: float | None = None,
    pose_source: str | None = None,
    progress: bool = True,
    planners: list[str] | None = None,
    discovery: str | None = None,
    plots: bool = True,
    explore: bool | None = None,
) -> tuple[list[dict], dict]:
    """Fly a mission per seed (module docstring), or per planner and seed; returns the rows in order
    (planner, then seed) and the aggregate (one per planner with several planners). ``plots=False``
    leaves out each mission's own PNG plots; ``explore`` overrides the mission file's ``explore``.

    The mission file is checked here, before any run starts, so a bad one fails at once."""
    from maptidal.mission.config import prepare_mission

    if not seeds:
        raise ValueError("no seeds to run")
    several = planners is not None and len(planners) > 1
    for planner in planners or [None]:  # fail fast on a bad file, override or plan
        prepare_mission(
            scenario, robots, duration_s, pose_source, planner=planner, discovery=discovery, explore=explore
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    runs = [
        BatchRun(
            None if scenario is None else str(Path(scenario).resolve()),
            seed,
            str(((out / planner if several else out) / f"seed_{seed:03d}").resolve()),
            robots,
            duration_s,
            pose_source,
            planner,
            discovery,
            plots,
            explore,
        )
        for planner in planners or [None]
        for seed in seeds
    ]
    bar = ProgressBar(len(runs), "batch", enabled=progress)
    results: dict[int, dict] = {}
    for index, row in run_jobs(run_one, runs, executor=executor, jobs=jobs, ray_address=ray_address):
        results[index] = row
        atomic_write_text(out / "batch.csv", batch_csv([results[k] for k in sorted(results)]))
        bar.advance(note=f"seed {row['seed']}: {row['tasks_done']}/{row['tasks_found']} tasks done")
    rows = [results[k] for k in sorted(results)]
    time_use = time_use_means(rows)
    ends = exploring_ends(rows)
    if several:
        summary = {p: aggregate([row for row in rows if row["planner"] == p]) for p in planners}
        markdown = planners_markdown(summary, len(seeds), time_use, rows, ends)
    else:
        summary = aggregate(rows)
        markdown = batch_markdown(summary, len(rows), time_use, ends)
    atomic_write_json(out / "batch.json", {"executor": executor, "rows": rows, "summary": summary})
    atomic_write_text(out / "batch.md", markdown)
    plot_batch(rows, out / "batch.png")
    plot_coverage_bands(rows, out / "coverage_time.png")
    if any(time_use.values()):
        plot_time_use(time_use, out / "time_use.png")
    return rows, summary
