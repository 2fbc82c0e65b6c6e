"""A non-editable install runs: the wheel carries the bundled data (tank, robots, scenarios) and every
package, and `maptidal compare` and `maptidal sim` work from it in a fresh virtual environment."""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# what a checkout holds beside the source that a wheel must not see
BUILD_LEFTOVERS = (
    ".git",
    ".venv",
    "build",
    "runs",
    "_build",
    "*.egg-info",
    "__pycache__",
    ".*_cache",
    ".gl",
    ".whl",
)


def test_every_package_of_the_source_tree_is_in_the_wheel_list():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    installed_as = {"maptidal": "maptidal", "envs": "maptidal.envs", "controllers": "maptidal.controllers"}
    found = {
        ".".join((installed_as[top], *init.parent.relative_to(ROOT / top).parts))
        for top in installed_as
        for init in (ROOT / top).rglob("__init__.py")
    }
    assert found <= listed, f"add {sorted(found - listed)} to [tool.setuptools] packages"
    assert all(name.split(".")[0] == "maptidal" for name in listed), "one namespace: maptidal"


def test_wheel_installed_in_a_fresh_venv_runs_compare_and_sim(tmp_path):
    wheels = tmp_path / "wheels"
    # built from a copy: setuptools packs whatever an earlier build left in the tree's build/lib
    source = tmp_path / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*BUILD_LEFTOVERS))
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(wheels),
            str(source),
        ],
        check=True,
        capture_output=True,
    )
    (wheel,) = wheels.glob("maptidal-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
    # one namespace: no generic top-level packages such as envs or controllers
    top_level = {name.split("/")[0] for name in names if ".dist-info/" not in name}
    assert top_level == {"maptidal"}, top_level
    assert {"maptidal/envs/simulation.py", "maptidal/envs/_hydro.c", "maptidal/envs/_flight.c"} <= names
    assert "maptidal/controllers/pose.py" in names
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = Path(
        subprocess.run(
            [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    # the dependencies come from this environment's site-packages (a .pth line does not run the .pth
    # files there, so this project's editable install stays out); maptidal itself only from the wheel
    (site / "dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--no-index",
            "--target",
            str(site),
            str(wheel),
        ],
        check=True,
        capture_output=True,
    )
    work = tmp_path / "elsewhere"  # not the source tree: assets must come from the install
    work.mkdir()
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONNOUSERSITE": "1"}
    environment.pop("PYTHONPATH", None)

    def maptidal(*argv: str) -> dict:
        completed = subprocess.run(
            [python, "-m", "maptidal.cli", *argv], cwd=work, env=environment, capture_output=True, text=True
        )
        assert completed.returncode == 0, completed.stderr
        return json.loads(completed.stdout)

    where = subprocess.run(
        [python, "-c", "import maptidal, maptidal.paths as p; print(maptidal.__file__); print(p.ASSETS)"],
        cwd=work,
        env=environment,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert all(line.startswith(str(site)) for line in where), where
    compare = maptidal("compare", "--no-write", "--json")
    assert set(compare["methods"]) == {"maptidal", "voronoi", "voronoi_generator", "boustrophedon"}
    sim = maptidal("sim", "--duration", "0.2", "--json")
    assert set(sim["robots"]) == {"rov0"}


def test_the_native_library_is_never_built_inside_an_installed_package(monkeypatch, tmp_path):
    from pathlib import Path

    from maptidal.envs.native_build import build_dirs

    monkeypatch.delenv("MAPTIDAL_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    installed = Path("/usr/lib/python3/site-packages/envs")
    assert build_dirs(installed) == [tmp_path / "cache" / "maptidal"]  # pip uninstall leaves nothing there
    checkout = tmp_path / "maptidal" / "envs"
    assert build_dirs(checkout) == [checkout / "_build", tmp_path / "cache" / "maptidal"]
    monkeypatch.setenv("MAPTIDAL_CACHE", str(tmp_path / "mine"))
    assert build_dirs(installed)[0] == tmp_path / "mine"
