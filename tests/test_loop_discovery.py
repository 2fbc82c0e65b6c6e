"""Map-aware discovery in the closed loop (issue [loop], part 2): the robots discover on their own maps and
the loop never asks the tank model where the water is. The proof: a mission whose tank model is swapped,
after the world was built and rendered, for a tank 1.2 m deep and 1.2 m wide (where nearly every viewpoint
of the real 2 m tank lies above the surface or behind a wall) still discovers and flies tasks in map-aware
mode, where the paper mode would have kept few of them (it keeps what the tank model calls free water)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from maptidal.cli import main
from maptidal.evaluation.free_space import free_space_mask
from maptidal.mission import run as run_module
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import read_events
from maptidal.mission.run import Mission, MissionParams
from maptidal.tank import LadderConfig, TankConfig, TankModel, WindowConfig

REACHABLE = run_module.reachable


def _never(*args, **kwargs):
    raise AssertionError("map-aware discovery asked the tank model where the water is")


WRONG_TANK = TankModel(
    TankConfig(
        water_depth=1.2,
        end_wall_width=1.2,
        angled_length=0.3,
        side_length=3.0,
        window=WindowConfig(width=0.0),
        ladder=LadderConfig(rails=0),
    )
)


def _fly(mode: str, out, duration_s: float = 40.0, apart: bool = True) -> tuple[Mission, dict]:
    scenario, _ = load_mission(None)
    if mode == "map-aware":  # the loop's tank-model check must not even be called
        run_module.reachable = _never
    mission = Mission(
        scenario,
        MissionParams(
            duration_s=duration_s, seed=1, discovery_mode=mode, perception_process=apart, plots=False
        ),
        out,
    )
    real_tank = scenario.tank
    # the world is built and drawn from the real tank; from here on the loop is told another one
    mission.scenario = dataclasses.replace(scenario, tank=WRONG_TANK)
    try:
        document = mission.run()
    finally:
        run_module.reachable = REACHABLE
    return mission, {"document": document, "real_tank": real_tank}


@pytest.fixture(scope="module")
def map_aware(tmp_path_factory):
    out = tmp_path_factory.mktemp("map_aware")
    _, flown = _fly("map-aware", out)
    return flown, out


def test_map_aware_discovery_does_not_need_the_tank_model(map_aware):
    flown, _ = map_aware
    document = flown["document"]
    tasks = document["tasks"]
    assert document["discovery"] == "map-aware"
    assert len(tasks) >= 3
    assert sum(bool(task["completed"]) for task in tasks) >= 1
    # the tasks the robots found on their own maps lie in the real tank's free water, as a robot sees it:
    # the tank model never told them where that was
    rows = np.array([[*t["position"], *t["direction"]] for t in tasks])
    assert free_space_mask(flown["real_tank"], rows).mean() >= 0.8
    # ... and the wrong tank calls most of them out of the water: had the loop asked it, they were gone
    assert free_space_mask(WRONG_TANK, rows).mean() < 0.5


def test_each_keyframe_reports_what_each_rule_removed(map_aware):
    _, out = map_aware
    keyframes = [e for e in read_events(out) if e["kind"] == "keyframe"]
    assert keyframes
    for event in keyframes:
        rules = event["rules"]
        removed = sum(rules[k] for k in ("no_support", "not_planar", "bridging", "not_free", "redundant"))
        assert removed + rules["final"] == rules["candidates"]
        assert rules["final"] == event["new_tasks"]


@pytest.mark.parametrize("argv", [["run", "--discovery", "bogus"], ["batch", "--discovery", "x"]])
def test_an_unknown_discovery_mode_is_refused(argv, capsys):
    assert main([*argv, "--out", "/nonexistent/never"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice" in err[0]


def test_an_unknown_discovery_mode_in_a_mission_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "mission.toml"
    from maptidal.paths import asset

    base = asset("scenarios", "mission.toml").read_text()
    path.write_text(base + '\n[mission]\ndiscovery = "sideways"\nduration_s = 5\n')
    status = main(["run", "--scenario", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "discovery must be one of" in err[0]


def test_each_robots_map_grows_the_same_in_the_worker_process_and_inline(map_aware, tmp_path):
    # the robots' maps live in the perception worker (sent there at the start, grown there); inline they
    # grow in the mission's process. A frame's answer is taken one frame later either way, so the two
    # missions are the same, task for task
    flown, _ = map_aware
    _, inline = _fly("map-aware", tmp_path / "inline", apart=False)
    assert inline["document"]["parallel"]["perception"] == "inline"
    assert inline["document"]["tasks"] == flown["document"]["tasks"]
