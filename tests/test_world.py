"""Scenarios, sensors, rendering (stereo geometry, water model, determinism) and `maptidal sim`."""

import gc
import json
import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import cv2
import mujoco
import numpy as np
import pytest

from maptidal.cli import main
from maptidal.envs import rendering
from maptidal.envs import water as water_module
from maptidal.envs.rendering import renders_on_gpu
from maptidal.envs.scenario import RobotSpec, Scenario, ScenarioError, load_scenario, scenario_from_dict
from maptidal.envs.sensors import SensorNoise, heading_from_field
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.envs.water import WaterModel, WaterParams
from maptidal.tank import LadderConfig, TankConfig, TankModel, WindowConfig

QUIET = SensorNoise(0, 0, 0, 0, 0, 0, 0)
PLAIN_WALL = TankModel(
    TankConfig(
        end_wall_width=4.0, angled_length=0.0, window=WindowConfig(width=0.0), ladder=LadderConfig(rails=0)
    )
)


def facing_wall(
    distance_m: float, water: WaterParams, backend: str = "auto", render_samples: int = 4, **robot
) -> Simulation:
    """A Heavy whose cameras are ``distance_m`` from a plain end wall, looking at it; ``backend`` is
    where the water model runs (a "gl" that cannot run here skips the test)."""
    vehicle = load_vehicle("heavy")
    x = -distance_m - vehicle.sensors.camera_position[0]
    spec = RobotSpec("rov", vehicle, (x, 0.0, 1.0), **robot)
    scenario = Scenario("wall", PLAIN_WALL, (spec,), water=water, noise=QUIET)
    return with_backend(scenario, backend, render_samples=render_samples)


def with_backend(scenario: Scenario, backend: str, **options) -> Simulation:
    """A Simulation of ``scenario`` whose water model runs on ``backend``; skips where GL cannot."""
    sim = Simulation(scenario, water_backend=backend, **options)
    if backend == "gl":
        try:
            assert sim.water_backend == "gl"
        except RuntimeError as err:
            pytest.skip(str(err))
    return sim


BACKENDS = ("cpu", "gl")


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
    np.testing.assert_array_equal(sim.render_stereo("rov")[0], left)  # disabled water changes nothing
    gray = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) for image in (left, right)]
    (shift_x, shift_y), _ = cv2.phaseCorrelate(gray[1], gray[0])
    expected = sim.camera.fx * sim.camera.baseline_m / distance
    assert abs(shift_x - expected) < 1.0 and abs(shift_y) < 0.5
    _, _, depth_left, _ = sim.render_stereo("rov", depth=True, water=False)
    assert depth_left[200, 320] == pytest.approx(distance, abs=0.005)


def _contrast(image: np.ndarray) -> float:
    return float(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[100:300, 200:440].std())


@pytest.mark.parametrize("backend", BACKENDS)
def test_turbidity_lowers_contrast_monotonically_with_range(backend):
    ratios = []
    for distance in (0.6, 1.2, 2.4):
        sim = facing_wall(distance, WaterParams(turbidity=0.6), backend)
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


@pytest.mark.parametrize("backend", BACKENDS)
def test_rendering_is_deterministic_for_the_same_state_and_seed(backend):
    sim = facing_wall(1.0, WaterParams(turbidity=0.3, noise_sigma=3.0, vignetting=0.2), backend)
    sim.reset(seed=5)
    first = sim.render_stereo("rov")
    sim.reset(seed=5)
    second = sim.render_stereo("rov")
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], first[1])  # the two cameras differ
    sim.reset(seed=6)
    assert not np.array_equal(sim.render_stereo("rov")[0], first[0])  # another seed, other noise


def _tank_view(water: WaterParams, backend: str) -> Simulation:
    """The default scenario (walls, window, ladder, ranges from 0.5 m to the far wall) with ``water``."""
    return with_backend(replace(load_scenario(), water=water, noise=QUIET), backend)


@pytest.mark.parametrize(
    "water",
    [WaterParams(turbidity=0.0), WaterParams(turbidity=0.6, vignetting=0.3), WaterParams(turbidity=1.0)],
    ids=["clear", "turbid-vignetted", "murky"],
)
def test_gl_water_shader_matches_the_cpu_model(water):
    cpu, gl = _tank_view(water, "cpu"), _tank_view(water, "gl")
    robot = cpu.robots[0]
    pairs = zip(gl.render_stereo(robot, depth=True), cpu.render_stereo(robot, depth=True), strict=True)
    for ours, reference in pairs:
        if ours.dtype == np.uint8:
            difference = np.abs(ours.astype(int) - reference.astype(int))
            # float rounding (exp, sqrt in the shader) may tip a value to the next level, never further
            assert difference.max() <= 1 and (difference > 0).mean() < 0.05
        else:
            np.testing.assert_array_equal(ours, reference)  # the same depth buffer, converted alike
    assert gl.water_backend == "gl" and cpu.water_backend == "cpu"


def test_gl_water_noise_has_the_requested_spread_and_is_independent_per_camera():
    sim = _tank_view(WaterParams(turbidity=0.3, noise_sigma=4.0), "gl")
    robot = sim.robots[0]
    noisy = sim.render_stereo(robot)
    sim.water = WaterModel(WaterParams(turbidity=0.3))
    plain = sim.render_stereo(robot)
    noise = [a.astype(float) - b for a, b in zip(noisy, plain, strict=True)]
    for frame in noise:
        for channel in range(3):
            assert abs(frame[..., channel].std() - 4.0) < 0.2
            assert abs(frame[..., channel].mean()) < 0.1
        # neighbouring pixels and channels draw unrelated noise
        assert abs(np.corrcoef(frame[:, :-1, 0].ravel(), frame[:, 1:, 0].ravel())[0, 1]) < 0.02
        assert abs(np.corrcoef(frame[..., 0].ravel(), frame[..., 2].ravel())[0, 1]) < 0.02
    assert abs(np.corrcoef(noise[0].ravel(), noise[1].ravel())[0, 1]) < 0.02


def test_gl_water_pass_leaves_mujoco_rendering_unchanged():
    sim = _tank_view(WaterParams(turbidity=0.5, noise_sigma=2.0, vignetting=0.2), "gl")
    robot = sim.robots[0]
    before = sim.render_stereo(robot, depth=True, water=False)
    sim.render_stereo(robot)
    after = sim.render_stereo(robot, depth=True, water=False)
    for a, b in zip(before, after, strict=True):
        np.testing.assert_array_equal(a, b)


def test_water_backend_is_checked_and_auto_picks_gl_only_on_a_gpu():
    with pytest.raises(ValueError, match="water_backend"):
        Simulation(water_backend="cuda")
    sim = Simulation()
    on_gpu = renders_on_gpu(sim.model, sim.camera.height, sim.camera.width)
    assert sim.water_backend == ("gl" if on_gpu else "cpu")


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
            "--water-backend",
            "cpu",
        ]
    )
    assert code == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result) >= {"robots", "sim_time_s", "steps_per_s", "realtime_factor"}
    rov0 = result["robots"]["rov0"]
    assert set(rov0) >= {"position_m", "velocity_body_m_s", "rpy_rad", "rpy_deg", "contacts"}
    assert result["sim_time_s"] == pytest.approx(1.0, abs=0.03)
    assert rov0["velocity_body_m_s"][0] > 0.3
    assert rov0["contacts"] == []  # 1 s at half surge does not reach the wall 1.5 m ahead
    assert len(list(tmp_path.glob("rov0_*.png"))) == 2
    assert result["water_backend"] == "cpu"
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
    # noise that would go below black clips to 0 (P(N(0, 4) < 0.5) = 0.55) rather than mirroring
    black = model.apply(np.zeros((200, 300, 3), np.uint8), ranges, rng)
    assert 0.5 < (black == 0).mean() < 0.6


def test_a_closed_or_collected_simulation_frees_its_renderer():
    with Simulation() as sim:
        sim.render_stereo(sim.robots[0])
        key = id(sim.model)
        assert key in rendering._renderers
    assert key not in rendering._renderers
    sim.close()  # closing twice is harmless
    again = Simulation()
    again.render_stereo(again.robots[0], water=False)
    key = id(again.model)
    del again
    gc.collect()
    assert key not in rendering._renderers


def test_water_model_gives_the_same_image_with_or_without_its_two_thread_split(monkeypatch):
    model = WaterModel(WaterParams(turbidity=0.7, noise_sigma=3.0, vignetting=0.3))
    rng = np.random.default_rng(11)
    image = rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)
    ranges = rng.uniform(0.2, 12.0, (240, 320))
    split = model.apply(image, ranges, np.random.default_rng(4))
    monkeypatch.setattr(water_module, "_SPLIT_MIN_ROWS", 10_000)
    whole = model.apply(image, ranges, np.random.default_rng(4))
    np.testing.assert_array_equal(split, whole)


def _yellow_pixels(image: np.ndarray) -> int:
    """Pixels of the colour MuJoCo draws rangefinder rays in (yellow: red and green high, blue low)."""
    r, g, b = (image[..., k].astype(int) for k in range(3))
    return int(np.count_nonzero((r > 150) & (g > 150) & (b < 90)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_cameras_do_not_see_another_robots_dvl_beams(backend):
    # rov1 hovers 2.6 m in front of and below rov0; its four DVL beams run down to the floor in view
    vehicle = load_vehicle("heavy")
    specs = (
        RobotSpec("rov0", vehicle, (-4.0, 0.0, 1.65)),
        RobotSpec("rov1", vehicle, (-1.2, 0.0, 1.0), yaw_deg=90.0),
    )
    clear = WaterParams(turbidity=0.0, noise_sigma=0.0, vignetting=0.0)
    sim = with_backend(Scenario("beams", TankModel(), specs, water=clear, noise=QUIET), backend)
    for water in (False, True):
        left, right = sim.render_stereo("rov0", water=water)
        assert _yellow_pixels(left) == 0 and _yellow_pixels(right) == 0
    # the same view with MuJoCo's default visual options shows the beams: the check can see them
    renderer = rendering.shared_renderer(sim.model, sim.camera.height, sim.camera.width)
    renderer.update_scene(sim.data, camera="rov0/left")
    assert _yellow_pixels(renderer.render()) > 100
    # and the camera option hides every sensor and debug visual
    option = rendering.camera_scene_option()
    assert not option.flags[mujoco.mjtVisFlag.mjVIS_RANGEFINDER]
    assert not option.sitegroup.any() and option.frame == mujoco.mjtFrame.mjFRAME_NONE
    assert not option.flags[mujoco.mjtVisFlag.mjVIS_CONTACTPOINT]


def test_rendered_window_has_the_oak_d_focal_length_and_square_pixels():
    # Luxonis' OAK-D spec sheet: 2.35 mm focal length, 3 um pixels binned 2 x 2 at 640 x 400
    focal_px = 2.35e-3 / 6e-6
    distance, window = 1.2, WindowConfig(width=1.0, height=0.6, centre_height=1.0)
    tank = TankModel(TankConfig(window=window, ladder=LadderConfig(rails=0)))
    vehicle = load_vehicle("heavy")
    camera = np.asarray(vehicle.sensors.camera_position)
    spec = RobotSpec("rov", vehicle, (-distance - camera[0], 0.0, window.centre_height - camera[2]))
    sim = Simulation(Scenario("window", tank, (spec,), water=WaterParams(enabled=False), noise=QUIET))
    # the left camera sits half a baseline to the left: look at the right camera's centred view too
    for side, image in zip(
        ("left", "right"), sim.render_stereo("rov", depth=True, water=False)[2:], strict=True
    ):
        opening = image > distance + 0.01  # the recess behind the wall plane
        rows, cols = np.flatnonzero(opening.any(axis=1)), np.flatnonzero(opening.any(axis=0))
        width, height = cols[-1] - cols[0] + 1, rows[-1] - rows[0] + 1
        assert width == pytest.approx(focal_px * window.width / (distance + 0.01), abs=2.5), side
        assert height == pytest.approx(focal_px * window.height / (distance + 0.01), abs=2.5), side
        assert width / height == pytest.approx(window.width / window.height, rel=0.02)
    assert sim.intrinsics()["K"][0][0] == pytest.approx(focal_px) == sim.intrinsics()["K"][1][1]


def test_render_samples_sets_the_anti_aliasing_and_keeps_the_geometry():
    distance = 0.8
    images = {}
    for samples in (0, 4):
        sim = facing_wall(distance, WaterParams(enabled=False), render_samples=samples)
        assert sim.model.vis.quality.offsamples == samples
        images[samples] = sim.render_stereo("rov", water=False)
        rendering.release(sim.model)
        sim.close()
    gray = [cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) for image in images[0]]
    (shift_x, _), _ = cv2.phaseCorrelate(gray[1], gray[0])
    assert abs(shift_x - sim.camera.fx * sim.camera.baseline_m / distance) < 1.0  # same geometry
    # multisampling blends the pixels an edge crosses (the wall's far corners and the floor line)
    assert not np.array_equal(images[0][0], images[4][0])
    for bad in (-1, 2.0, True, 17):
        with pytest.raises(ValueError, match="render_samples"):
            facing_wall(distance, WaterParams(enabled=False), render_samples=bad)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_stereo_snapshot_draws_its_moment_after_the_physics_moves_on(backend):
    # the mission takes a snapshot at the frame's moment and draws it on its GL thread while the physics
    # steps on: the images must be those of the moment, noise and all, on either water backend
    water = WaterParams(turbidity=0.4, noise_sigma=3.0)
    at_once, later = facing_wall(0.9, water, backend), facing_wall(0.9, water, backend)
    turn = {"rov": np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3])}
    with ThreadPoolExecutor(1) as gl_thread:
        # the renderer, and its GL context, belong to the thread that makes them
        gl_thread.submit(lambda: later.water_backend).result()
        for sim in (at_once, later):
            sim.reset(seed=5)
            for _ in range(10):
                sim.step(turn)
        expected = at_once.render_stereo("rov")
        snapshot = later.stereo_snapshot("rov")
        for _ in range(50):  # the robot turns away meanwhile
            later.step(turn)
        drawn = gl_thread.submit(later.render_snapshot, snapshot).result()
        moved = gl_thread.submit(later.render_stereo, "rov").result()
        gl_thread.submit(later.close).result()
    at_once.close()
    for mine, theirs in zip(drawn, expected, strict=True):
        np.testing.assert_array_equal(mine, theirs)
    assert np.abs(moved[0].astype(int) - drawn[0].astype(int)).mean() > 1.0  # the view did change


@pytest.mark.parametrize("shader_runs", [True, False])
def test_prefer_gl_takes_the_shader_where_it_runs_and_the_cpu_model_elsewhere(monkeypatch, shader_runs):
    import maptidal.envs.simulation as simulation_module

    monkeypatch.setattr(simulation_module, "gl_water_available", lambda *args: shader_runs)
    monkeypatch.setattr(simulation_module, "renders_on_gpu", lambda *args: False)  # a CPU rasteriser
    preferred = facing_wall(0.9, WaterParams(), "prefer-gl")
    assert preferred.water_backend == ("gl" if shader_runs else "cpu")
    # where "auto" keeps the CPU model on a CPU rasteriser, and "gl" insists
    assert facing_wall(0.9, WaterParams(), "auto").water_backend == "cpu"
    insisting = Simulation(facing_wall(0.9, WaterParams()).scenario, water_backend="gl")
    if shader_runs:
        assert insisting.water_backend == "gl"
    else:
        with pytest.raises(RuntimeError, match="cannot run"):
            insisting.water_backend  # noqa: B018


def test_a_cameras_own_frame_is_left_out_of_its_scene_and_no_pixel_changes():
    # the BlueROV2's frame, floats and thrusters lie behind its cameras' near plane: leaving them out of
    # the scene spares drawing them, and must change no pixel of any image, whatever the attitude
    sim = Simulation()
    sim.reset(seed=0)
    model, data = sim.model, sim.data
    width, height = sim.camera.width, sim.camera.height
    rng = np.random.default_rng(1)
    scene = mujoco.MjvScene(model, 10000)
    colours = model.geom_rgba.copy()
    for trial in range(16):
        robot = sim.robots[trial % len(sim.robots)]
        axis = rng.normal(size=3)
        tilt = np.r_[math.cos(0.4), math.sin(0.4) * axis / np.linalg.norm(axis)]
        yaw = rng.uniform(-math.pi, math.pi)
        attitude = np.zeros(4)
        mujoco.mju_mulQuat(attitude, np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]), tilt)
        position = [rng.uniform(-4.5, -0.5), rng.uniform(-1.0, 1.0), rng.uniform(0.4, 1.6)]
        sim.place(robot, position, quaternion=attitude)
        mujoco.mj_forward(model, data)
        for side in ("left", "right"):
            camera = f"{robot}/{side}"
            hidden = rendering.geoms_behind_camera(model, camera)
            own = (model.geom_bodyid == model.cam_bodyid[model.camera(camera).id]) & (model.geom_group < 3)
            assert set(hidden) == set(np.flatnonzero(own))  # the whole visible frame
            everything, _ = rendering.render_camera(
                model, rendering.update_camera_scene(model, data, camera, scene), height, width, False
            )
            drawn = scene.ngeom
            without, _ = rendering.render_camera(
                model, rendering.update_camera_scene(model, data, camera, scene, hidden), height, width, False
            )
            assert scene.ngeom == drawn - len(hidden)
            np.testing.assert_array_equal(without, everything)
    np.testing.assert_array_equal(model.geom_rgba, colours)  # the colours are as they were
    sim.close()


def test_only_geoms_wholly_behind_the_near_plane_count_as_behind_the_camera():
    spec = mujoco.MjSpec()
    body = spec.worldbody.add_body(name="rig", pos=[0, 0, 1])
    # MuJoCo's cameras look along -z: with this orientation the camera looks along +x
    body.add_camera(name="eye", pos=[0, 0, 0], xyaxes=[0, -1, 0, 0, 0, 1])
    boxes = {"behind": -0.1, "straddling": 0.0, "ahead": 0.1}
    for name, x in boxes.items():
        body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03, 0.03, 0.03], pos=[x, 0, 0])
    body.add_geom(
        name="hidden-group", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03] * 3, pos=[-0.1, 0, 0], group=3
    )
    spec.worldbody.add_geom(name="elsewhere", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.03] * 3, pos=[-1, 0, 1])
    model = spec.compile()
    names = {model.geom(int(g)).name for g in rendering.geoms_behind_camera(model, "eye")}
    assert names == {"behind"}


def test_a_mirror_shows_a_cameras_own_frame_so_nothing_is_left_out_then():
    # MuJoCo draws the scene mirrored in an opaque reflective geom, and there a robot facing it sees its
    # own frame; in the tank's transparent window pane it draws no reflection at all
    two = load_scenario(None)
    sim = Simulation(two)
    sim.reset(seed=0)
    model, data = sim.model, sim.data
    width, height = sim.camera.width, sim.camera.height
    centre = np.mean(two.tank.window_rim(), axis=0)
    sim.place("rov0", centre + np.array([-0.6, 0.0, 0.0]), 0.0)  # 0.6 m from the pane, facing it
    mujoco.mj_forward(model, data)
    camera, scene = "rov0/left", mujoco.MjvScene(model, 10000)
    own = np.flatnonzero(
        (model.geom_bodyid == model.cam_bodyid[model.camera(camera).id]) & (model.geom_group < 3)
    )

    def images_with_and_without_the_frame():
        drawn = rendering.update_camera_scene(model, data, camera, scene)
        everything, _ = rendering.render_camera(model, drawn, height, width, False)
        left_out = rendering.update_camera_scene(model, data, camera, scene, own)
        without, _ = rendering.render_camera(model, left_out, height, width, False)
        return everything, without

    assert not rendering.has_mirrors(model)
    assert set(rendering.geoms_behind_camera(model, camera)) == set(own)
    everything, without = images_with_and_without_the_frame()
    np.testing.assert_array_equal(without, everything)
    model.mat_rgba[model.material("glass").id, 3] = 1.0  # an opaque pane: a mirror
    assert rendering.has_mirrors(model)
    assert len(rendering.geoms_behind_camera(model, camera)) == 0
    everything, without = images_with_and_without_the_frame()
    assert (np.abs(everything.astype(int) - without.astype(int)).max(axis=2) > 0).sum() > 1000
    sim.close()


def test_the_texture_noise_is_the_middle_of_an_upsampled_three_by_three_tiling():
    # the fast path (two wrapped cells of padding) against the literal construction it replaces
    import cv2

    from maptidal.envs.textures import _noise

    # at small upsampling factors OpenCV's resize rounds a few pixels one float32 ulp apart between the
    # two sizes; at the textures' own size (1024 px, the default octaves) every pixel is the same
    cases = [(size, (4, 16, 32), (0.5, 0.3, 0.2), 1e-6) for size in (64, 96, 100)]
    cases.append((1024, (4, 16, 64, 256), (0.4, 0.25, 0.2, 0.15), 0.0))
    for size, octaves, weights, tolerance in cases:  # 100: not a multiple of every octave (literal path)
        got = _noise(np.random.default_rng(3), size, octaves, weights)
        rng = np.random.default_rng(3)
        want = np.zeros((size, size), np.float32)
        for cells, weight in zip(octaves, weights, strict=True):
            tiled = np.tile(rng.random((cells, cells)).astype(np.float32), (3, 3))
            up = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
            want += weight * up[size : 2 * size, size : 2 * size]
        np.testing.assert_allclose(got, np.clip(want, 0.0, 1.0), rtol=0, atol=tolerance)
