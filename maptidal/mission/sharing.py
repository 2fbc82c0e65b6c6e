"""How a team's discoveries spread over the acoustic channel, and what a failed robot took with it.

Two tables for ``mission.json`` and the report, from the mission's task ledger and, per robot, when it
learned each task (:attr:`maptidal.allocation.agent.CBBAAgent.learned_s`):

- ``sharing``: per robot, how many of its discoveries a teammate heard, and how long that took
  (median, 90th percentile, most). A robot whose discoveries leave slower than it makes them shows a
  growing delay and unheard tasks.
- ``tasks_lost``: per failed robot, each task it found before failing is exactly one of
    - *done*: some robot completed it (the finder, before failing, or a teammate);
    - *inherited*: a live teammate holds its record, so it stays in the team's auction;
    - *rediscovered*: no live teammate heard of it, but one found a task of its own whose viewpoint lies
      within the task's tolerances (the same position and direction tolerances a capture is verified
      against), so the view is still on the team's books;
    - *lost*: none of these; nobody alive will take that view.

Pure: numpy only, so that recorded missions can be scored again.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def _delays(values: list[float]) -> dict:
    if not values:
        return {"median_s": None, "p90_s": None, "max_s": None}
    a = np.asarray(values)
    return {
        "median_s": round(float(np.median(a)), 3),
        "p90_s": round(float(np.percentile(a, 90)), 3),
        "max_s": round(float(a.max()), 3),
    }


def sharing_table(
    tasks: list[dict], learned: Mapping[str, Mapping[int, float]], failed_at: Mapping[str, float]
) -> dict[str, dict]:
    """Per finder: ``found``, ``heard`` (by a teammate before the end, or before the finder failed),
    ``unheard``, and the delay from discovery to the first teammate that learned it.

    tasks: ledger entries with ``id``, ``found_by``, ``found_at_s``; learned: robot -> task key -> when
    it learned the task; failed_at: robot -> when it failed (a task heard after its finder failed came
    from a relay of a copy, which still counts as heard)."""
    tasks = [t for t in tasks if t.get("found_by") is not None]  # a plan's tasks had no finder
    table: dict[str, dict] = {}
    for finder in sorted({t["found_by"] for t in tasks}):
        own = [t for t in tasks if t["found_by"] == finder]
        delays = []
        for task in own:
            times = [
                heard[task["id"]]
                for robot, heard in learned.items()
                if robot != finder and task["id"] in heard
            ]
            if times:
                delays.append(max(0.0, min(times) - task["found_at_s"]))
        table[finder] = {
            "found": len(own),
            "heard": len(delays),
            "unheard": len(own) - len(delays),
            "delay": _delays(delays),
            **({"failed_at_s": round(failed_at[finder], 3)} if finder in failed_at else {}),
        }
    return table


def tasks_lost(
    tasks: list[dict],
    learned: Mapping[str, Mapping[int, float]],
    failed_at: Mapping[str, float],
    position_tolerance_m: float,
    direction_tolerance_deg: float,
) -> dict[str, dict]:
    """Per failed robot, its discoveries split into done, inherited, rediscovered and lost (the module
    docstring says which is which), with the lost share of those it found and the lost tasks' ids.

    tasks: ledger entries with ``id``, ``found_by``, ``found_at_s``, ``completed``, ``position``,
    ``direction``; learned: robot -> task key -> when it learned it; failed_at: robot -> failure time."""
    tasks = [t for t in tasks if t.get("found_by") is not None]
    alive = [robot for robot in learned if robot not in failed_at]
    by_id = {t["id"]: t for t in tasks}
    held_alive = set().union(*(set(learned[r]) for r in alive)) if alive else set()
    survivors_own = [t for t in tasks if t["found_by"] in alive]
    own_positions = np.array([t["position"] for t in survivors_own], dtype=float).reshape(-1, 3)
    own_directions = np.array([t["direction"] for t in survivors_own], dtype=float).reshape(-1, 3)
    cos_tolerance = math.cos(math.radians(direction_tolerance_deg))
    table: dict[str, dict] = {}
    for robot, failed_s in sorted(failed_at.items()):
        found = [t for t in tasks if t["found_by"] == robot and t["found_at_s"] <= failed_s]
        counts = {"done": 0, "inherited": 0, "rediscovered": 0, "lost": 0}
        lost_ids = []
        for task in found:
            if by_id[task["id"]].get("completed"):
                kind = "done"
            elif task["id"] in held_alive:
                kind = "inherited"
            else:
                near = np.linalg.norm(own_positions - np.asarray(task["position"]), axis=1)
                aligned = own_directions @ np.asarray(task["direction"], dtype=float) >= cos_tolerance
                kind = "rediscovered" if bool(((near <= position_tolerance_m) & aligned).any()) else "lost"
            counts[kind] += 1
            if kind == "lost":
                lost_ids.append(task["id"])
        table[robot] = {
            "failed_at_s": round(failed_s, 3),
            "found": len(found),
            **counts,
            "lost_pct": round(100.0 * counts["lost"] / len(found), 2) if found else 0.0,
            "lost_ids": lost_ids,
        }
    return table
