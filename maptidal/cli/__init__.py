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
exit status 2, Ctrl-C with one line and status 130, never a traceback; outputs are written atomically,
so nothing half-written is left behind.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from maptidal.cli import allocation, discovery, evaluation, mavlink, mission, perception, world
from maptidal.cli.common import EXIT_BAD_INPUT, EXIT_INTERRUPTED, Parser, RunError, UsageError

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "build_parser", "main"]

EXIT_INTERNAL_ERROR = 1


def package_version() -> str:
    """The installed maptidal version (the source tree's, when it is not installed)."""
    try:
        return version("maptidal")
    except PackageNotFoundError:
        return "0+unknown"


def build_parser() -> Parser:
    """The argument parser of the ``maptidal`` command and its subcommands."""
    parser = Parser(
        prog="maptidal",
        description="Map-TIDAL: mapping-guided task discovery and allocation for cooperative "
        "underwater inspection, in a headless MuJoCo testbed.",
    )
    parser.add_argument("--version", action="version", version=f"maptidal {package_version()}")
    commands = parser.add_subparsers(dest="subcommand", required=True, metavar="COMMAND")
    for group in (discovery, perception, mission, evaluation, world, allocation, mavlink):
        group.register(commands)
    return parser


def _message(err: BaseException) -> str:
    if isinstance(err, KeyError) and err.args:
        return str(err.args[0])
    if isinstance(err, OSError) and err.filename is not None:
        return f"cannot use {err.filename}: {err.strerror or err}"
    return str(err) or type(err).__name__


def _silence_stdout() -> None:
    # the reader of our output went away (`maptidal ... --json | head`): point stdout at /dev/null so that
    # the interpreter's final flush does not raise again
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``maptidal`` console script; returns the exit status.

    0 on success, 2 for bad input (values, files, paths, configs, a closed output pipe), 130 when
    interrupted, 1 for an internal error. Each failure is one line on stderr; set MAPTIDAL_TRACEBACK=1
    to see the traceback of an internal error.
    """
    from maptidal.discovery import DiscoveryInputError
    from maptidal.tank import TankConfigError

    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UsageError as err:
        print(err, file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    prefix = f"maptidal {args.subcommand}"
    try:
        status = args.handler(args)
        sys.stdout.flush()
        return status
    except KeyboardInterrupt:
        print(f"\n{prefix}: interrupted; files written so far are complete", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        _silence_stdout()
        print(f"{prefix}: error: the output pipe was closed before all output was written", file=sys.stderr)
        return EXIT_BAD_INPUT
    except (
        RunError,
        DiscoveryInputError,
        TankConfigError,
        ValueError,
        KeyError,
        OSError,
        OverflowError,
    ) as err:
        print(f"{prefix}: error: {_message(err)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except MemoryError:
        print(f"{prefix}: error: out of memory; try smaller inputs", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:
        if os.environ.get("MAPTIDAL_TRACEBACK"):
            raise
        print(
            f"{prefix}: internal error: {type(err).__name__}: {err} (MAPTIDAL_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL_ERROR


if __name__ == "__main__":
    sys.exit(main())
