"""Building maptidal's small C libraries (the hydrodynamics callback, ``envs/_hydro.c``, and the flight
stack, ``envs/_flight.c``) against the mujoco wheel's headers, once per source and MuJoCo version, with
the system's C compiler (``$CC`` or ``cc``). Without one, each caller falls back on its Python reference."""

from __future__ import annotations

import hashlib
import logging
import os
import subprocess
import sysconfig
from pathlib import Path

import mujoco

log = logging.getLogger(__name__)


def build_dirs(package_dir: Path | None = None) -> list[Path]:
    """Where the native library is looked for and built, first to last: ``$MAPTIDAL_CACHE``; the source
    checkout's ``envs/_build`` (``make setup`` builds it there), but never an installed package's folder
    (``pip uninstall`` would leave the library behind); the user's cache, ``$XDG_CACHE_HOME/maptidal``
    or ``~/.cache/maptidal``."""
    package_dir = package_dir or Path(__file__).resolve().parent
    dirs = []
    if os.environ.get("MAPTIDAL_CACHE"):
        dirs.append(Path(os.environ["MAPTIDAL_CACHE"]))
    if not {"site-packages", "dist-packages"} & set(package_dir.parts):
        dirs.append(package_dir / "_build")
    cache_home = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    dirs.append(Path(cache_home) / "maptidal")
    return dirs


def build_library(
    source_path: Path, stem: str, force: bool = False, link_mujoco: bool = False
) -> Path | None:
    """Compile the C file ``source_path`` into a shared library named ``stem``, once per source and
    MuJoCo version, in the first of :func:`build_dirs` that takes it; its path, or None without a
    compiler. ``link_mujoco``: link against the mujoco wheel's own ``libmujoco`` (the one Python has
    loaded, so the library calls the same MuJoCo, callbacks included)."""
    include = Path(mujoco.__file__).parent / "include"
    try:
        source = source_path.read_bytes()
    except OSError as error:  # an install without the C source: the Python takes over
        log.debug("no source for the %s library: %s", stem, error)
        return None
    tag = hashlib.sha1(source + mujoco.__version__.encode()).hexdigest()[:12]
    suffix = sysconfig.get_config_var("SHLIB_SUFFIX") or ".so"
    compiler = os.environ.get("CC", "cc")
    link: list[str] = []
    if link_mujoco:
        found = sorted(Path(mujoco.__file__).parent.glob("libmujoco*"))
        if not found:
            return None
        library = found[0]
        link = [f"-L{library.parent}", f"-l:{library.name}", f"-Wl,-rpath,{library.parent}"]
    for directory in build_dirs():
        target = directory / f"{stem}-{tag}{suffix}"
        if target.exists() and not force:
            return target
        try:
            directory.mkdir(parents=True, exist_ok=True)
            partial = target.with_suffix(f".{os.getpid()}.tmp")
            # -ffp-contract=off: no fused multiply-adds, so the C computes what the Python reference does
            command = [compiler, "-O2", "-ffp-contract=off", "-pthread", "-shared", "-fPIC", f"-I{include}"]
            command += ["-o", str(partial), str(source_path), *link, "-lm"]
            subprocess.run(command, check=True, capture_output=True, timeout=120)
            os.replace(partial, target)  # atomic: parallel builders never load a half-written file
            return target
        except (OSError, subprocess.SubprocessError) as err:
            log.debug("cannot build the %s library in %s: %s", stem, directory, err)
    return None
