"""The ``maptidal`` command line, one module per command group.

Subcommands:
  discover     Map-TIDAL task discovery on one mesh (PLY, OBJ or STL)   (cli.discovery)
  demo         discovery over a pass of synthetic keyframes             (cli.discovery)
  capture      fly a scripted path and record stereo frames and poses    (cli.perception)
  discover-frames  the stereo front end and discovery on a recording    (cli.perception)
  run          the closed-loop mission; `make run`                      (cli.mission)
  report       rebuild a mission's report from its event log            (cli.mission)
  batch        Monte-Carlo missions over seeds, local or on Ray         (cli.mission)
  coverage     views per voxel of a task list on the tank model         (cli.evaluation)
  compare      Map-TIDAL against Voronoi and boustrophedon (Sec. IV.E)  (cli.evaluation)
  sweep        Map-TIDAL over a grid of t, r_ex, theta_ex (Table I)     (cli.evaluation)
  calibrate-tank  the tank's unknown dimensions fitted to the baselines  (cli.evaluation)
  sim          step the MuJoCo world with a constant pilot command      (cli.world)
  export-mjcf  write a scenario's world as MJCF files                   (cli.world)
  allocate     decentralised CBBA allocation over an acoustic channel   (cli.allocation)

Every subcommand has ``--help``. Bad input (a bad value, file or path) ends with a one-line error and
exit status 2, Ctrl-C with one line and status 130 and SIGTERM with one line and status 143, never a
traceback; outputs are written atomically, so nothing half-written is left behind.

This package's own module is kept light: :func:`main` installs the signal handling
(:mod:`maptidal.cli.interrupts`) before it imports the commands (:mod:`maptidal.cli.app`), which takes
about a second; the parser and the rest are reached through here lazily.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence

from maptidal.cli.interrupts import Interrupts, prefix_from_argv


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``maptidal`` console script; returns the exit status.

    0 on success, 2 for bad input (values, files, paths, configs, a closed output pipe), 130 when
    interrupted (Ctrl-C), 143 when terminated (SIGTERM), 1 for an internal error. Each failure is one
    line on stderr; set MAPTIDAL_TRACEBACK=1 to see the traceback of an internal error.
    """
    with Interrupts() as interrupts:
        try:
            app = importlib.import_module("maptidal.cli.app")
            if interrupts.received is None:  # else the signal came during the imports and was swallowed
                return app.main(argv, interrupts)
        except KeyboardInterrupt:
            pass  # during the imports, or one that app.main had no handler around yet
        # A signal in the imports' last 20 ms leaves its retry pending after them: it raises once, in the
        # first instructions from here, so settle before anything else, and absorb that one raise
        try:
            interrupts.settle()
        except KeyboardInterrupt:
            interrupts.settle()
        print(interrupts.message(prefix_from_argv(argv)), file=sys.stderr)
        return interrupts.status


def __getattr__(name: str):
    """``build_parser``, the exit statuses and the rest of :mod:`maptidal.cli.app`, imported on first use."""
    if name.startswith("__"):
        raise AttributeError(name)
    # import_module, not ``from maptidal.cli import app``, which would ask this function for ``app``
    return getattr(importlib.import_module("maptidal.cli.app"), name)
