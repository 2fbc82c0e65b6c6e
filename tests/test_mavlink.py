"""The MAVLink bridge and the simulator as a MAVLink vehicle, over real loopback UDP."""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from pymavlink import mavutil

from maptidal.cli import main
from maptidal.controllers.convention import CommandError, PilotGain, boot_gain
from maptidal.controllers.mavlink_bridge import BridgeError, BridgeParams, MavlinkBridge, load_signing_key
from maptidal.controllers.mavlink_wire import (
    ARDUSUB_MODES,
    decode_manual_control,
    decode_rc_channel,
    encode_pilot,
)
from maptidal.controllers.mixing import MixerParams, mix
from maptidal.controllers.thrusters import command_to_pwm
from maptidal.envs.ardupilot_json import JsonBackend
from maptidal.envs.mavlink_vehicle import SimVehicle, SimVehicleParams, VehicleEndpointError
from maptidal.envs.simulation import Simulation

os.environ.setdefault("MAVLINK20", "1")
KEY = bytes(range(32))


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class Served:
    """A SimVehicle of the default scenario running in a thread on udpin:127.0.0.1:PORT."""

    def __init__(self, speedup: float = 1.0, key: bytes | None = None, pilot_gain: float = 1.0) -> None:
        self.port = free_port()
        self.sim = Simulation()
        self.sim.reset(seed=0)
        self.vehicle = SimVehicle(
            self.sim,
            url=f"udpin:127.0.0.1:{self.port}",
            params=SimVehicleParams(speedup=speedup, pilot_gain=pilot_gain),
            signing_key=key,
        )
        self.vehicle.open()
        self.thread = threading.Thread(target=self.vehicle.run, daemon=True)

    def __enter__(self) -> Served:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.vehicle.stop()
        self.thread.join(timeout=5)
        self.vehicle.close()

    @property
    def url(self) -> str:
        return f"udpout:127.0.0.1:{self.port}"


def raw_gcs(port: int, key: bytes | None = None):
    """A bare pymavlink ground station (system 255), to send hand-made packets."""
    connection = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{port}", source_system=255, source_component=190
    )
    if key is not None:
        connection.setup_signing(key, sign_outgoing=True)
    return connection


def wait_until(condition, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return False


# ----- the pilot command on the wire ----------------------------------------------------------------
def test_wire_encoding_round_trips_within_its_resolution():
    rng = np.random.default_rng(3)
    for _ in range(200):
        command = rng.uniform(-1, 1, 6)
        manual, channels = encode_pilot(command)
        surge, sway, heave, yaw = decode_manual_control(manual["x"], manual["y"], manual["z"], manual["r"])
        pitch, roll = decode_rc_channel(channels[0]), decode_rc_channel(channels[1])
        decoded = np.array([surge, sway, heave, roll, pitch, yaw])
        np.testing.assert_allclose(decoded, command, atol=0.5 / 400 + 1e-12)  # 1 us of RC, 0.001 of manual
    assert encode_pilot({"heave": 1.0})[0]["z"] == 1000 and encode_pilot({"heave": -1.0})[0]["z"] == 0
    assert encode_pilot({})[1][2:] == [65535] * 6  # channels 3-8 left to MANUAL_CONTROL


def test_one_action_gives_the_same_thruster_outputs_through_the_mixer_and_over_mavlink():
    """MANUAL mode: the vehicle's thrusters equal the simulator's own mixer on the same command, and its
    SERVO_OUTPUT_RAW equals ArduSub's PWM of them."""
    commands = [
        {"surge": 0.6, "yaw": -0.3},
        {"sway": -0.5, "heave": 0.4, "roll": 0.2},
        {"pitch": 0.7, "surge": -0.2, "heave": -0.6},
    ]
    with Served(speedup=2.0) as served, MavlinkBridge(served.url) as bridge:
        bridge.set_mode("manual")
        bridge.arm()
        params = MixerParams(served.sim.scenario.robots[0].vehicle.ardusub_frame)
        for command in commands:
            bridge.set_command(command)
            expected = mix(command, params)
            pwm = command_to_pwm(expected)
            assert wait_until(
                lambda e=expected: np.allclose(served.sim.thruster_outputs("rov0"), e, atol=0.004)
            )
            assert wait_until(lambda p=pwm: np.allclose(bridge.telemetry.servo_pwm[: len(p)], p, atol=2.0))


@pytest.mark.parametrize("gain", [1.0, 0.5])
def test_one_action_sequence_gives_the_same_pwm_through_the_gym_env_and_the_sim_vehicle(gain):
    """The same pilot actions, flown in MANUAL at the same pilot gain, through the Gymnasium environment
    and through ``sim-vehicle`` over MAVLink: the env's thruster outputs, taken to PWM as ArduSub does,
    equal the vehicle's SERVO_OUTPUT_RAW. (tests/test_sitl.py checks ArduSub SITL's own PWM against the
    same mixer where ARDUSUB_SITL is set.)"""
    import gymnasium

    import maptidal.envs  # noqa: F401

    actions = [
        [0.6, 0.0, 0.0, 0.0, 0.0, -0.3],
        [0.0, -0.5, 0.4, 0.2, 0.0, 0.0],
        [-0.2, 0.0, -0.6, 0.0, 0.7, 0.0],
    ]
    env = gymnasium.make("MapTidal/GoToPose-v1", flight_mode="manual", pilot_gain=gain)
    env.reset(seed=0)
    through_env = []
    for action in actions:
        env.step(np.asarray(action, np.float32))
        through_env.append(command_to_pwm(env.unwrapped.sim.thruster_outputs("rov0")))
    env.close()
    assert not np.allclose(through_env[0], 1500.0)
    with Served(speedup=2.0, pilot_gain=gain) as served, MavlinkBridge(served.url) as bridge:
        bridge.set_mode("manual")
        bridge.arm()
        for action, pwm in zip(actions, through_env, strict=True):
            bridge.set_command(action)
            # MANUAL_CONTROL carries each axis in thousandths: within a microsecond or two of PWM
            assert wait_until(lambda p=pwm: np.allclose(bridge.telemetry.servo_pwm[: len(p)], p, atol=2.0))


# ----- end to end -------------------------------------------------------------------------------------
def test_end_to_end_depth_hold_and_a_waypoint_over_udp(tmp_path):
    """maptidal mavlink flies the simulated vehicle over loopback UDP: arm, hold 1.0 m, fly 1 m north at
    1.0 m depth, disarm; the result comes from the vehicle's telemetry."""
    waypoints = tmp_path / "square.json"
    waypoints.write_text(json.dumps([{"north_m": -0.5, "east_m": 0.0, "depth_m": 1.0, "heading_deg": 0.0}]))
    with Served() as served:
        out = tmp_path / "result.json"
        start = served.sim.ground_truth("rov0")["position"]
        code = _run_cli_to(
            out, ["mavlink", "--connect", served.url, "--waypoints", str(waypoints), "--dwell", "1", "--json"]
        )
        assert code == 0
        result = json.loads(out.read_text())
        assert [w["status"] for w in result["waypoints"]] == ["capture"]
        assert abs(result["final_depth_m"] - 1.0) < 0.15  # the pressure sensor, 0.1 m above the CG
        north, east, down = result["final_position_ned_m"]
        assert abs(north - (-0.5)) < 0.15 and abs(east) < 0.15 and abs(down - 1.0) < 0.1
        truth = served.sim.ground_truth("rov0")["position"]
        assert truth[0] - start[0] > 0.8  # it really moved 1 m north (from x = -1.5 to -0.5)
        assert not served.vehicle.armed  # disarmed at the end


def _run_cli_to(path, argv) -> int:
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        code = main(argv)
    path.write_text(buffer.getvalue())
    return code


# ----- the pilot gain -----------------------------------------------------------------------------------
def test_the_bridge_flies_only_a_vehicle_at_the_gain_its_controller_expects():
    with Served(speedup=2.0) as full, MavlinkBridge(full.url) as bridge:
        assert bridge.check_pilot_gain(PilotGain(1.0)) == 1.0
        assert bridge.read_param("JS_GAIN_STEPS") == 4.0
        with pytest.raises(BridgeError, match="JS_THR_GAIN 1;"):  # heave scaled otherwise than expected
            bridge.check_pilot_gain(PilotGain(1.0, throttle_gain=1.5))
    with Served(speedup=2.0, pilot_gain=0.5) as half, MavlinkBridge(half.url) as bridge:
        assert bridge.check_pilot_gain(PilotGain(0.5)) == 0.5  # a policy trained at ArduSub's default
        with pytest.raises(BridgeError, match=r"gain of 0\.50 \(JS_GAIN_DEFAULT 0\.5.*reboot"):
            bridge.check_pilot_gain(PilotGain(1.0))
        assert half.vehicle.parameters["JS_GAIN_DEFAULT"] == 0.5  # nothing written unless asked
        with pytest.raises(BridgeError, match="reboot the vehicle, then connect again"):
            bridge.check_pilot_gain(PilotGain(1.0, throttle_gain=1.5), write=True)
        written = half.vehicle.parameters
        assert (written["JS_GAIN_DEFAULT"], written["JS_THR_GAIN"]) == (1.0, 1.5)
        assert written["JS_GAIN_MAX"] >= 1.0 and written["JS_GAIN_MIN"] <= 1.0
        assert half.vehicle.pilot_gain.gain == 0.5  # ArduSub takes the gain at boot, as the simulator
    # a vehicle booted with what was written flies at the new gain
    booted = boot_gain(written["JS_GAIN_DEFAULT"], written["JS_GAIN_MIN"], written["JS_GAIN_MAX"], 4)
    assert booted == 1.0


def test_an_unanswered_parameter_is_a_clear_error():
    with (
        Served(speedup=2.0) as served,
        MavlinkBridge(served.url) as bridge,
        pytest.raises(BridgeError, match="NO_SUCH_PARAM"),
    ):
        bridge.read_param("NO_SUCH_PARAM", timeout_s=0.6)


def test_maptidal_mavlink_refuses_a_vehicle_at_half_gain_without_arming(tmp_path, capsys):
    with Served(pilot_gain=0.5) as served:
        code = main(["mavlink", "--connect", served.url, "--mode", "depth-hold", "--depth", "1.0"])
        assert code == 2 and not served.vehicle.armed
    message = capsys.readouterr().err
    assert "JS_GAIN_DEFAULT" in message and "0.50" in message and len(message.strip().splitlines()) == 1


# ----- failsafes ----------------------------------------------------------------------------------------
def test_bridge_streams_neutral_within_half_a_second_when_the_vehicle_goes_silent():
    port = free_port()
    vehicle = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1, source_component=1)
    alive = threading.Event()
    alive.set()
    received: list[tuple[float, int]] = []

    def fake_vehicle():
        next_beat = 0.0
        while alive.is_set() or time.monotonic() < stop_at[0] + 1.5:
            now = time.monotonic()
            if alive.is_set() and now >= next_beat:
                vehicle.mav.heartbeat_send(12, 3, 1, 19, 3)
                vehicle.mav.attitude_send(0, 0, 0, 0, 0, 0, 0)
                next_beat = now + 0.1
            message = vehicle.recv_match(type="MANUAL_CONTROL", blocking=True, timeout=0.02)
            if message is not None:
                received.append((time.monotonic(), message.x))

    stop_at = [math.inf]
    thread = threading.Thread(target=fake_vehicle, daemon=True)
    thread.start()
    lost = []
    params = BridgeParams(connect_timeout_s=5, link_timeout_s=1.0)  # 3 s by default; shorter here
    bridge = MavlinkBridge(f"udpout:127.0.0.1:{port}", params, on_link_lost=lambda: lost.append(1)).connect()
    try:
        bridge.set_command({"surge": 0.8})
        time.sleep(0.5)
        stop_at[0] = time.monotonic()
        alive.clear()  # the vehicle dies: nothing more comes from it
        thread.join(timeout=5)
        # past the heartbeat timeout the link is reported lost and the command itself is dropped
        assert bridge.link_lost and lost == [1] and np.all(bridge.command == 0)
    finally:
        bridge.close(disarm=False)
        vehicle.close()
    before = [x for t, x in received if t < stop_at[0]]
    late = [x for t, x in received if t > stop_at[0] + 0.5]
    assert before and before[-1] == 800
    assert late and all(x == 0 for x in late)


def test_sim_vehicle_goes_neutral_when_the_pilot_stream_stops():
    sim = Simulation()
    sim.reset(seed=0)
    port = free_port()
    vehicle = SimVehicle(sim, url=f"udpin:127.0.0.1:{port}").open()
    gcs = raw_gcs(port)
    try:
        gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        vehicle.step()
        gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        gcs.mav.manual_control_send(1, 700, 0, 500, 0, 0)
        time.sleep(0.05)
        vehicle.step()
        assert vehicle.armed and vehicle.pilot[0] == pytest.approx(0.7)
        for _ in range(round(2.9 / sim.scenario.control_period_s)):
            vehicle.step()
        assert vehicle.pilot[0] == pytest.approx(0.7) and not vehicle.pilot_failsafe  # 2.9 s: still flying
        for _ in range(round(0.2 / sim.scenario.control_period_s)):
            vehicle.step()
        assert vehicle.pilot_failsafe and vehicle.counters.pilot_failsafes == 1
        assert np.all(vehicle.pilot == 0) and np.allclose(sim.thruster_outputs("rov0"), 0)
    finally:
        vehicle.close()
        gcs.close()


# ----- signing ----------------------------------------------------------------------------------------
def test_signed_link_works_and_unsigned_or_replayed_packets_are_rejected():
    with Served(speedup=2.0, key=KEY) as served:
        with MavlinkBridge(served.url, signing_key=KEY) as bridge:
            bridge.set_mode("stabilize")
            bridge.arm()
            bridge.disarm()
        assert not served.vehicle.armed
        # an unsigned ground station is ignored
        intruder = raw_gcs(served.port)
        for _ in range(5):
            intruder.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            time.sleep(0.05)
        assert wait_until(lambda: served.vehicle.counters.rejected_signatures >= 5)
        assert not served.vehicle.armed
        intruder.close()
        # a signed arm command, captured and replayed after a signed disarm, is rejected
        signed = raw_gcs(served.port, key=KEY)
        arm = signed.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
        arm_bytes = arm.pack(signed.mav)
        signed.write(arm_bytes)
        assert wait_until(lambda: served.vehicle.armed)
        signed.mav.command_long_send(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0)
        assert wait_until(lambda: not served.vehicle.armed)
        rejected = served.vehicle.counters.rejected_signatures
        signed.write(arm_bytes)  # the replay: an old timestamp on this stream
        assert wait_until(lambda: served.vehicle.counters.rejected_signatures > rejected)
        time.sleep(0.2)
        assert not served.vehicle.armed
        signed.close()


def test_signing_keys_come_from_a_file_or_the_environment(tmp_path, monkeypatch):
    raw = tmp_path / "key.bin"
    raw.write_bytes(KEY)
    hexed = tmp_path / "key.hex"
    hexed.write_text(KEY.hex() + "\n")
    assert load_signing_key(raw) == KEY and load_signing_key(hexed) == KEY
    monkeypatch.setenv("MAPTIDAL_MAVLINK_KEY", KEY.hex())
    assert load_signing_key() == KEY
    monkeypatch.delenv("MAPTIDAL_MAVLINK_KEY")
    assert load_signing_key() is None
    short = tmp_path / "short"
    short.write_text("abcd")
    with pytest.raises(ValueError, match="32 bytes"):
        load_signing_key(short)


# ----- ground-station protocol --------------------------------------------------------------------
def test_parameters_version_and_acknowledgements_for_ground_stations():
    with Served(speedup=2.0) as served:
        gcs = raw_gcs(served.port)
        gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        gcs.wait_heartbeat(timeout=5)
        gcs.mav.param_request_list_send(1, 1)
        names = set()
        deadline = time.monotonic() + 5
        while time.monotonic() < deadline and len(names) < len(served.vehicle.parameters):
            message = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if message is not None:
                names.add(message.param_id)
        assert names == set(served.vehicle.parameters)
        gcs.mav.param_set_send(1, 1, b"FS_PILOT_TIMEOUT", 1.5, 9)
        echo = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        assert echo.param_id == "FS_PILOT_TIMEOUT" and echo.param_value == pytest.approx(1.5)
        assert served.vehicle.parameters["FS_PILOT_TIMEOUT"] == 1.5
        gcs.mav.command_long_send(1, 1, 520, 0, 1, 0, 0, 0, 0, 0, 0)
        version = gcs.recv_match(type="AUTOPILOT_VERSION", blocking=True, timeout=5)
        assert version is not None and version.capabilities & 8192  # MAVLink 2
        gcs.mav.command_long_send(1, 1, 183, 0, 0, 0, 0, 0, 0, 0, 0)  # DO_SET_SERVO: not ours
        ack = gcs.recv_match(
            type="COMMAND_ACK", condition="COMMAND_ACK.command==183", blocking=True, timeout=5
        )
        assert ack.result == 3  # MAV_RESULT_UNSUPPORTED
        gcs.mav.command_long_send(1, 1, 176, 0, 1, ARDUSUB_MODES["auto"], 0, 0, 0, 0, 0)
        ack = gcs.recv_match(
            type="COMMAND_ACK", condition="COMMAND_ACK.command==176", blocking=True, timeout=5
        )
        assert ack.result == 3 and served.vehicle.mode == "manual"
        gcs.close()


def test_malformed_packets_are_counted_and_dropped():
    with Served(speedup=2.0) as served:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for junk in (b"\xfd\x09garbage", os.urandom(64), b"\xfe" * 20):
            sock.sendto(junk, ("127.0.0.1", served.port))
        sock.close()
        gcs = raw_gcs(served.port)
        # junk can claim a long payload and swallow what follows while the parser resynchronises, as on
        # any noisy link: a few heartbeats first, then MANUAL_CONTROL with x out of range, which ArduSub
        # clamps to full forward (counted)
        for _ in range(30):
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
        for _ in range(3):
            gcs.mav.manual_control_send(1, 5000, 0, 500, 0, 0)
            time.sleep(0.05)
        assert wait_until(lambda: served.vehicle.counters.bad_packets >= 1)
        assert wait_until(lambda: served.vehicle.counters.clamped_pilot_messages >= 1)
        assert served.thread.is_alive() and served.vehicle.pilot[0] == 1.0
        gcs.close()


def test_bad_input_gets_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('[{"north_m": 1, "east_m": "x", "depth_m": 1}]')
    assert main(["mavlink", "--connect", "udpout:127.0.0.1:9", "--waypoints", str(bad)]) == 2
    assert "waypoint 0 has a value that is not a number" in capsys.readouterr().err
    assert main(["mavlink", "--connect", "udpout:127.0.0.1:9", "--mode", "warp"]) == 2
    assert main(["mavlink", "--connect", "garbage://x", "--depth", "1"]) == 2
    assert "is not a MAVLink address" in capsys.readouterr().err
    assert main(["mavlink", "--connect", "udpout:127.0.0.1:9"]) == 2  # depth-hold, but no depth given
    assert "needs --depth" in capsys.readouterr().err
    assert main(["mavlink", "--connect", "udpout:127.0.0.1:9", "--depth", "50", "--max-depth", "2"]) == 2
    assert "deeper than --max-depth 2 m" in capsys.readouterr().err
    deep = tmp_path / "deep.json"
    deep.write_text('[{"north_m": 1, "east_m": 0, "depth_m": 3}]')
    assert (
        main(["mavlink", "--connect", "udpout:127.0.0.1:9", "--waypoints", str(deep), "--max-depth", "2"])
        == 2
    )
    assert "a waypoint at 3 m is deeper" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown mode"):
        MavlinkBridge("udpout:127.0.0.1:9").set_mode("acro")
    with pytest.raises(CommandError):
        MavlinkBridge("udpout:127.0.0.1:9").set_command([math.nan, 0, 0, 0, 0, 0])
    with pytest.raises(BridgeError, match="no vehicle heartbeat"):
        MavlinkBridge(f"udpout:127.0.0.1:{free_port()}", BridgeParams(connect_timeout_s=0.3)).connect()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", 0))
        port = taken.getsockname()[1]
        with pytest.raises(VehicleEndpointError, match="cannot open"):
            SimVehicle(Simulation(), url=f"udpin:127.0.0.1:{port}").open()
        assert main(["sim-vehicle", "--connect", f"udpin:127.0.0.1:{port}", "--duration", "0.1"]) == 2
    assert "cannot open" in capsys.readouterr().err


# ----- a ground station we did not write ------------------------------------------------------------
def test_mavproxy_connects_reads_parameters_arms_and_changes_mode(tmp_path):
    """MAVProxy (PyPI), as a subprocess, against the simulated vehicle over UDP."""
    mavproxy = shutil.which("mavproxy.py", path=os.path.dirname(sys.executable)) or shutil.which(
        "mavproxy.py"
    )
    if mavproxy is None:
        pytest.skip("MAVProxy is not installed (make setup installs it)")
    with Served() as served:
        process = subprocess.Popen(
            [sys.executable, mavproxy, f"--master={served.url}", "--source-system=255", "--nowait"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            cwd=tmp_path,  # its logs go here
            text=True,
        )
        try:
            assert wait_until(lambda: _params_sent(served), 20)
            for line, condition in (
                (
                    "param set FS_PILOT_TIMEOUT 2.5",
                    lambda: served.vehicle.parameters["FS_PILOT_TIMEOUT"] == 2.5,
                ),
                ("arm throttle", lambda: served.vehicle.armed),
                ("mode ALT_HOLD", lambda: served.vehicle.mode == "alt_hold"),
                ("disarm", lambda: not served.vehicle.armed),
            ):
                # each command is idempotent, and MAVProxy ignores a "param set" that comes before it
                # has loaded the parameters the vehicle finished sending: say it again until it lands
                for _ in range(5):
                    process.stdin.write(line + "\n")
                    process.stdin.flush()
                    if wait_until(condition, 2):
                        break
                assert condition(), line
        finally:
            process.terminate()
            output = process.communicate(timeout=10)[0]
    assert f"Received {len(served.vehicle.parameters)} parameters" in output, output[-2000:]
    assert "Got COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED" in output


def _params_sent(served) -> bool:
    return served.vehicle.counters.parameters_sent >= len(served.vehicle.parameters)


# ----- ArduPilot SITL's JSON backend ----------------------------------------------------------------
SERVO_LAYOUT = "<HHI16H"  # SIM_JSON.h: magic, frame_rate, frame_count, pwm[16]


def test_json_backend_answers_a_recorded_packet_field_by_field():
    sim = Simulation()
    sim.reset(seed=0)
    backend = JsonBackend(sim)
    truth = sim.ground_truth("rov0")
    packet = struct.pack(SERVO_LAYOUT, 18458, 1200, 1, *([1500] * 8 + [0] * 8))
    answer = backend.handle(packet).decode()
    assert answer.startswith("\n") and answer.endswith("\n") and ": " not in answer and ", " not in answer
    state = json.loads(answer)
    assert set(state) == {"timestamp", "imu", "position", "velocity", "quaternion"}
    assert state["timestamp"] == pytest.approx(1 / 1200, abs=sim.scenario.timestep_s)
    north, east, down = state["position"]
    x, y, z = truth["position"]
    assert (north, east) == pytest.approx((x, -y), abs=1e-4)
    assert down == pytest.approx(sim.scenario.tank.height - z, abs=1e-3)  # depth of the CG, > 0
    w = state["quaternion"][0]
    assert abs(w) == pytest.approx(1.0, abs=1e-3)  # level, facing north (the default start)
    ax, ay, az = state["imu"]["accel_body"]
    assert az == pytest.approx(-9.81, abs=0.1) and abs(ax) < 0.05 and abs(ay) < 0.05  # specific force, FRD
    assert np.allclose(state["imu"]["gyro"], 0, atol=1e-3)
    # the same frame again: the answer was lost, so the same answer again, without a second step
    time_before = sim.time
    assert backend.handle(packet).decode() == answer and backend.counters.repeated == 1
    assert sim.time == time_before
    # 32 channels are fine; junk is counted and dropped
    assert backend.handle(struct.pack("<HHI32H", 29569, 1200, 2, *([1500] * 32))) is not None
    for junk in (b"", b"\x00" * 40, struct.pack(SERVO_LAYOUT, 1234, 1200, 3, *([1500] * 16)), os.urandom(57)):
        assert backend.handle(junk) is None
    assert backend.counters.bad_packets == 4
    # frame_count going backwards: SITL restarted, so the world does too, and the backend says so
    backend.handle(struct.pack(SERVO_LAYOUT, 18458, 1200, 1, *([1500] * 16)))
    assert backend.counters.restarts == 1 and sim.time < 0.01
    assert any("SITL restarted" in line and "reset" in line for line in backend.events)


def test_a_backend_started_under_a_running_sitl_says_what_sitl_meets():
    sim = Simulation()
    sim.reset(seed=0)
    heard = []
    backend = JsonBackend(sim, on_event=heard.append)
    assert backend.handle(struct.pack(SERVO_LAYOUT, 18458, 1200, 1, *([1500] * 16))) is not None
    assert heard == []  # a fresh SITL's first frames: nothing to say
    fresh = JsonBackend(sim, on_event=heard.append)
    assert fresh.handle(struct.pack(SERVO_LAYOUT, 18458, 1200, 50000, *([1500] * 16))) is not None
    assert len(heard) == 1 and "already running" in heard[0] and "start pose" in heard[0]


@contextlib.contextmanager
def running_json_backend():
    """The default scenario's JSON backend answering on a loopback UDP port in a thread, and a client
    socket to play SITL with: ``(sim, backend, client)``; stopped and closed afterwards."""
    sim = Simulation()
    sim.reset(seed=0)
    backend = JsonBackend(sim, port=0, host="127.0.0.1").open()
    thread = threading.Thread(target=backend.run, daemon=True)
    thread.start()
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.settimeout(2.0)
    try:
        yield sim, backend, client
    finally:
        backend.stop()
        thread.join(timeout=5)
        backend.close()
        client.close()


def test_sitls_clock_keeps_moving_when_answers_are_lost():
    """A fake SITL in lockstep over UDP, as SIM_JSON.cpp is: it sends frame k until an answer comes,
    resending the same frame when none does. One answer in ten is dropped on the way back; the backend
    answers each resend with the answer it lost, so every frame is stepped once and the clock moves on."""
    rng = np.random.default_rng(0)
    frames, dropped, stamps = 600, 0, []
    with running_json_backend() as (sim, backend, client):
        for k in range(1, frames + 1):
            packet = struct.pack(SERVO_LAYOUT, 18458, 400, k, *([1500] * 16))
            while True:
                client.sendto(packet, ("127.0.0.1", backend.port))
                answer = json.loads(client.recv(4096))  # a lost answer would time out here
                if rng.random() < 0.1:
                    dropped += 1  # lost on the way back: SITL resends the same frame
                    continue
                stamps.append(answer["timestamp"])
                break
    assert dropped > 30 and backend.counters.repeated == dropped
    assert backend.counters.answered == frames
    assert np.all(np.diff(stamps) > 0)
    assert stamps[-1] == pytest.approx(frames / 400, abs=sim.scenario.timestep_s)


def test_the_json_backend_stops_when_no_sitl_ever_comes(capsys):
    port = free_port()
    args = ["sim-vehicle", "--ardupilot-json", "--port", str(port), "--duration", "2", "--idle-timeout", "1"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "no servo packet for 1 s: stopped" in err
    assert main(["sim-vehicle", "--ardupilot-json", "--idle-timeout", "-1"]) == 2


def test_a_fake_ardupilot_over_udp_hovers_level_and_yaws_the_right_way():
    with running_json_backend() as (_sim, backend, client):

        def fly(pwm, frames, first):
            state = None
            for k in range(first, first + frames):
                client.sendto(
                    struct.pack(SERVO_LAYOUT, 18458, 400, k, *(list(pwm) + [0] * 8)),
                    ("127.0.0.1", backend.port),
                )
                state = json.loads(client.recv(4096))
            return state

        level = fly([1500] * 8, 400, 1)  # 1 s of neutral servos
        roll, pitch, _ = _euler_from_quaternion(level["quaternion"])
        assert abs(roll) < math.radians(1) and abs(pitch) < math.radians(1)
        # yaw right: AP_Motors6DOF's yaw factors on M1..M4 are +1, -1, -1, +1
        yaw_pwm = [1500 + 120 * f for f in (1, -1, -1, 1)] + [1500] * 4
        turning = fly(yaw_pwm, 400, 401)
        assert turning["imu"]["gyro"][2] > 0.05  # FRD: positive z rate is clockwise from above, right
        _, _, yaw = _euler_from_quaternion(turning["quaternion"])
        assert yaw > math.radians(3)


def _euler_from_quaternion(q):
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


# ----- failsafes on the way out ---------------------------------------------------------------------
def test_an_exception_in_the_controller_sends_neutral_and_disarms():
    with Served(speedup=2.0) as served:
        with pytest.raises(RuntimeError, match="controller bug"), MavlinkBridge(served.url) as bridge:
            bridge.set_mode("manual")
            bridge.arm()
            bridge.set_command({"surge": 0.5})
            assert wait_until(lambda: served.vehicle.pilot[0] > 0.4)
            raise RuntimeError("controller bug")
        assert wait_until(lambda: not served.vehicle.armed)
        assert np.all(served.vehicle.pilot == 0)


def test_sigterm_makes_maptidal_mavlink_send_neutral_and_disarm():
    with Served(speedup=1.0) as served:
        command = [
            sys.executable,
            "-m",
            "maptidal.cli",
            "mavlink",
            "--connect",
            served.url,
            "--depth",
            "1.0",
            "--duration",
            "60",
        ]
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert wait_until(lambda: served.vehicle.armed, 30)
            process.send_signal(signal.SIGTERM)
            process.wait(timeout=15)
        finally:
            process.kill()
        assert process.returncode == 128 + signal.SIGTERM
        assert wait_until(lambda: not served.vehicle.armed, 5)


def test_sim_vehicle_exits_cleanly_on_sigterm():
    port = free_port()
    command = [sys.executable, "-m", "maptidal.cli", "sim-vehicle", "--connect", f"udpin:127.0.0.1:{port}"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    gcs = raw_gcs(port)
    try:
        deadline = time.monotonic() + 60
        heartbeat = None
        while heartbeat is None and time.monotonic() < deadline:
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)
            heartbeat = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert heartbeat is not None and heartbeat.type == 12  # a submarine
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=15)
    finally:
        process.kill()
        gcs.close()
    assert process.returncode == 0, err
    assert '"counters"' in err


def test_guided_flies_to_a_position_target():
    with Served(speedup=4.0) as served, MavlinkBridge(served.url) as bridge:
        bridge.set_mode("guided")
        bridge.arm()
        assert wait_until(lambda: bridge.telemetry.position_ned is not None)
        north, east, down = bridge.telemetry.position_ned
        bridge.set_position_target(north + 0.6, east, down)
        assert wait_until(lambda: abs(bridge.telemetry.position_ned[0] - (north + 0.6)) < 0.1, 15)
        truth = served.sim.ground_truth("rov0")["position"]
        assert abs(truth[0] - (north + 0.6)) < 0.15  # our x is north
        with pytest.raises(ValueError, match="finite"):
            bridge.set_position_target(math.nan, 0, 0)


def test_the_bridge_connects_over_tcp_too():
    sim = Simulation()
    sim.reset(seed=0)
    port = free_port()
    vehicle = SimVehicle(sim, url=f"tcpin:127.0.0.1:{port}", params=SimVehicleParams(speedup=4.0)).open()
    thread = threading.Thread(target=vehicle.run, daemon=True)
    thread.start()
    try:
        with MavlinkBridge(f"tcp:127.0.0.1:{port}") as bridge:
            bridge.set_mode("stabilize")
            bridge.arm()
            assert bridge.telemetry.mode == "stabilize" and vehicle.armed
    finally:
        vehicle.stop()
        thread.join(timeout=5)
        vehicle.close()


def test_the_bridge_takes_the_best_fresh_depth_and_never_freezes_on_one_source():
    """LOCAL_POSITION_NED (the autopilot's estimate) beats VFR_HUD beats SCALED_PRESSURE2 (the raw
    sensor); a source that stops is passed over for the next one that is still coming."""
    from maptidal.controllers.mavlink_bridge import DEPTH_FRESH_S, VehicleTelemetry

    t = VehicleTelemetry()
    assert t.depth_m is None and t.depth_age_s() is None
    t.update_depth("SCALED_PRESSURE2", 1.30, now_s=0.0)
    assert (t.depth_m, t.depth_source) == (1.30, "SCALED_PRESSURE2")
    t.update_depth("VFR_HUD", 1.10, now_s=0.1)
    assert (t.depth_m, t.depth_source) == (1.10, "VFR_HUD")
    t.update_depth("LOCAL_POSITION_NED", 1.00, now_s=0.2)
    t.update_depth("SCALED_PRESSURE2", 1.40, now_s=0.3)
    assert (t.depth_m, t.depth_source) == (1.00, "LOCAL_POSITION_NED")
    # the estimate stops; the pressure sensor goes on and its readings move: they are used, not frozen
    for k, depth in enumerate((1.5, 1.6, 1.7)):
        t.update_depth("SCALED_PRESSURE2", depth, now_s=0.3 + DEPTH_FRESH_S + 0.5 * (k + 1))
    assert (t.depth_m, t.depth_source) == (1.7, "SCALED_PRESSURE2")
    assert t.depth_age_s(now_s=0.3 + DEPTH_FRESH_S + 1.5 + 4.0) == pytest.approx(4.0)
    t.update_depth("VFR_HUD", math.nan, now_s=10.0)  # a bad reading is no reading
    assert t.depth_source == "SCALED_PRESSURE2"


def test_the_bridge_warns_once_when_the_depth_telemetry_stops(caplog):
    with Served(speedup=2.0) as served, MavlinkBridge(served.url) as bridge:
        assert wait_until(lambda: bridge.telemetry.depth_m is not None)
        assert bridge.telemetry.depth_source == "LOCAL_POSITION_NED"  # the vehicle's own estimate
        with caplog.at_level("WARNING", logger="maptidal.controllers.mavlink_bridge"):
            for name in ("LOCAL_POSITION_NED", "VFR_HUD", "SCALED_PRESSURE2"):  # the depth stops coming
                served.vehicle._rates[name] = 0.0
            assert wait_until(lambda: bridge.depth_stale, 10)
            time.sleep(1.0)
            assert not bridge.link_lost  # heartbeats and attitude go on: only the depth is stale
        assert sum("the depth is stale" in r.getMessage() for r in caplog.records) == 1


def test_set_mode_asks_again_while_the_vehicle_refuses_within_its_bound(monkeypatch):
    """ArduSub refuses ALT_HOLD ("need alt estimate") for its first seconds: the bridge asks again once a
    second within retry_for_s, and raises the refusal past it."""
    bridge = MavlinkBridge("udpout:127.0.0.1:9")
    monkeypatch.setattr("maptidal.controllers.mavlink_bridge.time.sleep", lambda _s: None)
    calls = []

    def refuse_twice(command, values, timeout_s):
        calls.append(command)
        if len(calls) <= 2:
            raise BridgeError(f"command {command} refused by the vehicle (MAV_RESULT 4)")
        bridge.telemetry.mode = "alt_hold"

    monkeypatch.setattr(bridge, "_command_long", refuse_twice)
    bridge.set_mode("alt_hold", timeout_s=1.0, retry_for_s=5.0)
    assert len(calls) == 3
    calls.clear()
    with pytest.raises(BridgeError, match="refused"):
        bridge.set_mode("alt_hold", timeout_s=1.0)  # no retry asked: the first refusal stands
    assert len(calls) == 1
    with pytest.raises(ValueError, match="retry_for_s"):
        bridge.set_mode("alt_hold", retry_for_s=-1.0)
