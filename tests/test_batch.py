"""Many missions: the executors (local processes and Ray) and ``maptidal batch``. The same seeds give the
same numbers locally and on a Ray cluster the test starts itself; the aggregate is checked against numpy
on the rows; bad seeds, a Ray address without the Ray executor and a bad mission file fail in one line."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import assert_one_line_error, maptidal_here, run_maptidal

from maptidal.executors import run_jobs
from maptidal.mission.batch import (
    METRICS,
    WALL_CLOCK,
    aggregate,
    batch_markdown,
    coverage_bands,
    exploring_ends,
    exploring_ends_markdown,
    mission_metrics,
    parse_planners,
    parse_seeds,
    run_batch,
    time_use_markdown,
    time_use_means,
)
from maptidal.mission.config import DEFAULT_MISSION as MISSION_FILE


def _square(value: int) -> int:
    return value * value


def _fail_on_three(value: int) -> int:
    if value == 3:
        raise ArithmeticError("three")
    return value


_SEEN: list[str] = []


def _remember(tag: str) -> None:
    _SEEN.append(tag)


def test_parse_seeds():
    assert parse_seeds("1-4") == [1, 2, 3, 4]
    assert parse_seeds("7") == [7]
    assert parse_seeds("1,4,9-11") == [1, 4, 9, 10, 11]
    for bad in ("5-1", "a", "", "1,,2", "-3", "1,1", "2-3,3"):
        with pytest.raises(ValueError):
            parse_seeds(bad)


@pytest.mark.parametrize("jobs", [1, 2])
def test_local_runs_come_back_whole_whatever_the_order(jobs):
    results = dict(run_jobs(_square, range(6), jobs=jobs))
    assert results == {k: k * k for k in range(6)}


def test_a_failing_run_raises_and_the_initializer_runs_once_in_process():
    _SEEN.clear()
    assert dict(run_jobs(_square, [2, 3], initializer=_remember, initargs=("x",))) == {0: 4, 1: 9}
    assert _SEEN == ["x"]
    for jobs in (1, 2):
        with pytest.raises(ArithmeticError, match="three"):
            dict(run_jobs(_fail_on_three, [1, 2, 3, 4], jobs=jobs))
    with pytest.raises(ValueError, match="unknown executor"):
        next(run_jobs(_square, [1], executor="slurm"))
    with pytest.raises(ValueError, match="needs --executor ray"):
        next(run_jobs(_square, [1], ray_address="127.0.0.1:1"))


def test_the_aggregate_is_numpys_over_the_rows():
    names = (*METRICS, *WALL_CLOCK)
    data = np.random.default_rng(4).uniform(0, 50, (5, len(names)))
    rows = [
        {"seed": s, "finished": s % 2 == 0, **dict(zip(names, map(float, values), strict=True))}
        for s, values in enumerate(data)
    ]
    summary = aggregate(rows)
    values = np.array([row["bytes"] for row in rows])
    assert summary["bytes"]["mean"] == pytest.approx(values.mean())
    assert summary["bytes"]["std"] == pytest.approx(values.std())
    assert (summary["bytes"]["min"], summary["bytes"]["max"]) == (values.min(), values.max())
    assert summary["finished"] == {"count": 3, "of": 5}


def test_a_metric_only_some_seeds_have_is_averaged_over_those_and_says_so():
    rows = [
        {"seed": s, "finished": True, **dict.fromkeys((*METRICS, *WALL_CLOCK), 1.0), "time_to_95_s": t}
        for s, t in enumerate([40.0, None, 60.0, None])
    ]
    summary = aggregate(rows)
    assert summary["time_to_95_s"]["mean"] == 50.0 and summary["time_to_95_s"]["count"] == 2
    assert summary["bytes"]["count"] == 4
    table = batch_markdown(summary, len(rows))
    assert "| time_to_95_s |" in table and "50 (2 of 4)" in table
    assert "| bytes | bytes | 1 |" in table


def test_the_coverage_bands_are_the_steps_mean_and_spread():
    """Two seeds' timelines, each held after its last view: the band at each time is the mean and the
    standard deviation of the two values read off by hand."""
    rows = [
        {"seed": 0, "planner": "a", "coverage_timeline": [[0, 0], [10, 40], [20, 80]]},
        {"seed": 1, "planner": "a", "coverage_timeline": [[0, 0], [15, 60]]},
        {"seed": 0, "planner": "b", "coverage_timeline": [[0, 0]]},
    ]
    grid = np.array([0.0, 9.9, 10.0, 14.0, 15.0, 25.0, 100.0])
    by_hand = {
        0.0: (0, 0),
        9.9: (0, 0),
        10.0: (40, 0),
        14.0: (40, 0),
        15.0: (40, 60),
        25.0: (80, 60),
        100.0: (80, 60),
    }
    bands = coverage_bands(rows, grid)
    expected = np.array([by_hand[t] for t in grid], float)
    np.testing.assert_allclose(bands["a"][0], expected.mean(axis=1))
    np.testing.assert_allclose(bands["a"][1], expected.std(axis=1))
    np.testing.assert_allclose(bands["b"][0], 0.0)


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A one-node Ray cluster started with ``ray start --head``, as on a real head node; its address.

    It uses token authentication (Ray's default from 2.59 on), with the token in ``RAY_AUTH_TOKEN`` for
    the head and for the ``maptidal`` processes that join it."""
    pytest.importorskip("ray")
    ray_command = Path(sys.executable).with_name("ray")
    port = _free_port()
    temp = Path("/tmp") / f"ray_{os.getpid()}"  # Ray's socket paths must stay short
    environment = pytest.MonkeyPatch()
    environment.setenv("RAY_AUTH_MODE", "token")
    environment.setenv("RAY_AUTH_TOKEN", secrets.token_hex(32))
    started = subprocess.run(
        [
            str(ray_command),
            "start",
            "--head",
            f"--port={port}",
            "--num-cpus=2",
            "--include-dashboard=false",
            "--disable-usage-stats",
            f"--temp-dir={temp}",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert started.returncode == 0, started.stderr
    try:
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([str(ray_command), "stop", "--force"], capture_output=True, timeout=120)
        shutil.rmtree(temp, ignore_errors=True)
        environment.undo()


def _rows(folder: Path) -> list[dict]:
    document = json.loads((folder / "batch.json").read_text())
    return [{k: v for k, v in row.items() if k not in WALL_CLOCK} for row in document["rows"]]


def test_a_batch_gives_the_same_numbers_locally_and_on_ray(tmp_path, ray_cluster):
    common = ["batch", "--seeds", "1-2", "--duration", "15", "--jobs", "2", "--no-plots"]
    local = run_maptidal(*common, "--out", tmp_path / "local")
    assert local.returncode == 0, local.stderr
    on_ray = run_maptidal(
        *common, "--executor", "ray", "--ray-address", ray_cluster, "--out", tmp_path / "ray"
    )
    assert on_ray.returncode == 0, on_ray.stderr
    rows = _rows(tmp_path / "local")
    assert [row["seed"] for row in rows] == [1, 2]
    assert rows == _rows(tmp_path / "ray")
    assert rows[0] != rows[1], "two seeds gave the same mission"
    for row in rows:
        mission = json.loads((tmp_path / "local" / row["folder"] / "mission.json").read_text())
        expected = {k: v for k, v in mission_metrics(mission).items() if k not in WALL_CLOCK}
        assert {k: row[k] for k in expected} == expected
        assert row["tasks_found"] > 0 and row["messages"] > 0
    csv_lines = (tmp_path / "local" / "batch.csv").read_text().splitlines()
    assert csv_lines[0].startswith("planner,seed,folder,finished") and len(csv_lines) == 3
    assert (tmp_path / "local" / "batch.png").stat().st_size > 0
    assert (tmp_path / "local" / "coverage_time.png").stat().st_size > 0
    assert "| tasks_found |" in (tmp_path / "local" / "batch.md").read_text()
    assert "| tasks_found |" in local.stdout


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--seeds", "9-3"], "bad seeds"),
        (["--ray-address", "127.0.0.1:1"], "needs --executor ray"),
        (["--jobs", "0"], "must be at least 1"),
        (["--duration", "-5"], "must be greater than 0"),
        (["--planners", "voronoi,greedy"], "unknown planner 'greedy'"),
        (["--seeds", ""], "bad seeds"),
        (["a.toml", "--scenario", "b.toml"], "two scenarios given (a.toml, --scenario b.toml)"),
        (["--scenario", "no_such_mission.toml"], "scenario not found: no_such_mission.toml"),
    ],
)
def test_bad_batch_arguments_give_one_line(tmp_path, arguments, message):
    assert_one_line_error(maptidal_here("batch", *arguments, "--out", tmp_path / "b"), message)


def test_parse_planners():
    assert parse_planners("all") == ["maptidal", "voronoi", "boustrophedon"]
    assert parse_planners("voronoi, maptidal") == ["voronoi", "maptidal"]
    for bad in ("greedy", "voronoi,voronoi", ""):
        with pytest.raises(ValueError):
            parse_planners(bad)


def test_each_planner_flies_each_seed_and_the_table_sets_them_side_by_side(tmp_path):
    rows, summary = run_batch(
        None, [1], tmp_path, duration_s=8.0, planners=["voronoi", "boustrophedon"], progress=False
    )
    assert [(row["planner"], row["seed"]) for row in rows] == [("voronoi", 1), ("boustrophedon", 1)]
    assert set(summary) == {"voronoi", "boustrophedon"}
    for row in rows:
        assert (tmp_path / row["folder"] / "mission.json").is_file()  # voronoi/seed_001, ...
        assert summary[row["planner"]]["tasks_found"]["mean"] == row["tasks_found"]
    table = (tmp_path / "batch.md").read_text()
    assert "| metric | unit | voronoi | boustrophedon |" in table
    # ... and the second against the first, seed by seed (one seed: no interval)
    assert "## Each planner against voronoi, seed by seed" in table and "### boustrophedon" in table
    assert (tmp_path / "batch.png").stat().st_size > 0
    # where each robot's time went, per planner and robot: the rows' own, a bar each
    for row in rows:
        document = json.loads((tmp_path / row["folder"] / "mission.json").read_text())
        assert row["time_use"] == {name: use["seconds"] for name, use in document["time_use"].items()}
        for robot in row["time_use"]:
            assert f"| {row['planner']}, {robot} |" in table
        # why each robot stopped exploring, as its mission says (None: it had not)
        explored = document["explored"]
        assert row["explored"] == {name: info and info["why"] for name, info in explored.items()}
    assert (tmp_path / "time_use.png").stat().st_size > 0


def test_the_time_use_means_are_per_planner_and_robot_with_a_missing_occupation_as_nought():
    rows = [
        {"planner": "a", "time_use": {"r0": {"first sweep": 20.0, "tasks": 10.0}, "r1": {"lost": 4.0}}},
        {"planner": "a", "time_use": {"r0": {"first sweep": 22.0, "surveying": 6.0}, "r1": {"lost": 8.0}}},
        {"planner": "b", "time_use": {"r0": {"tasks": 5.0}}},
        {"planner": "b", "time_use": {}},  # a mission recorded before the time use: left out
    ]
    means = time_use_means(rows)
    assert means == {
        "a": {"r0": {"first sweep": 21.0, "surveying": 3.0, "tasks": 5.0}, "r1": {"lost": 6.0}},
        "b": {"r0": {"tasks": 5.0}},
    }
    table = "\n".join(time_use_markdown(means))
    assert "| planner, robot | first sweep | surveying | tasks | lost |" in table
    assert "| a, r1 | 0 | 0 | 0 | 6 |" in table and "| b, r0 | 0 | 0 | 5 | 0 |" in table
    assert time_use_markdown({}) == []


def test_why_the_robots_stopped_exploring_is_counted_per_planner_and_robot():
    """exploring_ends: per planner and robot, the missions per reason (a robot that never stopped is
    "not explored"); the table lists the reasons most frequent first, and nothing without any."""
    rows = [
        {"planner": "maptidal", "explored": {"r0": "too little to see", "r1": "no stand"}},
        {"planner": "maptidal", "explored": {"r0": "too little to see", "r1": None}},
        {"planner": "maptidal", "explored": {"r0": "no stand", "r1": "no stand"}},
        {"planner": "voronoi", "explored": {"r0": "not exploring: its first sweep only"}},
        {"planner": "voronoi"},  # a row from before the explored record: nothing to count
    ]
    ends = exploring_ends(rows)
    assert ends == {
        "maptidal": {
            "r0": {"too little to see": 2, "no stand": 1},
            "r1": {"no stand": 2, "not explored": 1},
        },
        "voronoi": {"r0": {"not exploring: its first sweep only": 1}},
    }
    table = "\n".join(exploring_ends_markdown(ends))
    assert "| maptidal, r0 | too little to see 2, no stand 1 |" in table
    assert "| maptidal, r1 | no stand 2, not explored 1 |" in table
    assert exploring_ends_markdown({}) == [] and exploring_ends([{"planner": "a"}]) == {}


def test_a_bad_mission_file_fails_before_any_run(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(MISSION_FILE.read_text() + "\n[mission]\nduration_s = 5\nspeed = 3\n")
    done = run_maptidal("batch", bad, "--seeds", "1-3", "--out", tmp_path / "b")
    assert_one_line_error(done, "[mission] takes only")
    assert not (tmp_path / "b" / "seed_001").exists()


def test_a_sweep_gives_the_same_rows_locally_and_on_ray(tmp_path, ray_cluster):
    """sweep --executor ray: the grid cells run as Ray tasks (each worker builds its keyframes and
    coverage model once, through the executor's initializer) and come back as the local run's rows."""
    grid = ["--grid", "t=0.75", "r_ex=1.5,1.8", "theta_ex=0.25,0.3", "--no-plots", "--json"]
    local = run_maptidal("sweep", *grid, "--jobs", "2", "--out", tmp_path / "local")
    assert local.returncode == 0, local.stderr
    on_ray = run_maptidal(
        "sweep", *grid, "--executor", "ray", "--ray-address", ray_cluster, "--out", tmp_path / "ray"
    )
    assert on_ray.returncode == 0, on_ray.stderr
    rows = json.loads(local.stdout)["rows"]
    assert len(rows) == 4 and rows == json.loads(on_ray.stdout)["rows"]
