"""Where each robot's mission time went (issue [loop]): every control period goes to one occupation.

The occupations, the first that holds winning:

- ``not launched``: waiting to join the mission; ``failed``: out of it;
- ``lost``: no visual fix for a while, or too unsure of its position (a robot without a DVL): flying home,
  sweeping there, or standing down;
- ``giving way``: holding out of a teammate's way;
- ``first sweep``: the yaw sweep where it starts;
- ``surveying``: flying to a look at its map's frontier and sweeping there;
- ``tasks``: flying to a view and holding it for its capture;
- ``done``: explored, with no task left;
- ``idle``: with no task, waiting for its next looks to be worked out, or for a teammate near them.

A mission that finishes late on the surveys, or on a robot lost, shows it here: ``mission.json``'s
``time_use`` (per robot, the seconds per occupation and the spans), ``report.md``'s table, the
timeline's bars, and ``maptidal batch``'s ``surveying_s`` and ``lost_s``.

Pure: no simulator, so that a recorded mission's spans can be read again.
"""

from __future__ import annotations

from dataclasses import dataclass, field

OCCUPATIONS = (
    "first sweep",
    "surveying",
    "tasks",
    "giving way",
    "lost",
    "idle",
    "done",
    "not launched",
    "failed",
)
_OF_ACTIVITY = {"explore": "first sweep", "survey": "surveying", "fly": "tasks"}
# the timeline's colours (matplotlib's tab10, and greys for time out of the work)
OCCUPATION_COLOURS = {
    "first sweep": "tab:cyan",
    "surveying": "tab:blue",
    "tasks": "tab:green",
    "giving way": "tab:purple",
    "lost": "tab:red",
    "idle": "tab:olive",
    "done": "0.85",
    "not launched": "0.95",
    "failed": "black",
}


def occupation(activity: str, lost: bool, yielding: bool, explored: bool) -> str:
    """The occupation (module docstring) of a robot whose mission activity is ``activity`` (explore, fly,
    survey, idle, waiting, failed), lost or not, giving way or not, explored or not."""
    if activity == "waiting":
        return "not launched"
    if activity == "failed":
        return "failed"
    if lost:
        return "lost"
    if yielding:
        return "giving way"
    if activity in _OF_ACTIVITY:
        return _OF_ACTIVITY[activity]
    if activity == "idle":
        return "done" if explored else "idle"
    raise ValueError(f"unknown activity {activity!r}")


@dataclass
class TimeUse:
    """One robot's seconds per occupation, and the spans ``(start_s, end_s, occupation)`` it spent in
    each, in order, the last one still open."""

    seconds: dict[str, float] = field(default_factory=dict)
    _spans: list[tuple[float, float, str]] = field(default_factory=list)
    _current: str | None = None
    _since_s: float = 0.0

    def add(self, now_s: float, elapsed_s: float, kind: str) -> None:
        """The period of ``elapsed_s`` that ended at ``now_s`` was spent in ``kind``."""
        if kind not in OCCUPATIONS:
            raise ValueError(f"unknown occupation {kind!r}")
        self.seconds[kind] = self.seconds.get(kind, 0.0) + elapsed_s
        start = now_s - elapsed_s
        if kind != self._current:
            if self._current is not None:
                self._spans.append((self._since_s, start, self._current))
            self._current, self._since_s = kind, start

    def spans(self, now_s: float) -> list[tuple[float, float, str]]:
        """The spans so far, the open one ending at ``now_s``."""
        if self._current is None:
            return list(self._spans)
        return [*self._spans, (self._since_s, now_s, self._current)]

    def seconds_since(self, kind: str, start_s: float, now_s: float) -> float:
        """The seconds spent in ``kind`` between ``start_s`` and ``now_s``."""
        return sum(
            max(min(end, now_s) - max(begin, start_s), 0.0)
            for begin, end, held in self.spans(now_s)
            if held == kind
        )

    def as_dict(self, now_s: float) -> dict:
        """For ``mission.json``: the seconds per occupation (in the order of OCCUPATIONS, rounded to the
        millisecond) and the spans."""
        return {
            "seconds": {k: round(self.seconds[k], 3) for k in OCCUPATIONS if k in self.seconds},
            "spans": [[round(a, 3), round(b, 3), kind] for a, b, kind in self.spans(now_s)],
        }


def occupation_table(first_column: str, rows: list[tuple[str, dict[str, float]]]) -> list[str]:
    """A markdown table of seconds per occupation: a row per ``(label, seconds)``, a column per occupation
    any row has (in the order of OCCUPATIONS), whole seconds; an occupation a row lacks reads 0."""
    kinds = [k for k in OCCUPATIONS if any(k in seconds for _, seconds in rows)]
    lines = [f"| {first_column} | " + " | ".join(kinds) + " |", "|---" * (len(kinds) + 1) + "|"]
    for label, seconds in rows:
        lines.append(f"| {label} | " + " | ".join(f"{seconds.get(k, 0.0):.0f}" for k in kinds) + " |")
    return lines
