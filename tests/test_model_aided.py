"""Dead reckoning without a DVL (issue [mission]): the velocity from the thrust commands through the
vehicle's motion model (maptidal.controllers.estimation.MotionModel), checked against Fossen's closed forms
and against the simulator's truth; and the visual odometry's gate against the model-aided step."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from maptidal.controllers.estimation import DeadReckoning, EstimatorParams, MotionModel
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.perception.odometry import OdometryParams, VisualOdometry
from maptidal.perception.recording import CameraPose
from maptidal.tank import TankModel, open_water_config

MASS, LINEAR, QUADRATIC = 30.0, 5.0, 40.0


def _model(quadratic: float = QUADRATIC, buoyancy: float = 0.0) -> MotionModel:
    return MotionModel((MASS,) * 3, (LINEAR,) * 3, (quadratic,) * 3, net_buoyancy_n=buoyancy)


def test_the_speed_settles_where_thrust_balances_linear_and_quadratic_drag():
    force = 20.0
    v = np.zeros(3)
    for _ in range(5000):
        v = _model().step(v, [force, 0.0, 0.0], np.array([0.0, 0.0, 1.0]), 0.02)
    # d_l v + d_q v^2 = F, the positive root
    terminal = (-LINEAR + math.sqrt(LINEAR**2 + 4 * QUADRATIC * force)) / (2 * QUADRATIC)
    assert v[0] == pytest.approx(terminal, rel=1e-6)
    assert v[1] == pytest.approx(0.0, abs=1e-12)


def test_with_linear_damping_the_speed_rises_as_the_exponential():
    force, dt = 10.0, 1e-3
    v = np.zeros(3)
    tau = MASS / LINEAR  # the time constant of m dv/dt = F - d v
    for _ in range(round(tau / dt)):
        v = _model(quadratic=0.0).step(v, [force, 0.0, 0.0], np.array([0.0, 0.0, 1.0]), dt)
    expected = force / LINEAR * (1.0 - math.exp(-1.0))
    assert v[0] == pytest.approx(expected, rel=2e-3)


def test_net_buoyancy_pushes_along_the_world_vertical_in_body_axes():
    # rolled 90 degrees: the world's up is the body's -y
    up_body = np.array([0.0, -1.0, 0.0])
    v = np.zeros(3)
    for _ in range(6000):
        v = _model(quadratic=0.0, buoyancy=2.0).step(v, np.zeros(3), up_body, 0.02)
    np.testing.assert_allclose(v, [0.0, -2.0 / LINEAR, 0.0], atol=1e-6)


def test_a_long_step_stays_between_rest_and_the_terminal_speed():
    v = _model().step(np.zeros(3), [20.0, 0.0, 0.0], np.array([0.0, 0.0, 1.0]), 50.0)
    terminal = (-LINEAR + math.sqrt(LINEAR**2 + 4 * QUADRATIC * 20.0)) / (2 * QUADRATIC)
    assert 0.0 < v[0] <= 20.0 / LINEAR and np.isfinite(v).all()
    assert v[0] > 0.5 * terminal


def _readings(heading_deg: float, dvl_velocity=None, thrust=None) -> dict:
    readings = {
        "imu": {"accel": [0.0, 0.0, 9.81], "gyro": [0.0, 0.0, 0.0]},
        "depth": {"depth_m": 1.0},
        "compass": {"heading_deg": heading_deg},
    }
    if dvl_velocity is not None:
        readings["dvl"] = {"velocity_body": list(dvl_velocity), "valid": True}
    if thrust is not None:
        readings["thrust"] = {"force_body": list(thrust)}
    return readings


def _estimator(model: MotionModel | None, start_yaw: float = 0.0) -> DeadReckoning:
    return DeadReckoning(EstimatorParams(5.0, motion_model=model), (0.0, 0.0, 4.0), start_yaw)


def test_without_a_dvl_a_forward_thrust_moves_the_estimate_along_the_heading():
    # heading 270 deg clockwise from north is yaw +90 deg: body forward is world +y
    estimator = _estimator(_model(quadratic=0.0), start_yaw=math.pi / 2)
    for _ in range(500):
        state = estimator.update(_readings(270.0, thrust=(10.0, 0.0, 0.0)), 0.02)
    assert state.position[1] > 1.0 and abs(state.position[0]) < 1e-6 * state.position[1]
    assert state.velocity_body[0] == pytest.approx(
        10.0 / LINEAR * (1 - math.exp(-10 * LINEAR / MASS)), rel=0.02
    )


def test_without_a_model_or_a_thrust_reading_the_estimate_holds_its_place():
    for estimator, thrust in ((_estimator(None), (10.0, 0.0, 0.0)), (_estimator(_model()), None)):
        for _ in range(100):
            state = estimator.update(_readings(0.0, thrust=thrust), 0.02)
        np.testing.assert_allclose(state.position[:2], 0.0, atol=1e-12)


def test_a_valid_dvl_velocity_wins_over_the_model():
    estimator = _estimator(_model())
    for _ in range(50):
        state = estimator.update(_readings(0.0, dvl_velocity=(0.0, 0.1, 0.0), thrust=(50.0, 0.0, 0.0)), 0.02)
    # heading 0: body left (+y) is world +y; the thrust asked for surge, which the DVL says is not there
    # (the DVL's first step reads as a brief lateral acceleration, which tilts the attitude a hair)
    assert state.position[1] == pytest.approx(0.1, rel=1e-4) and abs(state.position[0]) < 1e-6


def test_the_simulators_robot_without_a_dvl_dead_reckons_its_own_thrust():
    vehicle = load_vehicle("heavy")
    robot = RobotSpec("rov", vehicle, (-15.0, 0.0, 15.0), sensors=("imu", "depth", "compass"))
    sim = Simulation(Scenario("open", TankModel(open_water_config(30.0)), (robot,)), flight_mode="stabilize")
    sim.reset(seed=0)
    start = np.asarray(sim.ground_truth("rov")["position"])
    for k in range(round(20.0 / sim.scenario.control_period_s)):
        sim.step({"rov": {"surge": 0.3, "sway": -0.2} if k < 600 else {}})  # 12 s of thrust, then coast
    truth = np.asarray(sim.ground_truth("rov")["position"])
    estimate = sim.estimate("rov").position
    travelled = np.linalg.norm((truth - start)[:2])
    assert travelled > 1.0
    # the model leaves out the thrusters' lag: within a tenth of the way
    assert np.linalg.norm((estimate - truth)[:2]) < 0.1 * travelled
    assert "thrust" in sim.latest_readings("rov")


def _pose(x: float) -> CameraPose:
    # a camera looking along world +x (optical z), at height 1 m
    rotation = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    return CameraPose(np.array([x, 0.0, 1.0]), rotation)


def _forward_motion(step_m: float):
    # the camera moved step_m along its optical axis: x_cur = x_prev - (0, 0, step)
    return np.eye(3), np.array([0.0, 0.0, -step_m]), 50


@pytest.mark.parametrize(("model_aided", "weight"), [(True, 0.5), (False, 1.0)])
def test_without_a_dvl_vision_weighs_by_what_the_dead_reckoning_knows(model_aided, weight):
    params = OdometryParams(has_dvl=False, model_aided=model_aided, visual_weight_depth=0.0)
    odometry = VisualOdometry(params)
    odometry.update(_pose(0.0), None)
    dr_step = 0.05 if model_aided else 0.0
    fused = odometry.update(_pose(dr_step), _forward_motion(0.1))
    assert fused.position[0] == pytest.approx(weight * 0.1 + (1 - weight) * dr_step)
    assert odometry.visual_updates == 1 and odometry.gated == 0


def test_the_gate_drops_a_visual_step_far_from_the_dead_reckoned_one():
    params = OdometryParams(has_dvl=False, model_aided=True, max_disagreement_m=0.12)
    odometry = VisualOdometry(params)
    odometry.update(_pose(0.0), None)
    fused = odometry.update(_pose(0.05), _forward_motion(-0.2))  # vision says 0.2 m back: 0.25 m off
    assert fused.position[0] == pytest.approx(0.05) and odometry.gated == 1 and odometry.visual_updates == 0
    # a robot whose dead reckoning has no horizontal motion has nothing to gate against
    blind = VisualOdometry(OdometryParams(has_dvl=False, model_aided=False))
    blind.update(_pose(0.0), None)
    assert blind.update(_pose(0.0), _forward_motion(-0.2)).position[0] == pytest.approx(-0.2)
    assert blind.gated == 0


def test_a_rolled_vehicle_rises_straight_up_under_its_buoyancy():
    roll = 0.5
    estimator = _estimator(_model(quadratic=0.0, buoyancy=5.0))
    estimator.set_attitude(roll, 0.0, 0.0)
    readings = _readings(0.0, thrust=(0.0, 0.0, 0.0))
    readings["imu"]["accel"] = [0.0, 9.81 * math.sin(roll), 9.81 * math.cos(roll)]  # at rest, rolled
    for _ in range(500):
        state = estimator.update(readings, 0.02)
    # the buoyancy is world-up: the body velocity it drives, rotated back, has no horizontal part
    assert state.rpy[0] == pytest.approx(roll, abs=1e-3)
    assert np.linalg.norm(state.velocity_body) > 0.5
    np.testing.assert_allclose(state.position[:2], 0.0, atol=1e-3)


def test_in_a_steady_turn_the_model_settles_where_fossens_coriolis_terms_balance():
    # per axis written out, Fossen's M dv/dt + C(v) v + D(v) v = tau for a diagonal mass and a turn at a
    # constant yaw rate r: 0 = X - d_u(u) u + m_v v r and 0 = -d_v(v) v - m_u u r
    from scipy.optimize import fsolve

    masses, linear, quadratic = (40.0, 60.0, 70.0), (5.0, 7.0, 9.0), (40.0, 50.0, 60.0)
    model = MotionModel(masses, linear, quadratic)
    thrust, r = 25.0, 0.4

    def balance(uv):
        u, v = uv
        return [
            thrust - (linear[0] + quadratic[0] * abs(u)) * u + masses[1] * v * r,
            -(linear[1] + quadratic[1] * abs(v)) * v - masses[0] * u * r,
        ]

    expected = fsolve(balance, [0.5, 0.0], xtol=1e-12)
    v = np.zeros(3)
    for _ in range(20000):
        v = model.step(v, [thrust, 0.0, 0.0], np.array([0.0, 0.0, 1.0]), 0.005, np.array([0.0, 0.0, r]))
    assert v[:2] == pytest.approx(expected, abs=2e-3)
    assert v[1] < -0.01  # turning left, the vehicle slips outwards, to its right
    straight = model.step(np.array([0.3, 0.0, 0.0]), [0.0, 0.0, 0.0], np.array([0.0, 0.0, 1.0]), 0.01)
    assert straight[1] == 0.0  # no turn, no sideways force


class _WithoutCoriolis(MotionModel):
    """The same model, deaf to the gyro (what the estimator had before session 17)."""

    def step(self, velocity_body, force_body, up_body, dt, angular_velocity_body=None):
        return super().step(velocity_body, force_body, up_body, dt)


def test_turning_at_speed_the_coriolis_terms_keep_the_dead_reckoning_closer_to_the_truth():
    vehicle = load_vehicle("heavy")
    robot = RobotSpec("rov", vehicle, (-15.0, 0.0, 15.0), sensors=("imu", "depth", "compass"))
    sim = Simulation(Scenario("open", TankModel(open_water_config(30.0)), (robot,)), flight_mode="stabilize")
    sim.reset(seed=0)
    truth0 = sim.ground_truth("rov")
    params = sim._estimators["rov"].params
    model = params.motion_model
    deaf = _WithoutCoriolis(
        model.inertia, model.linear_damping, model.quadratic_damping, model.net_buoyancy_n
    )
    replay = {
        name: DeadReckoning(dataclasses.replace(params, motion_model=m), truth0["position"], truth0["rpy"][2])
        for name, m in (("with", model), ("without", deaf))
    }
    period = sim.scenario.control_period_s
    for k in range(round(30.0 / period)):
        # full surge with a steady turn (some 15 deg/s), as the robots fly between viewpoints
        sim.step({"rov": {"surge": 0.6, "yaw": 0.25} if k < 1250 else {}})
        for estimator in replay.values():
            estimator.update(sim.latest_readings("rov"), period)
    truth = np.asarray(sim.ground_truth("rov")["position"])
    turned = abs(truth0["rpy"][2] - sim.ground_truth("rov")["rpy"][2])
    error = {name: float(np.linalg.norm((e.state.position - truth)[:2])) for name, e in replay.items()}
    assert turned > 0.5 or np.linalg.norm(truth[:2] - truth0["position"][:2]) > 2.0
    assert error["with"] < 0.7 * error["without"], error
    # the simulator's own estimator is the one with the terms
    assert np.allclose(sim.estimate("rov").position, replay["with"].state.position, atol=1e-9)
