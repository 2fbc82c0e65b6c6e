"""The front end's accuracy on rendered frames (issue [perception]): the median mesh error against the true
tank surface as the water grows turbid, the camera noisier and the range longer; how it falls with the
number of observations a landmark fused; and the absolute trajectory error of each pose source, on the
paper's path and on the exploration sweep, with and without a DVL. Writes a markdown table to stdout and
docs/img/frontend_accuracy.png.

    python tests/bench/frontend_accuracy.py [--out PNG]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from maptidal.camera import StereoCameraParams
from maptidal.envs.scenario import load_scenario
from maptidal.envs.water import WaterParams
from maptidal.frame_discovery import discover_on_recording
from maptidal.keyframes import PaperCaptureParams
from maptidal.mission.capture import CaptureParams, capture
from maptidal.perception.frontend import FrontEndParams

SOURCES = ("truth", "dr", "vo")


def _run(
    scratch: Path, tag: str, scenario, params: CaptureParams, keyframes: int | None, camera=None
) -> dict:
    recording = capture(scratch / tag, scenario, params, seed=0, camera=camera)
    results = {}
    for source in SOURCES:
        results[source] = discover_on_recording(recording, source, FrontEndParams(max_keyframes=keyframes))
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/img/frontend_accuracy.png", help="the figure (PNG)")
    args = parser.parse_args()
    base = load_scenario()
    conditions = [  # label, short label for the figure, turbidity, camera noise, range
        ("clear water, 1 m", "clear\n1 m", 0.0, 0.0, 1.0),
        ("default water (turbidity 0.3, noise 2), 1 m", "default\n1 m", 0.3, 2.0, 1.0),
        ("turbidity 0.6, 1 m", "turb. 0.6\n1 m", 0.6, 2.0, 1.0),
        ("turbidity 0.9, 1 m", "turb. 0.9\n1 m", 0.9, 2.0, 1.0),
        ("camera noise 6 levels, 1 m", "noise 6\n1 m", 0.3, 6.0, 1.0),
        ("default water, 1.5 m", "default\n1.5 m", 0.3, 2.0, 1.5),
        ("default water, 2 m", "default\n2 m", 0.3, 2.0, 2.0),
    ]
    rows, by_observations = [], None
    with tempfile.TemporaryDirectory() as scratch_name:
        scratch = Path(scratch_name)
        print("| condition | mesh error, truth / dr / vo (mm) | tasks, truth / dr / vo | ATE dr / vo (cm) |")
        print("|---|---|---|---|")
        for number, (label, short, turbidity, noise, distance) in enumerate(conditions):
            water = WaterParams(turbidity=turbidity, noise_sigma=noise, vignetting=0.2 if noise else 0.0)
            scenario = dataclasses.replace(base, water=water)
            params = CaptureParams(path="paper", paper=PaperCaptureParams(distance_from_end_wall_m=distance))
            results = _run(scratch, f"c{number}", scenario, params, 7)
            errors = [1000 * results[s].mesh_error_median_m for s in SOURCES]
            tasks = [len(results[s].tasks) for s in SOURCES]
            ates = [100 * results[s].ate_m for s in ("dr", "vo")]
            rows.append((short, turbidity, noise, distance, errors))
            if number == 1:
                by_observations = results["truth"].mesh_error_by_observations
            print(
                f"| {label} | {' / '.join(f'{e:.1f}' for e in errors)} | {' / '.join(map(str, tasks))} | "
                f"{' / '.join(f'{a:.2f}' for a in ates)} |"
            )
        print("\nAbsolute trajectory error (cm), default water:\n")
        print("| path | robot | frames | dr | vo |\n|---|---|---|---|---|")
        for path in ("paper", "sweep"):
            for dvl in (True, False):
                robots = tuple(
                    dataclasses.replace(r, sensors=tuple(s for s in r.sensors if dvl or s != "dvl"))
                    for r in base.robots
                )
                scenario = dataclasses.replace(base, robots=robots)
                results = _run(
                    scratch,
                    f"{path}{dvl}",
                    scenario,
                    CaptureParams(path=path),
                    7 if path == "paper" else None,
                )
                frames = len(results["dr"].run.frames)
                ates = [100 * results[s].ate_m for s in ("dr", "vo")]
                name = "Heavy with DVL" if dvl else "Heavy without DVL"
                print(f"| {path} | {name} | {frames} | {ates[0]:.2f} | {ates[1]:.2f} |")
        # the tails, and at the mission's own image size (maptidal.mission.run.MissionParams.image_size)
        print("\nMesh error median / p90 / max (mm), default water, by image size:\n")
        print("| image | range | truth | dr | vo |\n|---|---|---|---|---|")
        default = dataclasses.replace(base, water=WaterParams(turbidity=0.3, noise_sigma=2.0, vignetting=0.2))
        for width, height in ((640, 400), (320, 200)):
            for distance in (1.0, 2.0):
                paper = PaperCaptureParams(distance_from_end_wall_m=distance)
                params = CaptureParams(path="paper", paper=paper)
                camera = StereoCameraParams(width=width, height=height)
                results = _run(scratch, f"tail{width}{distance}", default, params, 7, camera)
                cells = [
                    " / ".join(
                        f"{1000 * v:.1f}"
                        for v in (r.mesh_error_median_m, r.mesh_error_p90_m, r.mesh_error_max_m)
                    )
                    for r in (results[s] for s in SOURCES)
                ]
                print(f"| {width}x{height} | {distance:g} m | {' | '.join(cells)} |", flush=True)
    print("\nMesh error by fused observations (default water, 1 m, truth):\n")
    print("| observations | vertices | median error (mm) |\n|---|---|---|")
    for row in by_observations:
        print(f"| {row['observations']} | {row['vertices']} | {1000 * row['median_error_m']:.2f} |")
    figure, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    labels = [row[0] for row in rows]
    for k, source in enumerate(SOURCES):
        left.plot(range(len(rows)), [row[4][k] for row in rows], "o-", label=f"pose: {source}")
    left.set_xticks(range(len(rows)), labels, fontsize=8)
    left.set_ylabel("median mesh error (mm)")
    left.set_title("Mesh error against the true surface")
    left.legend()
    right.bar(
        [r["observations"] for r in by_observations], [1000 * r["median_error_m"] for r in by_observations]
    )
    right.set_xlabel("observations fused per landmark")
    right.set_ylabel("median error (mm)")
    right.set_title("Fusion: error falls with observations")
    figure.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(args.out, dpi=120)
    print(f"\nfigure: {args.out}")


if __name__ == "__main__":
    main()
