"""Ctrl-C and SIGTERM for the ``maptidal`` command, from its first instruction to its last.

Importing the command's modules takes about a second, and a KeyboardInterrupt raised in the middle of
an import does harm: some libraries guard their imports with ``except BaseException`` (trimesh does)
and swallow it, so a Ctrl-C there used to be lost and the whole command ran; others are left half
made (scipy then fails with a NameError). So :class:`Interrupts` is installed before anything heavy is
imported and turns the first SIGINT or SIGTERM into one KeyboardInterrupt in the main thread, raised
*once no import is under way* (a 20 ms timer, SIGALRM, tries again until then), nor the start of a
child process (a spawned child that loses its parent while it reads its start-up data dies with a
traceback of its own). It also remembers the
signal: whoever swallows the exception, the command still ends with one line and the signal's status
(130 for SIGINT, 143 for SIGTERM, the shells' 128 + signal number). Later signals are ignored while
the command winds down, so its clean-up (closing a video, stopping workers) is not cut short by a
second traceback.

Light on purpose: only the standard library, since it runs before the rest is imported.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import threading
from collections.abc import Sequence

EXIT_INTERRUPTED = 128 + signal.SIGINT  # 130
EXIT_TERMINATED = 128 + signal.SIGTERM  # 143
HANDLED = (signal.SIGINT, signal.SIGTERM)
RETRY_S = 0.02  # how often a signal that came at a bad moment is tried again
_IMPORTING = "<frozen importlib"
_STARTING_A_CHILD = os.path.join("multiprocessing", "popen_")  # popen_spawn_posix, popen_fork, ...


def at_a_bad_moment(frame) -> bool:
    """Whether ``frame`` or a frame that called it is importing (importlib's machinery) or starting a
    child process (multiprocessing's Popen classes): no moment to raise a KeyboardInterrupt."""
    while frame is not None:
        name = frame.f_code.co_filename
        if name.startswith(_IMPORTING) or _STARTING_A_CHILD in name:
            return True
        frame = frame.f_back
    return False


class Interrupts:
    """A context in which SIGINT and SIGTERM raise one KeyboardInterrupt and are remembered.

    ``received`` is the first signal's number (None if none came). Outside the main thread (where Python
    cannot install handlers) it does nothing. The previous handlers come back on exit, so that calling
    :func:`maptidal.cli.main` from a program (or a test) leaves its signal handling as it was."""

    def __init__(self) -> None:
        self.received: int | None = None
        self._settled = False  # the command is saying so: a retry still pending must not raise any more
        self._previous: dict[int, object] = {}

    def __enter__(self) -> Interrupts:
        if threading.current_thread() is threading.main_thread():
            for number in HANDLED:
                self._previous[number] = signal.signal(number, self._handle)
            self._previous[signal.SIGALRM] = signal.getsignal(signal.SIGALRM)
        return self

    def __exit__(self, *exc_info) -> None:
        if self._previous:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
        for number, handler in self._previous.items():
            signal.signal(number, handler)  # type: ignore[arg-type]
        self._previous.clear()

    def _handle(self, number: int, frame) -> None:
        if self.received is not None:
            return  # winding down already: one message, one status
        self.received = number
        self._raise_when_safe(frame)

    def _raise_when_safe(self, frame) -> None:
        if self._settled:
            return
        if at_a_bad_moment(frame):
            signal.signal(signal.SIGALRM, lambda _number, later: self._raise_when_safe(later))
            signal.setitimer(signal.ITIMER_REAL, RETRY_S)
            return
        raise KeyboardInterrupt

    @property
    def status(self) -> int:
        """The exit status: 143 after SIGTERM, else 130 (SIGINT, or a KeyboardInterrupt from elsewhere)."""
        return EXIT_TERMINATED if self.received == signal.SIGTERM else EXIT_INTERRUPTED

    def settle(self) -> None:
        """The command has seen the signal and is ending: cancel a KeyboardInterrupt still waiting for a
        safe moment. (A signal during the last 20 ms of the imports used to raise it again in the middle
        of printing the one line, a traceback after all.)"""
        self._settled = True
        if self._previous:
            signal.setitimer(signal.ITIMER_REAL, 0.0)

    def message(self, prefix: str, hint: str = "") -> str:
        """The one line to print: what ended the command, that its files are complete, and ``hint``.
        Asking for it settles the signal (:meth:`settle`)."""
        self.settle()
        what = "terminated (SIGTERM)" if self.received == signal.SIGTERM else "interrupted"
        return f"{prefix}: {what}; files written so far are complete{hint}"


def prefix_from_argv(argv: Sequence[str] | None) -> str:
    """``maptidal SUBCOMMAND`` from the raw arguments, for a message printed before parsing finished
    (a Ctrl-C during the imports still names the command the user typed)."""
    words = list(sys.argv[1:] if argv is None else argv)
    command = next((word for word in words if not word.startswith("-")), "")
    return f"maptidal {command}" if re.fullmatch(r"[a-z][a-z0-9-]*", command) else "maptidal"
