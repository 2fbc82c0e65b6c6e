"""Menagerie-style MJCF export: the files load in plain MuJoCo and match the worlds maptidal builds."""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from maptidal.cli import main
from maptidal.envs.export import ROBOT_FILE_HEADER, export_world, robot_xml
from maptidal.envs.scenario import load_scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import FRAMES, load_vehicle

ASSETS = Path(__file__).resolve().parent.parent / "assets"


@pytest.mark.parametrize("frame", FRAMES)
def test_committed_robot_files_are_what_the_exporter_writes(frame):
    committed = (ASSETS / "bluerov2" / f"bluerov2_{frame}.xml").read_text()
    assert committed == ROBOT_FILE_HEADER + robot_xml(load_vehicle(frame)), (
        "run `python -m maptidal.envs.export`"
    )


@pytest.mark.parametrize("frame", FRAMES)
def test_robot_files_load_with_the_vehicle_numbers(frame):
    vehicle = load_vehicle(frame)
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "bluerov2" / f"bluerov2_{frame}.xml"))
    assert model.nu == vehicle.n_thrusters
    assert model.body("base").mass[0] == pytest.approx(vehicle.mass)
    assert {model.camera(i).name for i in range(model.ncam)} == {"left", "right"}


def test_menagerie_scene_includes_the_robot():
    model = mujoco.MjModel.from_xml_path(str(ASSETS / "bluerov2" / "scene.xml"))
    assert model.nu == 8 and model.geom("floor").type[0] == mujoco.mjtGeom.mjGEOM_PLANE


def test_exported_world_matches_the_simulation(tmp_path):
    scenario = load_scenario(ASSETS / "scenarios" / "two_robots.toml")
    written = export_world(scenario, tmp_path)
    assert {"scene.xml", "tank.xml", "README.md"} <= set(written)
    exported = mujoco.MjModel.from_xml_path(str(tmp_path / "scene.xml"))
    simulated = Simulation(scenario).model
    for count in ("nbody", "ngeom", "nu", "ncam", "nsensor", "nlight", "ntex", "nmat"):
        assert getattr(exported, count) == getattr(simulated, count), count
    # MJCF keeps 6 significant digits: a tenth of a millimetre in a 20 m tank
    np.testing.assert_allclose(exported.geom_size, simulated.geom_size, atol=1e-4)
    np.testing.assert_allclose(exported.geom_pos, simulated.geom_pos, atol=1e-4)
    np.testing.assert_allclose(exported.body_mass, simulated.body_mass, rtol=1e-5)
    assert (tmp_path / "textures" / "concrete.png").stat().st_size > 1000
    tank = mujoco.MjModel.from_xml_path(str(tmp_path / "tank.xml"))
    assert tank.nu == 0 and tank.ntex == 3


def test_export_command(tmp_path, capsys):
    assert main(["export-mjcf", "--frame", "standard", "--out", str(tmp_path)]) == 0
    assert "scene.xml" in capsys.readouterr().out
    assert (tmp_path / "bluerov2_standard.xml").exists() and not (tmp_path / "bluerov2_heavy.xml").exists()
    assert main(["export-mjcf", "--scenario", str(tmp_path / "missing.toml"), "--out", str(tmp_path)]) == 2
