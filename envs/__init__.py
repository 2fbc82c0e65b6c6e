"""The MuJoCo simulation: world building, hydrodynamics, sensors, rendering and the
Gymnasium environments (registered on import: ``maptidal.envs.gym``). It may import
``controllers`` and maptidal's pure modules, never maptidal.mission or maptidal.cli.

Headless rendering through EGL is the default (CPU-only machines through Mesa, and NVIDIA GPUs): it is
set here, before any module of the package imports mujoco, which reads ``MUJOCO_GL`` when it is first
imported. A value already in the environment wins.
"""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

from maptidal.envs.gym import register_environments  # after the rendering defaults

register_environments()
