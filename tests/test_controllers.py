"""The action convention and ArduSub's mixer, against a literal transcription and physics."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from maptidal.controllers.convention import AXES, CommandError, parse_command, pilot_command
from maptidal.controllers.mixing import (
    VECTORED_6DOF_FACTORS,
    VECTORED_FACTORS,
    MixerParams,
    allocation_matrix,
    mix,
)
from maptidal.envs.vehicle import load_vehicle


def literal_ardusub(command, frame, coupling=1.0):
    """AP_Motors6DOF::output_armed_stabilizing, motor by motor, as ArduSub's C++ reads."""
    forward, lateral, throttle, roll, pitch, yaw = command
    factors = VECTORED_6DOF_FACTORS if frame == "vectored_6dof" else VECTORED_FACTORS
    out = []
    if frame == "vectored_6dof":
        rpt = [roll * f[0] + pitch * f[1] + throttle * f[3] for f in factors]
        yfl = [yaw * f[2] + forward * f[4] + lateral * f[5] for f in factors]
        rpt_max = max([1.0] + [abs(x) for x in rpt])
        yfl_max = max([1.0] + [abs(x) for x in yfl])
        return np.array(
            [max(-1.0, min(1.0, a / rpt_max + b / yfl_max)) for a, b in zip(rpt, yfl, strict=True)]
        )
    limit = max(0.0, 1 - coupling * abs(throttle))
    direction = [-1, -1, 1, 1, 0, 0]
    for i, f in enumerate(factors):
        fwd = forward
        if forward != 0 and (forward < 0) == (direction[i] < 0) and direction[i] != 0:
            fwd = max(-limit, min(limit, forward))
        value = roll * f[0] + pitch * f[1] + yaw * f[2] + throttle * f[3] + fwd * f[4] + lateral * f[5]
        out.append(max(-1.0, min(1.0, value)))
    return np.array(out)


unit = st.floats(-1.0, 1.0)


@settings(max_examples=300, deadline=None)
@given(st.lists(unit, min_size=6, max_size=6), st.sampled_from(["vectored", "vectored_6dof"]))
def test_mix_matches_the_literal_ardusub_code(command, frame):
    surge, sway, heave, roll, pitch, yaw = command
    expected = literal_ardusub((surge, sway, heave, roll, pitch, yaw), frame)
    np.testing.assert_allclose(mix(command, MixerParams(frame)), expected, atol=1e-12)


def test_6dof_saturation_scales_the_group_instead_of_clipping():
    # forward + yaw saturate the horizontal group: ArduSub divides by the largest value
    out = mix({"surge": 1.0, "yaw": 1.0}, MixerParams("vectored_6dof"))
    np.testing.assert_allclose(out[:4], [0.0, -1.0, 0.0, 1.0])
    out = mix({"surge": 0.5, "yaw": 0.25}, MixerParams("vectored_6dof"))
    np.testing.assert_allclose(out[:4], [-0.25, -0.75, 0.25, 0.75])


def test_vectored_forward_vertical_coupling_limits_the_rear_thrusters():
    out = mix({"surge": 1.0, "heave": 0.5}, MixerParams("vectored"))
    # forward > 0: motors with coupling direction +1 (M3, M4) are limited to 1 - 0.5
    np.testing.assert_allclose(out[:4], [-1.0, -1.0, 0.5, 0.5])


@pytest.mark.parametrize("frame", ["standard", "heavy"])
def test_physical_allocation_of_pure_commands(frame):
    """Pure sway gives no yaw torque; pure heave no roll or pitch; surge only surge force."""
    vehicle = load_vehicle(frame)
    B = allocation_matrix(vehicle.thruster_positions, vehicle.thruster_directions)
    params = MixerParams(vehicle.ardusub_frame)

    def wrench(**command):
        cmd = mix(command, params)
        force = np.where(cmd >= 0, cmd * 50.0, cmd * 40.0)
        return B @ force

    sway = wrench(sway=1.0)
    assert sway[1] < -10 and abs(sway[5]) < 1e-9 and abs(sway[0]) < 1e-9  # right = -y, no yaw
    heave = wrench(heave=1.0)
    assert heave[2] > 10 and np.allclose(heave[[3, 4]], 0, atol=1e-9)
    surge = wrench(surge=1.0)
    assert surge[0] > 10 and np.allclose(surge[1:], 0, atol=1e-9)
    yaw = wrench(yaw=1.0)
    assert yaw[5] < 0 and np.allclose(yaw[:5], 0, atol=1e-9)  # turn right: clockwise from above


def test_commands_are_validated_and_parsed():
    assert parse_command("surge=1.0, heave=-0.2").tolist() == [1.0, 0.0, -0.2, 0.0, 0.0, 0.0]
    assert pilot_command({"yaw": 3.0})[AXES.index("yaw")] == 1.0  # clipped
    for bad in ("surge=abc", "warp=1", "surge"):
        with pytest.raises(CommandError):
            parse_command(bad)
    with pytest.raises(CommandError):
        pilot_command([np.nan, 0, 0, 0, 0, 0])
    with pytest.raises(CommandError):
        pilot_command([1, 2, 3])
