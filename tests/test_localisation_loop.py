"""Localisation in the closed loop (issue [truthful-loop]): a robot without a DVL that is unsure of its
position goes back to where its map is surest, and stays localised; with a DVL the front end's visual
fixes never take the estimate from the DVL; and a motion model whose coefficients are off does not
lose the robot. Judged on the simulator's truth, which the robots never see."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from mission_helpers import mission_at_rest

from maptidal.controllers.estimation import MotionModel
from maptidal.controllers.trajectory import PoseTrajectory, Route
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import read_events, standing_down_spans
from maptidal.mission.params import MissionParams
from maptidal.mission.run import Mission


def test_an_unsure_robot_goes_home_and_is_found_again_only_when_sure(tmp_path):
    with mission_at_rest(tmp_path, duration_s=10.0) as (mission, _):
        robot = mission.robots["rov1"]  # the robot without a DVL
        assert not robot.has_dvl
        mission._start_exploring(robot, 0.0)
        home, home_yaw = robot.home_position.copy(), robot.home_yaw
        robot.visual_updates, robot.position_sigma_m = 1, 0.05
        assert not mission._lost(robot, 0.5)
        robot.position_sigma_m = mission.params.lost_sigma_m + 0.01  # a fix came, but it is unsure
        robot.visual_updates = 2
        assert mission._lost(robot, 1.0) and robot.lost_why == "uncertain"
        # its way home: from where it believes it is to where it explored from, facing that way, and the
        # sweep there
        assert len(robot.recovery.legs) == 4
        end = robot.recovery.at(robot.recovery.duration + 1.0)
        assert end.position == pytest.approx(home) and math.remainder(
            end.yaw - home_yaw, math.tau
        ) == pytest.approx(0)
        # it was flying somewhere else: the lost robot's reference is its way home, not that route
        robot.route = Route(
            [PoseTrajectory(home, home_yaw, home + [1.0, 0.5, 0.0], home_yaw, mission._limits())]
        )
        robot.route_start_s = -100.0
        reference = mission._reference(robot, 1.0 + robot.recovery.duration)
        assert reference.position == pytest.approx(home)
        robot.position_sigma_m = 0.8 * mission.params.lost_sigma_m  # surer, but not by half: still lost
        robot.visual_updates = 3
        assert mission._lost(robot, 2.0)
        robot.position_sigma_m = 0.4 * mission.params.lost_sigma_m
        robot.visual_updates = 4
        assert not mission._lost(robot, 3.0)
        robot.position_sigma_m = 0.01
        assert mission._lost(robot, 3.0 + mission.params.lost_after_s + 0.1)  # no fix for too long
        assert not mission._lost(mission.robots["rov0"], 100.0)  # a DVL robot is never lost
    kinds = [e["kind"] for e in read_events(tmp_path) if e.get("robot") == "rov1"]
    assert kinds == ["position_lost", "position_regained", "position_lost"]


def test_the_time_a_dvl_gives_no_velocity_goes_to_the_front_end_with_the_next_frame(tmp_path):
    """The DVL robot set down on the floor, its beams shorter than their minimum range: each control
    period flown there counts, none flown in open water does, and the next frame hands the sum to its
    front end, which is then unsure as a robot without a DVL (maptidal.perception.odometry)."""
    with mission_at_rest(tmp_path) as (mission, _):
        robot = mission.robots["rov0"]
        assert robot.has_dvl
        front = mission.perception.fronts["rov0"]
        for _ in range(3):  # free water first: a first frame, and periods with the DVL in range
            before = mission.sim.time
            mission.sim.step({})
            mission._count_dvl_dropouts(mission.sim.time - before)
        assert robot.dvl_out_s == 0.0
        mission._see(robot, mission.sim.time)
        mission._frames["rov0"].result()
        assert not front.odometry.unaided
        mission.sim.place("rov0", [-1.0, 0.5, 0.15])  # on the floor
        flown = 0.0
        for _ in range(10):
            before = mission.sim.time
            mission.sim.step({})
            mission._count_dvl_dropouts(mission.sim.time - before)
            flown += mission.sim.time - before
            assert not mission.sim.latest_readings("rov0")["dvl"]["valid"]
        assert robot.dvl_out_s == pytest.approx(flown)
        assert mission.robots["rov1"].dvl_out_s == 0.0  # no DVL: nothing to lose
        mission._see(robot, mission.sim.time)
        mission._frames["rov0"].result()
        assert robot.dvl_out_s == 0.0
        assert front.odometry.unaided


def test_a_robot_that_lost_its_fix_is_found_again_at_its_next_sure_fix(tmp_path):
    # the halved limit is for a robot lost as unsure: one that went without a fix while 8 cm sure of
    # itself (as the default mission's robot without a DVL is) waited for many fixes to halve a limit it
    # never passed
    with mission_at_rest(tmp_path, duration_s=10.0) as (mission, params):
        robot = mission.robots["rov1"]
        mission._start_exploring(robot, 0.0)
        home = robot.home_position.copy()
        robot.visual_updates, robot.position_sigma_m = 1, 0.08
        assert not mission._lost(robot, 0.5)
        lost_at = 0.5 + params.lost_after_s + 0.1
        assert mission._lost(robot, lost_at) and robot.lost_why == "no_fix"
        # it goes home, as any lost robot does, and sweeps there
        assert len(robot.recovery.legs) == 4
        assert robot.recovery.legs[0].at(robot.recovery.legs[0].duration).position == pytest.approx(home)
        # a fix as sure as before (8 cm, over half the 15 cm limit) finds it again
        robot.visual_updates = 2
        assert not mission._lost(robot, lost_at + 1.0)
        # one too unsure does not
        assert mission._lost(robot, lost_at + 2.0 + params.lost_after_s)
        robot.visual_updates, robot.position_sigma_m = 3, params.lost_sigma_m + 0.01
        assert mission._lost(robot, lost_at + 3.0 + params.lost_after_s)
    lost = [e for e in read_events(tmp_path) if e["kind"] == "position_lost"]
    assert [e["why"] for e in lost] == ["no_fix", "no_fix"]
    assert lost[0]["sigma_m"] == pytest.approx(0.08) and lost[0]["unfixed_s"] > params.lost_after_s


def _flying_to_a_view(mission: Mission):
    """rov1, the robot without a DVL, after its sweep, given one view and flying to it at 1 s. Returns the
    robot, its agent and the task."""
    robot = mission.robots["rov1"]
    agent = mission.auction.agents[robot.index]
    mission._start_exploring(robot, 0.0)
    task = agent.discover_task([-1.0, -0.6, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
    agent.build_bundle(0.0)
    assert agent.path_keys() == [task.key]
    robot.activity = "idle"
    mission._advance_activity(robot, 1.0)
    assert robot.activity == "fly" and robot.task_key == task.key and robot.task_losses == 0
    return robot, agent, task


def _lose_twice_on_the_way(mission: Mission, params: MissionParams):
    """The robot without a DVL, given a view, flies to it and is lost twice on the way (found again
    between). Returns the robot, its agent and the task."""
    robot, agent, task = _flying_to_a_view(mission)
    robot.visual_updates, robot.position_sigma_m = 1, 0.08
    assert not mission._lost(robot, 1.0)
    first = 1.0 + params.lost_after_s + 0.1
    assert mission._lost(robot, first) and robot.task_losses == 1
    robot.visual_updates = 2
    assert not mission._lost(robot, first + 1.0)
    mission._advance_activity(robot, first + 1.0)
    assert robot.activity == "fly"  # once: it flies on
    second = first + 1.0 + params.lost_after_s + 0.1
    assert mission._lost(robot, second) and robot.task_losses == 2
    mission._advance_activity(robot, second)
    return robot, agent, task, second


def test_a_robot_lost_twice_on_its_way_to_a_view_gives_the_view_up(tmp_path):
    # lost a second time on the way to the same view, the robot gives the view up for a teammate to win
    with mission_at_rest(tmp_path, duration_s=10.0, lost_give_up=2) as (mission, params):
        robot, agent, task, second = _lose_twice_on_the_way(mission, params)
        assert robot.activity == "idle" and task.key in robot.skipped
        assert task.key not in agent.path_keys()
        # lost while not flying to a view (exploring, idle) counts against no view
        robot.visual_updates = 3
        assert not mission._lost(robot, second + 1.0)
        assert mission._lost(robot, second + 2.0 + params.lost_after_s) and robot.task_losses == 2
        # its next view starts with none counted
        other = agent.discover_task([-1.0, 0.2, 1.0], [1.0, 0.0, 0.0], now_s=second)
        agent.build_bundle(second)
        robot.visual_updates = 4
        assert not mission._lost(robot, second + 3.0 + params.lost_after_s)
        mission._advance_activity(robot, second + 3.0 + params.lost_after_s)
        assert robot.activity == "fly" and robot.task_key == other.key and robot.task_losses == 0
    gave_up = [e for e in read_events(tmp_path) if e["kind"] == "gave_up"]
    assert [(e["robot"], e["task"], e["lost"]) for e in gave_up] == [("rov1", task.key, 2)]
    for bad in (-1, 1.5):
        with pytest.raises(ValueError, match="lost_give_up"):
            MissionParams(lost_give_up=bad)


def test_by_default_a_robot_lost_on_its_way_flies_on_to_the_view(tmp_path):
    # lost_give_up is 0 by default: never given up for being lost (docs/mission.md, "Without a DVL", says why)
    with mission_at_rest(tmp_path, duration_s=10.0) as (mission, params):
        assert params.lost_give_up == 0
        robot, agent, task, _ = _lose_twice_on_the_way(mission, params)
        assert robot.activity == "fly" and task.key in agent.path_keys()
    assert not [e for e in read_events(tmp_path) if e["kind"] == "gave_up"]


def _idle_teammate_heard(mission: Mission, now: float, idle: bool = True) -> float:
    """rov0 explored, with nothing to do (or busy, ``idle`` False), says so over the channel until rov1
    has heard it; returns the time it was heard."""
    teammate = mission.auction.agents[mission.robots["rov0"].index]
    listener = mission.auction.agents[mission.robots["rov1"].index]
    teammate.idle = idle
    teammate.last_change_s = now  # news: it transmits in its next slot
    for step in range(1, 60):
        mission.auction.advance_to(now + step)
        if listener.peer_idle.get(teammate.index) is idle and teammate.index in listener.peer_positions:
            return now + step
    raise AssertionError("rov1 never heard rov0")


def _hand_over_cost_s(mission: Mission, robot, teammate_index: int) -> float:
    """What handing ``robot``'s view over costs, worked out here from the channel's slot and the
    teammate's heard position: a TDMA cycle (one slot per robot), then the flight at the routes' speed."""
    agent = mission.auction.agents[robot.index]
    position, _ = agent.peer_positions[teammate_index]
    cycle = mission.auction.channel.params.tdma_slot_s * len(mission.robots)
    return cycle + math.dist(robot.view[0], position) / mission.params.speed_m_s


def _fly_on(mission: Mission, now: float, seconds: float) -> float:
    """The mission's clock runs ``seconds`` on from ``now``, each robot's time going to what it does and
    whether it is lost (:meth:`Mission._count_time_use`); returns the new time."""
    mission._count_time_use(now + seconds, seconds)
    return now + seconds


def _fly_and_lose(mission: Mission, params: MissionParams, idle: bool = True):
    """rov1 flies to a view while rov0 says it is idle (or busy), then loses its fix on the way. Returns
    the robot, its agent, the task and the time it was lost."""
    robot, agent, task = _flying_to_a_view(mission)
    heard = _idle_teammate_heard(mission, 1.0, idle=idle)
    robot.visual_updates, robot.position_sigma_m, robot.fixes_seen = 1, 0.08, 0
    assert not mission._lost(robot, 1.0)
    now = _fly_on(mission, 1.0, heard - 1.0)  # found, flying: no time lost on the way
    mission._advance_activity(robot, now)
    assert robot.activity == "fly" and agent.path_keys() == [task.key]
    assert mission._lost_on_the_way_s(robot, now) == 0.0
    lost_at = _fly_on(mission, now, params.lost_after_s + 0.1)
    assert mission._lost(robot, lost_at)
    return robot, agent, task, lost_at


def test_a_robot_lost_on_its_way_hands_the_view_to_a_teammate_with_nothing_left_to_do(tmp_path):
    # the robot with a DVL has finished; its teammate without one, lost on its way to its last view for
    # as long as the hand-over would take, hands the view over, and the finished robot wins it
    with mission_at_rest(tmp_path, duration_s=10.0, lost_hand_over=True) as (mission, params):
        robot, agent, task, lost_at = _fly_and_lose(mission, params)
        teammate = mission.auction.agents[mission.robots["rov0"].index]
        cost = _hand_over_cost_s(mission, robot, teammate.index)
        assert 5.0 < cost < params.peer_fresh_s  # a cycle of some 8 s and a flight of a few seconds
        # lost for less than the hand-over costs: it keeps the view (it may well be found on the way)
        now = _fly_on(mission, lost_at, cost - 0.5)
        mission._advance_activity(robot, now)
        assert robot.activity == "fly" and agent.path_keys() == [task.key]
        # found again, it flies on, and the time it flies found does not count
        robot.visual_updates = 2
        assert not mission._lost(robot, now)
        now = _fly_on(mission, now, 1.0)
        mission._advance_activity(robot, now)
        assert robot.activity == "fly" and mission._lost_on_the_way_s(robot, now) == pytest.approx(cost - 0.5)
        # lost again, for as long as the hand-over costs all told, but found again before it decides:
        # found, it flies on
        now = _fly_on(mission, now, params.lost_after_s + 0.1)
        assert mission._lost(robot, now)
        now = _fly_on(mission, now, 1.0)
        robot.visual_updates = 3
        assert not mission._lost(robot, now)
        mission._advance_activity(robot, now)
        assert robot.activity == "fly" and agent.path_keys() == [task.key]
        # lost once more: it hands the view over at once
        now = _fly_on(mission, now, params.lost_after_s + 0.1)
        assert mission._lost(robot, now)
        mission._advance_activity(robot, now)
        assert robot.activity == "idle" and task.key in robot.skipped and agent.path_keys() == []
        mission.auction.advance_to(now + 30.0)
        assert teammate.path_keys() == [task.key]
        # its next view starts with no time lost
        now = _fly_on(mission, now, 30.0)
        other = agent.discover_task([-1.2, -0.4, 1.0], [1.0, 0.0, 0.0], now_s=now)
        agent.build_bundle(now)
        mission._advance_activity(robot, now)
        assert robot.task_key == other.key and mission._lost_on_the_way_s(robot, now) == 0.0
    handed = [e for e in read_events(tmp_path) if e["kind"] == "handed_over"]
    assert [(e["robot"], e["task"], e["to"]) for e in handed] == [("rov1", task.key, "rov0")]
    assert handed[0]["lost_s"] == pytest.approx(cost + 0.5, abs=0.01)


@pytest.mark.parametrize("case", ["busy", "stale", "off", "no dvl"])
def test_a_lost_robot_keeps_its_view_when_no_teammate_is_known_to_be_free(tmp_path, case):
    # the teammate busy, or heard idle longer ago than peer_fresh_s, or the rule off (the default:
    # docs/mission.md, "Without a DVL", says why), or the idle teammate without a DVL (it may be standing
    # down, lost itself, and would bid on nothing): it keeps the view, though lost on the way for longer
    # than the hand-over costs
    settings = {} if case == "off" else {"lost_hand_over": True}
    with mission_at_rest(tmp_path, duration_s=10.0, **settings) as (mission, params):
        assert params.lost_hand_over == (case != "off")
        if case == "no dvl":
            mission.robots["rov0"].has_dvl = False
        robot, agent, task, lost_at = _fly_and_lose(mission, params, idle=case != "busy")
        # lost until just before the teammate's message is too old (or just after, when stale)
        heard_s = agent.peer_positions[mission.robots["rov0"].index][1]
        lost_s = heard_s + params.peer_fresh_s + (0.5 if case == "stale" else -0.5) - lost_at
        assert _hand_over_cost_s(mission, robot, mission.robots["rov0"].index) < lost_s
        now = _fly_on(mission, lost_at, lost_s)
        mission._advance_activity(robot, now)
        assert robot.activity == "fly" and agent.path_keys() == [task.key]
    assert not [e for e in read_events(tmp_path) if e["kind"] == "handed_over"]
    for bad in ("yes", 1):
        with pytest.raises(ValueError, match="lost_hand_over"):
            MissionParams(lost_hand_over=bad)


def test_a_mission_file_turns_the_hand_over_on(tmp_path):
    from maptidal.mission.config import prepare_mission
    from maptidal.paths import asset

    path = tmp_path / "mission.toml"
    path.write_text(asset("scenarios", "mission.toml").read_text() + "\n[mission]\nlost_hand_over = true\n")
    _, params = prepare_mission(path)
    assert params.lost_hand_over is True
    _, params = prepare_mission(None)
    assert params.lost_hand_over is False


def test_a_robot_still_lost_after_its_recovery_stands_down_until_it_has_a_fix(tmp_path):
    # lost on its way to a view, home and swept, and still lost: it cannot tell when it reaches any view,
    # so it releases its tasks to its teammate and flies none; found again, it bids again
    with mission_at_rest(tmp_path, duration_s=10.0) as (mission, params):
        assert params.lost_stand_down
        teammate = mission.auction.agents[mission.robots["rov0"].index]
        robot, agent, task = _flying_to_a_view(mission)
        robot.visual_updates, robot.position_sigma_m = 1, 0.08
        assert not mission._lost(robot, 1.0)
        lost_at = 1.0 + params.lost_after_s + 0.1
        mission._reference(robot, lost_at)
        assert robot.lost and not agent.standing_down
        # within its recovery it holds its task
        mission._reference(robot, lost_at + robot.recovery.duration - 0.1)
        assert not agent.standing_down and agent.path_keys() == [task.key]
        # its recovery over, still lost: it stands down, and leaves its task
        done_at = lost_at + robot.recovery.duration + 0.1
        mission._reference(robot, done_at)
        assert agent.standing_down and agent.path_keys() == [] and robot.activity == "idle"
        assert task.key not in robot.skipped  # not given up for good
        # it holds where it is and sweeps there: it does not fly home on an estimate that far off
        estimate = mission._estimate(robot).position
        assert len(robot.recovery.legs) == 3
        for t in np.linspace(0.0, robot.recovery.duration, 7):
            assert robot.recovery.at(t).position == pytest.approx(estimate)
        # no task, and no look, while it stands down, though its map has a look worth a trip
        robot.frontier, robot.frontier_frame_s = np.array([[-1.0, 0.5, 1.0, 0.0, 0.0, 2.0, 1.5]]), done_at
        robot.survey_ended_s = 0.0
        mission._advance_activity(robot, done_at)
        assert robot.activity == "idle"
        # the teammate hears the release and wins the task; the mission does not wait on the lost robot
        mission.auction.advance_to(done_at + 30.0)
        assert teammate.path_keys() == [task.key]
        # found again, it bids again
        robot.visual_updates = 2
        assert not mission._lost(robot, done_at + 31.0) and not agent.standing_down
    events = [e for e in read_events(tmp_path) if e.get("robot") == "rov1"]
    stood = [e for e in events if e["kind"] == "stood_down"]
    assert len(stood) == 1 and stood[0]["left"] == "fly"
    assert stood[0]["lost_s"] == pytest.approx(done_at - lost_at, abs=0.01)
    assert [e["kind"] for e in events].count("resumed") == 1
    # the timeline shades it from the stand-down to the resumption
    resumed = next(e["t"] for e in events if e["kind"] == "resumed")
    spans = standing_down_spans(read_events(tmp_path), "rov1", 100.0)
    assert spans == [pytest.approx((stood[0]["t"], resumed - stood[0]["t"]))]


def test_the_spans_a_robot_stood_down_run_to_its_resumption_or_the_end():
    events = [
        {"t": 5.0, "kind": "stood_down", "robot": "rov1"},
        {"t": 6.0, "kind": "stood_down", "robot": "rov0"},
        {"t": 9.0, "kind": "resumed", "robot": "rov1"},
        {"t": 20.0, "kind": "stood_down", "robot": "rov1"},
        {"t": 25.0, "kind": "position_lost", "robot": "rov1"},
    ]
    assert standing_down_spans(events, "rov1", 30.0) == [(5.0, 4.0), (20.0, 10.0)]
    assert standing_down_spans(events, "rov0", 30.0) == [(6.0, 24.0)]
    assert standing_down_spans(events, "rov2", 30.0) == []


def test_a_robot_lost_for_good_is_not_waited_for_and_the_ending_says_so(tmp_path):
    with mission_at_rest(tmp_path, duration_s=10.0) as (mission, _):
        lost, able = mission.robots["rov1"], mission.robots["rov0"]
        task = mission.auction.agents[able.index].discover_task([-1.0, 0.3, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
        mission.auction.agents[able.index].mark_done(task.key, 0.0)
        able.explored = True
        lost.explored = False
        assert not mission._finished()  # the lost robot has not explored and stands for now
        mission.auction.agents[lost.index].stand_down(5.0)
        assert mission._finished()
        assert "rov1 lost, standing down" in mission.ending(5.0, True)
        lost.explored = able.explored = False
        assert "rov1 lost, standing down" in mission.ending(5.0, False)
        mission.auction.agents[able.index].stand_down(5.0)
        assert not mission._finished()  # nobody left able to work


def test_without_standing_down_a_lost_robot_keeps_its_task(tmp_path):
    with mission_at_rest(tmp_path, duration_s=10.0, lost_stand_down=False) as (mission, params):
        robot, agent, task = _flying_to_a_view(mission)
        robot.visual_updates, robot.position_sigma_m = 1, 0.08
        mission._lost(robot, 1.0)
        lost_at = 1.0 + params.lost_after_s + 0.1
        mission._reference(robot, lost_at)
        mission._reference(robot, lost_at + 2 * robot.recovery.duration + 0.2)
        assert robot.lost and not agent.standing_down and agent.path_keys() == [task.key]


def test_a_perturbed_motion_model_is_heavier_and_less_damped():
    model = MotionModel((10.0, 20.0, 30.0), (1.0, 2.0, 3.0), (4.0, 5.0, 6.0), net_buoyancy_n=2.0)
    off = model.perturbed(0.3)
    assert off.inertia == pytest.approx((13.0, 26.0, 39.0))
    assert off.linear_damping == pytest.approx((0.7, 1.4, 2.1))
    assert off.quadratic_damping == pytest.approx((2.8, 3.5, 4.2))
    assert off.net_buoyancy_n == pytest.approx(1.4)
    with pytest.raises(ValueError, match="error"):
        model.perturbed(1.0)


MISSIONS = {  # id: (motion model error, relocalisation)
    "exact-model": (0.0, True),
    "model-30pc-off": (0.3, True),
    "model-30pc-off-no-relocalisation": (0.3, False),
}


@pytest.fixture(scope="module")
def missions(tmp_path_factory):
    """180 s of the default mission (seed 2) for each of MISSIONS, run on first use (the bounds below were
    first measured over 300 s, then 240 s; 180 s keeps the test suite within its time)."""
    done: dict[str, tuple[dict, object]] = {}

    def get(name: str) -> tuple[dict, object]:
        if name not in done:
            error, relocalise = MISSIONS[name]
            scenario, _ = load_mission(None)
            out = tmp_path_factory.mktemp(name)
            # the paper's discovery, as when these bounds were measured: its many tasks keep the robots
            # flying, and localisation under way is what is tested
            params = MissionParams(
                duration_s=180.0,
                seed=2,
                motion_model_error=error,
                relocalise=relocalise,
                discovery_mode="paper",
                perception_process=False,  # the same mission as in a worker, without its start
                plots=name == "exact-model",  # whose report is checked
            )
            done[name] = (Mission(scenario, params, out).run(), out)
        return done[name]

    return get


def test_both_robots_stay_localised_over_a_mission(missions):
    """With the simulator's own coefficients: the robot without a DVL within 15 cm (median) and 60 cm
    (worst) of the truth over the mission, and doing its share (verified views); the robot with one within
    5 cm and 15 cm. Before relocalisation the robot without a DVL was 26 cm off (median) after 240 s, and
    growing."""
    document, _ = missions("exact-model")
    figures = document["localisation"]
    assert figures["rov1"]["median_m"] < 0.15, figures
    assert figures["rov1"]["max_m"] < 0.6, figures
    assert figures["rov0"]["median_m"] < 0.05, figures
    assert figures["rov0"]["max_m"] < 0.15, figures
    # its share: the bound was 5 verified views in 240 s; at that rate 180 s gives 3.75
    assert document["done_by_robot"]["rov1"]["verified"] >= 4, document["done_by_robot"]


def test_with_its_motion_model_30pc_off_the_robot_still_works_by_relocalising(missions):
    """Coefficients 30 % off the way that misleads most: the robot without a DVL still does verified
    work, where without relocalisation it does none, ever too unsure of its position to fly to a task (it
    spends the mission going home to find a fix). It is not well localised: 17 to 40 cm off (median) in
    this session's runs, so the bound here is only 50 cm (docs/mission.md, "Localisation for
    the whole mission")."""
    document, _ = missions("model-30pc-off")
    figures = document["localisation"]
    assert figures["rov1"]["median_m"] < 0.5, figures
    with_map = document["done_by_robot"]["rov1"]["verified"]
    assert with_map >= 3, document["done_by_robot"]
    without, _ = missions("model-30pc-off-no-relocalisation")
    assert without["done_by_robot"]["rov1"]["verified"] < with_map, without["done_by_robot"]
    assert without["localisation"]["rov0"]["median_m"] < 0.05  # the DVL robot does not need the map


def test_the_report_plots_and_tabulates_the_localisation(missions):
    document, out = missions("exact-model")
    rows = np.loadtxt(out / "trajectories.csv", delimiter=",", skiprows=1, usecols=(2, 3, 5, 6))
    assert (out / "localisation.png").stat().st_size > 10_000
    report = (out / "report.md").read_text()
    assert "## Localisation" in report and "![localisation](localisation.png)" in report
    worst = max(f["max_m"] for f in document["localisation"].values())
    assert worst == pytest.approx(np.hypot(rows[:, 0] - rows[:, 2], rows[:, 1] - rows[:, 3]).max(), abs=1e-4)


def test_with_the_pose_from_the_truth_every_robot_flies_on_the_truth(tmp_path):
    """``pose_source = "truth"`` is an oracle localisation: each frame sets what a robot flies on to its
    true pose, so the robot without a DVL, its motion model 30 % off, stays within a frame's dead
    reckoning of the truth (before, it meshed on the truth but flew on its dead reckoning alone) and
    its views are verified."""
    scenario, _ = load_mission(None)
    params = MissionParams(
        duration_s=60.0, seed=1, pose_source="truth", motion_model_error=0.3, perception_process=False
    )
    document = Mission(scenario, dataclasses.replace(params, plots=False), tmp_path).run()
    figures = document["localisation"]
    assert figures["rov1"]["median_m"] < 0.03, figures
    assert figures["rov1"]["max_m"] < 0.1, figures
    done = document["done_by_robot"]["rov1"]
    assert done["claimed"] >= 1 and done["verified"] == done["claimed"], done
