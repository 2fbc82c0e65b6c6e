"""The tank is closed (issue [truthful-loop], part 3): a far end wall where the side walls end, the dark
observation room behind the window glass as a surface of its own, and robots kept inside.

The geometry is checked by brute force: rays from random points in the water, against every scene
triangle (the Moeller-Trumbore caster of ``test_world_geometry``), and against MuJoCo's own ray caster on
the compiled world; the physics by driving a robot at full thrust into the far end wall."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from test_world_geometry import SURFACES_AND_LADDER, TANKS, brute_force_hits

from maptidal.envs.scenario import RobotSpec, Scenario, inside_tank
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.envs.world import build_tank_spec
from maptidal.evaluation.free_space import classify_tasks
from maptidal.tank import ROOM_DEPTH_M, TankModel


def _points_in_the_water(tank: TankModel, count: int, rng: np.random.Generator) -> np.ndarray:
    c = tank.config
    far_x = -(c.side_length + 3.0)  # wider than any tank here, so the check below decides
    points = []
    while len(points) < count:
        point = rng.uniform([far_x, -4.0, 0.0], [0.0, 4.0, tank.height])
        if inside_tank(tank, point, 0.05):
            points.append(point)
    return np.array(points)


@pytest.mark.parametrize("name", TANKS)
def test_no_ray_from_the_water_leaves_the_tank_except_through_the_surface(name):
    tank = TANKS[name]
    rng = np.random.default_rng(11)
    origins = _points_in_the_water(tank, 300, rng)
    directions = rng.normal(size=origins.shape)
    directions[: len(directions) // 2, 2] = -np.abs(directions[: len(directions) // 2, 2])
    directions[: len(directions) // 4, 2] = 0.0  # horizontal: the far end used to be open
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    hits = brute_force_hits(origins, directions, tank.scene_triangles())
    with np.errstate(divide="ignore"):
        to_surface = np.where(directions[:, 2] > 0, (tank.height - origins[:, 2]) / directions[:, 2], np.inf)
    # every ray meets a wall, the floor, the ladder or the glass, or leaves through the water surface first
    assert np.all(np.minimum(hits, to_surface) < np.inf)
    # and where it leaves through the surface, it does so inside the tank's outline
    up = to_surface < hits
    crossing = origins[up] + to_surface[up, None] * directions[up]
    assert all(inside_tank(tank, p - [0, 0, 1e-6], 0.0) for p in crossing)
    # horizontal rays never reach past the far end wall
    flat = np.abs(directions[:, 2]) < 1e-12
    ends = origins[flat] + hits[flat, None] * directions[flat]
    assert ends[:, 0].min() >= tank.far_x - 1e-9


@pytest.mark.parametrize("name", TANKS)
def test_mujoco_sees_the_far_end_wall_where_the_tank_file_puts_it(name):
    tank = TANKS[name]
    c = tank.config
    model = build_tank_spec(tank).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, np.int32)
    # the far end: the side walls' whole length beyond the evaluated region's far corner
    corner_x = min(float(seg.start[0]) for seg in tank.segments)
    expected_far_x = corner_x - (c.side_length - c.side_evaluated_length)
    origin = np.array([expected_far_x + 1.25, 0.0, 0.5 * tank.height])
    distance = mujoco.mj_ray(
        model, data, origin, np.array([-1.0, 0.0, 0.0]), SURFACES_AND_LADDER, 1, -1, geom
    )
    assert distance == pytest.approx(1.25, abs=1e-6)
    assert tank.far_x == pytest.approx(expected_far_x)


def test_the_room_behind_the_glass_is_a_surface_of_the_tank_and_of_the_world():
    tank = TankModel()
    pane = [(corners, normal) for corners, normal, kind in tank.scene_quads() if kind == "pane"]
    rooms = [(corners, normal) for corners, normal, kind in tank.scene_quads() if kind == "room"]
    assert len(pane) == 1 and len(rooms) == 1
    (pane_corners, normal), (room_corners, room_normal) = pane[0], rooms[0]
    np.testing.assert_allclose(room_corners, pane_corners - ROOM_DEPTH_M * normal)
    np.testing.assert_allclose(room_normal, normal)
    # a ray from the water through the pane's centre meets the pane, and one started just behind the
    # pane meets the room's plane ROOM_DEPTH_M further on, in the triangles and in MuJoCo alike
    centre = pane_corners.mean(axis=0)
    inward = -np.asarray(normal, float)
    behind = centre + 1e-4 * inward
    expected = brute_force_hits(behind[None], inward[None], tank.scene_triangles())[0]
    assert expected == pytest.approx(ROOM_DEPTH_M - 1e-4, abs=1e-6)
    model = build_tank_spec(tank).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    got = mujoco.mj_ray(model, data, behind, inward, SURFACES_AND_LADDER, 1, -1, np.zeros(1, np.int32))
    assert got == pytest.approx(expected, abs=1e-6)
    # the room is no part of the inspected region
    surface = tank.evaluated_surface()
    assert surface.vertices[:, 0].max() <= centre[0] + 1e-9  # nothing beyond the glass


def test_tasks_beyond_the_far_end_wall_are_behind_a_wall():
    tank = TankModel()
    tasks = np.array(
        [
            [tank.far_x + 0.5, 0.0, 1.0, -1.0, 0.0, 0.0],  # in the water, facing the far wall
            [tank.far_x - 0.5, 0.0, 1.0, 1.0, 0.0, 0.0],  # beyond it
        ]
    )
    labels = classify_tasks(tank, tasks, standoff_m=0.4)
    assert labels.tolist() == ["free", "behind_wall"]
    assert not inside_tank(tank, tasks[1, :3])


def test_a_robot_driven_at_the_far_end_wall_stays_in_the_tank():
    tank = TankModel()
    vehicle = load_vehicle("heavy")
    start = (tank.far_x + 1.5, 0.0, 1.0)
    scenario = Scenario("far", tank, (RobotSpec("rov0", vehicle, start, yaw_deg=180.0),))
    half_length = vehicle.hull_size[0] / 2
    xs = []
    with Simulation(scenario, flight_mode="stabilize") as sim:
        sim.reset(seed=0)
        while sim.time < 12.0:  # full surge at the far end wall (0.9 m/s: it arrives in about 2 s)
            sim.step({"rov0": np.array([1.0, 0, 0, 0, 0, 0])})
            xs.append(float(sim.ground_truth("rov0")["position"][0]))
    assert min(xs) < tank.far_x + half_length + 0.2  # it reached the wall
    assert min(xs) > tank.far_x + 0.5 * half_length  # and did not pass it
    assert math.isfinite(xs[-1]) and xs[-1] > tank.far_x
