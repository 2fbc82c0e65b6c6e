"""The MuJoCo simulation: world building, hydrodynamics, sensors, rendering and the
Gymnasium environments. Empty until the [world] issue lands; it may import
``controllers`` and maptidal's pure modules, never maptidal.mission or maptidal.cli.
"""
