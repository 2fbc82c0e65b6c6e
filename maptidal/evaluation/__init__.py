"""How well an inspection method does, and against what: one room for the evaluation.

- :mod:`maptidal.evaluation.coverage`: the voxelised walls and the coverage of a set of views, with
  occlusion (the paper's metrics: % uninspected, mean views, MAD);
- :mod:`maptidal.evaluation.baselines`: the paper's Voronoi and boustrophedon viewpoints;
- :mod:`maptidal.evaluation.free_space`: whether a view lies in the tank's free water;
- :mod:`maptidal.evaluation.comparison`: the paper's comparison and parameter sweep (``maptidal
  compare``, ``maptidal sweep``);
- :mod:`maptidal.evaluation.paper_table`: our sweep beside the paper's Table I;
- :mod:`maptidal.evaluation.calibration`: fitting the tank's dimensions to the paper's figures;
- :mod:`maptidal.evaluation.plots`: the figures of the comparison.

The coverage, baselines and free space need only numpy, scipy and trimesh, so they score views from any
source, a real vehicle's included.
"""
