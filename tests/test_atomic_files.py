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
