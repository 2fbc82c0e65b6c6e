"""Running the ``maptidal`` command in a subprocess, as a user would, for the tests that check its exit
status and its one-line errors."""

from __future__ import annotations

import subprocess
import sys


def run_maptidal(*args, timeout: float = 300) -> subprocess.CompletedProcess:
    """``maptidal ARGS...`` in a fresh interpreter; stdout and stderr captured as text."""
    return subprocess.run(
        [sys.executable, "-m", "maptidal.cli", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def assert_one_line_error(done: subprocess.CompletedProcess, message: str = "") -> None:
    """Exit status 2 and one line on stderr naming ``message``, never a traceback."""
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in done.stderr, done.stderr
