"""Scenarios, sensors, rendering (stereo geometry, water model, determinism) and `maptidal sim`."""

import json
import math

import cv2
import numpy as np
import pytest

from envs.scenario import RobotSpec, Scenario, ScenarioError, load_scenario, scenario_from_dict
from envs.sensors import SensorNoise, heading_from_field
from envs.simulation import Simulation
from envs.vehicle import load_vehicle
from envs.water import WaterModel, WaterParams
from maptidal.cli import main
from maptidal.tank import LadderConfig, TankConfig, TankModel, WindowConfig

QUIET = SensorNoise(0, 0, 0, 0, 0, 0, 0)
PLAIN_WALL = TankModel(
    TankConfig(
        end_wall_width=4.0, angled_length=0.0, window=WindowConfig(width=0.0), ladder=LadderConfig(rails=0)
    )
)


def facing_wall(distance_m: float, water: WaterParams, **robot) -> Simulation:
    """A Heavy whose cameras are ``distance_m`` from a plain end wall, looking at it."""
    vehicle = load_vehicle("heavy")
    x = -distance_m - vehicle.sensors.camera_position[0]
    spec = RobotSpec("rov", vehicle, (x, 0.0, 1.0), **robot)
    return Simulation(Scenario("wall", PLAIN_WALL, (spec,), water=water, noise=QUIET))


BAD = {
    "frame": ({"frame": "quadcopter"}, "unknown frame"),
    "outside": ({"position": [1.0, 0.0, 1.0]}, "outside the tank"),
    "negative mass": ({"mass": -1.0}, "mass must be"),
    "sensor": ({"sensors": ["sonar"]}, "unknown sensor"),
    "key": ({"colour": "red"}, "unknown key"),
    "above water": ({"position": [-1.5, 0.0, 3.0]}, "outside the tank"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_scenarios_get_a_clear_error(case):
    robot = {"name": "rov0", "frame": "heavy", "position": [-1.5, 0.0, 1.0]}
    robot.update(BAD[case][0])
    with pytest.raises(ScenarioError, match=BAD[case][1]):
        scenario_from_dict({"robots": [robot]})


def test_bundled_scenarios_load_and_bad_files_exit_2(tmp_path, capsys):
    assert [r.name for r in load_scenario("two_robots").robots] == ["rov0", "rov1"]
    bad = tmp_path / "bad.toml"
    bad.write_text('[[robots]]\nframe = "heavy"\nposition = [-1.5, 0, 1]\nmass = -2.0\n')
    assert main(["sim", "--scenario", str(bad), "--duration", "0.1"]) == 2
    assert "mass must be" in capsys.readouterr().err


def test_sensors_read_what_the_ground_truth_says():
    sim = facing_wall(1.5, WaterParams(), yaw_deg=30.0)
    for _ in range(25):
        sim.step({"rov": {"sway": 0.5}})
    truth, reading = sim.ground_truth("rov"), sim.sensors("rov")
    assert truth["ground_truth"] is True
    assert reading["depth"]["depth_m"] == pytest.approx(2.0 - truth["position"][2] - 0.1, abs=0.02)
    assert reading["dvl"]["valid"]
    np.testing.assert_allclose(reading["dvl"]["velocity_body"], truth["velocity_body"], atol=0.02)
    altitude = truth["position"][2] - 0.12
    expected = altitude / math.cos(math.radians(22.5))
    assert reading["dvl"]["beam_ranges_m"] == pytest.approx([expected] * 4, abs=0.02)
    assert reading["compass"]["heading_deg"] == pytest.approx(330.0, abs=0.5)
    assert reading["imu"]["accel"][2] == pytest.approx(9.81, abs=0.3)


def test_compass_heading_is_clockwise_from_north():
    up = np.array([0.0, 0.0, 9.81])
    for yaw_deg in (0.0, 45.0, -90.0, 170.0):
        yaw = math.radians(yaw_deg)
        north_in_body = np.array([math.cos(yaw), -math.sin(yaw), -2.0])
        assert heading_from_field(north_in_body, up) == pytest.approx((-yaw_deg) % 360.0, abs=1e-9)


def test_stereo_pair_has_the_disparity_of_a_wall_at_known_distance():
    distance = 0.8
    sim = facing_wall(distance, WaterParams(enabled=False))
    left, right = sim.render_stereo("rov", water=False)
    gray = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) for image in (left, right)]
    (shift_x, shift_y), _ = cv2.phaseCorrelate(gray[1], gray[0])
    expected = sim.camera.fx * sim.camera.baseline_m / distance
    assert abs(shift_x - expected) < 1.0 and abs(shift_y) < 0.5
    _, _, depth_left, _ = sim.render_stereo("rov", depth=True, water=False)
    assert depth_left[200, 320] == pytest.approx(distance, abs=0.005)


def _contrast(image: np.ndarray) -> float:
    return float(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[100:300, 200:440].std())


def test_turbidity_lowers_contrast_monotonically_with_range():
    ratios = []
    for distance in (0.6, 1.2, 2.4):
        sim = facing_wall(distance, WaterParams(turbidity=0.6))
        clear, _ = sim.render_stereo("rov", water=False)
        murky, _ = sim.render_stereo("rov", water=True)
        ratios.append(_contrast(murky) / _contrast(clear))
    assert ratios[0] > ratios[1] > ratios[2]
    # and at one range, more turbid water leaves less contrast
    image = np.random.default_rng(0).integers(0, 255, (40, 40, 3)).astype(np.uint8)
    contrasts = [
        _contrast_all(WaterModel(WaterParams(turbidity=t)).apply(image, np.full((40, 40), 2.0)))
        for t in (0.0, 0.5, 1.0)
    ]
    assert contrasts[0] > contrasts[1] > contrasts[2]


def _contrast_all(image):
    return float(image.astype(float).std())


def test_water_model_is_the_formula():
    model = WaterModel(WaterParams(turbidity=0.4))
    beta, veil = model.params.coefficients()
    image = np.full((2, 2, 3), 200, np.uint8)
    ranges = np.array([[0.0, 1.0], [2.0, 5.0]])
    out = model.apply(image, ranges).astype(float)
    expected = 200 * np.exp(-beta * ranges[..., None]) + 255 * veil * (1 - np.exp(-beta * ranges[..., None]))
    np.testing.assert_allclose(out, expected, atol=1.0)


def test_rendering_is_deterministic_for_the_same_state_and_seed():
    sim = facing_wall(1.0, WaterParams(turbidity=0.3, noise_sigma=3.0, vignetting=0.2))
    sim.reset(seed=5)
    first = sim.render_stereo("rov")
    sim.reset(seed=5)
    second = sim.render_stereo("rov")
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], first[1])  # the two cameras differ


def test_sim_cli_prints_the_final_state(tmp_path, capsys):
    code = main(
        [
            "sim",
            "--command",
            "surge=0.5",
            "--duration",
            "1",
            "--json",
            "--render-dir",
            str(tmp_path),
            "--render-every",
            "40",
        ]
    )
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) >= {"position", "velocity_body", "rpy", "sim_time_s", "steps_per_s", "realtime_factor"}
    assert result["sim_time_s"] == pytest.approx(1.0, abs=0.03)
    assert result["velocity_body"][0] > 0.3
    assert len(list(tmp_path.glob("rov0_*.png"))) == 2
    with pytest.raises(SystemExit):
        main(["sim", "--help"])


def test_camera_noise_has_the_requested_spread_and_changes_every_frame():
    model = WaterModel(WaterParams(turbidity=0.0, noise_sigma=4.0))
    flat = np.full((200, 300, 3), 128, np.uint8)
    ranges = np.zeros((200, 300))
    rng = np.random.default_rng(3)
    first, second = model.apply(flat, ranges, rng), model.apply(flat, ranges, rng)
    for frame in (first, second):
        assert abs(frame.astype(float).std() - 4.0) < 0.2
        assert abs(frame.astype(float).mean() - 128.0) < 0.2
    assert np.corrcoef(first.ravel().astype(float), second.ravel().astype(float))[0, 1] < 0.05
