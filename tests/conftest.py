"""Shared fixtures. The literal transcription of the paper's pseudo-code lives in
tests/bench/literal_discovery.py and serves as the oracle for maptidal.discovery."""

import os
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, str(Path(__file__).parent / "bench"))
