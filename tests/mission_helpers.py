"""A default mission built but not flown, for the tests that set its robots' state by hand and call its
steps one at a time."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from maptidal.envs.scenario import Scenario
from maptidal.mission.config import load_mission
from maptidal.mission.params import MissionParams
from maptidal.mission.run import Mission


@contextlib.contextmanager
def mission_at_rest(
    out: Path, scenario: Scenario | None = None, **settings
) -> Iterator[tuple[Mission, MissionParams]]:
    """The default mission file's scenario (or ``scenario``) as a :class:`Mission` writing to ``out`` (1 s
    long, perception inline, no plots, unless ``settings`` say otherwise), and its parameters; its worker,
    renderer and simulator are closed on the way out."""
    if scenario is None:
        scenario, _ = load_mission(None)
    params = MissionParams(**{"duration_s": 1.0, "perception_process": False, "plots": False, **settings})
    mission = Mission(scenario, params, out)
    try:
        yield mission, params
    finally:
        mission.perception.close()
        mission._gl.submit(mission.sim.close).result()
        mission._gl.shutdown()
