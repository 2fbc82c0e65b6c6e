"""Running the ``maptidal`` command in a subprocess, as a user would, for the tests that check its exit
status and its one-line errors; and in this process (:func:`maptidal_here`), for the many tests of bad
input whose error comes before any work, where a fresh interpreter's imports (several seconds on two
busy cores) would be most of the test."""

from __future__ import annotations

import contextlib
import io
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


def maptidal_here(*args) -> subprocess.CompletedProcess:
    """``maptidal ARGS...`` through the same entry point (:func:`maptidal.cli.main`) in this process,
    stdout and stderr captured as text; argparse's exits become the status, as in a process."""
    from maptidal.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = main([str(arg) for arg in args])
        except SystemExit as exit_:
            status = exit_.code if isinstance(exit_.code, int) else 1
    return subprocess.CompletedProcess(["maptidal", *map(str, args)], status, out.getvalue(), err.getvalue())


def assert_one_line_error(done: subprocess.CompletedProcess, message: str = "") -> None:
    """Exit status 2 and one line on stderr naming ``message``, never a traceback."""
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in done.stderr, done.stderr
