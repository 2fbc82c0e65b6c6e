"""The MuJoCo tank and maptidal.tank.TankModel are one geometry: rays hit both at the same distance.

MuJoCo's side is its own ray caster (``mj_ray``) on the compiled world and on the exported MJCF;
TankModel's side is a brute-force Moeller-Trumbore intersection written here against its scene
triangles. The only geoms left out are the thin decorations of group 1 (window frame, fouling
discs), which TankModel does not model.
"""

from pathlib import Path

import mujoco
import numpy as np
import pytest

from maptidal.envs.export import export_world
from maptidal.envs.scenario import inside_tank, load_scenario
from maptidal.envs.world import build_tank_spec, quat_from_axes
from maptidal.tank import LadderConfig, TankConfig, TankModel, WindowConfig

SURFACES_AND_LADDER = np.array([1, 0, 0, 0, 0, 0], np.uint8)  # geom group 0 only


def brute_force_hits(origins: np.ndarray, directions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Nearest hit distance of each ray against every triangle (inf where none), two-sided."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    p = np.cross(directions[:, None, :], e2[None])
    det = np.einsum("tk,rtk->rt", e1, p)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        s = origins[:, None, :] - a[None]
        u = np.einsum("rtk,rtk->rt", s, p) * inv
        q = np.cross(s, e1[None])
        v = np.einsum("rk,rtk->rt", directions, q) * inv
        t = np.einsum("tk,rtk->rt", e2, q) * inv
        ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)
    return np.where(ok, t, np.inf).min(axis=1)


def mujoco_hits(model: mujoco.MjModel, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Nearest hit distance of each ray on the model's group-0 geoms (inf where none)."""
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, np.int32)
    hits = []
    for origin, direction in zip(origins, directions, strict=True):
        distance = mujoco.mj_ray(model, data, origin, direction, SURFACES_AND_LADDER, 1, -1, geom)
        hits.append(np.inf if distance < 0 else distance)
    return np.array(hits)


def rays(tank: TankModel, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins in the water and unit directions: half random, half aimed at the ladder's parts."""
    rng = np.random.default_rng(seed)
    origins = []
    while len(origins) < count:
        point = rng.uniform([-4.0, -2.2, 0.0], [0.0, 2.2, tank.height])
        if inside_tank(tank, point, 0.05):
            origins.append(point)
    origins = np.array(origins)
    directions = rng.normal(size=(count, 3))
    boxes = tank.ladder_boxes()
    if boxes:
        aimed = np.arange(count // 2)
        targets = np.array([boxes[k % len(boxes)][0] for k in aimed])
        targets += rng.normal(scale=0.02, size=targets.shape)
        directions[aimed] = targets - origins[aimed]
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


TANKS = {
    "osb": TankModel(),
    "rectangular, ladder left": TankModel(
        TankConfig(angled_length=0.0, ladder=LadderConfig(centre_offset=-0.6), window=WindowConfig(width=0.0))
    ),
    "steep angled walls": TankModel(TankConfig(angled_angle_deg=70.0, end_wall_width=3.0)),
}


@pytest.mark.parametrize("name", TANKS)
def test_mujoco_tank_has_tank_model_geometry(name):
    tank = TANKS[name]
    origins, directions = rays(tank, 400, seed=len(name))
    expected = brute_force_hits(origins, directions, tank.scene_triangles())
    got = mujoco_hits(build_tank_spec(tank).compile(), origins, directions)
    assert np.array_equal(np.isinf(got), np.isinf(expected))
    finite = np.isfinite(expected)
    assert finite.sum() > 300
    np.testing.assert_allclose(got[finite], expected[finite], atol=1e-3)


def test_exported_mjcf_has_tank_model_geometry(tmp_path):
    scenario = load_scenario()
    model = mujoco.MjModel.from_xml_path(str(export_world(scenario, tmp_path)["tank.xml"]))
    origins, directions = rays(scenario.tank, 200, seed=7)
    expected = brute_force_hits(origins, directions, scenario.tank.scene_triangles())
    got = mujoco_hits(model, origins, directions)
    assert np.array_equal(np.isinf(got), np.isinf(expected))
    finite = np.isfinite(expected)
    np.testing.assert_allclose(got[finite], expected[finite], atol=1e-3)


def test_ladder_rungs_run_along_the_end_wall():
    tank = TankModel()
    model = build_tank_spec(tank).compile()
    ladder = tank.config.ladder
    boxes = [k for k in range(model.ngeom) if model.geom_type[k] == mujoco.mjtGeom.mjGEOM_BOX]
    rung = [
        k
        for k in boxes
        if np.allclose(model.geom_size[k], [ladder.rail_spacing / 2, *[ladder.rung_width / 2] * 2])
    ]
    assert rung
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    for k in rung:
        long_axis = data.geom_xmat[k].reshape(3, 3)[:, 0]
        # the end wall lies in x = 0 and runs along y
        assert abs(long_axis[1]) == pytest.approx(1.0, abs=1e-9)
        assert data.geom_xpos[k][0] == pytest.approx(-ladder.standoff)


def test_left_handed_frames_are_refused():
    x, y, z = np.eye(3)
    assert np.allclose(quat_from_axes(x, y, z), [1, 0, 0, 0])
    with pytest.raises(ValueError, match="right-handed"):
        quat_from_axes(x, -y, z)
    with pytest.raises(ValueError, match="right-handed"):
        quat_from_axes(x, 2 * y, z)


def test_every_frame_the_builder_makes_is_right_handed(monkeypatch):
    # every geom, site, camera and attachment frame of a two-robot world goes through quat_from_axes
    from maptidal.envs import world
    from maptidal.envs.simulation import Simulation

    frames = []

    def recording(x, y, z):
        frames.append(np.column_stack([x, y, z]))
        return quat_from_axes(x, y, z)

    monkeypatch.setattr(world, "quat_from_axes", recording)
    Simulation(load_scenario(Path(__file__).resolve().parent.parent / "assets/scenarios/two_robots.toml"))
    assert len(frames) > 30
    for matrix in frames:
        assert np.linalg.det(matrix) == pytest.approx(1.0, abs=1e-6)
