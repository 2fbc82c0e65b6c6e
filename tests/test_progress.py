"""The progress bar: a line per tenth of the way in a log, one redrawn line on a terminal, and a full bar
drawn once however far the work overshoots its count."""

from __future__ import annotations

import io

import pytest

from maptidal.progress import ProgressBar, line_open


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_a_line_per_tenth_and_the_full_bar_once():
    log = io.StringIO()
    bar = ProgressBar(100, "work", stream=log)
    for _ in range(130):  # 30 steps past the count, as a learner's last batch overshoots
        bar.advance()
    lines = log.getvalue().splitlines()
    assert len(lines) == 11  # 0.01 (the first tenth, 0), then one line at each tenth up to 10/10
    assert [line.split()[2] for line in lines][-2:] == ["90/100", "100/100"]
    assert sum("100/100" in line for line in lines) == 1


def test_a_terminal_redraws_one_line_and_ends_it_once():
    terminal = _Terminal()
    bar = ProgressBar(10, "work", stream=terminal)
    for _ in range(5):
        bar.advance()
    assert line_open() and "\n" not in terminal.getvalue()
    for _ in range(20):
        bar.advance()
    assert not line_open()
    assert terminal.getvalue().count("\n") == 1 and terminal.getvalue().endswith("\n")
    assert terminal.getvalue().count("10/10") == 1


def test_a_disabled_bar_writes_nothing_and_still_counts():
    log = io.StringIO()
    bar = ProgressBar(4, "work", stream=log, enabled=False)
    bar.advance(3)
    assert log.getvalue() == "" and bar.done == 3


@pytest.mark.parametrize("finished", [True, False])
def test_a_mission_that_ends_before_its_cap_fills_its_bar(monkeypatch, tmp_path, capsys, finished):
    """`maptidal run`'s bar counts the simulated time against the cap: a mission whose work is done at
    180 of 600 s shows a full bar saying so, not one stuck at 30 %."""
    import maptidal.mission.outputs
    import maptidal.mission.run
    from maptidal.cli import main

    class Flown:
        def __init__(self, scenario, params, out):
            self.writer = type("Writer", (), {"cleared": 0})()

        def run(self, progress):
            for now in (60.0, 120.0, 180.0):
                progress(now, 5, 5, 600.0, 90.0)
            return {"finished": finished, "sim_time_s": 180.0}

    monkeypatch.setattr(maptidal.mission.run, "Mission", Flown)
    monkeypatch.setattr(maptidal.mission.outputs, "summary_table", lambda document: "")
    assert main(["run", "--no-plots", "--out", str(tmp_path / "m")]) == 0
    last = capsys.readouterr().err.strip().splitlines()[-1]
    ended = "finished" if finished else "ended"
    assert "100/100" in last and f"{ended} at 180 s, before the cap" in last, last
