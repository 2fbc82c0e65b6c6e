"""A task is done only when its view was taken (issue [truthful-loop]): the judgement of a capture
against its task (maptidal/mission/verification.py) on hand-made views, the STABILIZE pitch stick, and
missions where the robot's estimate lies or the vehicle cannot pitch."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from maptidal.controllers.flight_modes import ModeParams, lean_stick, pilot_lean_angles
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import read_events
from maptidal.mission.params import MissionParams
from maptidal.mission.run import Mission
from maptidal.mission.verification import check_view, pitch_to_fly, view_pitch


def test_a_capture_is_judged_on_position_and_full_direction():
    task_position, task_direction = np.array([-1.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    exact = check_view(task_position, task_direction, task_position, task_direction, 0.15, 10.0)
    assert (exact.position_error_m, exact.direction_error_deg, exact.verified) == (0.0, 0.0, True)
    # 12 cm off and 8 deg off in pitch alone (the yaw is right): within both
    pitched = np.array([math.cos(math.radians(8)), 0.0, -math.sin(math.radians(8))])
    near = check_view(task_position + [0.0, 0.12, 0.0], pitched, task_position, task_direction, 0.15, 10.0)
    assert near.position_error_m == pytest.approx(0.12) and near.direction_error_deg == pytest.approx(8.0)
    assert near.verified
    # the right yaw and place but 25 deg of pitch missing: not seen, whatever the yaw says
    level = np.array([1.0, 0.0, 0.0])
    down = np.array([math.cos(math.radians(25)), 0.0, -math.sin(math.radians(25))])
    assert not check_view(task_position, level, task_position, down, 0.15, 10.0).verified
    # in the right direction but 20 cm away: not seen either
    assert not check_view(task_position + [0.2, 0, 0], level, task_position, level, 0.15, 10.0).verified


def test_the_pitch_of_a_view_and_whether_a_vehicle_can_fly_it():
    down_30 = [math.cos(math.radians(30)), 0.0, -math.sin(math.radians(30))]
    assert view_pitch(down_30) == pytest.approx(math.radians(30))  # nose down is positive
    assert view_pitch([0.0, 0.0, 1.0]) == pytest.approx(-math.pi / 2)
    assert pitch_to_fly(math.radians(30), 45.0, 10.0) == pytest.approx(math.radians(30))
    # capped at 45 deg, and 7 deg short of the view: within the tolerance
    assert pitch_to_fly(math.radians(52), 45.0, 10.0) == pytest.approx(math.radians(45))
    assert pitch_to_fly(math.radians(60), 45.0, 10.0) is None
    assert pitch_to_fly(math.radians(8), 0.0, 10.0) == 0.0  # a frame that cannot pitch: level, within
    assert pitch_to_fly(math.radians(-12), 0.0, 10.0) is None


@pytest.mark.parametrize("angle_deg", [-40.0, -10.0, 0.0, 3.0, 25.0, 45.0])
def test_the_lean_stick_asks_stabilize_for_the_lean(angle_deg):
    params = ModeParams()
    stick = lean_stick(math.radians(angle_deg), params)
    assert -1.0 <= stick <= 1.0
    _, pitch = pilot_lean_angles(0.0, stick, params)
    assert pitch == pytest.approx(math.radians(angle_deg))


def test_a_lying_estimator_claims_tasks_the_evaluation_does_not_count(tmp_path, monkeypatch):
    """rov0's estimate is 0.4 m off in x (it believes it is where it is not): it says its tasks are done,
    the true views miss them, and they neither count as verified nor enter the coverage."""
    scenario, _ = load_mission(None)
    mission = Mission(
        scenario, MissionParams(duration_s=45.0, seed=3, perception_process=False, plots=False), tmp_path
    )
    honest = Mission._estimate

    def lying(self, robot):
        estimate = honest(self, robot)
        if robot.name != "rov0":
            return estimate
        return dataclasses.replace(estimate, position=estimate.position + [0.4, 0.0, 0.0])

    monkeypatch.setattr(Mission, "_estimate", lying)
    document = mission.run()
    per_robot = document["done_by_robot"]
    assert per_robot["rov0"]["claimed"] >= 1 and per_robot["rov0"]["verified"] == 0
    done = [e for e in read_events(tmp_path) if e["kind"] == "done"]
    liars = [e for e in done if e["robot"] == "rov0"]
    assert all(not e["verified"] and e["position_error_m"] > 0.25 for e in liars)
    verified = sum(e["verified"] for e in done)
    assert document["coverage"]["occluded"]["n_viewpoints"] == verified


def test_a_vehicle_that_cannot_pitch_declines_pitched_views_and_never_marks_them_done(tmp_path):
    scenario, _ = load_mission(None)
    document = Mission(
        scenario,
        MissionParams(
            duration_s=45.0,
            seed=3,
            max_pitch_deg=0.0,
            discovery_mode="paper",
            perception_process=False,
            plots=False,
        ),
        tmp_path,
    ).run()
    events = read_events(tmp_path)
    declined = [e for e in events if e["kind"] == "declined"]
    assert declined and all("deg of pitch" in e["reason"] for e in declined)
    declined_keys = {e["task"] for e in declined}
    done_keys = {t["id"] for t in document["tasks"] if t["completed"]}
    assert not declined_keys & done_keys
    for task in document["tasks"]:
        if task["id"] in declined_keys:  # each of them needed more pitch than the tolerance
            assert abs(math.degrees(view_pitch(task["direction"]))) > 10.0


def test_bad_tolerances_are_refused():
    for bad in (
        {"position_tolerance_m": 0.0},
        {"direction_tolerance_deg": math.nan},
        {"max_pitch_deg": 90.0},
    ):
        with pytest.raises(ValueError, match="direction_tolerance_deg"):
            MissionParams(**bad)


def test_a_mission_refuses_an_endless_duration_and_events_after_its_end():
    from maptidal.mission.params import MissionEvent

    with pytest.raises(ValueError, match="at most 86400 s"):
        MissionParams(duration_s=1e12)
    late = MissionEvent(1e9, "current", current=(0.1, 0.0, 0.0))
    with pytest.raises(ValueError, match="after the mission's end"):
        MissionParams(duration_s=10.0, events=(late,))
    MissionParams(duration_s=10.0, events=(MissionEvent(5.0, "current", current=(0.1, 0.0, 0.0)),))
