"""The paper's baselines flown in the closed loop (issue [loop], part 3): ``--planner voronoi`` and
``boustrophedon`` give every robot the baseline's viewpoints from the tank model at the start, as a
mission plan, and the same robots, controllers, channel and CBBA fly them; discovery stays out. The
viewpoints are checked against the baselines' own functions and a hand-written reach band, not against
the mission's filter: a viewpoint above or below the band is flown at the band's edge, as a pilot flies
the plan."""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest

from maptidal.cli import main
from maptidal.evaluation.baselines import boustrophedon_viewpoints, voronoi_viewpoints
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import read_events
from maptidal.mission.params import MissionParams
from maptidal.mission.plan import into_reach, plan_tasks
from maptidal.mission.run import Mission
from maptidal.tank import TankModel

# a robot keeps 0.35 m from the floor and the surface (the mission's reach margin), and the OSB tank
# is 2.0 m deep: a viewpoint outside this band of heights is out of reach
REACH_BAND_M = (0.35, 2.0 - 0.35)


def flown_plan(rows: np.ndarray) -> tuple[np.ndarray, int]:
    """The baseline's rows with their heights held to the reach band by hand (the baselines look level
    at the walls, so a height moved keeps the distance to the wall), and how many were moved."""
    low, high = REACH_BAND_M
    flown = rows.copy()
    flown[:, 2] = np.clip(rows[:, 2], low, high)
    return flown, int(((rows[:, 2] < low) | (rows[:, 2] > high)).sum())


@pytest.fixture(scope="module")
def voronoi_mission(tmp_path_factory):
    scenario, _ = load_mission(None)
    out = tmp_path_factory.mktemp("voronoi")
    document = Mission(
        scenario,
        MissionParams(duration_s=30.0, seed=2, planner="voronoi", perception_process=False, plots=False),
        out,
    ).run()
    return scenario, document, out


def test_every_robot_starts_with_the_baselines_reachable_viewpoints(voronoi_mission):
    scenario, document, out = voronoi_mission
    rows = voronoi_viewpoints(scenario.tank)
    reachable, moved = flown_plan(rows)
    tasks = document["tasks"]
    assert document["planner"] == "voronoi"
    assert moved > 0  # the OSB tank's Voronoi layout has viewpoints above and below the band
    assert document["plan"] == {
        "viewpoints": len(rows),
        "moved_into_reach": moved,
        "merged": 0,
        "unreachable": 0,
    }
    assert len(tasks) == len(reachable) > 0
    for task in tasks:
        assert task["found_by"] == "plan" and task["found_at_s"] == 0.0
        # the task is one of the baseline's viewpoints (positions travel as centimetres)
        distance = np.linalg.norm(reachable[:, :3] - np.asarray(task["position"]), axis=1)
        nearest = int(np.argmin(distance))
        assert distance[nearest] < 0.01
        np.testing.assert_allclose(task["direction"], reachable[nearest, 3:], atol=0.01)
    events = read_events(out)
    planned = [e for e in events if e["kind"] == "planned"]
    assert len(planned) == 1 and planned[0]["t"] == 0.0 and planned[0]["tasks"] == len(reachable)


def test_a_baseline_mission_discovers_nothing_and_flies_its_plan(voronoi_mission):
    _, document, out = voronoi_mission
    assert {t["found_by"] for t in document["tasks"]} == {"plan"}
    kinds = [e["kind"] for e in read_events(out)]
    assert "discovered" not in kinds and "keyframe" not in kinds  # the frames serve localisation only
    assert "flying" in kinds  # the auction gave the plan out and the robots set off
    report = (out / "report.md").read_text()
    assert "| planner | voronoi |" in report
    plan = document["plan"]
    expected = (
        f"| baseline's plan | {plan['viewpoints']} viewpoints: {plan['moved_into_reach']} moved into reach, "
    )
    assert expected in report


def test_the_boustrophedon_plan_is_the_baselines_lanes_held_within_reach():
    scenario, _ = load_mission(None)
    tasks, summary = plan_tasks("boustrophedon", scenario.tank, MissionParams().discovery.standoff)
    rows = boustrophedon_viewpoints(scenario.tank)
    flown, moved = flown_plan(rows)
    # the paper's top and bottom lanes lie 8 cm from the surface and the floor: both are moved
    assert moved == 2 * len(rows) // 3
    assert summary == {"viewpoints": len(rows), "moved_into_reach": moved, "merged": 0, "unreachable": 0}
    assert len(tasks) == len(rows)
    for task, row in zip(tasks, flown, strict=True):
        # a task's pose is quantised (centimetres, and its direction's own step)
        np.testing.assert_allclose(task.position, row[:3], atol=0.006)
        np.testing.assert_allclose(task.direction, row[3:], atol=0.01)
    keys = [t.key for t in tasks]
    assert len(set(keys)) == len(keys) and all(k >> 16 == 255 for k in keys)  # the plan's own key space


def test_viewpoints_moved_into_reach_merge_and_only_level_ones_move():
    scenario, _ = load_mission(None)
    level = [-1.0, 0.0, 0.0]
    rows = np.array(
        [
            [-1.0, 0.2, 0.10, *level],  # below the band: up to 0.35
            [-1.0, 0.2, 0.20, *level],  # below as well, at the same place: merged into the first
            [-1.0, 0.2, 1.95, *level],  # above: down to 1.65
            [-1.0, 0.2, 1.00, *level],  # within: untouched
            [-1.0, 0.2, 0.10, 0.0, 0.0, -1.0],  # looking down: moving it would change what it sees
            [-1.0, 0.2, 0.10, 0.0, 1.0, 0.0],  # looking another way: not merged with the first
        ]
    )
    moved_rows, moved, merged = into_reach(scenario.tank, rows)
    assert (moved, merged) == (4, 1)
    expected = rows[[0, 2, 3, 4, 5]].copy()
    expected[[0, 4], 2] = 0.35
    expected[1, 2] = 1.65
    np.testing.assert_allclose(moved_rows, expected)
    # a tank shallower than twice the margin has no band to move into
    config = scenario.tank.config
    window = dataclasses.replace(config.window, width=0.0)
    shallow = TankModel(dataclasses.replace(config, water_depth=0.6, window=window))
    same, moved, merged = into_reach(shallow, rows)
    assert (moved, merged) == (0, 0)
    np.testing.assert_array_equal(same, rows)


def test_a_tank_with_no_reachable_viewpoint_is_refused_in_one_line(tmp_path):
    scenario, _ = load_mission(None)
    config = scenario.tank.config
    window = dataclasses.replace(config.window, width=0.0)  # no window in a 0.6 m wall
    shallow = TankModel(dataclasses.replace(config, water_depth=0.6, window=window))
    robots = tuple(dataclasses.replace(r, position=(*r.position[:2], 0.3)) for r in scenario.robots)
    scenario = dataclasses.replace(scenario, tank=shallow, robots=robots)
    earlier = set(threading.enumerate())  # an earlier test's mission may not be collected yet
    with pytest.raises(ValueError, match="boustrophedon baseline has no viewpoint the robots can reach"):
        Mission(scenario, MissionParams(duration_s=5.0, planner="boustrophedon", plots=False), tmp_path)
    # refused before any worker or drawing thread started
    assert not [t for t in set(threading.enumerate()) - earlier if t.name.startswith("maptidal-gl")]


def test_an_unknown_planner_is_refused():
    with pytest.raises(ValueError, match="planner must be one of"):
        MissionParams(planner="greedy")
    assert main(["run", "--planner", "greedy"]) == 2
