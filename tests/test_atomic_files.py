"""Atomic writes (maptidal/files.py) leave files with the mode a plain open gives them, and figures go
through them too (issue [signals])."""

from __future__ import annotations

import os
import stat

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pytest

from maptidal.files import atomic_write_text, save_png


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_an_atomic_write_gets_the_umasks_mode_not_mkstemps(tmp_path, umask):
    previous = os.umask(umask)
    try:
        written = atomic_write_text(tmp_path / "report.md", "# a report\n")
        with open(tmp_path / "plain.md", "w") as plain:  # what a plain open gives, the reference
            plain.write("x")
    finally:
        os.umask(previous)
    mode = stat.S_IMODE(written.stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "plain.md").stat().st_mode) == 0o666 & ~umask


def test_a_figure_is_saved_atomically_as_a_png(tmp_path):
    figure, axis = plt.subplots()
    axis.plot([0, 1], [1, 0])
    path = save_png(figure, tmp_path / "plot.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plot.png"]  # no temporary left behind
    assert not plt.fignum_exists(figure.number)  # and the figure is closed


def test_a_reused_mission_folder_is_cleared_of_the_earlier_missions_files_and_nothing_else(tmp_path):
    from maptidal.mission.outputs import MISSION_FILES, MissionWriter

    out = tmp_path / "mission"
    (out / "images").mkdir(parents=True)
    for name in MISSION_FILES:
        (out / name).write_text("from an earlier mission")
    (out / "images" / "task_0999_rov1.png").write_bytes(b"stale")
    (out / "notes.txt").write_text("the user's own")  # not ours: kept
    (out / "images" / "sketch.jpg").write_bytes(b"not a task image")  # not ours either
    writer = MissionWriter(out)
    writer.event(0.0, "start", robots=["rov0"])
    assert writer.cleared == len(MISSION_FILES) + 1
    assert not (out / "images" / "task_0999_rov1.png").exists()
    assert not (out / "mission.mp4").exists() and not (out / "report.md").exists()
    assert (out / "notes.txt").read_text() == "the user's own"
    assert (out / "images" / "sketch.jpg").exists()
    assert MissionWriter(tmp_path / "new").cleared == 0
