"""Shared fixtures. The literal transcription of the paper's pseudo-code lives in
tests/bench/literal_discovery.py and serves as the oracle for maptidal.discovery."""

import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).parent / "bench"))

# The slowest modules, slowest first (`pytest --durations`, summed by module). `make test` runs each module
# whole on one of two workers (--dist loadscope), in the order collected: a slow module collected late
# leaves the other worker idle at the end. Collected first, the slow ones overlap each other and the many
# quick ones fill in after (longest processing time first, Graham 1969).
SLOWEST_FIRST = (
    "test_mission.py",
    "test_signals.py",
    "test_localisation_loop.py",
    "test_batch.py",
    "test_mavlink.py",
    "test_gym.py",
    "test_readme.py",
    "test_frontend_rendered.py",
    "test_reward_exploits.py",
)


def pytest_collection_modifyitems(session, config, items):
    """Put the tests of the slowest modules first, in SLOWEST_FIRST's order; the rest keep theirs."""

    def rank(item) -> int:
        name = Path(str(item.fspath)).name
        return SLOWEST_FIRST.index(name) if name in SLOWEST_FIRST else len(SLOWEST_FIRST)

    items.sort(key=rank)  # stable: each module's own order is kept
