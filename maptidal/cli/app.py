"""The ``maptidal`` command's parser and its error handling: each command group registers its
subcommands (:mod:`maptidal.cli.discovery`, ``perception``, ``mission``, ``evaluation``, ``world``,
``allocation``, ``mavlink``); :func:`main` runs one and turns every failure into one line and a status.
:func:`maptidal.cli.main` calls it once the signal handling is in place.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from importlib.metadata import PackageNotFoundError, version

from maptidal import progress
from maptidal.cli import allocation, discovery, evaluation, mavlink, mission, perception, world
from maptidal.cli.common import EXIT_BAD_INPUT, Parser, RunError, UsageError, check_gl_backend
from maptidal.cli.interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED, Interrupts, prefix_from_argv

__all__ = ["EXIT_BAD_INPUT", "EXIT_INTERRUPTED", "EXIT_TERMINATED", "build_parser", "main"]

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


def _interrupted(interrupts: Interrupts, prefix: str, args) -> int:
    """Print the one line of an interrupted command, and return its status."""
    hint = ""
    if getattr(args, "subcommand", None) == "run" and getattr(args, "out", None):
        hint = f"; `maptidal report {args.out}` rebuilds the report"
    # a progress bar on a terminal leaves its line open: end it first, so the message stands alone
    opening = "\n" if progress.line_open() else ""
    print(opening + interrupts.message(prefix, hint), file=sys.stderr)
    return interrupts.status


def main(argv: Sequence[str] | None = None, interrupts: Interrupts | None = None) -> int:
    """Parse ``argv``, run the subcommand and return the exit status (see :func:`maptidal.cli.main`,
    which installs ``interrupts`` first; without them a KeyboardInterrupt still ends in one line)."""
    interrupts = interrupts or Interrupts()
    try:
        from maptidal.discovery import DiscoveryInputError
        from maptidal.tank import TankConfigError

        args = build_parser().parse_args(argv)
    except UsageError as err:
        print(err, file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return _interrupted(interrupts, prefix_from_argv(argv), None)
    prefix = f"maptidal {args.subcommand}"
    try:
        check_gl_backend()
        status = args.handler(args)
        sys.stdout.flush()
        if interrupts.received is not None:  # a library swallowed the KeyboardInterrupt: say so all the same
            interrupts.settle()  # inside the try: a retry still pending lands in the handler below
            return _interrupted(interrupts, prefix, args)
        return status
    except KeyboardInterrupt:
        return _interrupted(interrupts, prefix, args)
    except BrokenPipeError:
        _silence_stdout()
        print(f"{prefix}: error: the output pipe was closed before all output was written", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as err:
        if interrupts.received is not None:
            # the signal's KeyboardInterrupt came out as another error: an extension's argument conversion
            # (pybind11's, building the MuJoCo model) reports it as a TypeError of its own
            return _interrupted(interrupts, prefix, args)
        return _failed(err, prefix, (RunError, DiscoveryInputError, TankConfigError))


def _failed(err: Exception, prefix: str, ours: tuple[type, ...]) -> int:
    """One line for a command that failed with ``err``: bad input (status 2: one of ``ours``, the
    project's input errors, or a bad value, key, path or number) or an internal error (1)."""
    if isinstance(err, ours + (ValueError, KeyError, OSError, OverflowError)):
        print(f"{prefix}: error: {_message(err)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if isinstance(err, MemoryError):
        print(f"{prefix}: error: out of memory; try smaller inputs", file=sys.stderr)
        return EXIT_BAD_INPUT
    if os.environ.get("MAPTIDAL_TRACEBACK"):
        raise err
    print(
        f"{prefix}: internal error: {type(err).__name__}: {err} (MAPTIDAL_TRACEBACK=1 shows where)",
        file=sys.stderr,
    )
    return EXIT_INTERNAL_ERROR


if __name__ == "__main__":
    sys.exit(main())
