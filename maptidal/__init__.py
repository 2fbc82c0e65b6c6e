"""maptidal: a headless MuJoCo testbed for cooperative underwater inspection.

The algorithm modules (``discovery``, ``geometry``, ``files``, ``synthetic``)
depend only on numpy, scipy, trimesh and OpenCV, so they run on real SLAM data
without a simulator. Only ``maptidal.mission`` and ``maptidal.cli`` may import
the simulator package ``maptidal.envs``. The simulator (``maptidal.envs``) and the
controllers (``maptidal.controllers``) live in the top-level folders ``envs/`` and
``controllers/`` of the source tree and install under this package (pyproject.toml's
package-dir), so the wheel adds no generic top-level names.
"""

__version__ = "0.1.0"


# A source checkout run without installing (PYTHONPATH=. python -m maptidal.cli): the folders envs/ and
# controllers/ beside this package are its subpackages maptidal.envs and maptidal.controllers, as the
# wheel and the editable install lay them out (pyproject.toml's package-dir)
def _checkout_root() -> str | None:
    import os

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    marks = (
        "pyproject.toml",
        os.path.join("envs", "__init__.py"),
        os.path.join("controllers", "__init__.py"),
    )
    return root if all(os.path.exists(os.path.join(root, mark)) for mark in marks) else None


if (_root := _checkout_root()) is not None and _root not in __path__:
    __path__.append(_root)
