"""The paper's Table I data file, its colour rule, and sweep --paper-grid."""

from __future__ import annotations

import json

import pytest

from maptidal.cli import main
from maptidal.evaluation.paper_table import (
    PAPER_GRID,
    colour_class,
    paper_cells,
    rank_correlations,
    side_by_side,
    trends,
)


def _cell(t, r_ex, theta_ex):
    (cell,) = [c for c in paper_cells() if (c["t"], c["r_ex"], c["theta_ex"]) == (t, r_ex, theta_ex)]
    return cell


def test_the_data_file_matches_the_paper():
    """Spot checks typed in from the paper's Table I."""
    cells = paper_cells()
    assert len(cells) == 24
    assert {(c["t"], c["r_ex"], c["theta_ex"]) for c in cells} == {
        (t, r, a) for t in PAPER_GRID["t"] for r in PAPER_GRID["r_ex"] for a in PAPER_GRID["theta_ex"]
    }
    best = _cell(0.75, 1.7, 0.25)  # the paper's best setting (Sec. IV.D)
    assert (best["avg"], best["num"], best["pct"]) == (2.56, 20, 3.81)
    assert (_cell(0.70, 1.7, 0.30)["num"], _cell(0.70, 1.7, 0.30)["pct"]) == (18, 21.16)
    assert (_cell(0.80, 1.5, 0.30)["avg"], _cell(0.80, 1.5, 0.30)["avg_colour"]) == (3.06, "yellow")
    assert (_cell(0.70, 1.5, 0.25)["avg"], _cell(0.70, 1.5, 0.25)["avg_colour"]) == (4.26, "red")
    assert _cell(0.75, 1.6, 0.25)["pct"] == 11.73 and _cell(0.75, 1.6, 0.25)["pct_colour"] == "none"


def test_the_colour_rule_reproduces_the_printed_colours_but_for_two_stated_exceptions():
    mismatches = set()
    for c in paper_cells():
        rule = colour_class(c["avg"], c["num"], c["pct"])
        for column in ("avg", "num", "pct"):
            if rule[column] != c[f"{column}_colour"]:
                mismatches.add(
                    (c["t"], c["r_ex"], c["theta_ex"], column, c[f"{column}_colour"], rule[column])
                )
    assert mismatches == {
        (0.75, 1.7, 0.25, "avg", "green", "yellow"),  # 2.56 printed green; the text says under 2.5
        (0.70, 1.5, 0.30, "num", "yellow", "green"),  # 25 printed yellow; the text says 15 to 25
        (0.80, 1.7, 0.25, "num", "yellow", "green"),
    }


def _rows_from(values):
    return [
        {"t": c["t"], "r_ex": c["r_ex"], "theta_ex": c["theta_ex"], **v}
        for c, v in zip(paper_cells(), values, strict=True)
    ]


def test_rank_correlations_and_trends_on_known_rows():
    same = _rows_from(
        [{"mean_views": c["avg"], "tasks": c["num"], "pct_uninspected": c["pct"]} for c in paper_cells()]
    )
    cells = side_by_side(same)
    assert rank_correlations(cells) == pytest.approx({"avg": 1.0, "num": 1.0, "pct": 1.0})
    flipped = _rows_from(
        [{"mean_views": -c["avg"], "tasks": -c["num"], "pct_uninspected": -c["pct"]} for c in paper_cells()]
    )
    assert rank_correlations(side_by_side(flipped)) == pytest.approx({"avg": -1.0, "num": -1.0, "pct": -1.0})
    paper_trends = trends(cells, "paper")
    assert paper_trends["lower_r_ex_more_tasks"] and paper_trends["lower_theta_ex_more_tasks"]  # as stated
    with pytest.raises(ValueError, match="lacks the paper's cell"):
        side_by_side(same[:-1])


def test_sweep_paper_grid_prints_ours_beside_the_papers(tmp_path, capsys):
    assert main(["sweep", "--paper-grid", "--no-plots", "--json", "--out", str(tmp_path)]) == 0
    document = json.loads(capsys.readouterr().out)
    assert set(document) == {"cells", "rank_correlation", "trends"}
    assert len(document["cells"]) == 24
    cell = document["cells"][0]
    assert set(cell) == {"t", "r_ex", "theta_ex", "ours", "paper"}
    assert set(cell["ours"]) == {"avg", "num", "pct", "classes"}
    assert (tmp_path / "paper_table.md").exists() and (tmp_path / "paper_table.json").exists()
    assert main(["sweep", "--paper-grid", "--grid", "t=0.7", "--out", str(tmp_path)]) == 2


def test_the_papers_capture_protocol_is_seven_keyframes_rising_half_a_metre():
    from maptidal.evaluation.comparison import EvaluationConfig, config_keyframes
    from maptidal.keyframes import PaperCaptureParams, paper_capture_poses
    from maptidal.tank import TankModel

    poses = paper_capture_poses()
    assert len(poses) == 7
    heights = [position[2] for position, _ in poses]
    assert heights[-1] - heights[0] == pytest.approx(0.5) and heights == sorted(heights)
    assert all(position[0] == -1.0 and position[1] == 0.0 for position, _ in poses)  # 1 m, centre line
    assert all(forward.tolist() == [1.0, 0.0, 0.0] for _, forward in poses)  # facing the end wall
    assert len(paper_capture_poses(PaperCaptureParams(keyframes=3))) == 3
    keyframes = config_keyframes(TankModel(), EvaluationConfig(capture="paper"))
    assert len(keyframes) == 7 and all(len(k.mesh.faces) > 0 for k in keyframes)
    with pytest.raises(ValueError, match="capture"):
        EvaluationConfig(capture="spiral")
