"""The accelerometer's watch on the motion model (:mod:`maptidal.perception.unmodelled`): how far a robot
without a DVL may have moved unseen, pushed or blocked, and its front end's uncertainty grown by it.

References that share no code with what is tested: a vehicle's velocity written down by hand and the
accelerometer's reading made from it (the period's velocity change plus gravity, rotated by scipy), the
closed-form glide of a body under quadratic drag, and the simulator's truth."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from mission_helpers import mission_at_rest
from scipy.spatial.transform import Rotation

from maptidal.envs.scenario import load_scenario
from maptidal.envs.simulation import Simulation
from maptidal.mission.outputs import read_events
from maptidal.mission.params import MissionParams
from maptidal.perception.odometry import OdometryParams, VisualOdometry
from maptidal.perception.recording import CameraPose
from maptidal.perception.unmodelled import UnmodelledMotion, UnmodelledMotionParams

DT = 0.02  # the simulator's control period
G = 9.81
# a Heavy's sway (the default vehicle's motion model): no linear damping, so a glide slows as 1 / t
SWAY_MASS, SWAY_QUADRATIC = 20.62, 217.0
HEAVY = UnmodelledMotionParams(
    inertia=(19.86, SWAY_MASS, 32.18),
    linear_damping=(13.7, 0.0, 33.0),
    quadratic_damping=(141.0, SWAY_QUADRATIC, 190.0),
)


def fly(monitor: UnmodelledMotion, true_y: np.ndarray, model_y: np.ndarray, noise=None) -> None:
    """A level vehicle heading along x: its true and modelled sway velocities each period (m/s); the
    accelerometer reads the true period's velocity change plus gravity (and ``noise``, m/s^2, if given)."""
    for k in range(1, len(true_y)):
        force = np.array([0.0, (true_y[k] - true_y[k - 1]) / DT, G])
        if noise is not None:
            force = force + noise[k]
        monitor.update(force, (0.0, 0.0, 0.0), 0.0, 0.0, (0.0, model_y[k], 0.0), DT)


def unmodelled_distance(true_y: np.ndarray, model_y: np.ndarray) -> float:
    """The distance the vehicle went that its model did not say, by brute force."""
    return float(np.sum(np.abs(true_y[1:] - model_y[1:])) * DT)


def commanded_profile(seconds: float, seed: int) -> np.ndarray:
    """A sway velocity that changes as a vehicle's does under new commands every 0.5 s (a first-order
    approach to each new speed, up to 0.3 m/s)."""
    rng = np.random.default_rng(seed)
    velocity, target, out = 0.0, 0.0, []
    for k in range(int(seconds / DT)):
        if k % 25 == 0:
            target = rng.uniform(-0.3, 0.3)
        velocity += (target - velocity) * DT / 0.4
        out.append(velocity)
    return np.array(out)


# ----- hand-made flights -----------------------------------------------------------------------------
def test_a_vehicle_flying_as_its_model_says_counts_nothing_through_noise_and_bias():
    rng = np.random.default_rng(0)
    velocity = commanded_profile(60.0, 1)
    noise = rng.normal(0.0, 0.02, (len(velocity), 3)) + np.array([0.04, -0.05, 0.03])  # white, and a bias
    monitor = UnmodelledMotion(HEAVY)
    fly(monitor, velocity, velocity, noise)
    assert monitor.pushes == 0
    assert monitor.take() == 0.0
    assert monitor.offset[1] == pytest.approx(-0.05, abs=0.01)  # the bias, learned


@pytest.mark.parametrize("roll, pitch", [(0.1, -0.2), (-0.3, 0.15), (0.0, 0.4)])
def test_a_tilted_vehicle_at_rest_reads_gravity_alone(roll, pitch):
    # the accelerometer at rest reads the world's up in body axes, times g: scipy's rotation, z-y-x
    body_to_world = Rotation.from_euler("ZYX", [0.7, pitch, roll]).as_matrix()
    force = body_to_world.T @ np.array([0.0, 0.0, G])
    monitor = UnmodelledMotion(HEAVY)
    for _ in range(500):
        monitor.update(force, (0.0, 0.0, 0.0), roll, pitch, (0.0, 0.0, 0.0), DT)
    assert monitor.pushes == 0 and monitor.take() == 0.0
    assert max(abs(v) for v in monitor.offset) < 1e-9


def test_a_turn_at_speed_is_the_models_not_a_push():
    """Surging at 0.3 m/s while yawing at 0.8 rad/s: the body's acceleration is w x v, 0.24 m/s^2
    sideways, which the accelerometer reads and the model's v' + w x v says too."""
    monitor = UnmodelledMotion(HEAVY)
    velocity, rate = (0.3, 0.0, 0.0), (0.0, 0.0, 0.8)
    force = np.cross(rate, velocity) + np.array([0.0, 0.0, G])
    for _ in range(500):
        monitor.update(force, rate, 0.0, 0.0, velocity, DT)
    assert monitor.pushes == 0 and monitor.take() == 0.0


def test_a_push_counts_the_glide_that_follows():
    """Struck to 0.4 m/s sideways at 2 s, the vehicle glides on under quadratic drag, v = v0 / (1 + v0 k t)
    with k = d_q / m, and goes ln(1 + v0 k t) / k in t seconds; its model holds still. Over the 15 s
    after the blow that is 40 cm, half of it below 5 cm/s, where the accelerometer loses it: the
    glide on the model's drag counts it."""
    times = np.arange(0.0, 17.0, DT)
    k = SWAY_QUADRATIC / SWAY_MASS
    after = np.clip(times - 2.0, 0.0, None)
    true_y = np.where(times >= 2.0, 0.4 / (1.0 + 0.4 * k * after), 0.0)
    model_y = np.zeros_like(times)
    expected = math.log(1.0 + 0.4 * k * 15.0) / k
    assert unmodelled_distance(true_y, model_y) == pytest.approx(expected, rel=0.02)  # the sampling's
    gliding = UnmodelledMotion(HEAVY)
    fly(gliding, true_y, model_y)
    assert gliding.pushes == 1
    assert gliding.take() == pytest.approx(expected, rel=0.1)
    measured_only = UnmodelledMotion()  # no drag given: it counts what the accelerometer followed
    fly(measured_only, true_y, model_y)
    assert 0.3 * expected < measured_only.take() < 0.7 * expected


def test_a_second_push_during_the_glide_starts_from_the_glides_velocity():
    """Struck to 0.4 m/s at 2 s, the vehicle glides (its velocity worked out here by brute force, the
    drag stepped on the true velocity); struck again, +0.3 m/s, at 4 s. The second push starts from the
    velocity the glide left, which the drag's slowing has already taken down: the watch's unmodelled
    velocity is the true one to 1 cm/s through it, not short by the glide's slowing counted twice."""
    times = np.arange(0.0, 6.0, DT)
    k = SWAY_QUADRATIC / SWAY_MASS
    true_y = np.zeros_like(times)
    for i in range(1, len(times)):
        velocity = true_y[i - 1] + 0.4 * math.isclose(times[i], 2.0) + 0.3 * math.isclose(times[i], 4.0)
        true_y[i] = velocity / (1.0 + DT * k * abs(velocity))
    monitor = UnmodelledMotion(HEAVY)
    for i in range(1, len(times)):
        fly(monitor, true_y[i - 1 : i + 1], np.zeros(2))
        if times[i] > 2.0:
            assert monitor.velocity[1] == pytest.approx(true_y[i], abs=0.01), times[i]
    assert monitor.pushes == 2


def test_a_wall_that_stops_the_vehicle_counts_the_models_flight_on():
    """The vehicle speeds up to 0.3 m/s with its model, stops dead at a wall at 2 s; its model flies on
    for 3 s more, then slows to rest over 0.5 s. The estimate went on some 0.98 m the vehicle did not."""
    times = np.arange(0.0, 8.0, DT)
    model_y = np.clip(times, 0.0, 1.0) * 0.3
    model_y = np.where(times > 5.0, np.clip(0.3 * (1.0 - (times - 5.0) / 0.5), 0.0, None), model_y)
    true_y = np.where(times < 2.0, model_y, 0.0)
    expected = unmodelled_distance(true_y, model_y)
    assert expected == pytest.approx(0.3 * 3.0 + 0.3 * 0.25, abs=0.02)
    monitor = UnmodelledMotion(HEAVY)
    fly(monitor, true_y, model_y)
    assert monitor.pushes == 1
    assert monitor.take() == pytest.approx(expected, rel=0.1)
    assert not monitor.pushing and not monitor.coasting  # over once the model stopped too


def test_the_gyros_bias_is_learned_and_holds_the_vertical_through_a_long_push():
    """A vehicle at rest, level, its gyro reading a bias of 1 mrad/s about x and -0.7 about y. Two
    minutes learn it (the estimator's vertical, given here exactly, against the watch's); then a steady
    unmodelled push of 0.2 m/s^2 sideways for 4 s, with the estimator's vertical tilted as the push
    leans its correction (it takes the push for gravity: 0.2 / g rad). The watch's velocity is the
    push's to within 12 % (what its leaky integral loses while the filter rises past 0.15 m/s^2, some
    0.7 s), where integrating against the estimator's vertical gives 40 % less."""
    bias = (0.001, -0.0007, 0.0)
    monitor = UnmodelledMotion(HEAVY)
    level = (0.0, 0.0, G)
    for _ in range(6000):
        monitor.update(level, bias, 0.0, 0.0, (0.0, 0.0, 0.0), DT)
    assert monitor._gyro_bias[0] == pytest.approx(bias[0], rel=0.1)
    assert monitor._gyro_bias[1] == pytest.approx(bias[1], rel=0.1)
    push, lean = 0.2, math.atan(0.2 / G)
    for k in range(200):
        roll = -lean * min(1.0, k * DT / 5.0)  # the estimator's tilt, leaning towards the push over 5 s
        monitor.update((0.0, push, G), bias, roll, 0.0, (0.0, 0.0, 0.0), DT)
    assert monitor.pushing
    assert monitor.velocity[1] == pytest.approx(push * 4.0, rel=0.12)


def test_a_dvl_period_forgets_the_push_and_take_starts_again():
    monitor = UnmodelledMotion(HEAVY)
    true_y = np.r_[np.zeros(50), np.full(100, 0.3)]
    fly(monitor, true_y, np.zeros_like(true_y))
    assert monitor.pushing and monitor.take() > 0.2 and monitor.take() == 0.0
    monitor.update((0.0, 0.0, G), (0.0, 0.0, 0.0), 0.0, 0.0, (0.0, 0.3, 0.0), DT, modelled=False)
    assert not monitor.pushing and not monitor.coasting
    for _ in range(100):  # the DVL gone again: from its last velocity on, the model's
        monitor.update((0.0, 0.0, G), (0.0, 0.0, 0.0), 0.0, 0.0, (0.0, 0.3, 0.0), DT)
    assert monitor.take() == 0.0


def test_bad_readings_are_skipped_and_bad_settings_refused():
    monitor = UnmodelledMotion(HEAVY)
    monitor.update((math.nan, 0.0, G), (0.0, 0.0, 0.0), 0.0, 0.0, (0.0, 0.0, 0.0), DT)
    assert monitor.pushes == 0 and monitor.take() == 0.0
    with pytest.raises(ValueError, match="dt"):
        monitor.update((0.0, 0.0, G), (0.0, 0.0, 0.0), 0.0, 0.0, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ValueError, match="end_m_s2"):
        UnmodelledMotionParams(start_m_s2=0.1, end_m_s2=0.2)
    with pytest.raises(ValueError, match="settle_s"):
        UnmodelledMotionParams(settle_s=math.nan)
    with pytest.raises(ValueError, match="inertia"):
        UnmodelledMotionParams(inertia=(0.0, 1.0, 1.0))


# ----- the front end's uncertainty -------------------------------------------------------------------
def test_the_unmodelled_distance_adds_to_the_standard_deviation_outright():
    odometry = VisualOdometry(OdometryParams(has_dvl=False))
    pose = CameraPose(np.zeros(3), np.eye(3))
    odometry.update(pose, None)
    before = odometry.sigma_m
    odometry.update(pose, None, dt_s=1.0, unmodelled_m=0.3)
    drift = OdometryParams().drift_m2_s_no_dvl
    assert odometry.sigma_m == pytest.approx(math.sqrt(before**2 + drift) + 0.3)


# ----- in the simulator ------------------------------------------------------------------------------
MISSION = load_scenario("mission")  # rov1 has no DVL


def watched(sim: Simulation, robot: str = "rov1") -> UnmodelledMotion:
    return UnmodelledMotion(UnmodelledMotionParams.for_model(sim.motion_model(robot)))


def watch(sim: Simulation, monitor: UnmodelledMotion, robot: str = "rov1") -> None:
    readings, estimate = sim.latest_readings(robot), sim.estimate(robot)
    monitor.update(
        readings["imu"]["accel_mean"],
        readings["imu"]["gyro"],
        estimate.rpy[0],
        estimate.rpy[1],
        estimate.velocity_body,
        sim.scenario.control_period_s,
        not readings["dvl"]["valid"] if "dvl" in readings else True,
    )


def horizontal_error(sim: Simulation, robot: str = "rov1") -> float:
    truth = np.asarray(sim.ground_truth(robot)["position"])
    return float(np.hypot(*(truth[:2] - sim.estimate(robot).position[:2])))


def test_random_commands_without_contact_raise_no_push_in_the_simulator():
    """20 s of random commands, a new one every 0.1 s, away from the walls (the thrusters' lag, the
    sensors' noise and biases, the plant's own drag): the model explains the flight."""
    sim = Simulation(MISSION, flight_mode="stabilize")
    sim.reset(seed=7)
    monitor = watched(sim)
    rng = np.random.default_rng(7)
    command = np.zeros(6)
    for k in range(1000):
        if k % 5 == 0:
            command = rng.uniform(-0.6, 0.6, 6)
        sim.step({"rov1": command, "rov0": {}})
        watch(sim, monitor)
    assert sim.odometry("rov1").contact_s == 0.0
    assert monitor.pushes == 0 and monitor.take() == 0.0


@pytest.mark.parametrize("force_n", [20.0, 40.0])
def test_a_shove_in_open_water_is_counted_near_how_far_it_carried_the_estimate_off(force_n):
    """A hand's shove sideways for half a second (MuJoCo's applied force on the body), the robot holding
    still in STABILIZE: over the next 10 s the estimate goes 0.45 to 0.65 m off; the count follows it
    within a third."""
    sim = Simulation(MISSION, flight_mode="stabilize")
    sim.reset(seed=1)
    monitor = watched(sim)
    body = sim._slots["rov1"].body_id
    for _ in range(750):  # 15 s of rest first: the accelerometer's bias learned
        sim.step({"rov1": {}, "rov0": {}})
        watch(sim, monitor)
    assert monitor.pushes == 0 and monitor.take() == 0.0
    start = horizontal_error(sim)
    for k in range(500):
        sim.data.xfrc_applied[body, :3] = (0.0, force_n, 0.0) if k < 25 else (0.0, 0.0, 0.0)
        sim.step({"rov1": {}, "rov0": {}})
        watch(sim, monitor)
    carried = horizontal_error(sim) - start
    assert carried > 0.4 and sim.odometry("rov1").contact_s < 0.2
    assert monitor.pushes >= 1
    assert monitor.take() == pytest.approx(carried, rel=1 / 3)


def test_swayed_into_the_side_wall_the_count_covers_the_model_flying_on():
    """rov1 swayed at the side wall 17 cm off, at 0.6 stick for 4 s: its model flies it on through the
    wall while it stands against it; the count is at least most of how far off that leaves the estimate."""
    rov0, rov1 = MISSION.robots
    scenario = dataclasses.replace(
        MISSION,
        robots=(
            dataclasses.replace(rov0, position=(-3.0, 0.6, 1.0)),
            dataclasses.replace(rov1, position=(-3.0, -1.45, 1.0)),
        ),
    )
    sim = Simulation(scenario, flight_mode="stabilize")
    sim.reset(seed=0)
    monitor = watched(sim)
    for _ in range(500):
        sim.step({"rov1": {}, "rov0": {}})
        watch(sim, monitor)
    start = horizontal_error(sim)
    monitor.take()
    for k in range(500):
        sim.step({"rov1": {"sway": 0.6} if k < 200 else {}, "rov0": {}})
        watch(sim, monitor)
    carried = horizontal_error(sim) - start
    assert sim.odometry("rov1").contact_s > 1.0 and carried > 0.3
    assert 0.7 * carried < monitor.take() < 2.0 * carried


# ----- in the mission --------------------------------------------------------------------------------
@pytest.mark.parametrize("watching", [True, False])
def test_a_shoved_robot_is_told_at_its_next_frame(tmp_path, watching):
    """In the mission, rov1 (no DVL) shoved: its next frame's uncertainty holds the distance (and a
    ``pushed`` event says when) with the watch on, and not with it off. rov0's DVL measures its own
    velocity, and its watch counts nothing."""
    with mission_at_rest(tmp_path, duration_s=30.0, watch_pushes=watching) as (mission, _):
        robot, front = mission.robots["rov1"], mission.perception.fronts["rov1"]
        body = mission.sim._slots["rov1"].body_id
        for k in range(600):
            if k == 50:  # a first frame, after a second at rest
                mission._see(robot, mission.sim.time)
                mission._frames["rov1"].result()
                start_error, start_sigma = horizontal_error(mission.sim), front.odometry.sigma_m
                start_s = mission.sim.time
            push = (0.0, 40.0, 0.0) if 300 <= k < 325 else (0.0, 0.0, 0.0)
            mission.sim.data.xfrc_applied[body, :3] = push
            before = mission.sim.time
            mission.sim.step({})
            if watching:
                mission._watch_pushes(mission.sim.time - before)
        carried = horizontal_error(mission.sim) - start_error
        mission._see(robot, mission.sim.time)
        mission._frames["rov1"].result()
        # time alone grows it this much (and a fix could only shrink it)
        drift = front.odometry.params.drift_m2_s_no_dvl * (mission.sim.time - start_s)
        by_time = math.sqrt(start_sigma**2 + drift) - start_sigma
        grown = front.odometry.sigma_m - start_sigma
        assert carried > 0.3
        if watching:
            assert grown > by_time + 0.6 * carried
        else:
            assert grown <= by_time + 1e-9
        assert mission.robots["rov0"].unmodelled.take() == 0.0
        # its DVL measured every period's velocity: no period was the model's, nothing was learned
        assert mission.robots["rov0"].unmodelled.offset == [0.0, 0.0, 0.0]
    pushed = [e for e in read_events(tmp_path) if e["kind"] == "pushed"]
    assert [e["robot"] for e in pushed] == (["rov1"] if watching else [])
    if watching:
        assert 6.0 <= pushed[0]["t"] <= 6.8


def test_the_mission_file_turns_the_watch_on(tmp_path):
    from maptidal.mission.config import DEFAULT_MISSION, load_mission, prepare_mission

    assert MissionParams().watch_pushes is False  # off by default (docs/mission.md, "Without a DVL")
    mission_file = tmp_path / "mission.toml"
    text = DEFAULT_MISSION.read_text()  # the default mission has no [mission] table: add one
    mission_file.write_text(text + "\n[mission]\nwatch_pushes = true\n")
    assert load_mission(mission_file)[1]["watch_pushes"] is True
    assert prepare_mission(mission_file)[1].watch_pushes is True
    mission_file.write_text(text + '\n[mission]\nwatch_pushes = "yes"\n')
    with pytest.raises(ValueError, match="watch_pushes"):
        load_mission(mission_file)
