"""The MuJoCo simulation: world building, hydrodynamics, sensors, rendering and the
Gymnasium environments (registered on import: ``envs.gym``). It may import
``controllers`` and maptidal's pure modules, never maptidal.mission or maptidal.cli.
"""

from envs.gym import register_environments

register_environments()
