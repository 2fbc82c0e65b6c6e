"""Map-aware discovery in the closed loop (issue [loop], part 2): the robots discover on their own maps and
the loop never asks the tank model where the water is. The proof: a mission whose tank model is swapped,
after the world was built and rendered, for a tank 1.2 m deep and 1.2 m wide (where nearly every viewpoint
of the real 2 m tank lies above the surface or behind a wall) still discovers and flies tasks in map-aware
mode, where the paper mode would have kept few of them (it keeps what the tank model calls free water)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
from mission_helpers import mission_at_rest

from maptidal.cli import main
from maptidal.envs.scenario import inside_tank
from maptidal.evaluation.free_space import free_space_mask
from maptidal.mission import run as run_module
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import read_events, rebuild
from maptidal.mission.params import MissionParams
from maptidal.mission.plan import inspection_box
from maptidal.mission.run import Mission
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


# long enough for the robots to fly the tasks of their first sweep and start exploring: with seed 1 their
# first surveys began at 82 and 84 s once rule 5 kept the views of faces at the walls' top and foot
# (session 30; at 52 and 67 s before)
FLIGHT_S = 100.0


def _fly(mode: str, out, duration_s: float = FLIGHT_S, apart: bool = True) -> tuple[Mission, dict]:
    scenario, _ = load_mission(None)
    if mode == "map-aware":  # the loop's tank-model check must not even be called
        run_module.reachable = _never
    mission = Mission(
        scenario,
        MissionParams(
            duration_s=duration_s,
            seed=1,
            discovery_mode=mode,
            perception_process=apart,
            plots=False,
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


def test_robots_with_no_task_explore_their_own_maps_frontier_in_the_real_tanks_water(map_aware):
    # the loop was told the wrong tank: the looks come from each robot's own map, and lie in the real
    # tank's water with room for the hull, where the wrong tank would have most of them out of it
    flown, out = map_aware
    events = read_events(out)
    looks = [e for e in events if e["kind"] == "surveying"]
    assert looks, "no robot explored"
    for look in looks:
        assert inside_tank(flown["real_tank"], np.array(look["look"]), 0.3), look
        assert look["gain_m3"] >= MissionParams().frontier.min_gain_m3
    # mission.json counts each robot's surveys
    assert flown["document"]["surveys"] == {
        name: sum(e["robot"] == name for e in looks) for name in flown["document"]["surveys"]
    }
    outside = [not inside_tank(WRONG_TANK, np.array(look["look"]), 0.3) for look in looks]
    assert np.mean(outside) >= 0.5


def test_each_keyframe_reports_what_each_rule_removed(map_aware):
    _, out = map_aware
    keyframes = [e for e in read_events(out) if e["kind"] == "keyframe"]
    assert keyframes
    for event in keyframes:
        rules = event["rules"]
        removed = sum(
            rules[k]
            for k in ("outside", "no_support", "not_planar", "bridging", "too_steep", "not_free", "redundant")
        )
        assert 0 <= rules["lifted"] <= rules["candidates"]
        assert 0 <= rules["refitted"] <= rules["candidates"]
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
    looks = [e for e in read_events(tmp_path / "inline") if e["kind"] == "surveying"]
    assert looks == [e for e in read_events(map_aware[1]) if e["kind"] == "surveying"]


def test_an_idle_robot_surveys_its_best_look_waits_for_a_teammate_and_then_has_explored(tmp_path):
    with mission_at_rest(tmp_path) as (mission, params):
        robot = mission.robots["rov0"]
        robot.activity, robot.survey_ended_s = "idle", 10.0
        # its looks are worked out on a frame taken before its last sweep ended: stale, it waits
        robot.frontier, robot.frontier_frame_s = np.array([[-1.0, 0.5, 1.0, 3.0, 0.0, 2.0, 1.5]]), 9.0
        mission._explore(robot, 11.0)
        assert robot.activity == "idle" and not robot.explored
        # a fresh one: it flies to the look and sweeps there, and its centre ends at the look
        robot.frontier_frame_s = 10.5
        mission._explore(robot, 11.0)
        assert robot.activity == "survey" and robot.surveyed[-1] == pytest.approx([-1.0, 0.5, 1.0])
        end = robot.route.at(robot.route.duration + 1.0)
        assert end.position == pytest.approx([-1.0, 0.5, 1.0]) and end.yaw == pytest.approx(3.0)
        # no look left but those by a teammate: it waits, up to the task timeout, then has explored
        robot.activity, robot.frontier, robot.frontier_held = "idle", np.zeros((0, 7)), 3
        mission._explore(robot, 20.0)
        assert not robot.explored and robot.frontier is None
        robot.frontier = np.zeros((0, 7))
        mission._explore(robot, 10.0 + params.task_timeout_s + 1.0)
        assert robot.explored
        # none at all: explored at once
        other = mission.robots["rov1"]
        other.activity, other.survey_ended_s = "idle", 0.0
        other.frontier, other.frontier_frame_s, other.frontier_held = np.zeros((0, 7)), 1.0, 0
        mission._explore(other, 2.0)
        assert other.explored
    kinds = [(e["kind"], e.get("robot")) for e in read_events(tmp_path)]
    assert ("surveying", "rov0") in kinds and ("explored", "rov0") in kinds and ("explored", "rov1") in kinds


def test_a_robot_that_can_pitch_asks_for_pitched_looks_and_holds_the_pitch_through_the_sweep(tmp_path):
    with mission_at_rest(tmp_path) as (mission, params):
        robot = mission.robots["rov0"]
        # the Heavy pitches 45 deg for a view, under the camera's 54 deg field of view: looks level, 45
        # deg down and 45 deg up
        assert robot.max_pitch_deg == params.max_pitch_deg == 45.0
        assert mission._look_params(robot).pitches_deg == (0.0, 45.0, -45.0)
        robot.max_pitch_deg = 30.0  # capped at what it pitches for a view
        assert mission._look_params(robot).pitches_deg == (0.0, 30.0, -30.0)
        robot.max_pitch_deg = 0.0  # a frame that cannot pitch: level looks alone
        assert mission._look_params(robot).pitches_deg == (0.0,)
        robot.max_pitch_deg = 45.0
        # a robot without a DVL looks level: pitched at the floor it would lose its visual fixes
        without = mission.robots["rov1"]
        assert not without.has_dvl and without.max_pitch_deg == 45.0
        assert mission._look_params(without).pitches_deg == (0.0,)
        request = mission._explore_request(dataclasses.replace(robot, activity="idle", explored=False), 5.0)
        assert request is not None and request.params.pitches_deg == (0.0, 45.0, -45.0)
        # its looks leave a teammate's vicinity to it, unless the teammate said it had nothing left to do
        agent = mission.auction.agents[robot.index]
        agent.peer_positions[without.index] = (np.array([-1.0, -0.5, 1.0]), 3.0)
        asking = dataclasses.replace(robot, activity="idle", explored=False)
        np.testing.assert_allclose(mission._explore_request(asking, 5.0).teammates, [[-1.0, -0.5, 1.0, 2.0]])
        agent.peer_idle[without.index] = True
        assert len(mission._explore_request(asking, 5.0).teammates) == 0
        agent.peer_idle[without.index] = False
        # a look 40 deg nose down: the robot pitches on its way there and holds it through the sweep
        robot.activity, robot.survey_ended_s = "idle", 10.0
        pitch = math.radians(40.0)
        robot.frontier, robot.frontier_frame_s = np.array([[-1.0, 0.5, 1.0, 3.0, pitch, 2.0, 1.5]]), 10.5
        mission._explore(robot, 11.0)
        assert robot.activity == "survey"
        approach = robot.route.legs[0].duration
        halfway = mission._reference(robot, 11.0 + approach / 2)
        assert halfway.pitch == pytest.approx(pitch / 2, rel=0.05)
        for t in np.linspace(approach, robot.route.duration, 7):
            assert mission._reference(robot, 11.0 + t).pitch == pytest.approx(pitch), t
    (surveying,) = [e for e in read_events(tmp_path) if e["kind"] == "surveying"]
    assert surveying["pitch_deg"] == pytest.approx(40.0)
    with mission_at_rest(tmp_path / "level", survey_pitch_deg=0.0) as (mission, _):
        assert mission._look_params(mission.robots["rov0"]).pitches_deg == (0.0,)


def _turn_s(degrees: float, rate_deg_s: float) -> float:
    """How long a turn of ``degrees`` takes from rest to rest at ``rate_deg_s``, reached in 1 s (the
    loop's yaw acceleration is its yaw rate per second): a trapezoid, ramps of 1 s each way, or, for a
    turn too short to reach the rate (under the two ramps' rate x 1 s), a triangle."""
    if degrees >= rate_deg_s:
        return degrees / rate_deg_s + 1.0
    return 2.0 * math.sqrt(degrees / rate_deg_s)


def test_each_robot_sweeps_as_wide_and_as_fast_as_its_settings_say(tmp_path):
    settings = {"survey_sweep_deg": 30.0, "survey_sweep_no_dvl_deg": 0.0, "sweep_rate_dvl_deg_s": 36.0}
    with mission_at_rest(tmp_path, **settings) as (mission, params):
        rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
        assert rov0.has_dvl and not rov1.has_dvl
        # the first sweep, where the team starts: 60 deg one way, 120 back, 60 home, at the same rate for
        # both (a robot with a DVL that set off sooner met its teammate on the boustrophedon's lanes)
        rate = params.yaw_rate_deg_s
        for robot in (rov0, rov1):
            mission._start_exploring(robot, 0.0)
            expected = 2 * _turn_s(params.explore_yaw_deg, rate) + _turn_s(2 * params.explore_yaw_deg, rate)
            assert robot.route.duration == pytest.approx(expected)
        # a survey: the robot with the DVL sweeps 30 deg either side at 36 deg/s, the one without none
        look = np.array([[-1.0, 0.5, 1.0, 3.0, 0.0, 2.0, 1.5]])
        for robot in (rov0, rov1):
            robot.activity, robot.survey_ended_s = "idle", 10.0
            robot.frontier, robot.frontier_frame_s = look.copy(), 10.5
            mission._explore(robot, 11.0)
            assert robot.activity == "survey"
        assert len(rov0.route.legs) == 4 and len(rov1.route.legs) == 1
        sweep_s = rov0.route.duration - rov0.route.legs[0].duration
        assert sweep_s == pytest.approx(2 * _turn_s(30.0, 36.0) + _turn_s(60.0, 36.0))
        headings = [rov0.route.at(rov0.route.starts[1] + t).yaw for t in np.linspace(0, sweep_s, 200)]
        offsets = np.degrees(np.remainder(np.array(headings) - 3.0 + math.pi, 2 * math.pi) - math.pi)
        assert offsets.min() == pytest.approx(-30.0, abs=0.5)
        assert offsets.max() == pytest.approx(30.0, abs=0.5)
    # by default the robot with the DVL sweeps a look as its first sweep, at 39 deg/s; the one without
    # takes the look's own view
    with mission_at_rest(tmp_path / "defaults") as (mission, params):
        assert (params.survey_sweep_deg, params.survey_sweep_no_dvl_deg) == (params.explore_yaw_deg, 0.0)
        for robot in mission.robots.values():
            robot.activity, robot.survey_ended_s = "idle", 10.0
            robot.frontier, robot.frontier_frame_s = look.copy(), 10.5
            mission._explore(robot, 11.0)
        rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
        sweep_s = rov0.route.duration - rov0.route.legs[0].duration
        width = params.explore_yaw_deg
        assert sweep_s == pytest.approx(2 * _turn_s(width, 39.0) + _turn_s(2 * width, 39.0))
        assert len(rov1.route.legs) == 1


def test_with_survey_without_dvl_off_only_the_robots_with_a_dvl_survey(tmp_path):
    with mission_at_rest(tmp_path, survey_without_dvl=False) as (mission, _):
        look = np.array([[-1.0, 0.5, 1.0, 3.0, 0.0, 2.0, 1.5]])
        for name in ("rov0", "rov1"):
            robot = mission.robots[name]
            robot.activity, robot.survey_ended_s = "idle", 10.0
            robot.frontier, robot.frontier_frame_s = look.copy(), 10.5
            mission._explore(robot, 11.0)
        assert mission.robots["rov0"].has_dvl and mission.robots["rov0"].activity == "survey"
        rov1 = mission.robots["rov1"]
        assert not rov1.has_dvl and rov1.activity == "idle" and rov1.explored and rov1.surveyed == []
    explored = [e for e in read_events(tmp_path) if e["kind"] == "explored"]
    assert [(e["robot"], e["surveys"], e.get("without_dvl")) for e in explored] == [("rov1", 0, True)]


def test_a_robot_that_stops_short_of_its_viewpoint_gives_the_task_up_only_once_still_for_stall_s(tmp_path):
    with mission_at_rest(tmp_path) as (mission, params):
        robot = mission.robots["rov0"]
        here = np.array([-1.0, 0.0, 1.0])
        assert not mission._stalled(robot, here, True, 100.0)  # it starts watching
        assert not mission._stalled(robot, here + [0.04, 0.0, 0.0], True, 100.0 + params.stall_s - 0.1)
        # 4 cm in 10 s: stuck
        assert mission._stalled(robot, here + [0.04, 0.0, 0.0], True, 100.0 + params.stall_s)
        # moving on resets the watch; so do reaching the goal, giving way and being lost
        assert not mission._stalled(robot, here + [0.2, 0.0, 0.0], True, 111.0)
        assert not mission._stalled(robot, here + [0.2, 0.0, 0.0], True, 111.0 + params.stall_s - 0.1)
        assert not mission._stalled(robot, here + [0.2, 0.0, 0.0], False, 130.0)
        robot.yielding = True
        assert not mission._stalled(robot, here, True, 140.0)
        assert not mission._stalled(robot, here, True, 140.0 + 2 * params.stall_s)
        robot.yielding, robot.lost = False, True
        assert not mission._stalled(robot, here, True, 200.0)
        assert not mission._stalled(robot, here, True, 200.0 + 2 * params.stall_s)
    with pytest.raises(ValueError, match="stall_s"):
        MissionParams(stall_s=-1.0)


@pytest.mark.parametrize("dense", [True, False])
def test_each_keyframes_dense_depth_maps_the_walls_where_they_are(tmp_path, dense):
    """With ``dense_depth`` on, every robot's map holds its keyframes' dense stereo points, and they lie
    on the real tank's surface (the tank's own triangles, which the matching never sees); off, none."""
    from scipy.spatial import cKDTree

    scenario, _ = load_mission(None)
    params = MissionParams(
        duration_s=6.0,
        seed=2,
        perception_process=False,
        plots=False,
        map_aware=dataclasses.replace(
            MissionParams().map_aware, dense_depth=dense, dense_candidates_m=0.25 if dense else 0.0
        ),
    )
    mission = Mission(scenario, params, tmp_path)
    mission.run()
    maps = mission.perception.maps
    # the maps know the surface's datum and the steepest view the Heavies fly: their pitch for a view
    # and the tolerance a view is judged by
    for robot_map in maps.values():
        assert robot_map.params.surface_z == scenario.tank.height
        assert robot_map.params.max_view_pitch_deg == params.max_pitch_deg + params.direction_tolerance_deg
    # ... and each inspects the region it explores: its exploration radius about where it was launched
    for spec in scenario.robots:
        region = maps[spec.name].params
        assert region.region_radius_m == params.frontier.explore_radius_m
        assert np.allclose(region.region_centre, spec.position, atol=0.02)
        # ... within the box of the walls it was sent to inspect; it explores that box grown by the water
        # its views stand in
        box = inspection_box(params, scenario.tank)
        np.testing.assert_allclose(region.region_box, box)
        reach = params.discovery.standoff + region.clearance_m
        np.testing.assert_allclose(mission.explore_params.explore_box, [box[0] - reach, box[1] + reach])
        # ... and counts in a look's gain what it reveals of the box, grown as rule 1 grows it
        tolerance = region.plane_tolerance_m
        np.testing.assert_allclose(mission.explore_params.gain_box, [box[0] - tolerance, box[1] + tolerance])
    # with dense candidates a keyframe has more candidates than its mesh has faces; without, as many
    keyframes = [e for e in read_events(tmp_path) if e["kind"] == "keyframe" and "rules" in e]
    assert keyframes
    extra = [e["rules"]["candidates"] - e["faces"] for e in keyframes]
    assert (max(extra) > 0) if dense else (max(extra) == 0)
    surface = [robot_map.surface for robot_map in maps.values()]
    if not dense:
        assert all(len(points) == 0 for points in surface)
        return
    assert all(len(points) > 100 for points in surface)
    points = np.concatenate([np.stack(list(points.values())) for points in surface])
    # the tank's surface sampled every 2 cm or finer on each triangle: a point's distance to the nearest
    # sample is its distance to the surface within 1.5 cm
    samples = []
    for a, b, c in scenario.tank.scene_triangles():
        n = max(
            2, int(np.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)) / 0.02))
        )
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1))
        keep = i + j <= n
        u, v = i[keep] / n, j[keep] / n
        samples.append(a + u[:, None] * (b - a) + v[:, None] * (c - a))
    distance, _ = cKDTree(np.concatenate(samples)).query(points, k=1)
    assert np.median(distance) < 0.03 and np.percentile(distance, 80) < 0.1


def test_the_robots_dense_depth_knows_the_cameras_noise(tmp_path):
    """The texture test of each robot's dense depth is set from the scenario's camera noise, as a
    calibration would give it; with the water model off the images carry no noise."""
    scenario, _ = load_mission(None)
    assert scenario.water.noise_sigma > 0
    with mission_at_rest(tmp_path / "noisy", scenario) as (mission, _):
        for front in mission.perception.fronts.values():
            assert front.params.dense.pixel_noise_sigma == scenario.water.noise_sigma
    clear = dataclasses.replace(scenario, water=dataclasses.replace(scenario.water, enabled=False))
    with mission_at_rest(tmp_path / "clear", clear) as (mission, _):
        for front in mission.perception.fronts.values():
            assert front.params.dense.pixel_noise_sigma == 0.0


def test_the_views_of_a_maps_gaps_are_minted_as_tasks_found_without_a_keyframe(tmp_path):
    """A frame's answer with no keyframe (no faces) but gap views (maptidal.map_discovery.gap_views): each
    becomes a task of the robot's, in the ledger and the event log, marked as a gap's."""
    from maptidal.mission.perception import FrameResult

    gaps = np.array([[-1.0, 0.9, 1.0, 0.0, 1.0, 0.0], [-1.0, -0.9, 1.0, 0.0, -1.0, 0.0]])
    with mission_at_rest(tmp_path) as (mission, _):
        robot = mission.robots["rov1"]
        result = FrameResult("rov1", 5.0, None, None, 0, 0, np.zeros((0, 7)), 0.0, 0.0, gap_tasks=gaps)
        mission._use_frame_result(robot, result, 6.0)
        known = mission.auction.agents[robot.index].tasks
        assert len(known) == 2
        assert np.allclose([t.position for t in known], gaps[:, :3])
        assert len(mission.tasks) == 2
    found = [e for e in read_events(tmp_path) if e["kind"] == "discovered"]
    assert len(found) == 2 and all(e["gap"] and e["robot"] == "rov1" for e in found)
    assert not [e for e in read_events(tmp_path) if e["kind"] == "keyframe"]


def test_the_maps_settings_in_a_mission_file_are_checked(tmp_path, capsys):
    from maptidal.mission.config import load_mission, prepare_mission
    from maptidal.paths import asset

    base = asset("scenarios", "mission.toml").read_text()
    path = tmp_path / "mission.toml"

    def refused(setting: str) -> str:
        # `maptidal run` on the mission file with ``setting``: its one line of error (status 2)
        path.write_text(base + f"\n[mission]\n{setting}\nduration_s = 5\n")
        status = main(["run", "--scenario", str(path), "--out", str(tmp_path / "out")])
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1
        return err[0]

    assert "dense_depth must be true or false" in refused('dense_depth = "yes"')
    assert "survey_without_dvl must be true or false" in refused("survey_without_dvl = 0")
    assert "dense_candidates_m" in refused("dense_candidates_m = -0.25")
    path.write_text(base + "\n[mission]\ndense_depth = false\n")
    _, settings = load_mission(path)
    assert settings["map_aware"].dense_depth is False
    path.write_text(base + "\n[mission]\ndense_candidates_m = 0.25\n")
    _, settings = load_mission(path)
    assert settings["map_aware"].dense_candidates_m == 0.25 and settings["map_aware"].dense_depth is True
    path.write_text(base + "\n[mission]\nsurvey_without_dvl = false\n")
    _, params = prepare_mission(path)
    assert params.survey_without_dvl is False


def test_perception_reviews_the_path_against_the_views_taken_on_its_map():
    """``perception._review``: of the tasks on the robot's path, the keys of those whose views the done
    tasks' views leave fewer than min_new_points cells to; tasks neither on the path nor done are
    neither reviewed nor counted as taken."""
    from maptidal.discovery import DiscoveryParams
    from maptidal.map_discovery import MapAwareParams, RobotMap
    from maptidal.mission.perception import FrameJob, _review
    from maptidal.perception.recording import CameraPose

    ys, zs = np.meshgrid(np.arange(-2.0, 2.0, 0.05), np.arange(0.0, 2.0, 0.05))
    wall = np.column_stack([np.full(ys.size, 3.0), ys.ravel(), zs.ravel()])
    robot_map = RobotMap(MapAwareParams())
    robot_map.add_keyframe(np.array([1.0, 0.0, 1.0]), np.arange(len(wall)), wall)
    rows = np.array(
        [
            [2.0, 0.0, 1.0, 1.0, 0.0, 0.0],  # done
            [2.0, 0.02, 1.0, 1.0, 0.0, 0.0],  # on the path, as good as the done one: retired
            [2.0, 1.6, 1.0, 1.0, 0.0, 0.0],  # on the path, mostly new: kept
            [2.0, 1.6, 1.0, 1.0, 0.0, 0.0],  # open, not on the path: not reviewed, not taken
        ]
    )
    pose = CameraPose(np.zeros(3), np.eye(3))
    job = FrameJob(
        "rov0",
        0.0,
        None,
        None,
        pose,
        pose,
        rows,
        existing_keys=np.array([10, 11, 12, 13]),
        existing_done=np.array([True, False, False, False]),
        to_review=np.array([False, True, True, False]),
    )
    discovery = DiscoveryParams()

    def keys(found):
        return [found[0].tolist(), found[1].tolist()]

    assert keys(_review(robot_map, job, discovery)) == [[11], []]
    nothing_done = dataclasses.replace(job, existing_done=np.zeros(4, bool))
    assert keys(_review(robot_map, nothing_done, discovery)) == [[], []]
    assert keys(_review(robot_map, dataclasses.replace(job, to_review=None), discovery)) == [[], []]
    # the views taken not asked for: nothing is retired for them
    assert keys(_review(robot_map, dataclasses.replace(job, review_taken=False), discovery)) == [[], []]
    # repeats: nothing done; a teammate's task of lower key (robot 0's, key 2) holds the first task on
    # the path (robot 1's); the second, 1.6 m along, is a view of its own; a task not a stand-in counts not
    teammates = dataclasses.replace(
        nothing_done,
        existing_keys=np.array([2, 1 << 16 | 0, 1 << 16 | 1, 1 << 16 | 2]),
        stand_ins=np.ones(4, bool),
    )
    assert keys(_review(robot_map, teammates, discovery)) == [[], [1 << 16 | 0]]
    gave_up = dataclasses.replace(teammates, stand_ins=np.array([False, True, True, True]))
    assert keys(_review(robot_map, gave_up, discovery)) == [[], []]
    # one robot's own views are not judged against each other; nor the lower key against the higher
    own = dataclasses.replace(teammates, existing_keys=np.array([2, 3, 4, 5]))
    assert keys(_review(robot_map, own, discovery)) == [[], []]
    higher = dataclasses.replace(teammates, existing_keys=np.array([1 << 16 | 9, 0, 1, 2]))
    assert keys(_review(robot_map, higher, discovery)) == [[], []]
    # a task the views taken retire is not judged a repeat as well
    both = dataclasses.replace(teammates, existing_done=job.existing_done)
    assert keys(_review(robot_map, both, discovery)) == [[1 << 16 | 0], []]


@pytest.mark.parametrize(("taken", "repeats"), [(False, False), (True, False), (False, True), (True, True)])
def test_a_frame_asks_for_the_reviews_the_mission_settings_ask_for(tmp_path, taken, repeats):
    """The job a frame sends to perception reviews the open tasks on the robot's path only when
    ``retire_taken`` or ``retire_repeats`` is on; the views taken count only with ``retire_taken``, and
    every task but those the robot gave up may stand in for a repeat only with ``retire_repeats``."""
    with mission_at_rest(tmp_path, retire_taken=taken, retire_repeats=repeats) as (mission, _):
        robot = mission.robots["rov0"]
        agent = mission.auction.agents[robot.index]
        kept = agent.discover_task([-1.0, 0.2, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
        dropped = agent.discover_task([-1.0, -0.6, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
        agent.build_bundle(0.0)
        robot.skipped.add(dropped.key)
        jobs = []
        mission._draw_frame = lambda snapshot, job: jobs.append(job) or np.zeros((2, 2, 3), np.uint8)
        mission._see(robot, 1.0)
        mission._frames.pop(robot.name).result()
        (job,) = jobs
        if not (taken or repeats):
            assert job.to_review is None and job.stand_ins is None
            return
        order = [int(k) for k in job.existing_keys]
        assert sorted(order) == sorted([kept.key, dropped.key])
        assert job.to_review.tolist() == [key == kept.key for key in order]
        assert job.review_taken is taken
        if repeats:
            assert job.stand_ins.tolist() == [key != dropped.key for key in order]
        else:
            assert job.stand_ins is None


def test_a_task_counts_for_the_survey_whose_frame_found_it(tmp_path):
    """A task found on a frame taken during a survey counts for that survey, whenever the frame's answer
    comes (a frame later); one found on a frame before or after every survey counts for none; a survey
    the robot left standing down is not counted at all. ``mission.json``'s ``survey_outcomes`` and the
    report's table say so."""
    with mission_at_rest(tmp_path, duration_s=0.5) as (mission, _):
        robot = mission.robots["rov0"]
        row = np.array([[-1.0, 0.0, 1.0, 1.0, 0.0, 0.0]])
        look = np.array([[-1.0, 0.5, 1.0, 3.0, 0.0, 2.0, 1.5]])
        for start in (10.0, 100.0):
            robot.activity, robot.survey_ended_s, robot.explored = "idle", start - 1.0, False
            robot.frontier, robot.frontier_frame_s = look.copy(), start - 0.5
            mission._explore(robot, start)
            mission._advance_activity(robot, start + robot.route.duration + 0.1)
        first_end = robot.survey_log[0]["end_s"]
        mission._mint(robot, row, now=first_end + 0.5, frame_s=first_end - 0.5)  # answered after it ended
        mission._mint(robot, row, now=60.0, frame_s=59.0)  # between the surveys
        mission._mint(robot, row + [0.0, 0.3, 0.0, 0.0, 0.0, 0.0], now=5.0, frame_s=4.0)  # before both
        assert [entry["tasks"] for entry in robot.survey_log] == [1, 0]
        robot.activity, robot.survey_ended_s = "idle", 149.0
        robot.frontier, robot.frontier_frame_s = look.copy(), 149.5
        mission._explore(robot, 150.0)
        robot.lost_at_s = 140.0
        mission._stand_down(robot, 160.0)  # it leaves the survey: not one it flew
        assert robot.activity == "idle" and len(robot.survey_log) == len(robot.surveyed) == 2
        document = mission._write_final(200.0, time.perf_counter(), finished=False)
    outcome = document["survey_outcomes"]["rov0"]
    assert outcome["surveys"] == 2 and outcome["with_tasks"] == 1 and outcome["timed_out"] == 0
    second = robot.survey_log[1]
    assert outcome["seconds_without_tasks"] == pytest.approx(second["end_s"] - second["start_s"], abs=1e-3)
    report = (tmp_path / "report.md").read_text()
    assert "## What the surveys found" in report and "| rov0 | 2 | 1 | 0 |" in report


def test_a_robot_that_has_explored_says_when_and_why(tmp_path):
    """With no look worth a trip a robot has explored: its ``explored`` event, ``mission.json``'s
    ``explored`` and the report's table say when, and what its last search ran out of (here the best
    look's gain under the one a look must reveal); ``maptidal report``'s rebuild from the event log says
    the same. A robot with looks left near a teammate only waits: it has not explored."""
    summary = {"why": "too little to see", "frontier_voxels": 23, "stands": 8, "best_gain_m3": 0.0776}
    with mission_at_rest(tmp_path, duration_s=0.5) as (mission, _):
        robot = mission.robots["rov0"]
        robot.activity, robot.survey_ended_s, robot.explored = "idle", 20.0, False
        robot.frontier, robot.frontier_frame_s = np.zeros((0, 7)), 21.0
        robot.frontier_held, robot.frontier_summary = 2, {**summary, "why": ""}
        mission._explore(robot, 22.0)
        assert not robot.explored and robot.explored_why is None  # waiting for the teammate to move on
        robot.frontier, robot.frontier_frame_s = np.zeros((0, 7)), 23.0
        robot.frontier_held, robot.frontier_summary = 0, summary
        mission._explore(robot, 24.0)
        assert robot.explored
        document = mission._write_final(30.0, time.perf_counter(), finished=False)
    least = mission._look_params(robot).min_gain_m3
    assert document["explored"]["rov0"] == {"t": 24.0, **summary, "min_gain_m3": least}
    assert document["explored"]["rov1"] is None
    (event,) = [e for e in read_events(tmp_path) if e["kind"] == "explored"]
    assert (
        event["robot"] == "rov0" and event["why"] == "too little to see" and event["best_gain_m3"] == 0.0776
    )
    report = (tmp_path / "report.md").read_text()
    assert f"at 24 s: too little to see: the best look 0.078 m^3 of the {least:g} m^3" in report
    assert "| rov1 | 0 | 0 | 0 | 0 | 0 | not explored |" in report
    (tmp_path / "mission.json").unlink()  # the rebuild has the event log alone
    rebuilt = rebuild(tmp_path, mission.scenario.tank)
    assert rebuilt["explored"] == {"rov0": document["explored"]["rov0"]}
