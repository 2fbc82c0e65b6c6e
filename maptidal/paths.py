"""Where maptidal's bundled data lives: the ``assets/`` folder of the source tree, or its copy inside an
installed wheel (``maptidal/assets/``, see ``[tool.setuptools]`` in pyproject.toml).

Every module that reads a bundled file (the OSB tank, the BlueROV2 parameters, the scenarios) takes its
path from :data:`ASSETS`, so ``pip install .`` works as well as a checkout.
"""

from __future__ import annotations

from pathlib import Path

_INSTALLED = Path(__file__).resolve().parent / "assets"
_SOURCE_TREE = Path(__file__).resolve().parent.parent / "assets"

ASSETS: Path = _INSTALLED if _INSTALLED.is_dir() else _SOURCE_TREE


def asset(*parts: str) -> Path:
    """The path of a bundled file, such as ``asset("osb_tank", "tank.toml")``."""
    return ASSETS.joinpath(*parts)
