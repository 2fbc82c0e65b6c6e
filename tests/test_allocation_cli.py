"""`maptidal allocate`: scenario files, the JSON shape, the plot, and bad input."""

import json
from pathlib import Path

import pytest

from maptidal.allocation.scenario import AllocationScenarioError, load_scenario, scenario_from_dict
from maptidal.cli import main

SCENARIOS = Path(__file__).resolve().parent.parent / "assets" / "scenarios"


def allocate_json(capsys, path) -> dict:
    assert main(["allocate", str(path), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_json_has_the_documented_shape(capsys):
    result = allocate_json(capsys, SCENARIOS / "auction_2x20.json")
    for key, kind in {
        "robots": dict,
        "conflicts": int,
        "unassigned": list,
        "rounds": int,
        "messages": int,
        "bytes": int,
        "sim_time_s": float,
        "greedy_ratio": float,
    }.items():
        assert isinstance(result[key], kind), key
    assert set(result["robots"]) == {"r0", "r1"}
    assert all(set(r) == {"path", "length_m"} for r in result["robots"].values())
    held = [t for r in result["robots"].values() for t in r["path"]]
    assert sorted(held) == sorted(f"t{j}" for j in range(20))
    assert result["conflicts"] == 0 and result["greedy_ratio"] == pytest.approx(1.0)
    assert result["bytes"] < 1000  # issue #5's goal for 2 robots and 20 tasks


def test_dynamic_scenario_runs_with_plot_and_result_file(tmp_path, capsys):
    plot, out = tmp_path / "auction.png", tmp_path / "result.json"
    assert (
        main(["allocate", str(SCENARIOS / "auction_dynamic.json"), "--plot", str(plot), "--out", str(out)])
        == 0
    )
    printed = capsys.readouterr().out
    assert "converged" in printed and "conflicts 0" in printed
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads(out.read_text())
    assert result["failed"] == ["r1"]
    assert "r3" in result["robots"]  # the robot that joined
    assert "t0" not in [t for r in result["robots"].values() for t in r["path"]]  # completed
    assert {"found0", "found1"} <= {t for r in result["robots"].values() for t in r["path"]}


def _minimal() -> dict:
    return {
        "robots": [{"id": "r0", "position": [0, 0, -1]}, {"id": "r1", "position": [5, 0, -1]}],
        "tasks": [{"id": "t0", "position": [1, 1, -1], "direction": [0, 1, 0]}],
    }


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda d: d.update(colour="red"), "unknown key 'colour'"),
        (lambda d: d["robots"][0].update(position=[0, "x", 1]), "robots[0].position"),
        (lambda d: d["robots"][0].update(capabilities=["laser"]), "unknown capability 'laser'"),
        (lambda d: d["robots"][1].update(id="r0"), "unique"),
        (lambda d: d["tasks"][0].update(direction=[0, 0, 0]), "tasks[0]"),
        (lambda d: d["tasks"][0].update(position=[float("nan"), 0, 0]), "tasks[0].position"),
        (lambda d: d.update(channel={"loss": 1.5}), "loss"),
        (lambda d: d.update(channel={"bandwidth": 5}), "unknown key 'bandwidth'"),
        (lambda d: d.update(events=[{"time_s": 1, "kind": "explode", "robot": "r0"}]), "kind"),
        (lambda d: d.update(events=[{"time_s": 1, "kind": "fail", "robot": "r7"}]), "names no robot"),
        (lambda d: d.update(bundle_limit=-1), "bundle_limit"),
        (lambda d: d.update(robots=[]), "robots"),
    ],
)
def test_bad_scenarios_name_the_problem(change, words):
    document = _minimal()
    change(document)
    with pytest.raises(AllocationScenarioError) as caught:
        scenario_from_dict(document)
    assert words in str(caught.value)


def test_cli_exits_2_with_one_line_on_bad_input(tmp_path, capsys):
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    assert main(["allocate", str(broken)]) == 2
    assert main(["allocate", str(tmp_path / "missing.json")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 2 and all(e.startswith("maptidal allocate: error:") for e in errors)


def test_help_describes_the_command(capsys):
    with pytest.raises(SystemExit) as done:
        main(["allocate", "--help"])
    assert done.value.code == 0
    assert "SCENARIO.json" in capsys.readouterr().out


def test_discovered_tasks_get_keys_of_their_robot():
    document = _minimal()
    document["tasks"].append({"id": "new", "position": [2, 2, -1], "discovered_by": "r1", "time_s": 50})
    scenario = scenario_from_dict(document)
    (event,) = scenario.events
    assert event.kind == "discover" and event.robot == 1 and event.task.key >> 16 == 1


def test_scenario_files_load(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(json.dumps(_minimal()))
    scenario = load_scenario(path)
    assert [r.name for r in scenario.robots] == ["r0", "r1"] and len(scenario.tasks) == 1


def test_example_scenarios_are_in_the_tank_and_as_generated():
    from maptidal.allocation.examples import example_scenarios, scenario_text
    from maptidal.envs.scenario import inside_tank
    from maptidal.tank import TankModel

    tank = TankModel()
    for name, document in example_scenarios(tank).items():
        assert (SCENARIOS / name).read_text() == scenario_text(document), (
            "run python -m maptidal.allocation.examples"
        )
        robots = document["robots"] + [e["robot"] for e in document.get("events", []) if e["kind"] == "join"]
        for robot in robots:
            assert inside_tank(tank, robot["position"], 0.3), (name, robot)
        for task in document["tasks"]:
            assert inside_tank(tank, task["position"], 0.0), (name, task)
