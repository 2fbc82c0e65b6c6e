"""The compiled flight stack (``envs/_flight.c``, :mod:`maptidal.envs.native_flight`) against its
reference, the Python flight modes, mixer, thrust curve, sensors, estimator and odometry that
``Simulation(flight_backend="python")`` runs: the same scenario, seed and commands flown both ways must
give the same physics, estimates, readings, controller state and odometry.

The two agree to rounding, not bit for bit: numpy sums some small matrix products in another order (its
BLAS), so the last bits differ after a few periods and the difference grows slowly (about 1e-12 after 30
s). A wrong sign, a dropped term or noise drawn in another order shows at once, at the size of the term:
the tolerance here, 1e-8, is far below any of them (a sensor's noise is 1e-3 or more)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from maptidal.controllers.flight_modes import ModeParams
from maptidal.controllers.position_control import PosControlGains
from maptidal.envs import hydrodynamics, native_flight
from maptidal.envs.scenario import load_scenario, with_frame
from maptidal.envs.sensors import SensorNoise
from maptidal.envs.simulation import Simulation, SimulationError

pytestmark = pytest.mark.skipif(
    native_flight.library() is None, reason="no C compiler: no compiled flight stack"
)

TOLERANCE = 1e-8


def record(sim: Simulation, per_period: np.ndarray) -> np.ndarray:
    """Everything the flight stack writes, as one vector."""
    values = [sim.data.qpos, sim.data.qvel, sim.data.ctrl, sim.data.act, per_period.ravel()]
    for robot in sim.robots:
        estimator = sim._estimators[robot]
        e = estimator.state
        values += [estimator.quaternion, e.position, e.rpy, e.velocity_body, e.angular_velocity_body]
        values += [e.acceleration_world, [e.time_s], estimator._velocity_world]
        values += [estimator.thrust_lagged, [estimator.modelled_last]]
        readings = sim.latest_readings(robot)
        values += [readings["imu"]["accel"], readings["imu"]["gyro"], [readings["depth"]["depth_m"]]]
        values += [readings["imu"]["accel_mean"]]
        values += [
            [readings["compass"]["heading_deg"]],
            readings.get("thrust", {}).get("force_body", [0, 0, 0]),
        ]
        if "dvl" in readings:
            dvl = readings["dvl"]
            values += [dvl["velocity_body"] or [9, 9, 9], [float(dvl["valid"])]]
        sensors = sim._sensors[robot]
        values += [sensors.accel_bias, sensors.gyro_bias, sim.thruster_outputs(robot)]
        odometry = sim.odometry(robot)
        values += [[odometry.path_m, odometry.thruster_energy_j, odometry.contact_s]]
        autopilot = sim._autopilots.get(robot)
        if autopilot is not None:
            c = autopilot.controller
            values += [[c.time_s, c.heading or 0.0, *c._saturated]]
            values += [[p.integrator for p in c.rate], [p.error for p in c.rate]]
            d = c.depth_control
            values += [[d._integral, d.target_z or 0.0, d.target_climb_m_s, d.limit]]
            values += [c.position_control._integral, c._hold_xy if c._hold_xy is not None else [0, 0]]
    return np.concatenate([np.ravel(np.asarray(v, float)) for v in values])


def random_commands(rng: np.random.Generator, size: int, step: int) -> np.ndarray:
    """Every axis at once, within +-0.6."""
    return rng.uniform(-0.6, 0.6, size)


def fly(
    backend: str,
    scenario,
    mode: str = "stabilize",
    command_mode: str = "pilot",
    steps: int = 40,
    periods: int = 5,
    turbulent: bool = False,
    setup=None,
    commands=random_commands,
    **sim_options,
) -> np.ndarray:
    """``steps`` calls of ``periods`` control periods with ``commands(rng, size, step)`` for each robot
    (seeded); the records."""
    sim = Simulation(scenario, flight_mode=mode, flight_backend=backend, **sim_options)
    assert sim.flight_backend == backend
    if setup is not None:
        setup(sim)
    sim.reset(seed=7)
    for robot in sim.robots:
        sim.track_estimate(robot)
    rng = np.random.default_rng(11)
    rows = []
    for _ in range(steps):
        size = sim._specs[sim.robots[0]].vehicle.n_thrusters if command_mode == "thrusters" else 6
        given = {robot: commands(rng, size, len(rows)) for robot in sim.robots}
        currents = rng.uniform(-0.2, 0.2, (periods, 3)) if turbulent else None
        rows.append(record(sim, sim.step_periods(given, periods, command_mode, currents)))
    return np.array(rows)


def assert_same_flight(**case) -> None:
    native = fly("native", **case)
    python = fly("python", **case)
    difference = np.abs(native - python)
    worst = np.unravel_index(np.argmax(difference), difference.shape)
    assert difference.max() < TOLERANCE, (
        f"native and Python flights part at step, value {worst}: {difference.max()}"
    )
    assert np.ptp(native[:, 0]) > 0.0  # the robots moved


MISSION = load_scenario("mission")  # two Heavies, one without a DVL (its estimator dead-reckons on thrust)


@pytest.mark.parametrize("mode", ["manual", "stabilize", "alt_hold"])
def test_each_flight_mode_flies_as_the_python_does(mode):
    assert_same_flight(scenario=MISSION, mode=mode)


def hold_then_move(rng: np.random.Generator, size: int, step: int) -> np.ndarray:
    """Surge and sway centred for 15 steps in 20 (the position hold flies), the rest at random."""
    command = rng.uniform(-0.6, 0.6, size)
    if step % 20 < 15:
        command[:2] = 0.0
    return command


def test_poshold_flies_as_the_python_does():
    """The horizontal hold with ArduSub's gains, and with an integrator bound small enough to reach
    (PSC_VELXY_IMAX 5 cm/s^2 instead of 1000) and a derivative term (PSC_VELXY_D 0 by default), against
    a current."""
    scenario = load_scenario("default")  # POSHOLD needs a DVL on every robot
    assert_same_flight(scenario=scenario, mode="poshold", steps=60, commands=hold_then_move)
    bounded = ModeParams(position=PosControlGains(vel_xy_imax_cm_s2=5.0, vel_xy_d=0.2))
    assert_same_flight(
        scenario=scenario,
        mode="poshold",
        steps=60,
        commands=hold_then_move,
        turbulent=True,
        mode_params=bounded,
    )


def full_heave(rng: np.random.Generator, size: int, step: int) -> np.ndarray:
    """The heave stick at full up, then full down, for 2 s at a time: the depth hold's throttle saturates,
    its target stands still, and going up it stops at the surface's margin."""
    command = rng.uniform(-0.3, 0.3, size)
    command[2] = 1.0 if (step // 20) % 2 == 0 else -1.0
    return command


def test_a_saturated_depth_hold_flies_as_the_python_does():
    assert_same_flight(scenario=MISSION, mode="alt_hold", steps=60, commands=full_heave)


def test_the_standard_frame_mixes_as_the_python_does():
    """Six thrusters and ArduSub's vectored mixer, with its forward-vertical coupling."""
    assert_same_flight(scenario=with_frame(MISSION, "standard"), mode="stabilize")


def test_thruster_commands_in_manual_fly_as_the_python_does():
    assert_same_flight(scenario=MISSION, mode="manual", command_mode="thrusters")


def test_currents_set_each_period_fly_as_the_python_does():
    assert_same_flight(scenario=MISSION, mode="alt_hold", turbulent=True)


def test_unlinearised_thrust_flies_as_the_python_does():
    """ArduSub's literal path: the mixer's outputs straight to PWM."""
    assert_same_flight(scenario=MISSION, mode="stabilize", mode_params=ModeParams(linearise_thrust=False))


def test_a_randomised_plant_flies_as_the_python_does():
    """A plant that differs from what the robot believes: another thrust curve (12 V), heavier, thruster
    gains apart; the controllers linearise with the believed curve, the physics pushes with the plant's."""

    def setup(sim: Simulation) -> None:
        for k, robot in enumerate(sim.robots):
            believed = sim._specs[robot].vehicle
            plant = dataclasses.replace(
                believed,
                mass=believed.mass * 1.1,
                thruster=dataclasses.replace(believed.thruster, voltage_v=12.0, curve=None),
            )
            sim.set_plant(robot, plant, thruster_gains=np.linspace(0.8, 1.2, believed.n_thrusters) + 0.01 * k)

    assert_same_flight(scenario=MISSION, mode="stabilize", setup=setup)


def test_the_first_period_agrees_to_the_last_bit_of_noise():
    """The noise is drawn in the Python's order: after one period the readings agree to rounding (a draw
    out of order would be off by the noise itself)."""
    native = fly("native", scenario=MISSION, steps=1, periods=1)
    python = fly("python", scenario=MISSION, steps=1, periods=1)
    np.testing.assert_allclose(native, python, rtol=0, atol=1e-12)


def test_many_periods_in_one_call_are_periods_called_one_by_one():
    """step_periods(n) is n step() calls on the compiled path, bit for bit."""
    whole = Simulation(MISSION, flight_mode="stabilize")
    single = Simulation(MISSION, flight_mode="stabilize")
    for sim in (whole, single):
        sim.reset(seed=3)
    command = {"rov0": {"surge": 0.4, "yaw": 0.2}, "rov1": {"heave": -0.3}}
    whole.step_periods(command, 25)
    for _ in range(25):
        single.step(command)
    np.testing.assert_array_equal(record(whole, np.zeros(0)), record(single, np.zeros(0)))


def test_the_python_path_is_chosen_by_the_environment_and_by_a_numpy_callback(monkeypatch):
    monkeypatch.setenv("MAPTIDAL_FLIGHT", "python")
    assert Simulation(MISSION).flight_backend == "python"
    monkeypatch.delenv("MAPTIDAL_FLIGHT")
    sim = Simulation(MISSION)
    assert sim.flight_backend == "native"
    try:
        hydrodynamics.install_callback(prefer_native=False)  # a numpy callback cannot run inside C's loop
        assert sim.flight_backend == "python"
        sim.step({"rov0": {"surge": 0.5}})  # and the Python path flies
    finally:
        hydrodynamics.install_callback()
    assert sim.flight_backend == "native"


def test_bad_arguments_are_refused():
    sim = Simulation(MISSION)
    with pytest.raises(ValueError, match="flight_backend"):
        Simulation(MISSION, flight_backend="fortran")
    with pytest.raises(ValueError, match="n_periods"):
        sim.step_periods({}, 0)
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        sim.step_periods({}, 3, currents=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="finite"):
        sim.step_periods({}, 2, currents=[[0, 0, 0], [np.nan, 0, 0]])


def test_a_bad_state_in_the_middle_of_a_call_is_dated_and_raised():
    sim = Simulation(MISSION, flight_mode="stabilize")
    sim.reset(seed=0)
    sim.step_periods({}, 50)  # 1 s
    sim.data.qvel[0] = np.nan
    with pytest.raises(SimulationError, match=r"NaN or diverged .* after t = 1\.000 s"):
        sim.step_periods({}, 5)


@pytest.mark.parametrize("backend", ["native", "python"])
def test_the_estimates_position_and_attitude_move_in_place_on_both_paths(backend):
    """The Python estimator writes position and roll-pitch-yaw into their arrays; the compiled path does
    too, so a reference held across steps reads the same on both."""
    sim = Simulation(MISSION, flight_mode="stabilize", flight_backend=backend)
    sim.reset(seed=1)
    estimate = sim.estimate("rov0")
    position, rpy, bias = estimate.position, estimate.rpy, sim._sensors["rov0"].accel_bias
    before = position.copy()
    sim.step_periods({"rov0": {"surge": 0.8, "yaw": 0.5}}, 20)
    assert sim.estimate("rov0").position is position and sim.estimate("rov0").rpy is rpy
    assert sim._sensors["rov0"].accel_bias is bias
    assert not np.array_equal(position, before)


def test_changes_between_calls_reach_the_compiled_stack():
    """New noise levels and a new flight mode between calls are packed again (the parameter cache keys on
    the objects they come from), as the Python path reads them every period."""

    def flown(backend: str) -> np.ndarray:
        sim = Simulation(MISSION, flight_mode="stabilize", flight_backend=backend)
        sim.reset(seed=5)
        command = {"rov0": {"surge": 0.5, "heave": 0.4}, "rov1": {"yaw": 0.3}}
        sim.step_periods(command, 20)
        sim.set_sensor_noise("rov0", SensorNoise(accel_sigma=0.5, compass_sigma_deg=20.0))
        sim.step_periods(command, 20)
        sim.set_flight_mode("rov1", "alt_hold")
        per_period = sim.step_periods(command, 20)
        return record(sim, per_period)

    np.testing.assert_allclose(flown("native"), flown("python"), rtol=0, atol=TOLERANCE)


def drive_into_wall(sim: Simulation) -> None:
    """Full surge for 4 s, so that the later steps touch the wall (contacts, constraint forces)."""
    for _ in range(200):
        sim.step({robot: [1.0, 0.3, -0.2, 0.0, 0.0, 0.4] for robot in sim.robots})


@pytest.mark.parametrize("backend", ["native", "python"])
def test_a_period_is_plain_mj_steps_bit_for_bit(backend):
    """Both paths compute the sensors only in a period's last physics step (``step_physics``); the
    state and the sensor values a period ends with must be those of plain ``mj_step``, bit for bit, with
    the controls the period drove, and the model's disable flags must be left as they were."""
    import mujoco

    sim = Simulation(MISSION, flight_mode="stabilize", flight_backend=backend)
    sim.reset(seed=3)
    drive_into_wall(sim)
    flags = mujoco.mjtDisableBit.mjDSBL_WARMSTART  # a flag of the user's own, kept
    sim.model.opt.disableflags = flags
    twin = mujoco.MjData(sim.model)
    touched = 0
    for _ in range(40):
        mujoco.mj_copyData(twin, sim.model, sim.data)
        sim.step({robot: [1.0, 0.3, -0.2, 0.0, 0.0, 0.4] for robot in sim.robots})
        assert sim.model.opt.disableflags == flags
        twin.ctrl[:] = sim.data.ctrl  # what the period drove, held through it
        for _ in range(sim.scenario.substeps):
            mujoco.mj_step(sim.model, twin)
        for field in ("qpos", "qvel", "act", "sensordata", "qacc"):
            assert np.array_equal(getattr(twin, field), getattr(sim.data, field)), field
        touched += sim.data.ncon > 0
    assert touched > 0  # the wall was touched: constraint forces reached the accelerometer


def test_step_physics_is_mj_step_bit_for_bit():
    """The helper on its own, for any number of steps, against ``mj_step(nstep=...)``."""
    import mujoco

    from maptidal.envs.simulation import step_physics

    sim = Simulation(MISSION, flight_backend="python")
    sim.reset(seed=4)
    drive_into_wall(sim)
    reference = mujoco.MjData(sim.model)
    mujoco.mj_copyData(reference, sim.model, sim.data)
    for n in (1, 0, 7, 10, 2):
        step_physics(sim.model, sim.data, n)
        if n:
            mujoco.mj_step(sim.model, reference, nstep=n)
        for field in ("qpos", "qvel", "act", "sensordata"):
            assert np.array_equal(getattr(reference, field), getattr(sim.data, field)), (n, field)
        assert sim.model.opt.disableflags == 0
