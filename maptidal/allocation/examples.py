"""The example auction scenarios of ``assets/scenarios/``, made from the OSB tank itself.

Their robots start in the tank's water and their tasks are inspection viewpoints of its walls, in the
tank frame (x towards the end wall, which lies at x = 0; y left facing it; z up from the floor):

- ``auction_2x20.json``: two robots and the 20 Voronoi viewpoints of the evaluated walls, over a clean
  500 bit/s channel;
- ``auction_dynamic.json``: three robots and 16 boustrophedon viewpoints, one needing a tool, over a
  lossy channel with outages; a robot fails, one joins, two tasks are discovered during the mission
  and one is completed.

Run ``python -m maptidal.allocation.examples`` after a change to the tank or the baselines to rewrite
them; a test checks that the committed files are what this module writes.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from maptidal.evaluation.baselines import VoronoiParams, boustrophedon_viewpoints, voronoi_viewpoints
from maptidal.files import atomic_write_text
from maptidal.paths import asset
from maptidal.tank import TankModel, load_tank_config

HEADER_KEY = "about"


def _tasks(rows: np.ndarray, first: int = 0, requires: dict[int, list[str]] | None = None) -> list[dict]:
    requires = requires or {}
    return [
        {
            "id": f"t{first + k}",
            "position": [round(float(v), 3) for v in row[:3]],
            "direction": [round(float(v), 4) for v in row[3:6]],
            "requires": requires.get(first + k, ["camera"]),
        }
        for k, row in enumerate(rows)
    ]


def example_scenarios(tank: TankModel | None = None) -> dict[str, dict]:
    """The example scenario documents, by file name."""
    tank = tank or TankModel(load_tank_config())
    voronoi = voronoi_viewpoints(tank, VoronoiParams(seed=0))
    lanes = boustrophedon_viewpoints(tank)
    plan, later = lanes[:16], lanes[16:18]
    found = _tasks(later)
    for k, (task, robot, time_s) in enumerate(zip(found, ("r2", "r0"), (600, 650), strict=True)):
        task.update(id=f"found{k}", discovered_by=robot, time_s=time_s)
    return {
        "auction_2x20.json": {
            HEADER_KEY: "Two robots, at most 10 tasks each, and the 20 Voronoi viewpoints of the OSB tank "
            "(tank frame, m); written by maptidal.allocation.examples.",
            "robots": [
                {"id": "r0", "position": [-1.5, 1.0, 1.0], "speed": 0.5, "capabilities": ["camera", "dvl"]},
                {"id": "r1", "position": [-1.5, -1.0, 1.0], "speed": 0.5, "capabilities": ["camera", "dvl"]},
            ],
            "tasks": _tasks(voronoi),
            "channel": {"bandwidth_bps": 500, "loss": 0.0, "range_m": 100, "latency_s": 0.0, "seed": 1},
            "bundle_limit": 10,  # without a limit one robot takes every task: each insertion costs little
        },
        "auction_dynamic.json": {
            HEADER_KEY: "Three robots and 16 boustrophedon viewpoints of the OSB tank (tank frame, m) over a "
            "lossy channel; r1 fails, r3 joins, two tasks are found during the mission and t0 is done. "
            "Written by maptidal.allocation.examples.",
            "robots": [
                {"id": "r0", "position": [-3.0, 0.8, 1.0], "speed": 0.5, "capabilities": ["camera", "dvl"]},
                {
                    "id": "r1",
                    "position": [-4.0, -0.8, 1.2],
                    "speed": 0.4,
                    "capabilities": ["camera", "dvl", "tool"],
                },
                {
                    "id": "r2",
                    "position": [-5.0, 0.0, 0.8],
                    "speed": 0.6,
                    "capabilities": ["camera"],
                    "energy_per_m": 0.5,
                },
            ],
            "tasks": _tasks(plan, requires={3: ["camera", "tool"]}) + found,
            "channel": {
                "bandwidth_bps": 300,
                "loss": 0.3,
                "range_m": 50,
                "latency_s": 0.2,
                "jitter_s": 1.0,
                "seed": 3,
                "mean_up_s": 60,
                "mean_down_s": 20,
                "random_outages_until_s": 900,
                "outages": [{"start_s": 100, "end_s": 160, "robots": ["r0", "r2"]}],
            },
            "bundle_limit": 10,
            "timing": {"failure_timeout_s": 120, "heartbeat_s": 30},
            "events": [
                {"time_s": 300, "kind": "fail", "robot": "r1"},
                {
                    "time_s": 700,
                    "kind": "join",
                    "robot": {
                        "id": "r3",
                        "position": [-5.0, 0.5, 1.0],
                        "speed": 0.5,
                        "capabilities": ["camera", "tool"],
                    },
                },
                {"time_s": 1000, "kind": "done", "robot": "r0", "task": "t0"},
            ],
        },
    }


def scenario_text(document: dict) -> str:
    """A scenario document as the committed file's text."""
    return json.dumps(document, indent=1) + "\n"


def write_examples(folder: str | Path | None = None) -> list[Path]:
    """Write the example scenarios into ``folder`` (default: the bundled scenarios folder)."""
    folder = Path(folder) if folder else asset("scenarios")
    return [atomic_write_text(folder / name, scenario_text(doc)) for name, doc in example_scenarios().items()]


if __name__ == "__main__":
    for path in write_examples():
        print(path)
