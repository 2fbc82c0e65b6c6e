"""maptidal's bundled data (tank, robots, scenarios), installed as ``maptidal.assets``
(see maptidal/paths.py)."""
