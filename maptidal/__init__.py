"""maptidal: a headless MuJoCo testbed for cooperative underwater inspection.

The algorithm modules (``discovery``, ``geometry``, ``files``, ``synthetic``)
depend only on numpy, scipy, trimesh and OpenCV, so they run on real SLAM data
without a simulator. Only ``maptidal.mission`` and ``maptidal.cli`` may import
the simulator package ``envs``.
"""

__version__ = "0.1.0"
