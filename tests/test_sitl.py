"""Real ArduSub firmware (SITL, ``--model JSON``) on our physics, where ``ARDUSUB_SITL`` names the
``ardusub`` binary (docs/mavlink.md, "ArduSub SITL on our physics"; ``make sitl-test``). Skipped elsewhere.

One SITL serves the module. It is started with FRAME_CONFIG 2 (the Heavy), no arming checks, and
JS_GAIN_DEFAULT = JS_GAIN_MAX = 1, so a stick of 1 is ArduSub's full RC range. Every test judges on
two things at once: the true state, which this process has (the simulation the JSON backend steps), and
ArduSub's own estimate from its telemetry (never the second barometer, SCALED_PRESSURE2, which SITL
fills with about 0.12 m of noise). Telemetry that stops fails the test."""

from __future__ import annotations

import math
import os
import subprocess
import threading
import time

import numpy as np
import pytest
from test_mavlink import free_port, wait_until

from maptidal.controllers.convention import pilot_command
from maptidal.controllers.mavlink_bridge import BridgeParams, MavlinkBridge
from maptidal.controllers.mixing import MixerParams, mix
from maptidal.controllers.thrusters import command_to_pwm
from maptidal.envs.ardupilot_json import JsonBackend
from maptidal.envs.simulation import Simulation

SITL = os.environ.get("ARDUSUB_SITL")
pytestmark = [
    pytest.mark.sitl,
    pytest.mark.skipif(not SITL, reason="set ARDUSUB_SITL to an ardusub SITL binary"),
]
EKF_ATTITUDE, EKF_POS_VERT_ABS = 1, 32  # EKF_STATUS_REPORT flags (MAVLink's EKF_STATUS_FLAGS)
PARAMETERS = "FRAME_CONFIG 2\nARMING_CHECK 0\nJS_GAIN_DEFAULT 1.0\nJS_GAIN_MAX 1.0\n"


class Firmware:
    """SITL on our physics: the simulation, its JSON backend, the SITL process and a bridge to it."""

    def __init__(self, scratch) -> None:
        self.sim = Simulation()
        self.sim.reset(seed=0)
        self.robot = self.sim.robots[0]
        self.backend = JsonBackend(self.sim, port=free_port(), host="127.0.0.1").open()
        self.thread = threading.Thread(target=self.backend.run, daemon=True)
        self.thread.start()
        defaults = scratch / "sub.parm"
        defaults.write_text(PARAMETERS)
        command = [SITL, "--model", "JSON:127.0.0.1", "--home", "-35.0,149.0,0,0", "-I0"]
        command += ["--sim-port-out", str(self.backend.port), "--defaults", str(defaults)]
        self.process = subprocess.Popen(
            command, cwd=scratch, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        self.bridge = MavlinkBridge("tcp:127.0.0.1:5760", BridgeParams(connect_timeout_s=60)).connect()
        # ALT_HOLD needs the EKF's attitude and vertical position: wait for them, not for a guess of time
        ready = EKF_ATTITUDE | EKF_POS_VERT_ABS
        flags = lambda: self.bridge.telemetry.ekf_flags or 0  # noqa: E731
        assert wait_until(lambda: flags() & ready == ready, 90), f"EKF not ready: flags {flags()}"

    def close(self) -> None:
        """Disarm, then stop SITL for certain (a SITL stalled on physics ignores SIGTERM)."""
        try:
            self.bridge.close()
        finally:
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)
            self.backend.stop()
            self.thread.join(timeout=5)
            self.backend.close()

    def fly(self, mode: str, legs) -> np.ndarray:
        """Fly (pilot command, seconds) legs in ``mode``; rows of true (t, roll, pitch, yaw, x, y, z) and
        ArduSub's depth. Fails when its telemetry or the physics stops."""
        bridge = self.bridge
        bridge.set_mode(mode, timeout_s=5.0, retry_for_s=30.0)
        if not bridge.telemetry.armed:
            bridge.arm(timeout_s=30)
        rows = []
        for command, seconds in legs:
            bridge.set_command(command)
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                messages, sim_time = bridge.telemetry.messages, self.sim.time
                time.sleep(0.1)
                assert bridge.telemetry.messages > messages, "telemetry stopped"
                assert self.sim.time > sim_time, "the physics stopped (no servo packets)"
                assert not bridge.link_lost
                truth = self.sim.ground_truth(self.robot)
                depth = bridge.telemetry.depth_m
                assert bridge.telemetry.depth_source in ("LOCAL_POSITION_NED", "VFR_HUD")
                rows.append([truth["time_s"], *truth["rpy"], *truth["position"], depth])
        bridge.neutral()
        return np.array(rows)


@pytest.fixture(scope="module")
def firmware(tmp_path_factory):
    running = Firmware(tmp_path_factory.mktemp("sitl"))
    try:
        yield running
    finally:
        running.close()


def test_alt_hold_holds_the_true_depth_and_ardusubs_own(firmware):
    path = firmware.fly("alt_hold", [({}, 10.0)])
    true_depth = firmware.sim.scenario.tank.height - path[:, 6]
    assert np.ptp(true_depth) < 0.05
    assert np.ptp(path[:, 7]) < 0.10  # ArduSub's estimate, with its own noise
    assert np.ptp(path[:, 0]) > 9.0  # the physics went on: ten seconds of it


def test_a_heading_step_is_held_after_the_stick_is_centred(firmware):
    path = firmware.fly("stabilize", [({"yaw": 0.5}, 2.0), ({}, 8.0)])
    yaw = np.degrees(np.unwrap(path[:, 3]))
    assert abs(yaw[-1] - yaw[0]) > 20.0  # it turned
    assert np.ptp(yaw[-30:]) < 2.0  # and holds the new heading


def test_a_lean_while_turning_stays_level_in_pitch(firmware):
    path = firmware.fly("stabilize", [({"roll": 0.3, "yaw": 0.5}, 8.0), ({}, 4.0)])
    assert np.max(np.abs(path[:, 2])) < math.radians(5)  # pitch, while rolled and turning


def test_the_same_manual_command_gives_our_mixers_pwm(firmware):
    """One pilot command in MANUAL: ArduSub's SERVO_OUTPUT_RAW against our mixer and ArduSub's PWM map,
    with the pilot gain at 1."""
    command = {"surge": 0.4, "yaw": 0.2, "heave": 0.3}
    firmware.fly("manual", [(command, 2.0)])
    firmware.bridge.set_command(command)
    time.sleep(1.0)
    ours = command_to_pwm(mix(pilot_command(command), MixerParams(frame="vectored_6dof")))
    theirs = np.array(firmware.bridge.telemetry.servo_pwm[: len(ours)], float)
    firmware.bridge.neutral()
    np.testing.assert_allclose(theirs, ours, atol=10.0)
