"""The tank config and the geometry built from it."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from maptidal.tank import (
    DEFAULT_TANK_CONFIG,
    TankConfig,
    TankConfigError,
    TankModel,
    WindowConfig,
    load_tank_config,
    tank_config_from_dict,
    tank_config_to_dict,
)

ROOT = Path(__file__).resolve().parent.parent


def test_default_config_has_the_issues_dimensions():
    config = load_tank_config()
    assert config.end_wall_width == 2.4 and config.water_depth == 2.0
    assert config.angled_length == 1.0 and config.angled_angle_deg == 45.0
    assert config.side_length == 6.0 and config.side_evaluated_length == 0.5
    window = config.window
    assert (window.width, window.height, window.recess, window.centre_height) == (1.0, 0.6, 0.1, 1.0)
    assert config.ladder.standoff == 0.15 and config.ladder.rails == 2


def test_strip_and_segments_follow_the_top_view():
    tank = TankModel(load_tank_config())
    lengths = {seg.name: seg.length for seg in tank.segments}
    assert lengths == pytest.approx(
        {"side_left": 0.5, "angled_left": 1.0, "end": 2.4, "angled_right": 1.0, "side_right": 0.5}
    )
    assert tank.strip_length == pytest.approx(5.4)
    angled = tank.segment("angled_left")
    # 45 degrees between the angled wall and the end wall's plane.
    assert math.degrees(math.acos(abs(angled.tangent @ tank.segment("end").tangent))) == pytest.approx(45.0)
    # Inward normals point into the water: towards the tank's centre line and away from the end wall.
    centre = np.array([-1.5, 0.0, 1.0])
    for seg in tank.segments:
        point, normal = tank.strip_to_world(seg.s0 + seg.length / 2, 1.0)
        assert float((centre - point[0]) @ normal[0]) > 0.0


def test_evaluated_surface_area_and_normals():
    tank = TankModel()
    surface = tank.evaluated_surface()
    # Walls 5.4 x 2 m, the window hole replaced by its pane, plus four 0.1 m reveals.
    expected = 5.4 * 2.0 + 2 * (1.0 + 0.6) * 0.1
    assert surface.area == pytest.approx(expected)
    # Every face's normal points to the water side: a short step along it stays in the tank.
    inside = surface.triangles_center + 0.01 * surface.face_normals
    assert np.all(inside[:, 0] < 0.1 + 1e-9)
    assert np.all(surface.bounds[:, 2] == pytest.approx([0.0, 2.0]))


def test_ladder_stands_off_the_end_wall_right_of_centre():
    tank = TankModel()
    boxes = tank.ladder_boxes()
    rails = boxes[:2]
    for centre, _half, _axes in rails:
        assert centre[0] == pytest.approx(-0.15)  # axis 0.15 m off the wall plane x = 0
        assert centre[1] < 0.0  # right of centre when facing the end wall is -y
    assert len(boxes) > 2  # rungs


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ({"water_depth": -1.0}, "water_depth"),
        ({"end_wall": {"width": 0.0}}, "end_wall.width"),
        ({"window": {"width": 3.0}}, "does not fit in the 2.4 m end wall"),
        ({"window": {"height": 2.5}}, "does not fit in the 2.0 m wall height"),
        ({"side_walls": {"evaluated_length": 7.0}}, "exceeds"),
        ({"angled_walls": {"angle_deg": 120.0}}, "angle_deg"),
        ({"ladder": {"centre_offset": 1.2}}, "does not fit on"),
        ({"window": {"colour": "blue"}}, "unknown key 'colour'"),
        ({"roof": 1}, "unknown key 'roof'"),
        ({"fouling": [{"s": 1.0, "z": 1.0}]}, "radius"),
        ({"fouling": [{"s": 1.0, "z": 1.0, "radius": -0.1}]}, "fouling.radius"),
    ],
)
def test_bad_configs_get_a_clear_error(document, message):
    with pytest.raises(TankConfigError, match=message):
        tank_config_from_dict({"water_depth": 2.0, "end_wall": {"width": 2.4}, **document})


@pytest.mark.parametrize(
    "document, message",
    [
        ({}, "empty"),
        ({"end_wall": {"width": 2.4}}, "no water_depth"),
        ({"water_depth": 2.0}, "no \\[end_wall\\]"),
    ],
)
def test_a_tank_without_its_size_is_refused(document, message):
    with pytest.raises(TankConfigError, match=message):
        tank_config_from_dict(document)


def test_bad_files(tmp_path):
    with pytest.raises(TankConfigError, match="not found"):
        load_tank_config(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("water_depth = = 2\n")
    with pytest.raises(TankConfigError, match="not valid TOML"):
        load_tank_config(broken)


def test_another_tank_rectangular_without_window(tmp_path):
    path = tmp_path / "box.toml"
    path.write_text(
        'name = "box"\nwater_depth = 3.0\n[end_wall]\nwidth = 4.0\n[angled_walls]\nlength = 0.0\n'
        "[side_walls]\nlength = 10.0\nevaluated_length = 1.0\n[window]\nwidth = 0.0\n[ladder]\nrails = 0\n"
    )
    tank = TankModel(load_tank_config(path))
    assert [seg.name for seg in tank.segments] == ["side_left", "end", "side_right"]
    assert tank.evaluated_surface().area == pytest.approx((1.0 + 4.0 + 1.0) * 3.0)
    assert tank.ladder_boxes() == []


def test_config_dataclass_validates_directly():
    with pytest.raises(TankConfigError):
        TankConfig(window=WindowConfig(width=1.0, height=0.0))
    assert DEFAULT_TANK_CONFIG.is_file()


def test_the_baselines_geometry_may_cut_the_side_walls():
    """side_walls.baseline_length: the baselines lay their points on a shorter strip than the evaluated
    one (the paper's Fig. 6A), and a part longer than the evaluated one is refused."""
    from maptidal.evaluation.baselines import boustrophedon_viewpoints
    from maptidal.tank import TankConfigError, TankModel, tank_config_from_dict

    document = {"water_depth": 2.0, "end_wall": {"width": 2.4}, "side_walls": {"evaluated_length": 0.5}}
    full = TankModel(tank_config_from_dict(document))
    document["side_walls"]["baseline_length"] = 0.0
    cut = TankModel(tank_config_from_dict(document))
    assert cut.strip_length == full.strip_length  # the evaluated region is the same
    assert cut.baseline_geometry().strip_length == pytest.approx(full.strip_length - 1.0)
    assert full.baseline_geometry() is full
    # without the side parts a lane has 4 corners and 2 points inside the end wall: 6, times 3 lanes
    assert len(boustrophedon_viewpoints(cut)) == 18 and len(boustrophedon_viewpoints(full)) == 24
    document["side_walls"]["baseline_length"] = 0.6
    with pytest.raises(TankConfigError, match="baseline_length"):
        tank_config_from_dict(document)


def test_the_calibrated_variant_loads():
    from maptidal.paths import asset
    from maptidal.tank import TankModel, load_tank_config

    tank = TankModel(load_tank_config(asset("osb_tank", "calibrated.toml")))
    assert tank.config.name == "osb_tank_calibrated"
    assert tank.strip_length > TankModel(load_tank_config(None)).strip_length  # the fit's larger region
    assert tank.baseline_geometry().strip_length <= tank.strip_length


@pytest.mark.parametrize(
    "path",
    [
        DEFAULT_TANK_CONFIG,
        ROOT / "tests" / "bench" / "tanks" / "variant_a" / "tank.toml",
        ROOT / "tests" / "bench" / "tanks" / "variant_b" / "tank.toml",
        ROOT / "tests" / "bench" / "tanks" / "variant_c" / "tank.toml",
        ROOT / "tests" / "bench" / "tanks" / "variant_d" / "tank.toml",
    ],
)
def test_a_tank_config_written_out_reads_back_the_same(path):
    import json
    import tomllib

    config = load_tank_config(path)
    written = tank_config_to_dict(config)
    assert tank_config_from_dict(json.loads(json.dumps(written))) == config  # through an event log's JSON
    # every value the TOML file gives is written out as the file gives it
    document = tomllib.loads(Path(path).read_text())
    for table in ("end_wall", "angled_walls", "side_walls", "window", "ladder"):
        for key, value in document.get(table, {}).items():
            assert written[table][key] == value, (table, key)
    assert written["fouling"] == document.get("fouling", [])
    assert written["water_depth"] == document["water_depth"]
    with_baseline = dataclasses.replace(config, side_baseline_length=0.3)
    assert tank_config_from_dict(tank_config_to_dict(with_baseline)) == with_baseline


def test_the_random_tanks_bench_draws_valid_tanks_whose_window_clears_the_ladder():
    """tests/bench/random_tanks.py's draws stay in their ranges, validate as tanks, and never put the
    window over the ladder (checked on the built model's geometry: the window's edges against the
    ladder's boxes, along the end wall)."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent / "bench"))
    import random_tanks

    from maptidal.tank import TankModel, tank_config_from_dict

    rng = np.random.default_rng(3)
    windows = 0
    for index in range(60):
        document = random_tanks.draw_tank(rng, index)
        config = tank_config_from_dict(document)  # raises on an invalid tank
        assert random_tanks.WIDTH_M[0] <= config.end_wall_width <= random_tanks.WIDTH_M[1]
        assert random_tanks.DEPTH_M[0] <= config.water_depth <= random_tanks.DEPTH_M[1]
        model = TankModel(config)
        if not model.has_window():
            continue
        windows += 1
        window = config.window
        left, right = window.centre_offset - window.width / 2, window.centre_offset + window.width / 2
        wall = model.segment("end")
        middle = np.array([*wall.start[:2], 0.0]) + wall.length / 2 * wall.tangent
        for centre, half, axes in model.ladder_boxes():
            along = float((centre - middle) @ axes[0])  # axes[0]: along the end wall, as offsets run
            reach = float(half[0])
            assert along + reach <= left or along - reach >= right, (index, along, left, right)
    assert 20 < windows < 60  # some tanks have a window, some none
