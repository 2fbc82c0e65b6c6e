"""The closed-loop mission (issue [mission], started): a short mission through `maptidal run`; its outputs,
its comms figures against the channel's own counters, repeatability, the report rebuilt from the event
log after a kill -9, and bad mission files."""

from __future__ import annotations

import itertools
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import types
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, maptidal_here, run_maptidal

from maptidal.evaluation.coverage import CoverageModel, CoverageParams
from maptidal.mission.config import load_mission
from maptidal.mission.outputs import mission_metrics, read_events, time_to_coverage
from maptidal.mission.params import MissionParams
from maptidal.mission.run import Mission

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def short_mission(tmp_path_factory):
    scenario, _ = load_mission(None)
    out = tmp_path_factory.mktemp("mission")
    # the paper's discovery: these tests of the loop's workings need the many tasks it finds, and an
    # unfinished mission (docs/mission.md, "Map-aware discovery")
    mission = Mission(scenario, MissionParams(duration_s=55.0, seed=3, discovery_mode="paper"), out)
    # every robot's true position (its free joint's, by name) after each control period, for the
    # odometry's test
    sim = mission.sim
    positions: dict[str, list] = {name: [] for name in sim.robots}
    address = {name: sim.model.jnt_qposadr[sim.model.body(f"{name}/base").jntadr[0]] for name in positions}
    step = sim.step

    # and each robot's state after each control period, for the time-use test
    states: dict[str, list] = {name: [] for name in sim.robots}

    def recorded_step(commands=None, mode="pilot"):
        result = step(commands, mode)
        for name, track in positions.items():
            track.append(sim.data.qpos[address[name] : address[name] + 3].copy())
            robot = mission.robots[name]
            states[name].append((sim.time, robot.activity, robot.lost, robot.yielding, robot.explored))
        return result

    sim.step = recorded_step
    document = mission.run()
    mission.true_positions = {name: np.array(track) for name, track in positions.items()}
    mission.recorded_states = states
    return mission, document, out


def test_each_robots_time_is_told_by_occupation_period_by_period(short_mission):
    """Every control period goes to one occupation, the first that holds of: not launched, failed, lost,
    giving way, then the activity (first sweep, surveying, tasks; idle, or done once explored); counted
    here again from each robot's state after each period, and the spans run end to end."""
    mission, document, _ = short_mission
    end = document["sim_time_s"]
    for name, states in mission.recorded_states.items():
        expected: dict[str, float] = {}
        previous = 0.0
        for time_s, activity, lost, yielding, explored in states:
            if activity == "waiting":
                kind = "not launched"
            elif activity == "failed":
                kind = "failed"
            elif lost:
                kind = "lost"
            elif yielding:
                kind = "giving way"
            else:
                kind = {"explore": "first sweep", "survey": "surveying", "fly": "tasks"}.get(
                    activity, "done" if explored else "idle"
                )
            expected[kind] = expected.get(kind, 0.0) + time_s - previous
            previous = time_s
        use = document["time_use"][name]
        assert use["seconds"].keys() == expected.keys()
        for kind, seconds in expected.items():
            assert use["seconds"][kind] == pytest.approx(seconds, abs=2e-3)
        assert sum(use["seconds"].values()) == pytest.approx(end, abs=2e-3)
        spans = use["spans"]
        assert spans[0][0] == 0.0 and spans[-1][1] == pytest.approx(end, abs=1e-3)
        assert all(a[1] == b[0] and a[2] != b[2] for a, b in itertools.pairwise(spans))
        assert spans[0][2] == "first sweep"  # every robot starts with its sweep
    metrics = mission_metrics(document)
    for key, kind in (("surveying_s", "surveying"), ("lost_s", "lost")):
        total = sum(row["seconds"].get(kind, 0.0) for row in document["time_use"].values())
        assert metrics[key] == pytest.approx(total, abs=1e-6)


def test_a_mission_cut_off_by_its_cap_says_what_was_left(short_mission):
    _, document, out = short_mission
    done = sum(1 for t in document["tasks"] if t["completed"])
    open_tasks = len(document["tasks"]) - done  # in 55 s nobody has given a task up
    assert not document["finished"]
    assert document["ending"].startswith(f"not finished at the {document['sim_time_s']:.1f} s cap")
    assert (
        f"{open_tasks} of {len(document['tasks'])} known tasks neither done nor given up"
        in document["ending"]
    )
    end = [e for e in read_events(out) if e["kind"] == "end"]
    assert end[-1]["ending"] == document["ending"]
    assert f"| ended | {document['ending']} |" in (out / "report.md").read_text()


def test_a_short_mission_discovers_allocates_and_completes_tasks(short_mission):
    mission, document, out = short_mission
    tasks = document["tasks"]
    assert len(tasks) > 5
    done = [t for t in tasks if t["completed"]]
    assert done, "no task completed"
    for task in done:
        assert task["assigned_to"] in mission.robots and (out / task["image"]).is_file()
        assert (
            0 < task["completion_time"] <= document["sim_time_s"]
            and task["found_at_s"] <= task["completion_time"]
        )
    events = read_events(out)
    # allocated without conflicts: no task was inspected by two robots (while the 500 bit/s channel
    # is still carrying news, two bundles may briefly hold the same task: mission.json counts them)
    captured = [e["task"] for e in events if e["kind"] == "done"]
    assert len(captured) == len(set(captured)) == len(done)
    assert isinstance(document["allocation_conflicts"], int)
    assert document["duplicate_inspections"] == len(captured) - len(set(captured)) == 0
    kinds = {e["kind"] for e in events}
    assert {"start", "keyframe", "discovered", "flying", "done", "end"} <= kinds
    # only the captures whose true view was within the task's tolerances are scored
    verified = [t for t in done if t["verified"]]
    assert verified and document["coverage"]["occluded"]["n_viewpoints"] == len(verified)
    assert document["coverage"]["occluded"]["pct_uninspected"] < 100.0
    per_robot = document["done_by_robot"]
    assert sum(r["claimed"] for r in per_robot.values()) == len(done)
    assert sum(r["verified"] for r in per_robot.values()) == len(verified)
    for event in (e for e in events if e["kind"] == "done"):
        within = event["position_error_m"] <= 0.15 and event["direction_error_deg"] <= 10.0
        assert event["verified"] == within
    # rov0 localises on its DVL: what it says it has seen, it has (pitched into the views it needs)
    assert per_robot["rov0"]["claimed"] >= 1
    assert per_robot["rov0"]["verified"] >= 0.8 * per_robot["rov0"]["claimed"]


def test_the_comms_figures_are_the_channels_own_counters(short_mission):
    mission, document, _ = short_mission
    stats = mission.auction.channel.stats
    assert document["comms"]["messages"] == stats.transmissions == len(mission.auction.transmissions) > 0
    assert document["comms"]["bytes"] == stats.bytes == sum(n for _, _, n in mission.auction.transmissions)
    assert document["comms"]["lost"] == stats.lost


def test_every_output_exists_and_parses(short_mission):
    out = short_mission[2]
    saved = json.loads((out / "mission.json").read_text())
    for key in ("realtime_factor", "sim_time_s", "wall_time_s", "coverage", "comms", "tasks", "timing"):
        assert key in saved, key
    assert set(saved["timing"]) == {
        "physics",
        "rendering",
        "perception",
        "discovery",
        "allocation",
        "control",
    }
    rows = (out / "trajectories.csv").read_text().splitlines()
    assert rows[0].startswith("time_s,robot") and len(rows) > 40
    for name in ("top_view.png", "timeline.png", "histogram.png", "voxel_views.png", "report.md"):
        assert (out / name).stat().st_size > 0, name
    # what ran beside the loop, and on what: the drawing thread's and the worker's own seconds
    beside = saved["parallel"]["beside_the_loop_s"]
    assert saved["parallel"]["perception"] == "process" and saved["renderer"]
    assert 0 < beside["rendering"] <= saved["timing"]["rendering"]
    assert beside["perception"] == saved["timing"]["perception"] > 0
    report = (out / "report.md").read_text()
    assert "Where the wall time went" in report and saved["renderer"] in report


def test_a_frames_tasks_enter_the_auction_at_the_robots_next_frame(short_mission):
    # the one-frame latency of perception (maptidal.mission.perception): a keyframe's tasks are minted one
    # frame period after the frame was taken, within the control period the frame clock falls in
    mission, document, out = short_mission
    period = mission.scenario.control_period_s
    events = read_events(out)
    keyframes = [e for e in events if e["kind"] == "keyframe"]
    assert keyframes
    for event in keyframes:
        robot = mission.robots[event["robot"]]
        assert abs(event["t"] - event["frame_s"] - robot.frame_every_s) <= period + 1e-6, event
    found = {t["id"]: t["found_at_s"] for t in document["tasks"]}
    for event in (e for e in events if e["kind"] == "discovered"):
        assert found[event["task"]] == event["t"] and event["frame_s"] < event["t"]
    # the robots' cameras are not in step: rov0's frames fall on the second, rov1's half a second later
    for name, phase in (("rov0", 0.0), ("rov1", 0.5)):
        offsets = {round(e["frame_s"] % 1.0, 2) for e in keyframes if e["robot"] == name}
        assert offsets and all(abs(o - phase) <= period + 1e-6 for o in offsets), (name, offsets)


def test_the_same_seed_gives_the_same_mission_with_perception_apart_or_inline(short_mission, tmp_path):
    # the fixture's perception ran in its worker process; this one runs it in the mission's own process.
    # A frame's answer is taken one frame later either way, so the two missions are the same event for
    # event, not merely alike
    scenario, _ = load_mission(None)
    _, first, first_out = short_mission
    assert first["parallel"]["perception"] == "process"
    again = Mission(
        scenario,
        MissionParams(duration_s=55.0, seed=3, perception_process=False, discovery_mode="paper", plots=False),
        tmp_path,
    ).run()
    assert again["parallel"]["perception"] == "inline"
    assert again["tasks"] == first["tasks"]
    assert again["comms"] == first["comms"]
    assert again["inspected_pct"] == first["inspected_pct"]
    without_start = lambda out: [e for e in read_events(out) if e["kind"] != "start"]  # noqa: E731
    assert without_start(tmp_path) == without_start(first_out)


def test_a_killed_mission_leaves_a_log_the_report_rebuilds(tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(
        [sys.executable, "-m", "maptidal.cli", "run", "--duration", "200", "--out", str(tmp_path)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            log = tmp_path / "events.jsonl"
            if log.is_file() and '"kind": "done"' in log.read_text():
                break
            time.sleep(0.5)
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL
    # the perception worker sees its pipe close and exits: the kill leaves no process behind
    (start,) = [e for e in read_events(tmp_path) if e["kind"] == "start"]
    assert start["perception"]["mode"] == "process"
    worker = start["perception"]["pid"]
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and _alive(worker):
        time.sleep(0.2)
    assert not _alive(worker), f"the perception worker {worker} outlived the killed mission"
    done = run_maptidal("report", tmp_path)
    assert done.returncode == 0, done.stderr
    rebuilt = json.loads((tmp_path / "mission.json").read_text())
    assert rebuilt["rebuilt_from_events"] and not rebuilt["finished"]
    assert rebuilt["ending"] == "killed before its end: rebuilt from the event log"
    assert any(t["completed"] for t in rebuilt["tasks"])
    done_events = [e["task"] for e in read_events(tmp_path) if e["kind"] == "done"]
    assert rebuilt["duplicate_inspections"] == len(done_events) - len(set(done_events))
    assert rebuilt["coverage"]["occluded"]["n_viewpoints"] >= 1
    assert (tmp_path / "report.md").is_file() and (tmp_path / "top_view.png").is_file()


def test_a_rebuilt_report_names_only_the_images_on_disk(short_mission, tmp_path):
    # a task's image is drawn and written on the GL thread just after its "done" event: a mission killed
    # in between leaves an event whose image never reached the disk, and the rebuilt report says so
    out = tmp_path / "mission"
    shutil.copytree(short_mission[2], out)
    done = [e for e in read_events(out) if e["kind"] == "done"]
    assert len(done) >= 2
    (out / done[0]["image"]).unlink()
    assert run_maptidal("report", out).returncode == 0
    images = {t["id"]: t["image"] for t in json.loads((out / "mission.json").read_text())["tasks"]}
    assert images[done[0]["task"]] is None
    assert all(images[e["task"]] == e["image"] and (out / e["image"]).is_file() for e in done[1:])


def test_a_report_is_rebuilt_on_the_tank_the_mission_was_flown_in(short_mission, tmp_path):
    from maptidal.tank import load_tank_config, tank_config_from_dict, tank_config_to_dict

    out = tmp_path / "mission"
    shutil.copytree(short_mission[2], out)
    flown = json.loads((out / "mission.json").read_text())["coverage"]
    (start,) = [e for e in read_events(out) if e["kind"] == "start"]
    assert tank_config_from_dict(start["tank"]) == load_mission(None)[0].tank.config
    # no --scenario: the log's own tank, the same coverage as the mission wrote
    done = run_maptidal("report", out)
    assert done.returncode == 0 and "does not name its tank" not in done.stderr, done.stderr
    assert json.loads((out / "mission.json").read_text())["coverage"] == flown
    # a log that says another tank (variant A): the report is rebuilt on that tank, as --scenario gives it
    variant = ROOT / "tests" / "bench" / "tanks" / "variant_a"
    lines = (out / "events.jsonl").read_text().splitlines()
    first = json.loads(lines[0])
    assert first["kind"] == "start"
    first["tank"] = tank_config_to_dict(load_tank_config(variant / "tank.toml"))
    (out / "events.jsonl").write_text("\n".join([json.dumps(first), *lines[1:]]) + "\n")
    assert run_maptidal("report", out).returncode == 0
    on_variant = json.loads((out / "mission.json").read_text())["coverage"]
    assert on_variant != flown
    explicit = tmp_path / "explicit"
    shutil.copytree(out, explicit)
    assert run_maptidal("report", explicit, "--scenario", variant / "mission.toml").returncode == 0
    assert json.loads((explicit / "mission.json").read_text())["coverage"] == on_variant
    # a log from before the start event named its tank: the default mission's, and a note that says so
    del first["tank"]
    (out / "events.jsonl").write_text("\n".join([json.dumps(first), *lines[1:]]) + "\n")
    done = run_maptidal("report", out)
    assert done.returncode == 0 and "does not name its tank" in done.stderr
    assert json.loads((out / "mission.json").read_text())["coverage"] == flown


def test_a_report_never_invents_figures_and_names_the_file_it_cannot_read(short_mission, tmp_path):
    out = tmp_path / "mission"
    shutil.copytree(short_mission[2], out)
    (out / "mission.json").unlink()  # no snapshot: the comms figures are not known
    assert run_maptidal("report", out).returncode == 0
    report = (out / "report.md").read_text()
    assert "Comms: unknown" in report and "| messages / bytes / lost | unknown |" in report
    events = out / "events.jsonl"
    lines = events.read_text().splitlines()
    events.write_text("\n".join([lines[0], '{"t": 1.0, "robot": "rov0"}', *lines[1:]]) + "\n")
    assert_one_line_error(maptidal_here("report", out), "events.jsonl, line 2: an event needs a 'kind'")
    events.write_text("")
    assert_one_line_error(maptidal_here("report", out), "the event log is empty")


@pytest.mark.parametrize("write", ["snapshot", "final"])
def test_mission_json_waits_for_the_task_images_it_names(monkeypatch, tmp_path, write):
    # a task's image is drawn and written on the GL thread after its "done": hold one back, and neither
    # the periodic mission.json nor the final one may be written before it is on disk
    from maptidal.mission.outputs import MissionWriter

    scenario, _ = load_mission(None)
    mission = Mission(scenario, MissionParams(duration_s=1.0, seed=3, plots=False), tmp_path)
    image = tmp_path / "images" / "held_back.png"
    release = threading.Event()

    def late_image():
        release.wait(10)
        image.write_bytes(b"png")

    mission._captures.append(mission._gl.submit(late_image))
    threading.Timer(0.3, release.set).start()
    written = []
    for method in ("snapshot", "finish"):
        original = getattr(MissionWriter, method)

        def checked(self, document, *rest, _original=original):
            written.append(image.is_file())
            return _original(self, document, *rest)

        monkeypatch.setattr(MissionWriter, method, checked)
    try:
        if write == "snapshot":
            mission._write_snapshot(0.0, 1.0)
        else:
            mission._write_final(0.0, time.perf_counter(), finished=False)
    finally:
        mission.perception.close()
        mission._gl.submit(mission.sim.close).result()
        mission._gl.shutdown()
    assert written == [True]


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie, dead but not yet reaped by init, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.parametrize(
    ("mission_table", "message"),
    [
        ('[[mission.events]]\ntime_s = 5\nkind = "explode"\n', "unknown mission event"),
        ("[mission]\nduration_s = -3\n", "duration"),
        ("[mission]\nclearance_m = -1\n", "clearance_m"),
        ('[mission]\nclearance_m = "far"\n', "clearance_m"),
        ("[mission]\nrender_samples = -1\n", "render_samples"),
        ("[mission]\nrender_samples = 2.5\n", "render_samples"),
        ("[mission]\nperception_process = 1\n", "perception_process"),
        ('[mission]\nwater_backend = "gpu"\n', "water_backend"),
        ("[mission]\nwater_backend = 1\n", "water_backend"),
        ("[mission]\ncommand_rate_hz = 0\n", "command_rate_hz"),
        ('[mission]\ninspect_region = "sea"\n', "inspect_region"),
        ("[mission]\ninspect_box = [[0, 0, 0], [1, -1, 1]]\n", "inspect_box"),
        ("[mission]\ninspect_box = 3\n", "inspect_box"),
        ("[mission]\nretire_taken = 1\n", "retire_taken"),
        ('[mission]\nretire_repeats = "yes"\n', "retire_repeats"),
        ("[mission]\nlost_stand_down = 0\n", "lost_stand_down"),
        ('[mission]\nlost_hand_over = "yes"\n', "lost_hand_over"),
        ('[[mission.events]]\ntime_s = 5\nkind = "fail"\nrobot = "rov7"\n', "rov7"),
        ("[mission]\nspeed = 3\n", "[mission] takes only"),
        ('[[mission.events]]\ntime_s = 5\nkind = "join"\nrobot = "rov9"\n', "rov9"),
        ('[[mission.events]]\ntime_s = 5\nkind = "outage"\n', "positive duration_s"),
        (
            '[[mission.events]]\ntime_s = 5\nkind = "outage"\nduration_s = 3\nrobots = ["rov0"]\n',
            "two robots",
        ),
        (
            '[[mission.events]]\ntime_s = 5\nkind = "join"\nrobot = "rov0"\n'
            '[[mission.events]]\ntime_s = 6\nkind = "join"\nrobot = "rov1"\n',
            "at least one must start",
        ),
        (
            '[[mission.events]]\ntime_s = 5\nkind = "join"\nrobot = "rov1"\n'
            '[[mission.events]]\ntime_s = 9\nkind = "join"\nrobot = "rov1"\n',
            "joins once",
        ),
        (
            '[[mission.events]]\ntime_s = 20\nkind = "join"\nrobot = "rov1"\n'
            '[[mission.events]]\ntime_s = 10\nkind = "fail"\nrobot = "rov1"\n',
            "before it joins",
        ),
    ],
)
def test_bad_mission_files_give_one_line_and_status_2(tmp_path, mission_table, message):
    from maptidal.paths import asset

    base = asset("scenarios", "mission.toml").read_text()
    path = tmp_path / "bad.toml"
    path.write_text(base + "\n" + mission_table)
    assert_one_line_error(maptidal_here("run", "--scenario", path, "--out", tmp_path / "o"), message)


def test_run_takes_its_scenario_named_or_as_batch_takes_it(tmp_path):
    """``maptidal run SCENARIO`` reads the file ``--scenario`` names (the same one-line refusal of its
    bad [mission] table); the same file both ways is one scenario; two different files are refused."""
    from maptidal.paths import asset

    path = tmp_path / "bad.toml"
    path.write_text(asset("scenarios", "mission.toml").read_text() + "\n[mission]\nspeed = 3\n")
    out = tmp_path / "o"
    assert_one_line_error(maptidal_here("run", path, "--out", out), "[mission] takes only")
    assert_one_line_error(
        maptidal_here("run", path, "--scenario", path, "--out", out), "[mission] takes only"
    )
    other = asset("scenarios", "mission.toml")
    assert_one_line_error(
        maptidal_here("run", path, "--scenario", other, "--out", out), "two scenarios given"
    )


def test_a_robot_outside_the_tank_is_refused(tmp_path):
    from maptidal.paths import asset

    text = asset("scenarios", "mission.toml").read_text().replace("[-1.6, 0.6, 1.0]", "[-1.6, 0.6, 9.0]")
    path = tmp_path / "outside.toml"
    path.write_text(text)
    assert_one_line_error(maptidal_here("run", "--scenario", path, "--out", tmp_path / "o"))


def test_a_failed_robots_tasks_pass_to_the_survivor(tmp_path):
    """rov1 fails at 40 s. Once the others have not heard from it for the agents' failure timeout (40 s),
    CBBA releases its tasks and the survivor takes them: at the end no task is still rov1's in the
    survivor's view, and every task rov1 held when it failed (and had shared) is the survivor's or done.
    (Both robots carry a DVL here, so that the survivor can fly what it takes.)"""
    import dataclasses

    from maptidal.allocation.messages import DONE
    from maptidal.mission.params import MissionEvent

    scenario, _ = load_mission(None)
    with_dvl = tuple(
        dataclasses.replace(r, sensors=tuple(dict.fromkeys((*r.sensors, "dvl")))) for r in scenario.robots
    )
    scenario = dataclasses.replace(scenario, robots=with_dvl)
    # perception inline: the same mission as in a worker process (test_mission.py proves it), without
    # a second interpreter's start
    params = MissionParams(
        duration_s=110.0,
        seed=1,
        events=(MissionEvent(40.0, "fail", "rov1"),),
        perception_process=False,
        plots=False,
    )
    mission = Mission(scenario, params, tmp_path)
    document = mission.run()
    survivor, failed = mission.auction.agents[0], mission.auction.agents[1]
    winners = survivor.winners()
    # a task rov1 found and failed before telling anyone is lost with it; the others it held must pass on
    held_at_failure = [failed.tasks[j].key for j in failed.bundle if failed.tasks[j].key in winners]
    assert held_at_failure, "rov1 held no shared task when it failed: the test shows nothing"
    assert 1 in survivor.failed
    assert all(winners[key] in (0, DONE) for key in held_at_failure), {k: winners[k] for k in held_at_failure}
    assert all(w != 1 for w in winners.values())
    assert document["robots"]["rov1"] == "failed"
    assert not any(
        t["assigned_to"] == "rov1" and t["completion_time"] and t["completion_time"] > 40.0
        for t in document["tasks"]
    )


def _third_robot(scenario, position=(-2.4, 0.0, 1.1)):
    """The mission scenario with a third Heavy, rov2 (with a DVL), parked at ``position``."""
    import dataclasses

    first = scenario.robots[0]
    extra = dataclasses.replace(first, name="rov2", position=position)
    return dataclasses.replace(scenario, robots=(*scenario.robots, extra))


def test_a_robot_joins_the_mission_and_the_auction_when_its_time_comes(tmp_path):
    """rov2 is parked (it does not move, talk or discover) until its join event at 15 s; then it explores,
    talks and takes part in the auction, and learns of tasks the others found before it came (some of
    them: at 500 bit/s, with 250-byte frames every 4 s per robot, a backlog of a hundred tasks takes
    minutes to pass on)."""
    from maptidal.mission.outputs import _trajectory_rows
    from maptidal.mission.params import MissionEvent

    scenario = _third_robot(load_mission(None)[0])
    # the paper's discovery, whose many tasks give the late robot some to win
    params = MissionParams(
        duration_s=32.0,
        seed=2,
        events=(MissionEvent(15.0, "join", "rov2"),),
        discovery_mode="paper",
        perception_process=False,
        plots=False,
    )
    mission = Mission(scenario, params, tmp_path)
    document = mission.run()
    senders = [(t, owner) for t, owner, _ in mission.auction.transmissions]
    assert all(t >= 15.0 for t, owner in senders if owner == 2)
    assert any(owner == 2 for _, owner in senders), "rov2 never spoke after joining"
    assert all(t["found_at_s"] >= 15.0 for t in document["tasks"] if t["found_by"] == "rov2")
    rows = _trajectory_rows(tmp_path)
    parked = rows[(rows[:, 0] == 2) & (rows[:, 1] < 15.0)][:, 2:5]
    moved = rows[(rows[:, 0] == 2) & (rows[:, 1] > 25.0)][:, 2:5]
    assert np.ptp(parked, axis=0).max() < 0.01, "rov2 moved while parked"
    assert len(moved) and np.abs(moved - parked[0]).max() < 1.0  # it explores where it was launched
    joiner = mission.auction.agents[2]
    found_before = {t["id"] for t in document["tasks"] if t["found_at_s"] < 15.0}
    assert found_before & {t.key for t in joiner.tasks}
    events = read_events(tmp_path)
    assert [e["robot"] for e in events if e["kind"] == "join"] == ["rov2"]
    assert next(e for e in events if e["kind"] == "start")["waiting"] == ["rov2"]


def test_a_link_outage_drops_every_message_in_its_window(tmp_path):
    """All links are down from 5 to 20 s: every broadcast in that window counts as link-down at its one
    receiver, and none outside it; a pair outage names the two robots' indices."""
    from maptidal.comms.channel import Outage
    from maptidal.mission.params import MissionEvent

    scenario, _ = load_mission(None)
    params = MissionParams(
        duration_s=28.0,
        seed=1,
        events=(MissionEvent(5.0, "outage", duration_s=15.0),),
        perception_process=False,
        plots=False,
    )
    mission = Mission(scenario, params, tmp_path / "all")
    document = mission.run()
    inside = sum(1 for t, _, _ in mission.auction.transmissions if 5.0 <= t < 20.0)
    assert inside > 0
    stats = mission.auction.channel.stats
    assert stats.link_down == inside == document["comms"]["link_down"]
    assert stats.delivered == stats.transmissions - inside - stats.lost - stats.out_of_range
    pair = MissionParams(
        duration_s=6.0, events=(MissionEvent(3.0, "outage", duration_s=2.0, robots=("rov1", "rov0")),)
    )
    assert Mission(scenario, pair, tmp_path / "pair").auction.channel.params.outages == (
        Outage(3.0, 5.0, (1, 0)),
    )


def test_video_has_a_frame_every_half_simulated_second(tmp_path, monkeypatch):
    """--video: mission.mp4 at the asked size, two frames per simulated second, readable by OpenCV, and no
    partial file left; the frames change as the robots move. Every frame is drawn on the mission's
    drawing thread, where its cameras are drawn, never beside them on the physics' thread (two threads
    drawing at once crashed Mesa's EGL)."""
    import dataclasses
    import threading

    import cv2

    from maptidal.mission import video as video_module

    drawn_on = []

    def recording(*args, **kwargs):
        drawn_on.append(threading.current_thread().name)
        return third_person_frame(*args, **kwargs)

    third_person_frame = video_module.third_person_frame
    monkeypatch.setattr(video_module, "third_person_frame", recording)
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "egl"))
    scenario, _ = load_mission(None)
    params = dataclasses.replace(MissionParams(duration_s=6.0, seed=0), video=True, video_size=(320, 200))
    document = Mission(scenario, params, tmp_path).run()
    expected = "MainThread" if os.environ["MUJOCO_GL"] == "glfw" else "maptidal-gl"
    assert len(drawn_on) == 13 and all(name.startswith(expected) for name in drawn_on), drawn_on
    capture = cv2.VideoCapture(str(tmp_path / "mission.mp4"))
    frames = []
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(frame)
    assert len(frames) == document["video"]["frames"] == 13  # at 0, 0.5, ..., 6 s
    assert frames[0].shape == (200, 320, 3)
    assert np.abs(frames[-1].astype(int) - frames[0].astype(int)).mean() > 0.5
    assert not (tmp_path / "mission.part.mp4").exists()


def test_the_progress_coverage_is_the_final_reports(short_mission):
    _, document, _ = short_mission
    uninspected = document["coverage"]["occluded"]["pct_uninspected"]
    assert document["inspected_pct"] == pytest.approx(100.0 - uninspected, abs=1e-9)


FAIL_AT = 27.0  # rov1 is on its way to its first task then (seed 1)


def test_after_a_failure_the_survivor_finishes_every_task_and_the_mission_ends(tmp_path):
    """With coarse discovery parameters (r_ex 3 m, theta_ex 1.2 rad: a handful of tasks) the whole
    mission can finish. rov1 fails at 27 s while flying to a task; once the 40 s failure timeout has
    passed the survivor takes that task and does it, every task is done or given up with its reason
    (declined, timed out, stalled, or lost with rov1), and the mission ends before its time limit.
    (Both robots carry a DVL, so that the survivor can fly what it takes.) The limit, 450 s, only needs
    to leave room: since the tank was closed (session 16) the survivor also finds views of the far end
    wall, and ended at 376 s when measured, where it ended before 300 s in the open tank."""
    import dataclasses

    from maptidal.discovery import DiscoveryParams
    from maptidal.mission.params import MissionEvent

    scenario, _ = load_mission(None)
    with_dvl = tuple(
        dataclasses.replace(r, sensors=tuple(dict.fromkeys((*r.sensors, "dvl")))) for r in scenario.robots
    )
    scenario = dataclasses.replace(scenario, robots=with_dvl)
    params = MissionParams(
        duration_s=450.0,
        seed=1,
        discovery=DiscoveryParams(r_ex=3.0, theta_ex=1.2),
        events=(MissionEvent(FAIL_AT, "fail", "rov1"),),
        perception_process=False,
        plots=False,
        explore=False,  # the handover is what is tested; exploring its frontier adds some 300 s of flight
    )
    document = Mission(scenario, params, tmp_path).run()
    assert document["finished"] and document["sim_time_s"] < 450.0
    assert document["ending"] == (
        f"finished at {document['sim_time_s']:.1f} s: every robot explored and every known task was done or "
        "given up"
    )
    events = read_events(tmp_path)
    # every task is done, or given up by the survivor with its reason in the log: declined (a view it
    # cannot pitch to) or timed out (since session 15, two views a hull's width from the ladder's rails)
    kinds = ("declined", "timeout", "stalled")
    given_up = {e["task"] for e in events if e["kind"] in kinds and e["robot"] == "rov0"}
    # ... or died with rov1, found in its last seconds and never heard by the survivor (tasks_lost)
    lost = set(document["tasks_lost"]["rov1"]["lost_ids"])
    assert document["tasks"] and all(t["completed"] or t["id"] in given_up | lost for t in document["tasks"])
    assert sum(t["completed"] for t in document["tasks"]) > len(given_up)
    flying = [e for e in events if e["kind"] == "flying" and e["robot"] == "rov1" and e["t"] < FAIL_AT]
    done_by_rov1 = {e["task"] for e in events if e["kind"] == "done" and e["robot"] == "rov1"}
    orphan = flying[-1]["task"]  # what rov1 was flying to when it failed
    assert orphan not in done_by_rov1, "the premise: rov1 fails while flying to a task, not after it"
    taken = next(t for t in document["tasks"] if t["id"] == orphan)
    assert taken["assigned_to"] == "rov0" and taken["completion_time"] > FAIL_AT + 40.0


def _placed(mission, positions: dict):
    """Make the mission's robots believe they are at ``positions`` (name -> xyz)."""
    import types

    estimate = mission._estimate
    mission._estimate = lambda robot: (
        types.SimpleNamespace(position=np.asarray(positions[robot.name], float))
        if robot.name in positions
        else estimate(robot)
    )


def test_a_robot_keeps_clear_of_the_way_a_teammate_said_it_was_bound(tmp_path):
    """A teammate heard at the origin bound 3 m along x may be anywhere on that way as far as it can
    have flown since (0.25 m/s): a robot crossing the way at x = 2 goes on 2 s after the message and
    waits 12 s after it, 1 m short of the way. Its own messages say where it is bound: its route's end."""
    from maptidal.controllers.trajectory import PoseReference, PoseTrajectory, Route

    scenario, _ = load_mission(None)
    params = MissionParams(duration_s=1.0, clearance_m=1.0, peer_fresh_s=30.0, speed_m_s=0.25, plots=False)
    mission = Mission(scenario, params, tmp_path)
    rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
    agent = mission.auction.agents[rov1.index]
    agent.peer_positions[rov0.index] = (np.array([0.0, 0.0, 1.0]), 10.0)
    agent.peer_goals[rov0.index] = np.array([3.0, 0.0, 1.0])
    _placed(mission, {"rov1": [2.0, -3.0, 1.0]})
    crossing = PoseReference(np.array([2.0, 3.0, 1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0)
    assert mission._keep_clear(rov1, crossing, now=12.0) is crossing  # 0.5 m along, at most
    waits = mission._keep_clear(rov1, crossing, now=22.0)
    np.testing.assert_allclose(waits.position, [2.0, -1.0, 1.0])
    assert agent.goal is None  # not flying anywhere yet
    rov1.route = Route([PoseTrajectory(np.zeros(3), 0.0, np.array([1.0, 2.0, 0.5]), 0.0, mission._limits())])
    rov1.activity = "fly"
    mission._keep_clear(rov1, crossing, now=22.0)
    np.testing.assert_allclose(agent.goal, [1.0, 2.0, 0.5])
    agent.peer_goals[rov0.index] = None  # holding where it is: a ball again
    assert mission._keep_clear(rov1, crossing, now=22.0) is crossing
    mission.sim.close()


def test_a_robot_keeps_clear_of_a_teammate_it_has_heard_from(tmp_path):
    from maptidal.controllers.trajectory import PoseReference

    scenario, _ = load_mission(None)
    mission = Mission(
        scenario, MissionParams(duration_s=1.0, clearance_m=1.0, peer_fresh_s=30.0, plots=False), tmp_path
    )
    rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
    teammate = np.array([0.0, 0.0, 1.0])
    mission.auction.agents[rov1.index].peer_positions[rov0.index] = (teammate, 10.0)
    mission.auction.agents[rov0.index].peer_positions[rov1.index] = (teammate, 10.0)
    _placed(mission, {"rov0": [3.0, 0.0, 1.0], "rov1": [3.0, 0.0, 1.0]})

    def reference(at):
        return PoseReference(np.asarray(at, float), np.full(3, 0.1), np.full(3, 0.01), 0.3, 0.05)

    # bound for a point beyond the teammate, it stops on its own side of it, not on the far side
    beyond = mission._keep_clear(rov1, reference([-2.0, 0.0, 1.0]), now=12.0)
    np.testing.assert_allclose(beyond.position, [1.0, 0.0, 1.0])
    assert beyond.yaw == 0.3 and not beyond.velocity.any()
    assert mission.auction.agents[rov1.index].giving_way  # and its messages say so
    outside = reference([1.2, 0.0, 1.0])
    assert mission._keep_clear(rov1, outside, now=12.0) is outside
    assert not mission.auction.agents[rov1.index].giving_way
    # rov0 gives way to rov1 too, a teammate holding at a viewpoint (a 0.37 m collision in a 1200 s
    # mission came of rov0 yielding to nobody) ...
    near = reference([0.3, 0.4, 1.0])
    waits = mission._keep_clear(rov0, near, now=12.0).position
    assert abs(np.linalg.norm(waits - teammate) - 1.0) < 1e-9 and waits[0] > 0.9  # on its own side
    # ... but not while rov1's last message said it was giving way itself: the lower index goes on
    mission.auction.agents[rov0.index].peer_giving_way[rov1.index] = True
    assert mission._keep_clear(rov0, near, now=12.0) is near
    # and a position heard too long ago counts for nothing
    assert mission._keep_clear(rov1, near, now=41.0) is near
    assert mission._keep_clear(rov0, near, now=12.6) is near  # clear for clear_after_s: the spell ends
    kinds = [(e["robot"], e["kind"]) for e in read_events(tmp_path)]
    assert kinds.count(("rov1", "yielding")) == 1 and kinds.count(("rov1", "clear")) == 1
    assert kinds.count(("rov0", "yielding")) == 1 and kinds.count(("rov0", "clear")) == 1
    mission.sim.close()


def test_a_spell_of_giving_way_broken_for_less_than_clear_after_s_is_one_spell(tmp_path):
    """A robot backing out of a teammate that comes on towards it is clear, then inside its ball again,
    every few control periods: its events and time use count one spell until its way has been clear
    for clear_after_s; its reference is the clear way's at once all the same."""
    from maptidal.controllers.trajectory import PoseReference

    scenario, _ = load_mission(None)
    params = MissionParams(duration_s=1.0, clearance_m=1.0, clear_after_s=0.5, plots=False)
    mission = Mission(scenario, params, tmp_path)
    rov1 = mission.robots["rov1"]
    teammate = np.array([0.0, 0.0, 1.0])
    mission.auction.agents[rov1.index].peer_positions[0] = (teammate, 10.0)
    _placed(mission, {"rov0": [3.0, 0.0, 1.0], "rov1": [3.0, 0.0, 1.0]})
    blocked = PoseReference(np.array([-2.0, 0.0, 1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0)
    clear = PoseReference(np.array([4.0, 0.0, 1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0)
    spell = [(10.0, blocked), (10.2, clear), (10.4, blocked), (10.5, clear), (10.9, clear), (11.0, clear)]
    flags = []
    for now, reference in spell:
        held = mission._keep_clear(rov1, reference, now=now)
        assert (held is reference) == (reference is clear)  # the flight never waits on the spell
        flags.append(rov1.giving_way)
        mission._count_time_use(now, 0.1)
    assert flags == [True, True, True, True, True, False]  # clear from 10.5, for 0.5 s at 11.0
    events = [(e["kind"], e["t"]) for e in read_events(tmp_path) if e.get("robot") == "rov1"]
    assert [e for e in events if e[0] in ("yielding", "clear")] == [("yielding", 10.0), ("clear", 11.0)]
    assert rov1.time_use.seconds["giving way"] == pytest.approx(0.5)
    mission.sim.close()


def test_a_robot_with_nothing_left_to_do_gets_out_of_the_way_and_nobody_waits_on_it(tmp_path):
    # a teammate that had finished held the way home of a lost robot for the last 350 s of a mission:
    # the robot waited on it, and it on nothing
    from maptidal.allocation.messages import decode
    from maptidal.controllers.trajectory import PoseReference

    scenario, _ = load_mission(None)
    mission = Mission(
        scenario, MissionParams(duration_s=1.0, clearance_m=1.0, peer_fresh_s=30.0, plots=False), tmp_path
    )
    rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
    agent0, agent1 = mission.auction.agents[rov0.index], mission.auction.agents[rov1.index]
    _placed(mission, {"rov0": [0.0, 0.0, 1.0], "rov1": [0.6, 0.0, 1.0]})
    agent1.peer_positions[rov0.index] = (np.array([0.0, 0.0, 1.0]), 10.0)
    agent0.peer_positions[rov1.index] = (np.array([0.6, 0.0, 1.0]), 10.0)

    def reference(at):
        return PoseReference(np.asarray(at, float), np.zeros(3), np.zeros(3), 0.0, 0.0)

    hold = reference([0.0, 0.0, 1.0])
    # busy, rov0 (the lower index) holds its place with rov1 60 cm away, rov1 giving way to it
    agent0.peer_giving_way[rov1.index] = True
    rov0.activity, rov0.explored = "fly", False
    assert mission._keep_clear(rov0, hold, now=12.0) is hold and not agent0.idle
    # finished, it backs out of rov1's ball all the same, horizontally, away from rov1, and says it is
    # idle
    rov0.activity, rov0.explored = "idle", True
    out = mission._keep_clear(rov0, hold, now=12.0).position
    assert abs(np.linalg.norm(out - [0.6, 0.0, 1.0]) - 1.0) < 1e-9 and out[0] < 0 and out[2] == 1.0
    assert agent0.idle and agent0.giving_way
    data = agent0.make_message(12.0)
    message = decode(data)
    assert message.idle and message.giving_way
    # rov1, bound past it, waits on it while it is busy ...
    beyond = reference([-2.0, 0.0, 1.0])
    assert mission._keep_clear(rov1, beyond, now=12.0) is not beyond
    # ... and not once its message says it is idle
    assert agent1.receive(data, 13.0) and agent1.peer_idle[rov0.index]
    assert mission._keep_clear(rov1, beyond, now=13.0) is beyond
    mission.sim.close()


def test_a_robot_giving_way_takes_its_route_up_where_it_left_off(tmp_path):
    """Its route pauses while it waits: once clear, the reference goes on from the waiting point, not
    from where the route's clock would have put it (a leap the robot would rush at full thrust)."""
    from maptidal.controllers.trajectory import PoseTrajectory, Route

    scenario, _ = load_mission(None)
    mission = Mission(
        scenario, MissionParams(duration_s=1.0, clearance_m=1.0, peer_fresh_s=30.0, plots=False), tmp_path
    )
    rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
    start, goal = np.array([0.0, 0.0, 1.0]), np.array([4.0, 0.0, 1.0])
    _placed(mission, {"rov0": start})
    rov0.route, rov0.route_start_s = Route([PoseTrajectory(start, 0.0, goal, 0.0, mission._limits())]), 0.0
    assert rov0.route.duration < 30.0  # over long before the teammate is forgotten
    mission.auction.agents[rov0.index].peer_positions[rov1.index] = (np.array([3.0, 0.0, 1.0]), 0.0)
    positions = {}
    for step in range(401):  # 0 to 40 s; the teammate counts until 30 s
        now = step / 10.0
        positions[now] = mission._reference(rov0, now).position
    np.testing.assert_allclose(positions[25.0], [2.0, 0.0, 1.0], atol=1e-9)  # waiting where its way meets it
    resumed = positions[30.1]
    assert 2.0 <= resumed[0] < 2.1, resumed  # on from the waiting point, not at the goal
    assert np.linalg.norm(positions[40.0] - goal) < np.linalg.norm(positions[30.1] - goal)  # and on its way
    mission.sim.close()


def test_two_robots_waiting_on_each_other_are_released_by_one_message(tmp_path):
    """Each one's goal beyond the other: both give way at first; once the higher-indexed one's message
    says it gives way, the lower-indexed one goes on, and the higher-indexed one still waits."""
    from maptidal.allocation.messages import decode
    from maptidal.controllers.trajectory import PoseReference

    scenario, _ = load_mission(None)
    mission = Mission(
        scenario, MissionParams(duration_s=1.0, clearance_m=1.0, peer_fresh_s=30.0, plots=False), tmp_path
    )
    rov0, rov1 = mission.robots["rov0"], mission.robots["rov1"]
    agent0, agent1 = (mission.auction.agents[r.index] for r in (rov0, rov1))
    at0, at1 = np.array([0.0, 0.0, 1.0]), np.array([1.5, 0.0, 1.0])
    agent0.set_position(at0)
    agent1.set_position(at1)
    _placed(mission, {"rov0": at0, "rov1": at1})
    goal0 = PoseReference(at1 - [0.2, 0, 0], np.zeros(3), np.zeros(3), 0.0, 0.0)  # next to the other
    goal1 = PoseReference(at0 + [0.2, 0, 0], np.zeros(3), np.zeros(3), 0.0, 0.0)

    def exchange(now):
        for sender, receiver in ((agent0, agent1), (agent1, agent0)):
            data = sender.make_message(now)
            assert decode(data).giving_way == sender.giving_way  # the flag travels on the wire
            receiver.receive(data, now)

    exchange(1.0)
    assert mission._keep_clear(rov0, goal0, now=2.0) is not goal0  # both wait ...
    assert mission._keep_clear(rov1, goal1, now=2.0) is not goal1
    exchange(3.0)
    assert agent0.peer_giving_way[rov1.index] and agent1.peer_giving_way[rov0.index]
    assert mission._keep_clear(rov0, goal0, now=4.0) is goal0  # ... until rov1's message says it waits
    assert mission._keep_clear(rov1, goal1, now=4.0) is not goal1  # rov1 never goes onto rov0
    mission.sim.close()


def test_go_to_pose_streams_its_commands_at_the_command_rate(tmp_path):
    scenario, _ = load_mission(None)
    mission = Mission(scenario, MissionParams(duration_s=2.0, command_rate_hz=10.0, plots=False), tmp_path)
    calls = {name: 0 for name in mission.robots}
    for name, robot in mission.robots.items():
        update = robot.controller.update

        def counted(*args, _update=update, _name=name):
            calls[_name] += 1
            return _update(*args)

        robot.controller.update = counted
    mission.run()
    assert calls == {name: 20 for name in mission.robots}  # 2 s at 10 Hz, on 50 Hz physics


def test_a_robot_keeps_clear_of_two_teammates_at_once(tmp_path):
    from maptidal.controllers.trajectory import PoseReference

    scenario = _third_robot(load_mission(None)[0])
    mission = Mission(scenario, MissionParams(duration_s=1.0, clearance_m=1.0, plots=False), tmp_path)
    last = mission.robots_by_index[2]
    peers = mission.auction.agents[2].peer_positions
    peers[0], peers[1] = (np.array([0.0, 0.0, 1.0]), 5.0), (np.array([1.2, 0.0, 1.0]), 5.0)
    goal = PoseReference(np.array([0.6, 0.1, 1.0]), np.zeros(3), np.zeros(3), 0.0, 0.0)
    _placed(mission, {last.name: [0.6, -2.0, 1.0]})
    moved = mission._keep_clear(last, goal, now=6.0).position
    assert moved[1] < -0.5  # short of both, on its own side
    for position, _ in peers.values():
        assert np.linalg.norm(moved - position) >= 1.0 - 1e-9
    mission.sim.close()


def test_a_mission_that_cannot_start_leaves_no_worker_behind(monkeypatch, tmp_path):
    import maptidal.mission.run as run_module

    started = []

    def start_and_keep(*args, **kwargs):
        started.append(run_module.start_perception.__wrapped__(*args, **kwargs))
        return started[-1]

    def no_simulator(*args, **kwargs):
        raise RuntimeError("no simulator today")

    start_and_keep.__wrapped__ = run_module.start_perception
    monkeypatch.setattr(run_module, "start_perception", start_and_keep)
    monkeypatch.setattr(run_module, "Simulation", no_simulator)
    scenario, _ = load_mission(None)
    with pytest.raises(RuntimeError, match="no simulator today"):
        Mission(scenario, MissionParams(duration_s=5.0), tmp_path)
    (perception,) = started
    assert perception.mode == "process" and not _alive(perception.pid)


def test_a_mission_with_no_task_done_still_writes_every_plot_and_a_whole_report(tmp_path):
    scenario, _ = load_mission(None)
    document = Mission(scenario, MissionParams(duration_s=4.0), tmp_path).run()
    assert not any(t["completed"] for t in document["tasks"])
    occluded = document["coverage"]["occluded"]
    assert occluded["n_viewpoints"] == 0 and occluded["pct_uninspected"] == 100.0
    assert occluded["histogram"][0] == 1.0 and occluded["mad"] > 0  # every voxel unseen, against gamma
    for name in ("top_view.png", "timeline.png", "histogram.png", "voxel_views.png", "report.md"):
        assert (tmp_path / name).stat().st_size > 0, name


def test_a_mission_the_physics_fails_in_raises_and_leaves_no_worker_nor_thread(tmp_path):
    import threading

    from maptidal.envs.simulation import SimulationError

    scenario, _ = load_mission(None)
    earlier = set(threading.enumerate())  # an earlier test's mission may not be collected yet
    mission = Mission(scenario, MissionParams(duration_s=20.0), tmp_path)
    step = mission.sim.step

    def diverging(*args, **kwargs):
        if mission.sim.time > 5.0:
            raise SimulationError("the physics state became NaN")
        return step(*args, **kwargs)

    mission.sim.step = diverging
    with pytest.raises(SimulationError, match="NaN"):
        mission.run()
    assert not _alive(mission.perception.pid)
    assert not [t for t in set(threading.enumerate()) - earlier if t.name.startswith("maptidal-gl")]
    assert any(e["kind"] == "keyframe" for e in read_events(tmp_path))  # the log so far is readable


def test_drawing_on_the_loops_own_thread_gives_the_same_mission(short_mission, tmp_path, monkeypatch):
    # under MUJOCO_GL=glfw, whose contexts stay on the main thread, the loop draws its cameras itself:
    # the snapshots make that the same mission, event for event
    import maptidal.mission.run as run_module

    monkeypatch.setattr(run_module, "_drawing_thread", run_module._SameThread)
    scenario, _ = load_mission(None)
    _, first, first_out = short_mission
    again = Mission(
        scenario, MissionParams(duration_s=55.0, seed=3, discovery_mode="paper", plots=False), tmp_path
    )
    assert isinstance(again._gl, run_module._SameThread)
    document = again.run()
    assert document["tasks"] == first["tasks"] and document["comms"] == first["comms"]
    without_start = lambda out: [e for e in read_events(out) if e["kind"] != "start"]  # noqa: E731
    assert without_start(tmp_path) == without_start(first_out)


def test_the_coverage_timeline_steps_at_each_scored_view(short_mission, tmp_path):
    """A point per verified capture, at its time; each point is the coverage evaluation of the views
    scored so far (evaluated afresh here, not incrementally); the last is the report's coverage; the
    report rebuilt from the event log gives the same timeline."""
    mission, document, out = short_mission
    timeline = document["coverage_timeline"]
    scored = [e for e in read_events(out) if e["kind"] == "done" and e["verified"]]
    assert len(scored) >= 3
    assert timeline[0] == [0.0, 0.0]
    assert [t for t, _ in timeline[1:]] == [e["t"] for e in scored]
    model = CoverageModel.from_tank(mission.scenario.tank, CoverageParams(occlusion=True))
    for k in (1, len(scored) // 2, len(scored)):
        report, _ = model.evaluate(np.array([e["view"] for e in scored[:k]]))
        assert timeline[k][1] == pytest.approx(100.0 - report.pct_uninspected, abs=1e-9)
    assert timeline[-1][1] == pytest.approx(100.0 - document["coverage"]["occluded"]["pct_uninspected"])
    rebuilt_folder = tmp_path / "rebuilt"
    shutil.copytree(out, rebuilt_folder)
    assert run_maptidal("report", rebuilt_folder).returncode == 0
    rebuilt = json.loads((rebuilt_folder / "mission.json").read_text())
    np.testing.assert_allclose(rebuilt["coverage_timeline"], timeline, atol=1e-9)
    assert (out / "coverage_time.png").stat().st_size > 0 and "coverage_time.png" in (
        out / "report.md"
    ).read_text()


def test_time_to_coverage_is_the_first_time_the_share_is_reached():
    timeline = [[0.0, 0.0], [10.0, 50.0], [20.0, 94.9], [30.0, 95.0], [40.0, 99.0]]
    assert time_to_coverage(timeline, 95.0) == 30.0
    assert time_to_coverage(timeline, 50.0) == 10.0
    assert time_to_coverage(timeline, 99.5) is None


def _coarse_path(points: np.ndarray, step_m: float) -> float:
    """A polyline's length through ``points``, a vertex whenever one is ``step_m`` from the last."""
    length, last = 0.0, points[0]
    for point in points[1:]:
        if np.linalg.norm(point - last) >= step_m:
            length, last = length + float(np.linalg.norm(point - last)), point
    return length


def test_each_robot_s_odometry_follows_its_trajectory(short_mission):
    """The simulator's path is the polyline its documentation states, written out here on the true
    positions (the free joint's) recorded after every control period: a vertex whenever the body is
    5 cm from the last.
    It is no shorter than a coarse path through the trajectory file's once-a-second positions (a vertex
    every 20 cm), which cuts the same motion's corners, by more than a few cm. The thrusters drew a
    plausible average power (between an idle hover's watt and eight T200s at full throttle); the
    mission's metrics are the robots' sums."""
    mission, document, out = short_mission
    rows = [line.split(",") for line in (out / "trajectories.csv").read_text().splitlines()[1:]]
    for name, odometry in document["odometry"].items():
        literal = _coarse_path(mission.true_positions[name], 0.05)
        assert odometry["path_m"] == pytest.approx(literal, rel=1e-9, abs=1e-9), (odometry["path_m"], literal)
        points = np.array([[float(v) for v in row[2:5]] for row in rows if row[1] == name])
        coarse = _coarse_path(points, 0.2)
        assert odometry["path_m"] >= coarse - 0.05, (odometry["path_m"], coarse)
        mean_power_w = odometry["thruster_energy_j"] / document["sim_time_s"]
        assert 1.0 < mean_power_w < 8 * 380.0
        assert 0.0 <= odometry["contact_s"] <= document["sim_time_s"]
    metrics = mission_metrics(document)
    assert metrics["path_m"] == pytest.approx(sum(o["path_m"] for o in document["odometry"].values()))
    assert metrics["contact_s"] == pytest.approx(sum(o["contact_s"] for o in document["odometry"].values()))
    assert metrics["thruster_energy_kj"] == pytest.approx(
        sum(o["thruster_energy_j"] for o in document["odometry"].values()) / 1000.0
    )


PLOTS = ("top_view.png", "timeline.png", "coverage_time.png", "histogram.png", "voxel_views.png")


def test_a_mission_flown_without_plots_draws_none_and_the_report_draws_them_later(tmp_path):
    done = maptidal_here("run", "--duration", "3", "--no-plots", "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    assert not any((tmp_path / name).exists() for name in (*PLOTS, "localisation.png"))
    report = (tmp_path / "report.md").read_text()
    assert "--no-plots" in report and ".png)" not in report
    assert json.loads((tmp_path / "mission.json").read_text())["plots"] is False
    assert maptidal_here("report", tmp_path).returncode == 0
    assert all((tmp_path / name).stat().st_size > 0 for name in PLOTS)
    assert "![top view](top_view.png)" in (tmp_path / "report.md").read_text()


def test_the_box_a_team_is_sent_to_inspect():
    """``inspect_region = "walls"``: the box of the tank's evaluated walls, written out for the default
    tank (end wall 2.4 m, angled walls 1 m at 45 deg, 0.5 m of each side wall, a 10 cm window recess, 2 m
    of water); "launch": none; ``inspect_box`` states one."""
    from maptidal.mission.plan import inspection_box

    scenario, _ = load_mission(None)
    box = inspection_box(MissionParams(), scenario.tank)
    reach = 1.2 + math.sqrt(0.5)
    np.testing.assert_allclose(box, [[-math.sqrt(0.5) - 0.5, -reach, 0.0], [0.1, reach, 2.0]], atol=1e-9)
    assert inspection_box(MissionParams(inspect_region="launch"), scenario.tank) is None
    given = ((-1.0, -1.0, 0.0), (0.0, 1.0, 2.0))
    np.testing.assert_allclose(inspection_box(MissionParams(inspect_box=given), scenario.tank), given)


def test_a_robot_retires_the_task_its_review_found_covered_when_it_comes_to_it(tmp_path):
    """The review's answer (``_Robot.covered``) is acted on when the robot comes to the task: done in
    the auction without an image, a ``retired`` event and the ledger's ``retired``; a task not covered
    is flown."""
    scenario, _ = load_mission(None)
    mission = Mission(scenario, MissionParams(duration_s=1.0, plots=False), tmp_path)
    robot = mission.robots["rov0"]
    agent = mission.auction.agents[robot.index]
    covered = agent.discover_task([-1.0, 0.2, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
    flown = agent.discover_task([-1.0, -0.6, 1.0], [1.0, 0.0, 0.0], now_s=0.0)
    agent.build_bundle(0.0)
    assert set(agent.path_keys()) == {covered.key, flown.key}
    first = agent.path_keys()[0]
    robot.activity, robot.explored, robot.covered = "idle", True, {covered.key: "repeat"}
    _placed(mission, {"rov0": [-1.5, 0.0, 1.0]})
    mission._estimate = lambda r: types.SimpleNamespace(position=np.array([-1.5, 0.0, 1.0]), yaw=0.0)
    mission._advance_activity(robot, now=2.0)
    if first == flown.key:  # flies the first; the covered one waits its turn
        assert robot.activity == "fly" and agent.is_open(covered.key)
        robot.activity = "idle"
        agent.mark_done(flown.key, 3.0)
        mission._advance_activity(robot, now=3.0)
    assert not agent.is_open(covered.key) and robot.activity == "idle"
    assert mission.tasks[covered.key]["retired"] and not mission.tasks[covered.key].get("completed")
    assert mission.tasks[covered.key]["retired_why"] == "repeat"
    assert covered.key not in robot.covered
    mission._advance_activity(robot, now=4.0)
    assert robot.activity == "fly" or not agent.is_open(flown.key)
    mission.sim.close()
    retired = [e for e in read_events(tmp_path) if e["kind"] == "retired"]
    assert [(e["robot"], e["task"], e["why"]) for e in retired] == [("rov0", covered.key, "repeat")]
