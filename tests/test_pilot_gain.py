"""ArduSub's pilot gain (issue [rl], part 2): ``PilotGain`` against a literal transcription of
``Sub::transform_manual_control_to_rc_override`` and ``Sub::init_joystick`` (ArduSub/joystick.cpp,
ArduPilot master), and the gain in the simulator's and the Gymnasium environments' pilot path."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import maptidal.envs  # noqa: F401  (registers the environments)
from maptidal.controllers.convention import PilotGain, boot_gain


def _constrain_int16(value: float, low: int, high: int) -> int:
    as_int16 = int(value)  # C++'s float -> int16_t argument conversion truncates towards zero
    return min(max(as_int16, low), high)


def _ardusub_channels(x: int, y: int, z: int, r: int, gain: float, throttle_gain: float) -> tuple[int, ...]:
    """The forward, lateral, throttle and yaw RC overrides (us) ArduSub makes of a MANUAL_CONTROL."""
    rpy_scale = 0.4 * gain
    throttle_scale = 0.8 * gain * throttle_gain
    rpy_center = 1500
    throttle_base = int(1500 - 500 * throttle_scale)  # int16_t throttleBase
    throttle = _constrain_int16(z * throttle_scale + throttle_base, 1100, 1900)
    yaw = _constrain_int16(r * rpy_scale + rpy_center, 1100, 1900)
    forward = _constrain_int16(x * rpy_scale + rpy_center, 1100, 1900)
    lateral = _constrain_int16(y * rpy_scale + rpy_center, 1100, 1900)
    return forward, lateral, throttle, yaw


@settings(max_examples=300, deadline=None)
@given(
    x=st.integers(-1000, 1000),
    y=st.integers(-1000, 1000),
    z=st.integers(0, 1000),
    r=st.integers(-1000, 1000),
    gain=st.floats(0.1, 1.0),
    throttle_gain=st.floats(0.5, 4.0),
)
def test_the_gain_scales_the_sticks_as_ardusub_makes_its_channels(x, y, z, r, gain, throttle_gain):
    command = np.array([x / 1000, y / 1000, (z - 500) / 500, 0.3, -0.2, r / 1000])
    scaled = PilotGain(gain, throttle_gain).apply(command)
    forward, lateral, throttle, yaw = _ardusub_channels(x, y, z, r, gain, throttle_gain)
    expected = np.array([forward, lateral, throttle, yaw]) - 1500
    # within the truncation to whole microseconds, of the 400 us half-range
    np.testing.assert_allclose(scaled[[0, 1, 2, 5]] * 400, expected, atol=2.0)
    assert scaled[3] == 0.3 and scaled[4] == -0.2  # roll and pitch do not come through MANUAL_CONTROL


def _ardusub_boot_gain(default: float, minimum: float, maximum: float, steps: int) -> float:
    """Sub::init_joystick, transcribed (steps already at least 1)."""
    if steps == 1 or (default < maximum + 0.01 and default > minimum - 0.01):
        gain = min(max(default, minimum), maximum)
    else:
        gain = minimum + (steps // 2 - 1) * (maximum - minimum) / (steps - 1)
    return min(max(gain, 0.1), 1.0)


@pytest.mark.parametrize(
    "parameters",
    [
        (0.5, 0.25, 1.0, 4),
        (2.0, 0.25, 1.0, 4),
        (2.0, 0.25, 1.0, 1),
        (0.05, 0.1, 0.8, 6),
        (0.3, 0.25, 1.0, 10),
    ],
)
def test_the_boot_gain_follows_init_joystick(parameters):
    assert boot_gain(*parameters) == pytest.approx(_ardusub_boot_gain(*parameters))
    assert boot_gain(0.5, 0.25, 1.0, 4) == 0.5  # ArduSub's defaults: half the stick


def test_an_environment_at_half_gain_flies_a_full_stick_as_half_a_stick_at_full_gain():
    action = np.array([1.0, -0.8, 0.6, 0.3, -0.2, 0.9], np.float32)
    halved = action.copy()
    halved[[0, 1, 2, 5]] *= 0.5
    outputs = []
    for gain, flown in ((0.5, action), (1.0, halved), (1.0, action)):
        env = gymnasium.make("MapTidal/GoToPose-v1", pilot_gain=gain)
        try:
            env.reset(seed=4)
            for _ in range(5):
                env.step(flown)
            outputs.append(env.unwrapped.sim.thruster_outputs(env.unwrapped.robot))
        finally:
            env.close()
    np.testing.assert_allclose(outputs[0], outputs[1], atol=1e-12)
    assert not np.allclose(outputs[0], outputs[2], atol=0.05)  # and the gain does change what flies


@pytest.mark.parametrize("bad", [0.0, 1.5, True, "half", float("nan")])
def test_a_pilot_gain_outside_ardusubs_bounds_is_refused(bad):
    with pytest.raises(ValueError, match="pilot_gain"):
        gymnasium.make("MapTidal/GoToPose-v1", pilot_gain=bad)
    with pytest.raises(ValueError, match=r"JS_GAIN|pilot gain"):
        PilotGain(bad if not isinstance(bad, str) else 2.0)


def test_the_simulated_vehicle_scales_manual_control_by_its_gain_and_serves_it():
    import types

    from maptidal.envs.mavlink_vehicle import SimVehicle, SimVehicleParams
    from maptidal.envs.simulation import Simulation

    sim = Simulation(None)
    try:
        for gain in (1.0, 0.5):
            vehicle = SimVehicle(sim, url="udpin:127.0.0.1:0", params=SimVehicleParams(pilot_gain=gain))
            assert vehicle.parameters["JS_GAIN_DEFAULT"] == gain  # what a ground station reads
            stick = types.SimpleNamespace(target=0, x=1000, y=-400, z=1000, r=-1000)
            vehicle._on_manual_control(stick)
            np.testing.assert_allclose(vehicle.pilot[[0, 1, 2, 5]], np.array([1.0, -0.4, 1.0, -1.0]) * gain)
        with pytest.raises(ValueError, match="JS_GAIN"):
            SimVehicleParams(pilot_gain=0.05)
    finally:
        sim.close()


def test_sim_vehicle_refuses_a_pilot_gain_outside_ardusubs_bounds():
    from cli_helpers import assert_one_line_error, run_maptidal

    result = run_maptidal("sim-vehicle", "--pilot-gain", "2", "--duration", "1")
    assert_one_line_error(result, "pilot gain")


def test_the_environment_flies_the_flight_mode_asked_for():
    """Centred sticks: STABILIZE lets the buoyant Heavy rise; ALT_HOLD holds its depth."""
    rise = {}
    for mode in ("stabilize", "alt_hold"):
        env = gymnasium.make(
            "MapTidal/StationKeeping-v1", flight_mode=mode, max_current_m_s=0.0, turbulence_m_s=0.0
        )
        try:
            env.reset(seed=2, options={"pose": (-2.0, 0.0, 1.0, 0.0)})
            for _ in range(50):
                env.step(np.zeros(6, np.float32))
            rise[mode] = env.unwrapped.sim.ground_truth(env.unwrapped.robot)["position"][2] - 1.0
        finally:
            env.close()
    assert rise["stabilize"] > 0.1 and abs(rise["alt_hold"]) < 0.05, rise


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"flight_mode": "sport"}, "flight_mode"),
        ({"action": "thrusters", "flight_mode": "manual"}, "thrusters"),
    ],
)
def test_a_flight_mode_that_cannot_be_flown_is_refused(options, message):
    with pytest.raises(ValueError, match=message):
        gymnasium.make("MapTidal/GoToPose-v1", **options)


def test_maptidal_sim_flies_the_mode_and_gain_asked_for():
    import json

    from cli_helpers import assert_one_line_error, maptidal_here, run_maptidal

    heights = {}
    for mode in ("stabilize", "alt_hold"):
        done = run_maptidal("sim", "--mode", mode, "--duration", "5", "--json")
        assert done.returncode == 0, done.stderr
        result = json.loads(done.stdout)
        assert result["flight_mode"] == mode and result["pilot_gain"] == 1.0
        heights[mode] = result["robots"]["rov0"]["position_m"][2]
    assert heights["stabilize"] > heights["alt_hold"] + 0.1  # STABILIZE floats up; ALT_HOLD holds
    assert_one_line_error(maptidal_here("sim", "--pilot-gain", "2"), "pilot gain")
