"""No task dies with its finder (issue [truthful-loop], part 4): a robot's own discoveries leave first and
oldest first, a record a teammate overheard is not relayed to it again, the lost-task accounting against
hand-made ledgers, and the failure scenario in the loop (3 robots, rov1 failing at 60 s)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from maptidal.allocation.agent import CBBAAgent
from maptidal.allocation.messages import decode, size_of
from maptidal.allocation.scoring import RobotProfile
from maptidal.mission.sharing import sharing_table, tasks_lost

# ---------------------------------------------------------------- the accounting, by hand


def _task(key, finder, found_at, position, direction=(1.0, 0.0, 0.0), completed=False):
    return {
        "id": key,
        "found_by": finder,
        "found_at_s": found_at,
        "position": list(position),
        "direction": list(direction),
        "completed": completed,
    }


def _unit(deg: float) -> tuple[float, float, float]:
    return (math.cos(math.radians(deg)), math.sin(math.radians(deg)), 0.0)


def test_a_failed_robots_discoveries_split_into_done_inherited_rediscovered_and_lost():
    tasks = [
        _task(1, "rov1", 10.0, (0, 0, 1), completed=True),  # done (by anyone)
        _task(2, "rov1", 11.0, (1, 0, 1)),  # a live teammate holds it: inherited
        _task(3, "rov1", 12.0, (2, 0, 1)),  # rov0 found its own view 0.1 m and 5 deg away: rediscovered
        _task(4, "rov1", 13.0, (3, 0, 1)),  # rov0's own is 0.1 m but 15 deg away: lost
        _task(5, "rov1", 14.0, (4, 0, 1)),  # rov0's own is 0.2 m away: lost
        _task(6, "rov1", 15.0, (5, 0, 1)),  # only rov2 heard it, and rov2 failed too: lost
        _task(7, "rov1", 70.0, (6, 0, 1)),  # found after it failed (a clock skew): not counted
        _task(10, "rov0", 20.0, (2.1, 0, 1), _unit(5.0)),
        _task(11, "rov0", 21.0, (3.1, 0, 1), _unit(15.0)),
        _task(12, "rov0", 22.0, (4.2, 0, 1)),
    ]
    learned = {
        "rov0": {2: 30.0, 10: 20.0, 11: 21.0, 12: 22.0},
        "rov1": {k: 10.0 + k for k in range(1, 8)},
        "rov2": {6: 40.0},
    }
    table = tasks_lost(tasks, learned, {"rov1": 60.0, "rov2": 80.0}, 0.15, 10.0)
    row = table["rov1"]
    assert (row["found"], row["done"], row["inherited"], row["rediscovered"], row["lost"]) == (6, 1, 1, 1, 3)
    assert row["lost_ids"] == [4, 5, 6]
    assert row["lost_pct"] == pytest.approx(50.0)
    assert table["rov2"]["found"] == 0 and table["rov2"]["lost_pct"] == 0.0


def test_sharing_delays_are_from_discovery_to_the_first_teammate_that_learned_it():
    tasks = [_task(k, "rov0", float(k), (k, 0, 1)) for k in range(5)]
    learned = {
        "rov0": {k: float(k) for k in range(5)},
        "rov1": {0: 3.0, 1: 9.0, 2: 2.5},  # 2 heard at once (2.5 < found 2.0 + 0.5)
        "rov2": {0: 1.0, 3: 23.0},  # 0: rov2 first, 1 s after
    }
    row = sharing_table(tasks, learned, {})["rov0"]
    delays = [1.0, 8.0, 0.5, 20.0]  # task 4 never heard
    assert (row["found"], row["heard"], row["unheard"]) == (5, 4, 1)
    assert row["delay"]["median_s"] == pytest.approx(float(np.median(delays)))
    assert row["delay"]["max_s"] == pytest.approx(20.0)
    assert row["delay"]["p90_s"] == pytest.approx(float(np.percentile(delays, 90)))


# ---------------------------------------------------------------- what a full message carries


def _pair(n_own: int):
    """Robot 0 has found n_own tasks, in order, 1 s apart; robot 1 has heard robot 0 and nothing else."""
    finder = CBBAAgent(RobotProfile("r0", 0, [0.0, 0.0, -1.0]))
    peer = CBBAAgent(RobotProfile("r1", 1, [5.0, 0.0, -1.0]))
    finder.receive(peer.make_message(0.0), 0.1)  # the finder has heard of its peer: records are owed
    keys = [
        finder.discover_task([0.3 * n, 0.2 * (n % 3), -1.0], [1.0, 0.0, 0.0], now_s=1.0 + n).key
        for n in range(n_own)
    ]
    return finder, peer, keys


def test_a_robots_own_discoveries_leave_oldest_first_within_the_modems_frame():
    finder, peer, keys = _pair(60)
    sent: list[int] = []
    now = 70.0
    for _ in range(6):
        finder.build_bundle(now)
        data = finder.make_message(now, capacity_bytes=256)
        assert len(data) <= 256
        message = decode(data)
        sent += [t.key for t in message.tasks]
        peer.receive(data, now + 0.5)
        finder.receive(peer.make_message(now + 1.0), now + 1.5)  # the peer's ack
        now += 10.0
        if set(keys) <= set(sent):
            break
    assert set(keys) <= set(sent), "the finder never finished sharing what it found"
    first = sent[: len(keys)]
    # each slot takes the oldest records the peer lacks: in the order they were found, none sent twice
    # before the last has gone (the entry of the task it flies to next may take its record ahead)
    ahead = [k for k in first if k in finder.path_keys()[:1]]
    in_order = [k for k in first if k not in ahead]
    assert in_order == sorted(in_order)
    assert set(peer.learned_s) >= set(keys)


def test_own_records_go_before_relayed_ones():
    finder, peer, other = (CBBAAgent(RobotProfile(f"r{i}", i, [3.0 * i, 0.0, -1.0])) for i in range(3))
    hello = {agent.robot.index: agent.make_message(0.0) for agent in (finder, peer, other)}
    for listener in (finder, peer, other):
        for index, data in hello.items():
            if index != listener.robot.index:
                listener.receive(data, 0.1)
    # robot 2 tells the finder of 30 tasks; the peer, out of robot 2's range, lacks them: relays are owed
    for n in range(30):
        other.discover_task([6.0, 0.1 * n, -1.0], now_s=1.0 + n)
    relay = other.make_message(40.0)
    assert len(decode(relay).tasks) == 30
    finder.receive(relay, 40.5)
    for n in range(40):
        finder.discover_task([0.3 * n, 0.2 * (n % 3), -1.0], now_s=1.0 + n)
    finder.build_bundle(60.0)
    message = decode(finder.make_message(60.0, capacity_bytes=size_of(3, 1, 25, 3, 2)))
    origins = [t.key >> 16 for t in message.tasks]
    assert len(origins) >= 20
    assert origins.count(2) == 0  # the room went to its own 40 first


def test_a_record_a_teammate_overheard_is_not_relayed_to_it():
    a, b, c = (CBBAAgent(RobotProfile(f"r{i}", i, [float(i), 0.0, -1.0])) for i in range(3))
    hello = {agent.robot.index: agent.make_message(0.0) for agent in (a, b, c)}
    for listener in (a, b, c):  # everyone has heard everyone
        for index, data in hello.items():
            if index != listener.robot.index:
                listener.receive(data, 0.1)
    for n in range(5):
        a.discover_task([0.2 * n, 1.0, -1.0], now_s=1.0)
    data = a.make_message(2.0)
    assert len(decode(data).tasks) == 5
    b.receive(data, 2.5)
    c.receive(data, 2.5)
    # c's slot has room for its clocks and its ack of a's message only; b overhears that ack
    ack_only = c.make_message(3.0, capacity_bytes=size_of(3, 1, 0, 0))
    assert decode(ack_only).acks == [(0, decode(data).seq)] and not decode(ack_only).tasks
    b.receive(ack_only, 3.5)
    b.build_bundle(4.0)
    relayed = b.make_message(4.0)
    # without the overheard ack b would relay a's five records to c, which holds them already
    assert relayed is None or not [t for t in decode(relayed).tasks if t.key >> 16 == 0]


# ---------------------------------------------------------------- in the loop


@pytest.fixture(scope="module")
def failure_mission(tmp_path_factory):
    from maptidal.mission.config import prepare_mission
    from maptidal.mission.run import Mission

    # the paper's discovery: the bar is about how much of what a robot found dies with it, and needs a
    # robot that found many tasks (docs/mission.md, "Map-aware discovery")
    scenario, params = prepare_mission(
        "assets/scenarios/failure.toml", duration_s=120.0, seed=0, discovery="paper"
    )
    params = dataclasses.replace(params, perception_process=False, plots=False)  # as in a worker
    out = tmp_path_factory.mktemp("failure")
    return Mission(scenario, params, out).run(), out


def test_a_failed_robot_takes_at_most_a_tenth_of_what_it_found_with_it(failure_mission):
    """The issue's bar: with 3 robots at 500 bit/s and rov1 failing at 60 s, the tasks lost are at most
    10 % of those rov1 found (before this, 59 of 87 were never heard by a teammate)."""
    document, _ = failure_mission
    row = document["tasks_lost"]["rov1"]
    assert row["found"] >= 30, "rov1 found too little for the test to show anything"
    assert row["done"] + row["inherited"] + row["rediscovered"] + row["lost"] == row["found"]
    assert row["lost"] <= 0.10 * row["found"], row
    shared = document["sharing"]["rov1"]
    assert shared["heard"] >= 0.9 * shared["found"]
    assert shared["delay"]["max_s"] < 60.0  # bounded: its whole first minute's work left within a minute


def test_the_report_counts_the_tasks_lost(failure_mission):
    document, out = failure_mission
    report = (out / "report.md").read_text()
    assert "## Tasks lost with a failed robot" in report
    lost = document["tasks_lost"]["rov1"]
    assert f"| rov1 | {lost['failed_at_s']:.1f} | {lost['found']} |" in report
    assert "## Sharing what was found" in report
