"""The default mission in tanks drawn at random, none of them seen while the loop was built: how each
planner does there, per tank (issue [loop]'s bars are judged on tanks the project never saw).

Each tank keeps the OSB tank's angled and side walls and draws what the issue names: the end wall's
width, the water's depth, and where the window and the ladder sit. The robots launch where the default
mission launches them. Every tank gets a folder with its tank.toml and mission.toml, and a batch of the
given planners and seeds; the summary prints per tank and lands in summary.md.

    python tests/bench/random_tanks.py --tanks 6 --draw-seed 1 --seeds 0-1 --out runs/random_tanks

A change is judged on tanks it was not made on: fly the same draw before and after it (another checkout,
another --out), then ``--against BEFORE`` pairs every tank's missions seed by seed with BEFORE's and
writes against.md, as ``maptidal compare-batches`` does for one tank (each tank's seed counts as a
pair of its own).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_TANK = ROOT / "assets" / "osb_tank" / "tank.toml"
DEFAULT_MISSION = ROOT / "assets" / "scenarios" / "mission.toml"

# The ranges drawn from: a 2-robot BlueROV2 team's end wall from 1.6 m (variant A's 1.8, a little
# under) to 3.2 m (B's 3.0, a little over), water 1.5 to 2.6 m deep (C's 1.6 to B's 2.4, widened).
WIDTH_M = (1.6, 3.2)
DEPTH_M = (1.5, 2.6)
WINDOW_WIDTH_M = (0.5, 1.2)
WINDOW_CHANCE = 0.7
GAP_M = 0.1  # the least space between the window's edge and the ladder's rail


def draw_tank(rng: np.random.Generator, index: int) -> dict:
    """One tank document: the default tank with the end wall's width, the depth, the window and the
    ladder drawn; the window is left out when it and the ladder cannot both fit apart."""
    with open(DEFAULT_TANK, "rb") as stream:
        document = tomllib.load(stream)
    width = round(float(rng.uniform(*WIDTH_M)), 2)
    depth = round(float(rng.uniform(*DEPTH_M)), 2)
    document["name"] = f"random_{index:02d}"
    document["water_depth"] = depth
    document["end_wall"]["width"] = width
    ladder = document["ladder"]
    ladder["top"] = round(depth + 0.3, 2)
    half_span = ladder["rail_spacing"] / 2 + ladder["rail_width"] / 2
    ladder_room = width / 2 - half_span - 0.05
    ladder["centre_offset"] = round(float(rng.uniform(-ladder_room, ladder_room)), 2)
    window = document["window"]
    window["width"] = 0.0
    if rng.random() < WINDOW_CHANCE:
        window_width = round(float(rng.uniform(*WINDOW_WIDTH_M)), 2)
        # the window's centre may go where it fits in the wall and clears the ladder
        lo, hi = -width / 2 + window_width / 2 + 0.05, width / 2 - window_width / 2 - 0.05
        keep_out = half_span + GAP_M + window_width / 2
        places = np.linspace(lo, hi, 41) if hi > lo else np.array([])
        places = places[np.abs(places - ladder["centre_offset"]) > keep_out]
        if places.size:
            half_h = window["height"] / 2
            window["width"] = window_width
            window["centre_offset"] = round(float(rng.choice(places)), 2)
            window["centre_height"] = round(float(rng.uniform(half_h + 0.2, depth - half_h - 0.2)), 2)
    return document


def mission_text(tank_file: str) -> str:
    """The default mission scenario, pointed at ``tank_file`` (beside it)."""
    lines = DEFAULT_MISSION.read_text().splitlines()
    return "\n".join(f'tank = "{tank_file}"' if line.startswith("tank =") else line for line in lines) + "\n"


def summarise(batch_csv: Path) -> dict[str, dict[str, float]]:
    """Means per planner of a batch.csv: finish (s), finished share, uninspected (%), tasks done."""
    rows: dict[str, list[dict]] = {}
    with open(batch_csv) as stream:
        for row in csv.DictReader(stream):
            rows.setdefault(row["planner"], []).append(row)
    out = {}
    for planner, group in rows.items():
        out[planner] = {
            "finish_s": statistics.mean(float(r["completion_time_s"]) for r in group),
            "finished": statistics.mean(r["finished"] == "True" for r in group),
            "uninspected_pct": statistics.mean(float(r["pct_uninspected"]) for r in group),
            "tasks_done": statistics.mean(float(r["tasks_done"]) for r in group),
        }
    return out


def _row(name: str, document: dict | None, window_cell: str, means: list[dict[str, float]]) -> str:
    """One line of the summary table: the tank, then each metric as the planners' means, slashed."""

    def cell(key: str, form: str) -> str:
        return " / ".join(format(m[key], form) for m in means)

    shape = (
        f"{document['end_wall']['width']} | {document['water_depth']} | {window_cell} | "
        f"{document['ladder']['centre_offset']}"
        if document
        else " | | |"
    )
    return (
        f"| {name} | {shape} | {cell('finish_s', '.0f')} | {cell('finished', '.0%')} | "
        f"{cell('uninspected_pct', '.1f')} | {cell('tasks_done', '.1f')} |"
    )


def main() -> int:
    """Draw the tanks, fly their batches, print and write the summary."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--tanks", type=int, default=6, help="how many tanks to draw (default 6)")
    parser.add_argument("--draw-seed", type=int, default=1, help="seed of the tanks' draw (default 1)")
    parser.add_argument("--seeds", default="0-1", help="mission seeds per tank (default 0-1)")
    parser.add_argument("--planners", default="maptidal,boustrophedon", help="as maptidal batch takes them")
    parser.add_argument("--jobs", type=int, default=2, help="missions at once (default 2)")
    parser.add_argument("--out", type=Path, default=Path("runs/random_tanks"), help="output folder")
    parser.add_argument(
        "--against", type=Path, help="an earlier run's --out, of the same draw: pair every mission with it"
    )
    args = parser.parse_args()
    from maptidal.tank import tank_toml

    rng = np.random.default_rng(args.draw_seed)
    planners = args.planners.split(",")
    against = " / ".join(planners)
    lines = [
        f"| tank | end wall m | depth m | window m (offset) | ladder offset m | finish s ({against}) "
        f"| finished | uninspected % | tasks done |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    every: dict[str, list[dict[str, float]]] = {planner: [] for planner in planners}
    for index in range(args.tanks):
        document = draw_tank(rng, index)
        folder = args.out / document["name"]
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "tank.toml").write_text(
            tank_toml(document, f"drawn by random_tanks.py, draw seed {args.draw_seed}")
        )
        (folder / "mission.toml").write_text(mission_text("tank.toml"))
        if not (folder / "batch" / "batch.json").exists():
            command = [
                sys.executable, "-m", "maptidal.cli", "batch", str(folder / "mission.toml"),
                "--seeds", args.seeds, "--planners", args.planners, "--jobs", str(args.jobs),
                "--no-plots", "--out", str(folder / "batch"),
            ]  # fmt: skip
            subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        means = summarise(folder / "batch" / "batch.csv")
        for planner in planners:
            every[planner].append(means[planner])
        window = document["window"]
        window_cell = f"{window['width']} ({window['centre_offset']})" if window["width"] else "none"
        lines.append(_row(document["name"], document, window_cell, [means[p] for p in planners]))
        print(lines[-1], flush=True)
    overall = {p: {k: statistics.mean(m[k] for m in every[p]) for k in every[p][0]} for p in planners}
    lines.append(_row("mean", None, "", [overall[p] for p in planners]))
    print(lines[-1])
    (args.out / "summary.md").write_text("\n".join(lines) + "\n")
    if args.against is not None:
        text = paired_against(args.out, args.against, args.tanks)
        (args.out / "against.md").write_text(text)
        print(text)
    return 0


def paired_against(after: Path, before: Path, tanks: int) -> str:
    """Every metric of every planner, paired mission by mission between two runs of the same draw
    (``maptidal compare-batches``'s table): a tank's seed is one pair."""
    from maptidal.mission.batch_compare import compare_batches, comparison_markdown, read_batch

    rows: dict[Path, list[dict]] = {after: [], before: []}
    for index in range(tanks):
        for run, collected in rows.items():
            for row in read_batch(run / f"random_{index:02d}" / "batch"):
                collected.append({**row, "seed": index * 1000 + row["seed"]})  # unique across tanks
    differences = compare_batches(rows[before], rows[after])
    return comparison_markdown(differences, str(before), str(after))


if __name__ == "__main__":
    raise SystemExit(main())
