"""Where each robot's mission time went (issue [loop], maptidal.mission.time_use): the occupation of each
state, its precedence, and the seconds and spans a robot's periods add up to."""

from __future__ import annotations

import itertools

import pytest

from maptidal.mission.outputs import team_time_use
from maptidal.mission.time_use import OCCUPATIONS, TimeUse, occupation


def test_an_occupation_is_the_first_that_holds():
    for activity, lost, yielding, explored in itertools.product(
        ("explore", "survey", "fly", "idle", "waiting", "failed"), (False, True), (False, True), (False, True)
    ):
        got = occupation(activity, lost, yielding, explored)
        if activity in ("waiting", "failed"):  # out of the mission, whatever else holds
            assert got == ("not launched" if activity == "waiting" else "failed")
        elif lost:
            assert got == "lost"
        elif yielding:
            assert got == "giving way"
        elif activity == "idle":
            assert got == ("done" if explored else "idle")
        else:
            assert got == {"explore": "first sweep", "survey": "surveying", "fly": "tasks"}[activity]
        assert got in OCCUPATIONS


def test_an_unknown_activity_or_occupation_is_refused():
    with pytest.raises(ValueError, match="unknown activity"):
        occupation("swim", False, False, False)
    with pytest.raises(ValueError, match="unknown occupation"):
        TimeUse().add(1.0, 0.5, "swimming")


def test_the_periods_add_up_to_seconds_and_end_to_end_spans():
    use = TimeUse()
    periods = ["first sweep"] * 3 + ["tasks"] * 2 + ["giving way"] + ["tasks"] * 4 + ["done"] * 2
    for n, kind in enumerate(periods, start=1):
        use.add(0.5 * n, 0.5, kind)
    assert use.seconds == {"first sweep": 1.5, "tasks": 3.0, "giving way": 0.5, "done": 1.0}
    assert use.spans(6.0) == [
        (0.0, 1.5, "first sweep"),
        (1.5, 2.5, "tasks"),
        (2.5, 3.0, "giving way"),
        (3.0, 5.0, "tasks"),
        (5.0, 6.0, "done"),
    ]
    document = use.as_dict(6.0)
    assert list(document["seconds"]) == ["first sweep", "tasks", "giving way", "done"]  # OCCUPATIONS' order
    assert document["spans"][-1] == [5.0, 6.0, "done"]
    assert TimeUse().spans(3.0) == [] and TimeUse().as_dict(3.0) == {"seconds": {}, "spans": []}
    # the seconds in one occupation from a moment on, spans cut there: each period's part after it here
    for start in (0.0, 1.0, 2.75, 4.0, 6.0):
        by_period = sum(
            max(0.5 * n - max(0.5 * (n - 1), start), 0.0)
            for n, kind in enumerate(periods, start=1)
            if kind == "tasks"
        )
        assert use.seconds_since("tasks", start, 6.0) == pytest.approx(by_period)
    assert use.seconds_since("lost", 0.0, 6.0) == 0.0 and use.seconds_since("done", 0.0, 5.5) == 0.5


def test_the_batch_counts_the_teams_seconds_surveying_and_lost():
    document = {
        "time_use": {
            "rov0": {"seconds": {"first sweep": 23.0, "surveying": 40.5, "tasks": 30.0}},
            "rov1": {"seconds": {"surveying": 10.0, "lost": 52.25, "giving way": 3.0}},
        }
    }
    assert team_time_use(document) == {"surveying_s": 50.5, "lost_s": 52.25}
    assert team_time_use({}) == {"surveying_s": None, "lost_s": None}  # a mission recorded before it


def test_a_robots_surveys_are_told_by_what_their_frames_found():
    """``survey_outcomes`` counts the surveys, those that found a task, those that timed out, and the
    seconds of all and of those that found none (one still under way ends now); the batch's
    ``fruitless_survey_s`` sums the team's; a document without them gives None."""
    from maptidal.mission.outputs import survey_outcomes, team_survey_outcomes

    log = [
        {"start_s": 10.0, "end_s": 40.0, "timed_out": False, "tasks": 2},
        {"start_s": 50.0, "end_s": 110.0, "timed_out": True, "tasks": 0},
        {"start_s": 120.0, "end_s": 150.5, "timed_out": False, "tasks": 0},
        {"start_s": 200.0, "end_s": None, "timed_out": False, "tasks": 0},
    ]
    outcome = survey_outcomes(log, now=212.0)
    assert outcome == {
        "surveys": 4,
        "with_tasks": 1,
        "timed_out": 1,
        "seconds": 30.0 + 60.0 + 30.5 + 12.0,
        "seconds_without_tasks": 60.0 + 30.5 + 12.0,
    }
    assert survey_outcomes([], now=5.0) == {
        "surveys": 0,
        "with_tasks": 0,
        "timed_out": 0,
        "seconds": 0.0,
        "seconds_without_tasks": 0.0,
    }
    document = {"survey_outcomes": {"rov0": outcome, "rov1": survey_outcomes(log[:1], 50.0)}}
    assert team_survey_outcomes(document) == {"fruitless_survey_s": 102.5}
    assert team_survey_outcomes({}) == {"fruitless_survey_s": None}
