"""ArduSub's loops as units (controllers/pid.py, flight_modes.py, position_control.py), each against
numbers worked by hand from ArduPilot's formulas and defaults; and our own PID's integrator."""

import math

import numpy as np
import pytest

from maptidal.controllers.estimation import StateEstimate
from maptidal.controllers.flight_modes import (
    ModeParams,
    dead_zone,
    pilot_climb_rate,
    pilot_lean_angles,
)
from maptidal.controllers.pid import (
    ACPID,
    PID,
    ACPIDGains,
    PIDGains,
    inverse_sqrt_controller,
    lowpass_alpha,
    sqrt_controller,
)
from maptidal.controllers.position_control import VerticalPositionControl
from maptidal.controllers.thrusters import T200_16V, linearise_thrusters


def test_our_pid_integrates_while_unsaturated_and_stops_when_saturated():
    pid = PID(PIDGains(kp=0.0, ki=1.0, output_limit=5.0))
    for _ in range(100):  # 1 s of error 2, far from the limit: the integral is ki e t
        pid.update(2.0, 0.0, 0.01)
    assert pid.integral == pytest.approx(2.0)
    for _ in range(1000):  # 10 s more: it stops at the output limit, not 22
        pid.update(2.0, 0.0, 0.01)
    assert pid.integral == pytest.approx(5.0, abs=0.03)
    # saturated by the P term alone from the start, the integral does not grow at all, so the output
    # leaves saturation as soon as the error allows (a free integrator would have wound up to 5)
    pid = PID(PIDGains(kp=10.0, ki=1.0, output_limit=5.0))
    for _ in range(1000):
        assert pid.update(1.0, 0.0, 0.01) == 5.0
    assert pid.integral == 0.0
    assert pid.update(0.4, 0.0, 0.01) == pytest.approx(4.0 + 0.004)


def test_sqrt_controller_is_linear_near_zero_and_a_braking_curve_beyond():
    p, a = 6.0, math.radians(1100.0)
    linear = a / p**2  # 0.533 rad
    assert sqrt_controller(0.3, p, a, 0.0) == pytest.approx(1.8)
    assert sqrt_controller(-0.3, p, a, 0.0) == pytest.approx(-1.8)
    assert sqrt_controller(1.0, p, a, 0.0) == pytest.approx(math.sqrt(2 * a * (1.0 - linear / 2)))
    # continuous at the switch
    assert sqrt_controller(linear * (1 + 1e-9), p, a, 0.0) == pytest.approx(p * linear, rel=1e-6)
    # never more than the whole error in one step
    assert sqrt_controller(0.01, 200.0, 0.0, 0.02) == pytest.approx(0.01 / 0.02)
    for output in (0.5, 3.0, 10.0, -4.0):
        assert sqrt_controller(inverse_sqrt_controller(output, p, a), p, a, 0.0) == pytest.approx(output)


def test_acpid_follows_ardupilots_update_all_step_by_step():
    """AC_PID with P 1, I 2, D 0.5, IMAX 0.3, FLTT 0, FLTE 0, FLTD 10 Hz at dt 0.01."""
    pid = ACPID(ACPIDGains(kp=1.0, ki=2.0, kd=0.5, imax=0.3, derivative_filter_hz=10.0))
    alpha = 0.01 / (0.01 + 1 / (2 * math.pi * 10.0))
    assert lowpass_alpha(0.01, 10.0) == pytest.approx(alpha) and lowpass_alpha(0.01, 0.0) == 1.0
    # first sample: the filters start at it, no derivative; integrator 2 x 0.1 x 0.01
    assert pid.update(0.1, 0.0, 0.01) == pytest.approx(0.1 + 0.002)
    # a target step to 0.5: the derivative is the error's, so it kicks (AC_PID differentiates the error)
    derivative = alpha * (0.5 - 0.1) / 0.01
    integrator = 0.002 + 2.0 * 0.5 * 0.01
    assert pid.update(0.5, 0.0, 0.01) == pytest.approx(0.5 + integrator + 0.5 * derivative)
    # the integrator stops at IMAX
    for _ in range(200):
        pid.update(0.5, 0.0, 0.01)
    assert pid.integrator == pytest.approx(0.3)


def test_acpid_integrator_only_shrinks_while_the_output_is_limited():
    pid = ACPID(ACPIDGains(kp=0.0, ki=1.0, imax=10.0))
    pid.update(1.0, 0.0, 0.1)
    held = pid.integrator
    pid.update(1.0, 0.0, 0.1, limit=True)  # saturated, error pushing further: frozen
    assert pid.integrator == held
    pid.update(-1.0, 0.0, 0.1, limit=True)  # saturated, error pulling back: it shrinks
    assert pid.integrator == pytest.approx(held - 0.1)
    assert pid.update(math.nan, 0.0, 0.1) == 0.0  # AC_PID returns 0 for a non-finite input


def test_acpid_target_filter_smooths_a_step():
    pid = ACPID(ACPIDGains(kp=1.0, target_filter_hz=5.0))
    pid.update(0.0, 0.0, 0.01)
    alpha = 0.01 / (0.01 + 1 / (2 * math.pi * 5.0))
    assert pid.update(1.0, 0.0, 0.01) == pytest.approx(alpha)


def test_stick_scaling_follows_ardusubs_defaults():
    params = ModeParams()
    assert dead_zone(0.05, 0.1) == 0.0 and dead_zone(-1.0, 0.1) == -1.0
    assert dead_zone(0.55, 0.1) == pytest.approx(0.5)
    # roll stick 0.5 alone: (0.5 - 0.075) / 0.925 of 45 deg
    roll, pitch = pilot_lean_angles(0.5, 0.0, params)
    assert roll == pytest.approx(math.radians(45) * 0.425 / 0.925) and pitch == 0.0
    # both full: the circular limit keeps the lean at 45 deg, then roll becomes an Euler roll
    roll, pitch = pilot_lean_angles(1.0, 1.0, params)
    leg = math.radians(45) / math.sqrt(2)
    assert pitch == pytest.approx(leg)
    assert roll == pytest.approx(math.atan(math.cos(leg) * math.tan(leg)))
    # the throttle: THR_DZ 100 of 1000 around 500 is +-0.2 of the stick, then 500 cm/s at full
    assert pilot_climb_rate(0.19, params) == 0.0 and pilot_climb_rate(-0.19, params) == 0.0
    assert pilot_climb_rate(0.6, params) == pytest.approx(5.0 * 0.4 / 0.8)
    assert pilot_climb_rate(-1.0, params) == pytest.approx(-5.0)


def test_the_depth_target_moves_with_the_climb_rate_and_stops_at_pilot_accel_z():
    control = VerticalPositionControl()
    at = StateEstimate(position=np.array([0.0, 0.0, -2.0]))
    for _ in range(50):  # 0.5 s at 1 m/s^2 towards a 2 m/s climb: 0.5 m/s, 0.125 m up
        control.update_from_climb_rate(2.0, at, 0.01)
    assert control.target_climb_m_s == pytest.approx(0.5)
    assert control.target_z == pytest.approx(-2.0 + 0.5 * 1.0 * 0.5**2, abs=0.01)
    for _ in range(200):  # centred: it brakes at 1 m/s^2 and stands
        control.update_from_climb_rate(0.0, at, 0.01)
    assert control.target_climb_m_s == 0.0
    assert control.target_z == pytest.approx(-2.0 + 0.125 + 0.5**2 / 2, abs=0.01)


def test_the_depth_target_never_rises_above_surface_depth():
    control = VerticalPositionControl(surface_z_m=0.0)
    near = StateEstimate(position=np.array([0.0, 0.0, -0.2]))
    for _ in range(300):
        control.update_from_climb_rate(5.0, near, 0.01)
    assert control.target_z == pytest.approx(-0.10)


def test_reverse_thrust_is_linearised_against_the_reverse_maximum():
    """Half reverse asks for half of the 39.9 N reverse thrust, not half of the 51.4 N forward."""
    for fraction in (-0.5, -0.2, 0.5):
        command = linearise_thrusters([fraction], T200_16V)
        peak = T200_16V.max_reverse_n if fraction < 0 else T200_16V.max_forward_n
        assert T200_16V.thrust_from_command(command)[0] == pytest.approx(fraction * peak, rel=1e-6)


def test_manual_control_out_of_range_is_clamped_as_ardusub_clamps_it():
    from maptidal.controllers.mavlink_wire import WireError, decode_manual_control, manual_control_in_range

    np.testing.assert_allclose(decode_manual_control(5000, -3000, 1200, 0), [1.0, -1.0, 1.0, 0.0])
    np.testing.assert_allclose(decode_manual_control(500, 0, -20, -1000), [0.5, 0.0, -1.0, -1.0])
    assert not manual_control_in_range(5000, 0, 500, 0) and manual_control_in_range(1000, -1000, 0, 0)
    with pytest.raises(WireError, match="finite"):
        decode_manual_control(math.nan, 0, 500, 0)


def test_the_sitl_comparison_reads_its_responses_as_a_pilot_would():
    """tests/bench/flight_steps.py's measures on hand-made traces, and our half of its heading step."""
    from flight_steps import STEPS, fly_ours, response

    depth, heading, lean = STEPS
    times = np.arange(1, 601) * 0.02  # 12 s
    z = np.where(times < 2.0, times * 0.5, 1.0 + 0.1 * np.exp(-(times - 2.0)))  # climbs, overshoots 0.1
    z[times >= 2.0] = np.maximum(z[times >= 2.0], 1.0)
    states = np.zeros((len(times), 6))
    states[:, 5] = z
    measured = response(depth, times, states)
    assert measured["change_m"] == pytest.approx(z[-1] - z[0])
    assert measured["return_m"] == pytest.approx(z[times >= 2.0].max() - z[-1])
    states = np.zeros((len(times), 6))
    states[:, 2] = np.radians(-20.0 * times)  # 20 deg/s clockwise
    states[:, 0] = np.radians(8.0)
    measured = response(lean, times, states)
    assert measured["yaw_rate_deg_s"] == pytest.approx(-20.0) and measured["roll_deg"] == pytest.approx(8.0)
    ours = fly_ours(heading)
    assert ours["change_deg"] < -90.0 and ours["bounce_back_deg"] < 3.0


def test_bad_loop_parameters_are_refused():
    with pytest.raises(ValueError, match="AC_PID kp"):
        ACPIDGains(kp=-0.1)
    with pytest.raises(ValueError, match="target_filter_hz"):
        ACPIDGains(kp=0.1, target_filter_hz=math.inf)
    with pytest.raises(ValueError, match="throttle_dead_zone"):
        ModeParams(throttle_dead_zone=1.0)
    with pytest.raises(ValueError, match="max_lean_deg"):
        ModeParams(max_lean_deg=90.0)
    with pytest.raises(ValueError, match="max_yaw_rate_deg_s"):
        ModeParams(max_yaw_rate_deg_s=math.nan)
