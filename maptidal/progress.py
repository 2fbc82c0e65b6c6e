"""A dependency-free progress bar for long runs, written to stderr.

On a terminal it redraws one line; in a log (CI, a pipe) it prints a line at
every tenth of the way, so logs stay short.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

_open_bars: set[int] = set()  # the interactive bars whose line is drawn and not yet ended


def line_open() -> bool:
    """Whether a progress bar on a terminal has drawn a line it has not ended (a message printed now
    should start on a new line)."""
    return bool(_open_bars)


class ProgressBar:
    """Count ``total`` steps of work labelled ``label``; call :meth:`advance` per step."""

    def __init__(self, total: int, label: str, stream: TextIO | None = None, enabled: bool = True) -> None:
        self.total = max(int(total), 1)
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.done = 0
        self._start = time.monotonic()
        self._last_tenth = -1
        self._interactive = bool(getattr(self.stream, "isatty", lambda: False)())

    def advance(self, steps: int = 1, note: str = "") -> None:
        """Record ``steps`` more finished steps and redraw (a bar already full is not drawn again: work
        that overshoots its count, such as a learner's last batch, would repeat the full bar's line)."""
        was_full = self.done >= self.total
        self.done = min(self.total, self.done + steps)
        if not self.enabled or was_full:
            return
        fraction = self.done / self.total
        elapsed = time.monotonic() - self._start
        filled = round(24 * fraction)
        line = (
            f"{self.label} [{'#' * filled}{'.' * (24 - filled)}] {self.done}/{self.total} "
            f"{elapsed:5.1f}s {note}"
        )
        if self._interactive:
            end = "\n" if self.done == self.total else ""
            self.stream.write("\r" + line.ljust(100)[:100] + end)
            if end:
                _open_bars.discard(id(self))
            else:
                _open_bars.add(id(self))
            self.stream.flush()
            return
        tenth = int(fraction * 10)
        if tenth != self._last_tenth or self.done == self.total:
            self._last_tenth = tenth
            self.stream.write(line.rstrip() + "\n")
            self.stream.flush()
