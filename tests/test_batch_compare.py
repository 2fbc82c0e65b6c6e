"""Two batches compared seed by seed (maptidal.mission.batch_compare, `maptidal compare-batches`): the
paired differences and their Student's t intervals against a hand calculation with the t table's value,
the pairing by planner and seed, both of a batch's files, and the command's outputs and one-line errors."""

from __future__ import annotations

import json
import math

import pytest
from cli_helpers import assert_one_line_error, maptidal_here

from maptidal.mission.batch import METRICS, WALL_CLOCK, batch_csv
from maptidal.mission.batch_compare import (
    COMPARED,
    between_planners,
    compare_batches,
    comparison_markdown,
    paired_difference,
    planners_pairs_markdown,
    read_batch,
)

# Student's t at 97.5 % (a two-sided 95 % interval), from the t table: 4 and 9 degrees of freedom
T_4, T_9 = 2.7764, 2.2622


def _row(seed: int, planner: str = "maptidal", **values) -> dict:
    """A batch row with every metric at 1, but those given."""
    row = {"planner": planner, "seed": seed, "folder": f"seed_{seed:03d}", "finished": True}
    row.update(dict.fromkeys((*METRICS, *WALL_CLOCK), 1.0))
    row.update(values)
    return row


def test_the_mean_difference_and_its_interval_are_students_t_on_the_seeds_differences():
    before = [_row(s, completion_time_s=300.0 + 7 * s) for s in range(5)]
    steps = [1.0, 2.0, 3.0, 4.0, 5.0]  # after - before, seed by seed
    after = [_row(s, completion_time_s=300.0 + 7 * s + steps[s]) for s in range(5)]
    d = paired_difference(before, after, "completion_time_s", "maptidal")
    mean = sum(steps) / 5
    s = math.sqrt(sum((x - mean) ** 2 for x in steps) / 4)  # 1.58, the sample deviation
    half = T_4 * s / math.sqrt(5)
    assert d.seeds == (0, 1, 2, 3, 4)
    assert d.mean_difference == pytest.approx(3.0)
    assert d.mean_before == pytest.approx(314.0) and d.mean_after == pytest.approx(317.0)
    assert d.low == pytest.approx(mean - half, abs=1e-3) and d.high == pytest.approx(mean + half, abs=1e-3)
    assert d.higher_in == 5 and d.lower_in == 0 and d.within_noise is False
    # the seeds' own spread (7 s a seed) plays no part: only the differences do
    spread = [_row(s, completion_time_s=300.0 + 70 * s + steps[s]) for s in range(5)]
    wide = paired_difference(
        [_row(s, completion_time_s=300.0 + 70 * s) for s in range(5)], spread, "completion_time_s", "maptidal"
    )
    assert (wide.low, wide.high) == pytest.approx((d.low, d.high))


def test_a_difference_that_goes_either_way_is_within_the_seeds_noise():
    steps = [-30.0, 25.0, -10.0, 40.0, -20.0, 15.0, 5.0, -35.0, 30.0, -5.0]
    before = [_row(s, pct_uninspected=3.0) for s in range(10)]
    after = [_row(s, pct_uninspected=3.0 + steps[s] / 10) for s in range(10)]
    d = paired_difference(before, after, "pct_uninspected", "maptidal")
    mean = sum(steps) / 100
    s = math.sqrt(sum((x / 10 - mean) ** 2 for x in steps) / 9)
    assert d.low == pytest.approx(mean - T_9 * s / math.sqrt(10), abs=1e-3)
    assert d.within_noise is True and d.lower_in == 5 and d.higher_in == 5


def test_pairs_are_made_by_planner_and_seed_and_only_where_both_batches_have_the_metric():
    before = [
        _row(3, tasks_found=10.0),
        _row(1, tasks_found=12.0),
        _row(2, tasks_found=None),  # not in the pairs
        _row(5, tasks_found=20.0),  # no such seed after
        _row(4, tasks_found=15.0),  # the same after: neither lower nor higher
        _row(1, "voronoi", tasks_found=30.0),
    ]
    after = [
        _row(1, tasks_found=14.0),
        _row(2, tasks_found=9.0),
        _row(3, tasks_found=11.0),
        _row(4, tasks_found=15.0),
        _row(1, "voronoi", tasks_found=28.0),
    ]
    ours = paired_difference(list(reversed(before)), after, "tasks_found", "maptidal")
    assert ours.seeds == (1, 3, 4) and ours.before == (12.0, 10.0, 15.0) and ours.after == (14.0, 11.0, 15.0)
    assert ours.mean_difference == pytest.approx(1.0) and (ours.lower_in, ours.higher_in) == (0, 2)
    theirs = paired_difference(before, after, "tasks_found", "voronoi")
    assert theirs.seeds == (1,) and theirs.mean_difference == pytest.approx(-2.0)
    assert theirs.low is None and theirs.within_noise is None  # one seed: no interval
    compared = compare_batches(before, after)
    assert {(d.planner, d.metric) for d in compared} == {
        (p, m) for p in ("maptidal", "voronoi") for m in COMPARED
    }
    markdown = comparison_markdown(compared, "old", "new")
    assert "## maptidal" in markdown and "## voronoi" in markdown and "too few seeds" in markdown
    with pytest.raises(ValueError, match="nothing to pair"):
        compare_batches(before, [_row(9)])


def test_a_batch_reads_the_same_from_its_json_and_its_csv(tmp_path):
    rows = [_row(s, completion_time_s=250.0 + s, time_to_95_s=None) for s in (4, 2, 7)]
    (tmp_path / "csv").mkdir()
    (tmp_path / "csv" / "batch.csv").write_text(batch_csv(rows))
    (tmp_path / "json").mkdir()
    (tmp_path / "json" / "batch.json").write_text(json.dumps({"rows": rows, "summary": {}}))
    from_csv, from_json = read_batch(tmp_path / "csv"), read_batch(tmp_path / "json")
    for a, b in zip(from_csv, from_json, strict=True):
        for name in ("planner", "seed", *COMPARED):
            assert a[name] == b[name], name
    assert [row["seed"] for row in from_csv] == [4, 2, 7]


def test_compare_batches_writes_its_table_data_and_plot(tmp_path):
    for name, shift in (("before", 0.0), ("after", -12.0)):
        folder = tmp_path / name
        folder.mkdir()
        rows = [_row(s, completion_time_s=300.0 + 5 * s + shift + (s % 3)) for s in range(6)]
        (folder / "batch.csv").write_text(batch_csv(rows))
    done = maptidal_here(
        "compare-batches", tmp_path / "before", tmp_path / "after", "--out", tmp_path / "cmp"
    )
    assert done.returncode == 0, done.stderr
    assert "| finish time (s) |" in done.stdout and "lower |" in done.stdout
    document = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    finish = next(d for d in document["differences"] if d["metric"] == "completion_time_s")
    assert finish["lower_in"] == 6 and finish["ci_high"] < 0 and finish["within_noise"] is False
    assert (tmp_path / "cmp" / "compare.md").read_text().startswith("# after against before")
    assert (tmp_path / "cmp" / "compare.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_batches_are_one_line(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "batch.csv").write_text(batch_csv([_row(8)]))
    (tmp_path / "ours").mkdir()
    (tmp_path / "ours" / "batch.csv").write_text(batch_csv([_row(1)]))
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "batch.json").write_text("{not json")
    (tmp_path / "twice").mkdir()
    (tmp_path / "twice" / "batch.csv").write_text(batch_csv([_row(1), _row(2), _row(1)]))
    (tmp_path / "none").mkdir()
    (tmp_path / "none" / "batch.csv").write_text(batch_csv([]))
    out = tmp_path / "cmp"
    for before, after, message in (
        (tmp_path / "missing", tmp_path / "ours", "no such batch folder"),
        (tmp_path / "empty", tmp_path / "ours", "neither batch.json nor batch.csv"),
        (tmp_path / "broken", tmp_path / "ours", "not a batch's batch.json"),
        (tmp_path / "none", tmp_path / "ours", "no mission in it"),
        (tmp_path / "other", tmp_path / "ours", "nothing to pair"),
        (tmp_path / "ours", tmp_path / "twice", "seed 1 of maptidal is there twice"),
    ):
        assert_one_line_error(maptidal_here("compare-batches", before, after, "--out", out), message)


def test_each_planner_is_set_against_map_tidal_seed_by_seed_in_one_batch():
    finish = {"maptidal": [300.0, 280.0, 320.0, 290.0], "boustrophedon": [130.0, 120.0, 160.0, 125.0]}
    rows = [
        _row(seed, planner, completion_time_s=values[seed])
        for planner, values in finish.items()
        for seed in range(4)
    ]
    rows.append(_row(0, "voronoi", completion_time_s=200.0))
    differences = between_planners(rows, "maptidal", "boustrophedon")
    d = next(d for d in differences if d.metric == "completion_time_s")
    steps = [b - m for m, b in zip(finish["maptidal"], finish["boustrophedon"], strict=True)]
    mean = sum(steps) / 4
    s = math.sqrt(sum((x - mean) ** 2 for x in steps) / 3)
    assert d.planner == "boustrophedon - maptidal" and d.mean_difference == pytest.approx(mean)
    assert d.high == pytest.approx(mean + 3.1824 * s / 2, rel=1e-4)  # t table, 3 degrees of freedom
    assert d.lower_in == 4 and d.within_noise is False
    lines = planners_pairs_markdown(rows)
    text = "\n".join(lines)
    assert "### boustrophedon" in text and "### voronoi" in text and "too few seeds" in text
    assert "| finish time (s) | 298 | 134 |" in text
    assert planners_pairs_markdown([row for row in rows if row["planner"] == "maptidal"]) == []
    assert planners_pairs_markdown(rows, reference="greedy") == []
    # without Map-TIDAL, each planner against the first
    others = "\n".join(planners_pairs_markdown([row for row in rows if row["planner"] != "maptidal"]))
    assert "against boustrophedon" in others and "### voronoi" in others and "### boustrophedon" not in others


def test_the_random_tanks_bench_pairs_each_tanks_missions_by_seed(tmp_path):
    """tests/bench/random_tanks.py --against: two tanks of two seeds each are four pairs (a seed of one
    tank is not the same seed's mission of another), and the difference is the missions' mean."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
    import random_tanks

    finish = {"before": {(0, 0): 300.0, (0, 1): 310.0, (1, 0): 200.0, (1, 1): 220.0}}
    finish["after"] = {
        key: value + step for (key, value), step in zip(finish["before"].items(), (1, 2, 3, 6), strict=True)
    }
    for run, values in finish.items():
        for tank in (0, 1):
            folder = tmp_path / run / f"random_{tank:02d}" / "batch"
            folder.mkdir(parents=True)
            rows = [_row(seed, completion_time_s=values[(tank, seed)]) for seed in (0, 1)]
            (folder / "batch.csv").write_text(batch_csv(rows))
    text = random_tanks.paired_against(tmp_path / "after", tmp_path / "before", 2)
    (line,) = [line for line in text.splitlines() if line.startswith("| finish time")]
    assert "| 3 [" in line and "0 / 4 of 4" in line, line  # mean of 1, 2, 3 and 6; higher on all four
