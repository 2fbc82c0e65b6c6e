"""A mission's outputs, written as it runs (issue [mission]):

- ``events.jsonl``: the append-only event log, one JSON object per line, flushed as each is written;
- ``trajectories.csv``: per frame, each robot's true and estimated position;
- ``images/``: the image captured at each task;
- ``mission.json``: an atomic snapshot every few simulated seconds, and the final document;
- at the end: ``top_view.png``, ``histogram.png``, ``voxel_views.png``, ``timeline.png``,
  ``coverage_time.png`` (the walls' inspected share against time), ``localisation.png`` and
  ``report.md``.

A mission killed midway leaves a readable ``events.jsonl`` (at worst its last line cut, which is
skipped) and its last snapshot; :func:`rebuild` makes ``mission.json``, the plots and ``report.md`` again
from the log (``maptidal report DIR``).
"""

from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import numpy as np

from maptidal.files import atomic_write_bytes, atomic_write_json, atomic_write_text, save_png
from maptidal.mission.time_use import OCCUPATION_COLOURS, OCCUPATIONS, occupation_table

EVENTS = "events.jsonl"
TRAJECTORIES = "trajectories.csv"
# every file a mission writes at the top of its folder (its task images go in images/)
MISSION_FILES = (
    EVENTS,
    TRAJECTORIES,
    "mission.json",
    "report.md",
    "top_view.png",
    "timeline.png",
    "coverage_time.png",
    "localisation.png",
    "histogram.png",
    "voxel_views.png",
    "mission.mp4",
    "mission.part.mp4",
)


def clear_earlier_mission(root: Path) -> int:
    """Remove what an earlier mission wrote in ``root`` (:data:`MISSION_FILES` and ``images/*.png``), so
    that a reused folder holds no stale task image or video beside the new run's; any other file is left
    alone. Returns how many files went."""
    stale = [root / name for name in MISSION_FILES if (root / name).is_file()]
    if (root / "images").is_dir():
        stale += [path for path in (root / "images").glob("*.png") if path.is_file()]
    for path in stale:
        path.unlink()
    return len(stale)


class MissionWriter:
    """Writes one mission's outputs into ``out_dir`` (module docstring)."""

    def __init__(self, out_dir) -> None:
        self.root = Path(out_dir)
        self.cleared = clear_earlier_mission(self.root) if self.root.is_dir() else 0
        (self.root / "images").mkdir(parents=True, exist_ok=True)
        self._events = open(self.root / EVENTS, "w", encoding="utf-8")  # noqa: SIM115 (open for the mission)
        self._trajectories = open(self.root / TRAJECTORIES, "w", encoding="utf-8")  # noqa: SIM115
        self._trajectories.write("time_s,robot,true_x,true_y,true_z,est_x,est_y,est_z,true_yaw\n")

    def event(self, time_s: float, kind: str, **fields) -> None:
        """Append one event to the log and flush it."""
        self._events.write(json.dumps({"t": round(float(time_s), 3), "kind": kind, **fields}) + "\n")
        self._events.flush()

    def trajectory(self, time_s: float, poses: dict[str, dict]) -> None:
        """Append each robot's true and estimated position."""
        for name, pose in poses.items():
            values = [*pose["truth"], *pose["estimate"], pose["yaw"]]
            self._trajectories.write(f"{time_s:.3f},{name}," + ",".join(f"{v:.4f}" for v in values) + "\n")
        self._trajectories.flush()

    def image(self, name: str, rgb: np.ndarray) -> str:
        """Write a captured image atomically; returns its path relative to the output folder."""
        import cv2

        ok, encoded = cv2.imencode(".png", cv2.cvtColor(np.asarray(rgb), cv2.COLOR_RGB2BGR))
        if not ok:
            raise ValueError(f"could not encode {name}")
        atomic_write_bytes(self.root / "images" / name, encoded.tobytes())
        return self.image_path(name)

    @staticmethod
    def image_path(name: str) -> str:
        """Where :meth:`image` writes ``name``, relative to the output folder."""
        return f"images/{name}"

    def snapshot(self, document: dict) -> None:
        """Replace ``mission.json`` atomically."""
        atomic_write_json(self.root / "mission.json", document)

    def finish(
        self, document: dict, views: np.ndarray, view_times: np.ndarray, tank, plots: bool = True
    ) -> dict:
        """Add the coverage of the captured views (``view_times``: when each was captured), write
        ``mission.json``, the plots (unless ``plots`` is False: ``report.md`` then says how to draw
        them) and ``report.md``."""
        self._events.close()
        self._trajectories.close()
        document["coverage"], occluded = coverage_of(views, tank)
        document["coverage_timeline"] = coverage_timeline(views, view_times, tank)
        document["localisation"] = localisation_errors(self.root, list(document.get("robots", {})))
        document["plots"] = plots
        atomic_write_json(self.root / "mission.json", document)
        if plots:
            write_plots(self.root, document, views, tank, occluded)
        atomic_write_text(self.root / "report.md", report_markdown(document))
        return document


def coverage_of(views: np.ndarray, tank) -> tuple[dict, tuple | None]:
    """[coverage]'s report of the viewpoints ``(N, 6)``, with occlusion on and off, and the occluded
    evaluation (model, report, views per voxel) for the plots. With no viewpoint (no task done yet) the
    report is whole too: every voxel unseen, and the plots say so."""
    from maptidal.evaluation.coverage import CoverageModel, CoverageParams

    out, occluded = {}, None
    views = np.asarray(views, float).reshape(-1, 6)
    for occlusion in (True, False):
        name = "occluded" if occlusion else "unoccluded"
        model = CoverageModel.from_tank(tank, CoverageParams(occlusion=occlusion))
        report, per_voxel = model.evaluate(views)
        out[name] = report.to_dict()
        if occlusion:
            occluded = (model, report, per_voxel)
    return out, occluded


def coverage_timeline(views: np.ndarray, times: np.ndarray, tank) -> list[list[float]]:
    """The walls' inspected share (% of the coverage voxels seen by some view, occlusion on) against
    simulated time: ``[0, 0]``, then ``[t, %]`` after each view, in the order of ``times``. Its last value
    is 100 minus the coverage report's ``pct_uninspected``."""
    from maptidal.evaluation.coverage import CoverageModel, CoverageParams, SeenVoxels

    views = np.asarray(views, float).reshape(-1, 6)
    times = np.asarray(times, float).reshape(-1)
    if len(times) != len(views):
        raise ValueError(f"{len(views)} views but {len(times)} capture times")
    seen = SeenVoxels(CoverageModel.from_tank(tank, CoverageParams(occlusion=True)))
    timeline = [[0.0, 0.0]]
    for k in np.argsort(times, kind="stable"):
        seen.look(views[k])
        timeline.append([round(float(times[k]), 3), 100.0 * float(seen.seen.mean())])
    return timeline


def time_to_coverage(timeline: list[list[float]], pct: float) -> float | None:
    """The first time (s) the inspected share reached ``pct`` %, or None if it never did."""
    return next((t for t, covered in timeline if covered >= pct - 1e-9), None)


def team_odometry(document: dict) -> dict[str, float | None]:
    """The team's distance travelled (``path_m``), thruster energy (``thruster_energy_kj``) and
    robot-seconds in contact with the tank or a teammate (``contact_s``; a collision of two robots
    counts for both), summed over the robots' odometry; None each for a document without it."""
    odometry = document.get("odometry")
    if not odometry:
        return dict.fromkeys(("path_m", "thruster_energy_kj", "contact_s"))
    rows = odometry.values()
    return {
        "path_m": float(sum(row["path_m"] for row in rows)),
        "thruster_energy_kj": float(sum(row["thruster_energy_j"] for row in rows)) / 1000.0,
        "contact_s": float(sum(row.get("contact_s", 0.0) for row in rows)),
    }


def read_events(root) -> list[dict]:
    """The event log's events (a cut last line, from a killed mission, is skipped). An event that is not
    an object with a ``kind`` and a finite time ``t`` raises ValueError naming the file and the line."""
    path = Path(root) / EVENTS
    lines = path.read_text(encoding="utf-8").splitlines()
    events = []
    for number, line in enumerate(lines, start=1):
        try:
            event = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):
                continue  # the line a killed mission was writing
            raise ValueError(f"{path}, line {number}: not JSON") from None
        t = event.get("t") if isinstance(event, dict) else None
        valid_time = isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t)
        if not (isinstance(event, dict) and isinstance(event.get("kind"), str) and valid_time):
            raise ValueError(f"{path}, line {number}: an event needs a 'kind' and a finite time 't'")
        events.append(event)
    return events


def standing_down_spans(events: list[dict], robot: str, end_s: float) -> list[tuple[float, float]]:
    """When ``robot`` stood down, lost (``stood_down`` events, each to the next ``resumed`` or to
    ``end_s``): ``(start, duration)`` pairs, in order."""
    spans, since = [], None
    for event in events:
        if event.get("robot") != robot:
            continue
        if event["kind"] == "stood_down" and since is None:
            since = float(event["t"])
        elif event["kind"] == "resumed" and since is not None:
            spans.append((since, float(event["t"]) - since))
            since = None
    if since is not None:
        spans.append((since, max(end_s - since, 0.0)))
    return spans


def write_plots(root: Path, document: dict, views: np.ndarray, tank, occluded: tuple | None) -> None:
    """The top view, the coverage histogram and the views-per-voxel map (from ``occluded``, the evaluation
    :func:`coverage_of` made) and the timeline."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from maptidal.evaluation.plots import plot_histograms, plot_voxel_views

    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    robots = list(document.get("robots", {}))
    colour_of = {name: colours[k % len(colours)] for k, name in enumerate(robots)}
    figure, axis = plt.subplots(figsize=(7, 6))
    for segment in tank.segments:
        axis.plot([segment.start[0], segment.end[0]], [segment.start[1], segment.end[1]], "k-", lw=2)
    rows = _trajectory_rows(root)
    for name in robots:
        mine = rows[rows[:, 0] == robots.index(name)] if len(rows) else rows
        if len(mine):
            axis.plot(mine[:, 2], mine[:, 3], "-", color=colour_of[name], lw=1.5, label=f"{name} (true path)")
            axis.plot(mine[:, 5], mine[:, 6], ":", color=colour_of[name], lw=1, label=f"{name} (estimate)")
    if len(rows):
        last = {name: rows[rows[:, 0] == k][-1] for k, name in enumerate(robots) if np.any(rows[:, 0] == k)}
        names = list(last)
        for a in range(len(names)):
            for b in range(a + 1, len(names)):
                pa, pb = last[names[a]], last[names[b]]
                axis.plot([pa[2], pb[2]], [pa[3], pb[3]], "--", color="0.6", lw=0.8)
    for task in document.get("tasks", []):
        colour = colour_of.get(task.get("assigned_to"), "0.5")
        x, y = task["position"][:2]
        dx, dy = task["direction"][:2]
        axis.arrow(
            x, y, 0.2 * dx, 0.2 * dy, color=colour, head_width=0.05, alpha=1.0 if task["completed"] else 0.35
        )
    axis.set_aspect("equal")
    axis.set_xlabel("x (m)")
    axis.set_ylabel("y (m)")
    axis.set_title("Paths, tasks by robot (faint: not done), acoustic links (dashed)")
    if axis.get_legend_handles_labels()[0]:  # a mission cut short may have no path drawn yet
        axis.legend(fontsize=7, loc="lower left")
    figure.tight_layout()
    save_png(figure, root / "top_view.png")

    if occluded is not None:
        model, report, per_voxel = occluded
        plot_histograms(
            {"mission": report}, root / "histogram.png", title="Views per voxel against the ideal gamma"
        )
        plot_voxel_views(
            model.voxels,
            per_voxel,
            views,
            root / "voxel_views.png",
            "Views per voxel (captured images)",
            tank=tank,
        )

    events = read_events(root) if (root / EVENTS).is_file() else []
    figure, axis = plt.subplots(figsize=(8, 3.8))
    marks = {"discovered": ("o", "found"), "flying": ("^", "allocated / flying"), "done": ("s", "done")}
    for kind, (marker, label) in marks.items():
        for k, name in enumerate(robots):
            times = [e["t"] for e in events if e["kind"] == kind and e.get("robot") == name]
            axis.scatter(
                times,
                [k] * len(times),
                marker=marker,
                color=colour_of[name],
                label=f"{label}" if k == 0 else None,
            )
    end_s, label = float(document.get("sim_time_s", 0.0)), "standing down (lost)"
    for k, name in enumerate(robots):
        spans = standing_down_spans(events, name, end_s)
        if spans:
            axis.broken_barh(spans, (k - 0.3, 0.6), color="0.8", zorder=0, label=label)
            label = None  # once in the legend
    # where each robot's time went: a thin band under its marks, coloured by occupation
    shown: set[str] = set()
    for k, name in enumerate(robots):
        spans = document.get("time_use", {}).get(name, {}).get("spans", [])
        for kind in OCCUPATIONS:
            bars = [(a, b - a) for a, b, of in spans if of == kind and b > a]
            if bars:
                axis.broken_barh(
                    bars,
                    (k - 0.45, 0.12),
                    color=OCCUPATION_COLOURS[kind],
                    zorder=0,
                    label=None if kind in shown else kind,
                )
                shown.add(kind)
    for event in events:
        if event["kind"] == "fail":
            axis.axvline(event["t"], color="red", lw=1)
    axis.set_yticks(range(len(robots)), robots)
    axis.set_xlabel("simulated time (s)")
    axis.set_title(
        "Tasks found, allocated and done per robot (red line: a failure; grey: standing down; "
        "band: occupation)",
        fontsize=9,
    )
    if axis.get_legend_handles_labels()[0]:  # a log with nothing flown yet has nothing to name
        axis.legend(fontsize=7, ncol=5, loc="upper center", bbox_to_anchor=(0.5, -0.3))
    figure.tight_layout()
    save_png(figure, root / "timeline.png")

    plot_coverage_time(document, root / "coverage_time.png")

    figure, axis = plt.subplots(figsize=(8, 3))
    for name in robots:
        mine = rows[rows[:, 0] == robots.index(name)] if len(rows) else rows
        if len(mine):
            error = np.hypot(mine[:, 2] - mine[:, 5], mine[:, 3] - mine[:, 6])
            axis.plot(mine[:, 1], 100.0 * error, color=colour_of[name], lw=1, label=name)
    axis.set_xlabel("simulated time (s)")
    axis.set_ylabel("horizontal error (cm)")
    axis.set_title("Localisation: the estimate each robot flies on against the truth")
    if axis.get_legend_handles_labels()[0]:
        axis.legend(fontsize=7)
    figure.tight_layout()
    save_png(figure, root / "localisation.png")


def plot_coverage_time(document: dict, path: Path) -> None:
    """The walls' inspected share against simulated time, as a step per captured view, held to the
    mission's end, with the 95 % mark."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from maptidal.evaluation.plots import finish_coverage_time

    timeline = np.array(document.get("coverage_timeline", [[0.0, 0.0]]), float).reshape(-1, 2)
    end = max(float(document.get("sim_time_s", 0.0)), float(timeline[-1, 0]))
    figure, axis = plt.subplots(figsize=(8, 3))
    axis.step(np.r_[timeline[:, 0], end], np.r_[timeline[:, 1], timeline[-1, 1]], where="post", lw=1.5)
    reached = time_to_coverage(timeline.tolist(), 95.0)
    axis.set_title(
        "Walls inspected by the scored views (occlusion on): "
        + (f"95 % at {reached:.0f} s" if reached is not None else f"{timeline[-1, 1]:.0f} % at the end")
    )
    finish_coverage_time(figure, axis, path, legend_size=7)


def localisation_errors(root, robots: list[str]) -> dict:
    """Each robot's horizontal localisation error (m) over the mission, from ``trajectories.csv``'s true
    and estimated positions (what the robot flew on): the root mean square (the absolute trajectory
    error, unaligned: every estimate starts at the true pose), median, 90th percentile, maximum and
    final. A robot with no row is left out."""
    rows = _trajectory_rows(Path(root))
    out = {}
    for k, name in enumerate(robots):
        mine = rows[rows[:, 0] == k] if len(rows) else rows
        if not len(mine):
            continue
        error = np.hypot(mine[:, 2] - mine[:, 5], mine[:, 3] - mine[:, 6])
        out[name] = {
            "ate_m": float(np.sqrt(np.mean(error**2))),
            "median_m": float(np.median(error)),
            "p90_m": float(np.percentile(error, 90)),
            "max_m": float(error.max()),
            "final_m": float(error[-1]),
        }
    return out


def localisation_lines(document: dict) -> list[str]:
    """``report.md``'s table of each robot's horizontal localisation error (``mission.json``'s
    ``localisation``); none for a document without it."""
    errors = document.get("localisation")
    if not errors:
        return []
    rows = ["| robot | ATE (RMS) | median | p90 | max | final |", "|---|---|---|---|---|---|"]
    for name, e in errors.items():
        cells = " | ".join(
            f"{100 * e[key]:.1f} cm" for key in ("ate_m", "median_m", "p90_m", "max_m", "final_m")
        )
        rows.append(f"| {name} | {cells} |")
    note = "Horizontal error of the estimate each robot flew on, against the truth."
    figure = ["![localisation](localisation.png)", ""] if document.get("plots", True) else []
    return ["## Localisation", "", note, "", *rows, "", *figure]


def _trajectory_rows(root: Path) -> np.ndarray:
    """trajectories.csv as rows (robot index, time, true xyz, estimated xyz, yaw)."""
    path = root / TRAJECTORIES
    if not path.is_file():
        return np.zeros((0, 9))
    names: dict[str, int] = {}
    rows = []
    for line in path.read_text().splitlines()[1:]:
        parts = line.split(",")
        if len(parts) != 9:
            continue  # a line cut by a kill
        index = names.setdefault(parts[1], len(names))
        try:
            rows.append([index, float(parts[0]), *map(float, parts[2:])])
        except ValueError:
            continue
    return np.array(rows).reshape(-1, 9)


def mission_metrics(document: dict) -> dict:
    """A mission document's figures: whether it finished, tasks found and done, the coverage of the captured
    views (occlusion on), the completion time, the comms counters and the wall-clock figures (what
    ``maptidal batch`` aggregates, and the summary table shows)."""
    tasks = document.get("tasks", [])
    coverage = document.get("coverage", {}).get("occluded", {})
    comms = document.get("comms")  # None: unknown (a log rebuilt without a readable snapshot)
    return {
        "finished": bool(document.get("finished")),
        "tasks_found": len(tasks),
        "tasks_done": sum(1 for t in tasks if t.get("completed")),
        # done and seen: the true view of the capture within the task's tolerances (None: not judged)
        "tasks_verified": sum(1 for t in tasks if t.get("verified")),
        # retired unflown: the views the team had taken covered them, or they repeated a teammate's task
        # (MissionParams.retire_taken, retire_repeats)
        "tasks_retired": sum(1 for t in tasks if t.get("retired")),
        "pct_uninspected": float(coverage.get("pct_uninspected", 100.0)),
        "mean_views": float(coverage.get("mean_views", 0.0)),
        "mad": coverage.get("mad"),  # None without captured views
        "completion_time_s": float(document.get("sim_time_s", 0.0)),
        # the first time the scored views had seen 95 % of the walls (None: never)
        "time_to_95_s": time_to_coverage(document.get("coverage_timeline", []), 95.0),
        **team_odometry(document),  # path_m, thruster_energy_kj, contact_s
        **team_time_use(document),  # surveying_s, lost_s
        **team_survey_outcomes(document),  # fruitless_survey_s
        "messages": None if comms is None else int(comms.get("messages", 0)),
        "bytes": None if comms is None else int(comms.get("bytes", 0)),
        "lost": None if comms is None else int(comms.get("lost", 0)),
        "realtime_factor": document.get("realtime_factor"),
        "wall_time_s": document.get("wall_time_s"),
        # tasks found by robots that failed, which no live robot holds, did or found again (None: unknown)
        "tasks_lost": (
            None
            if "tasks_lost" not in document
            else sum(row["lost"] for row in document["tasks_lost"].values())
        ),
    }


def survey_outcomes(log: list[dict], now: float) -> dict:
    """What a robot's surveys gave, from its log of them (each ``start_s``, ``end_s``, None while under
    way, which ``now`` ends, ``timed_out`` and ``tasks``, the tasks found on the frames it took): how many
    it flew, how many found a task, how many ran out their timeout, and the seconds they took, all told
    and those of the ones that found none."""
    seconds = [(entry["end_s"] if entry["end_s"] is not None else now) - entry["start_s"] for entry in log]
    return {
        "surveys": len(log),
        "with_tasks": sum(1 for entry in log if entry["tasks"] > 0),
        "timed_out": sum(1 for entry in log if entry["timed_out"]),
        "seconds": round(sum(seconds), 3),
        "seconds_without_tasks": round(
            sum(s for s, entry in zip(seconds, log, strict=True) if entry["tasks"] == 0), 3
        ),
    }


def team_survey_outcomes(document: dict) -> dict:
    """The team's robot-seconds on surveys that found no task (``fruitless_survey_s``), from
    ``mission.json``'s ``survey_outcomes``; None for a document without it."""
    outcomes = document.get("survey_outcomes")
    if outcomes is None:
        return {"fruitless_survey_s": None}
    return {"fruitless_survey_s": round(sum(row["seconds_without_tasks"] for row in outcomes.values()), 3)}


def team_time_use(document: dict) -> dict:
    """The team's robot-seconds surveying the map's frontier (``surveying_s``) and lost (``lost_s``),
    from ``mission.json``'s ``time_use`` (:mod:`maptidal.mission.time_use`); None for a document without
    it."""
    use = document.get("time_use")
    if not use:
        return {"surveying_s": None, "lost_s": None}
    return {
        f"{kind}_s": round(sum(row["seconds"].get(kind, 0.0) for row in use.values()), 3)
        for kind in ("surveying", "lost")
    }


def time_use_lines(document: dict) -> list[str]:
    """``report.md``'s table of where each robot's time went (seconds per occupation); none for a
    document without ``time_use``."""
    use = document.get("time_use")
    if not use:
        return []
    rows = occupation_table("robot", [(name, row["seconds"]) for name, row in use.items()])
    return [
        "## Where each robot's time went",
        "",
        "Simulated seconds per occupation, the first that held winning: lost (no fix, or too unsure), "
        "giving way to a teammate, then what it was doing (the timeline shows when).",
        "",
        *rows,
        "",
    ]


# what an ``explored`` event says of why (Mission._explore; maptidal.exploration.Exploration.summary)
EXPLORED_FIELDS = ("why", "frontier_voxels", "stands", "best_gain_m3", "min_gain_m3")


def explored_cell(info: dict | None) -> str:
    """When a robot stopped exploring and why, for ``report.md`` (``mission.json``'s ``explored``: the
    time, and the numbers of the search that found no look, :class:`maptidal.exploration.Exploration`)."""
    if not info:
        return "not explored"
    why = info.get("why") or "no look left"
    if why == "too little to see" and "best_gain_m3" in info:
        least = info.get("min_gain_m3")
        of = f" of the {least:g} m^3 a look must reveal" if least is not None else ""
        why += f": the best look {info['best_gain_m3']:.3f} m^3{of}"
    return f"at {info['t']:.0f} s: {why}"


def survey_lines(document: dict) -> list[str]:
    """``report.md``'s table of what each robot's surveys gave (``survey_outcomes``) and when and why
    it stopped exploring (``explored``); none for a document with neither surveys nor a robot explored."""
    outcomes = document.get("survey_outcomes") or {}
    explored = document.get("explored") or {}
    if not any(row["surveys"] for row in outcomes.values()) and not any(explored.values()):
        return []
    rows = [
        f"| {name} | {row['surveys']} | {row['with_tasks']} | {row['timed_out']} | {row['seconds']:.0f} | "
        f"{row['seconds_without_tasks']:.0f} | {explored_cell(explored.get(name))} |"
        for name, row in outcomes.items()
    ]
    return [
        "## What the surveys found",
        "",
        "Each robot's surveys of its map's frontier, those whose frames found a task, those that ran out "
        "their timeout, the simulated seconds of all of them and of those that found none, and when and "
        "why it stopped exploring (no look worth a trip: what ran out first).",
        "",
        "| robot | surveys | found a task | timed out | seconds | seconds finding none | explored |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def report_markdown(document: dict) -> str:
    """``report.md``: the summary table and the plots."""
    m = mission_metrics(document)
    lines = [
        "# Map-TIDAL mission",
        "",
        summary_table(document),
        "",
        f"Tasks: {m['tasks_found']} found, {m['tasks_done']} said done by the robots, {m['tasks_verified']} "
        "of them verified (the true view of the capture within the task's tolerances), "
        f"{m['tasks_retired']} retired unflown (the views taken covered them, or a teammate's repeated "
        "them). Coverage of the verified views (occlusion on): "
        f"{m['pct_uninspected']:.1f} % of the walls uninspected. Comms: "
        + (
            "unknown (no readable mission.json snapshot)."
            if m["messages"] is None
            else f"{m['messages']} messages, {m['bytes']} bytes, {m['lost']} lost."
        ),
        "",
        *video_lines(document),
        *verification_lines(document),
        *sharing_lines(document),
        *localisation_lines(document),
        *time_use_lines(document),
        *survey_lines(document),
        *timing_lines(document),
        *(
            [
                "![top view](top_view.png)",
                "",
                "![timeline](timeline.png)",
                "",
                "![coverage against time](coverage_time.png)",
                "",
                "![histogram](histogram.png)",
                "",
                "![views per voxel](voxel_views.png)",
                "",
            ]
            if document.get("plots", True)
            else ["Flown with `--no-plots`: `maptidal report` on this folder draws the plots.", ""]
        ),
    ]
    return "\n".join(lines)


def verification_lines(document: dict) -> list[str]:
    """``report.md``'s table of tasks each robot said were done against those verified on the true pose
    (``mission.json``'s ``done_by_robot``); none for a document without it."""
    per_robot = document.get("done_by_robot")
    if not per_robot:
        return []
    rows = ["| robot | said done | verified | share verified |", "|---|---|---|---|"]
    for name, counts in per_robot.items():
        claimed, verified = counts["claimed"], counts["verified"]
        share = f"{100.0 * verified / claimed:.0f} %" if claimed else "n/a"
        rows.append(f"| {name} | {claimed} | {verified} | {share} |")
    return ["## Done and seen", "", *rows, ""]


def video_lines(document: dict) -> list[str]:
    """``report.md``'s line on the mission's video: where it is, or that it was cut short (a mission
    interrupted leaves ``mission.part.mp4`` finished and playable; one killed with ``kill -9`` leaves it
    unfinished, and it may not play)."""
    video = document.get("video")
    if not video:
        return []
    if video.get("partial"):
        return [
            f"Video: `{video['file']}`, cut short: the mission ended before it finished the video (it plays "
            "after Ctrl-C or SIGTERM; after `kill -9` it may not).",
            "",
        ]
    frames = f", {video['frames']} frames" if "frames" in video else ""
    return [f"Video: [{video['file']}]({video['file']}){frames}.", ""]


def sharing_lines(document: dict) -> list[str]:
    """``report.md``'s tables of how fast each robot's discoveries reached a teammate and, per failed
    robot, what its discoveries came to (``mission.json``'s ``sharing`` and ``tasks_lost``); none for a
    document without them."""
    sharing = document.get("sharing")
    if not sharing:
        return []

    def seconds(value) -> str:
        return "n/a" if value is None else f"{value:.1f}"

    rows = [
        "| finder | found | heard by a teammate | never heard | delay median / p90 / max (s) |",
        "|---|---|---|---|---|",
    ]
    for name, row in sharing.items():
        delay = row["delay"]
        rows.append(
            f"| {name} | {row['found']} | {row['heard']} | {row['unheard']} | "
            f"{seconds(delay['median_s'])} / {seconds(delay['p90_s'])} / {seconds(delay['max_s'])} |"
        )
    lines = [
        "## Sharing what was found",
        "",
        "How long each robot's discoveries took to reach a teammate over the acoustic channel.",
        "",
        *rows,
        "",
    ]
    lost = document.get("tasks_lost")
    if lost:
        rows = [
            "| failed robot | failed at (s) | found | done | inherited | rediscovered | lost |",
            "|---|---|---|---|---|---|---|",
        ]
        for name, row in lost.items():
            rows.append(
                f"| {name} | {row['failed_at_s']:.1f} | {row['found']} | {row['done']} | {row['inherited']} "
                f"| {row['rediscovered']} | {row['lost']} ({row['lost_pct']:.1f} %) |"
            )
        lines += [
            "## Tasks lost with a failed robot",
            "",
            "Of the tasks a robot found before it failed: done by someone; inherited (a live teammate holds "
            "the task); rediscovered (a live teammate found a view within the task's tolerances); lost "
            "(none of these).",
            "",
            *rows,
            "",
        ]
    return lines


def timing_lines(document: dict) -> list[str]:
    """``report.md``'s lines on where the wall time went: each stage's own seconds, and whether it ran in
    the loop or beside it (``mission.json``'s ``timing`` and ``parallel``); none for a document without
    timing."""
    timing = document.get("timing")
    if not timing:
        return []
    parallel = document.get("parallel", {})
    beside = parallel.get("beside_the_loop_s", {})
    wall = document.get("wall_time_s") or 0.0
    rows = ["| stage | in the loop (s) | beside it (s) |", "|---|---|---|"]
    for stage, seconds in timing.items():
        apart = beside.get(stage, 0.0)
        rows.append(f"| {stage} | {seconds - apart:.2f} | {apart:.2f} |")
    if "loop_waited_s" in parallel:
        rows.append(f"| waiting for frames and answers | {parallel['loop_waited_s']:.2f} | |")
    where = {"process": "in a worker process", "inline": "on the drawing thread"}
    lines = [
        "## Where the wall time went",
        "",
        f"{wall:.1f} s of wall time in all. The frames are drawn on a thread of their own, and perception "
        f"runs {where.get(parallel.get('perception'), 'beside the loop')}."
        + (f" Renderer: {document['renderer']}." if document.get("renderer") else ""),
        "",
        *rows,
        "",
    ]
    return lines


def plan_line(plan: dict) -> str:
    """A baseline's plan summary (``mission.json``'s ``plan``) in words."""
    return (
        f"{plan.get('viewpoints', 0)} viewpoints: {plan.get('moved_into_reach', 0)} moved into reach, "
        f"{plan.get('merged', 0)} merged, {plan.get('unreachable', 0)} out of reach"
    )


def summary_table(document: dict) -> str:
    """The one-table summary printed at the end of a mission."""
    m = mission_metrics(document)
    rtf = m["realtime_factor"]
    rows = [
        ("simulated time", f"{m['completion_time_s']:.1f} s"),
        ("real-time factor", f"{rtf:.1f}x" if rtf else "n/a"),
        *([("planner", document["planner"])] if document.get("planner") else []),
        *([("baseline's plan", plan_line(document["plan"]))] if document.get("plan") else []),
        ("finished", str(m["finished"])),
        *([("ended", document["ending"])] if document.get("ending") else []),
        ("tasks found / done / verified", f"{m['tasks_found']} / {m['tasks_done']} / {m['tasks_verified']}"),
        ("tasks retired unflown (covered)", str(m["tasks_retired"])),
        ("tasks inspected twice", str(document.get("duplicate_inspections", "n/a"))),
        # a snapshot of the auction, not a fault: on a slow channel two bundles may hold a task for a while
        ("tasks in two bundles at the end", str(document.get("allocation_conflicts", "n/a"))),
        ("walls uninspected (occluded)", f"{m['pct_uninspected']:.1f} %"),
        (
            "95 % of the walls inspected at",
            "not reached" if m["time_to_95_s"] is None else f"{m['time_to_95_s']:.1f} s",
        ),
        (
            "robot-seconds in contact (tank or teammate)",
            "unknown" if m["contact_s"] is None else f"{m['contact_s']:.1f} s",
        ),
        (
            "path / thruster energy (team)",
            "unknown" if m["path_m"] is None else f"{m['path_m']:.1f} m / {m['thruster_energy_kj']:.1f} kJ",
        ),
        *([("tasks lost with failed robots", str(m["tasks_lost"]))] if document.get("tasks_lost") else []),
        (
            "messages / bytes / lost",
            "unknown" if m["messages"] is None else f"{m['messages']} / {m['bytes']} / {m['lost']}",
        ),
    ]
    return "\n".join(["| figure | value |", "|---|---|", *(f"| {a} | {b} |" for a, b in rows)])


def flown_tank(root):
    """The tank (a :class:`maptidal.tank.TankModel`) the mission in folder ``root`` was flown in, from its
    event log's ``start`` event; None where the log does not say (written before the start event carried
    it, or without a start event)."""
    from maptidal.tank import TankModel, tank_config_from_dict

    start = next((event for event in read_events(root) if event["kind"] == "start"), {})
    return None if "tank" not in start else TankModel(tank_config_from_dict(start["tank"]))


def rebuild(root, tank) -> dict:
    """Make ``mission.json``, the plots and ``report.md`` again from the event log (and the last snapshot,
    for the comms counters and timing), as after a mission killed midway."""
    root = Path(root)
    if not (root / EVENTS).is_file():
        raise ValueError(f"{root}: no {EVENTS}; is this a mission folder?")
    events = read_events(root)
    if not events:
        raise ValueError(f"{root / EVENTS}: the event log is empty; nothing to report")
    snapshot = {}
    if (root / "mission.json").is_file():
        try:
            snapshot = json.loads((root / "mission.json").read_text())
        except json.JSONDecodeError:
            snapshot = {}
    tasks: dict[int, dict] = {}
    views, view_times = [], []
    robots: dict[str, str] = {}
    done_by_robot: dict[str, dict[str, int]] = {}
    explored: dict[str, dict] = {}
    for event in events:
        kind = event["kind"]
        if kind == "start":
            robots = dict.fromkeys(event.get("robots", []), "unknown")
        elif kind == "discovered":
            tasks[event["task"]] = {
                "id": event["task"],
                "position": event["position"],
                "direction": event.get("direction", [1.0, 0.0, 0.0]),
                "found_by": event["robot"],
                "found_at_s": event["t"],
                "assigned_to": None,
                "completed": False,
                "completion_time": None,
                "image": None,
            }
        elif kind == "flying" and event["task"] in tasks:
            tasks[event["task"]]["assigned_to"] = event["robot"]
        elif kind == "done" and event["task"] in tasks:
            image = event.get("image")
            verified = event.get("verified")  # None in logs older than the judgement
            # the image is written just after its event: a mission killed in between never wrote it
            tasks[event["task"]].update(
                completed=True,
                verified=verified,
                completion_time=event["t"],
                image=image if image and (root / image).is_file() else None,
                assigned_to=event["robot"],
            )
            counts = done_by_robot.setdefault(event["robot"], {"claimed": 0, "verified": 0})
            counts["claimed"] += 1
            counts["verified"] += int(bool(verified))
            if "view" in event and verified:  # only the views that show their task are scored
                views.append(event["view"])
                view_times.append(event["t"])
        elif kind == "fail":
            robots[event["robot"]] = "failed"
        elif kind == "explored":
            explored[event["robot"]] = {"t": event["t"]} | {
                key: event[key] for key in EXPLORED_FIELDS if key in event
            }
    inspections = Counter(e["task"] for e in events if e["kind"] == "done")
    document = {
        **snapshot,
        "rebuilt_from_events": True,
        "duplicate_inspections": sum(n - 1 for n in inspections.values()),
        "finished": any(e["kind"] == "end" and e.get("finished") for e in events),
        # how it ended, from its end event; a killed mission has none, and its snapshot's is stale
        "ending": next(
            (e.get("ending") for e in events if e["kind"] == "end"),
            "killed before its end: rebuilt from the event log",
        ),
        "sim_time_s": max((e["t"] for e in events), default=0.0),
        "robots": snapshot.get("robots", robots),
        "tasks": sorted(tasks.values(), key=lambda t: t["id"]),
        "done_by_robot": done_by_robot,
    }
    if explored:
        document["explored"] = {**snapshot.get("explored", {}), **explored}
    document.pop("video", None)
    if (root / "mission.mp4").is_file():
        document["video"] = {"file": "mission.mp4", **snapshot.get("video", {}), "partial": False}
    elif (root / "mission.part.mp4").is_file():  # the mission never finished its video
        document["video"] = {"file": "mission.part.mp4", "partial": True}
    views_array = np.array(views).reshape(-1, 6)
    document["coverage"], occluded = coverage_of(views_array, tank)
    document["coverage_timeline"] = coverage_timeline(views_array, np.array(view_times), tank)
    document["plots"] = True
    document["localisation"] = localisation_errors(root, list(document["robots"]))
    atomic_write_json(root / "mission.json", document)
    write_plots(root, document, views_array, tank, occluded)
    atomic_write_text(root / "report.md", report_markdown(document))
    return document
