"""The simulator as a MAVLink vehicle: one MuJoCo BlueROV2 behind an endpoint that behaves like
ArduSub for the subset a ground station and :mod:`maptidal.controllers.mavlink_bridge` use.

It provides:

- HEARTBEAT once a second as a submarine (MAV_TYPE_SUBMARINE) with the ArduPilot autopilot, its
  armed flag and ArduSub's custom_mode numbers; SYS_STATUS and AUTOPILOT_VERSION;
- arming and disarming (MAV_CMD_COMPONENT_ARM_DISARM) and the modes MANUAL, STABILIZE, ALT_HOLD,
  POSHOLD (ArduSub's, from :mod:`maptidal.controllers.flight_modes`) and GUIDED
  (SET_POSITION_TARGET_LOCAL_NED, flown by :class:`maptidal.controllers.pose.PoseController`), by
  MAV_CMD_DO_SET_MODE or SET_MODE; a COMMAND_ACK
  for every command, MAV_RESULT_UNSUPPORTED for those it does not implement and DENIED for a mode
  the robot cannot fly (POSHOLD and GUIDED need a DVL);
- MANUAL_CONTROL and RC_CHANNELS_OVERRIDE (roll and pitch, channels 1 and 2), taken only from the
  ground station's system id (SYSID_MYGCS, 255), decoded by :mod:`maptidal.controllers.mavlink_wire`;
- ArduSub's pilot failsafe: with no MANUAL_CONTROL for FS_PILOT_TIMEOUT (3 s) of simulated time the
  pilot input goes neutral (a STATUSTEXT says so) until input returns;
- telemetry at ArduSub-like rates from the vehicle's own estimate (its sensors, dead reckoning), never
  ground truth: ATTITUDE and LOCAL_POSITION_NED (with a DVL) at 10 Hz, VFR_HUD and SCALED_PRESSURE2
  (the depth sensor) at 4 Hz, SERVO_OUTPUT_RAW (the thruster PWM, ArduSub's mapping) at 10 Hz;
  SET_MESSAGE_INTERVAL changes them;
- the parameter protocol (PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET) on a small table
  (:data:`PARAMETERS`), an empty mission list, and MAVLink FTP refused ("file not found"), so ground
  stations connect without complaint and fetch parameters the classic way.

With a signing key (MAVLink 2 signing), unsigned and wrongly signed packets are dropped and counted in
:attr:`SimVehicle.counters`, as are packets that do not parse. Nothing that arrives can crash the loop.
"""

from __future__ import annotations

import logging
import math
import os
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from maptidal.controllers.convention import PilotGain, boot_gain
from maptidal.controllers.estimation import DeadReckoning, EstimatorParams, rotation_from_rpy
from maptidal.controllers.mavlink_wire import (
    ARDUSUB_MODES,
    GCS_SYSTEM_ID,
    MODE_NAMES,
    WireError,
    decode_manual_control,
    decode_rc_channel,
    flu_from_frd,
    manual_control_in_range,
    ned_from_world,
    rpy_to_ned,
    world_from_ned,
)
from maptidal.controllers.pose import PoseController
from maptidal.controllers.thrusters import command_to_pwm
from maptidal.controllers.trajectory import PoseReference
from maptidal.envs.simulation import Simulation
from maptidal.envs.world import DEPTH_SENSOR_POSITION

log = logging.getLogger(__name__)

MAV_TYPE_SUBMARINE = 12
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_STATE_STANDBY, MAV_STATE_ACTIVE = 3, 4
MAV_RESULT_ACCEPTED, MAV_RESULT_DENIED, MAV_RESULT_UNSUPPORTED = 0, 2, 3
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES = 520
MAV_PARAM_TYPE_REAL32 = 9
AUTOPILOT_VERSION_ID = 148
# MAV_PROTOCOL_CAPABILITY: MISSION_FLOAT 1, PARAM_FLOAT 2, SET_POSITION_TARGET_LOCAL_NED 128,
# MAVLINK2 8192, MISSION_INT 4
CAPABILITIES = 1 | 2 | 4 | 128 | 8192
# SYS_STATUS sensor bits: 3D gyro 1, 3D accel 2, 3D mag 4, absolute pressure 8
SENSOR_BITS = 1 | 2 | 4 | 8
MODES_FLOWN = ("manual", "stabilize", "alt_hold", "poshold", "guided")
# MAVLink FTP (FILE_TRANSFER_PROTOCOL payload header: seq, session, opcode, size, req_opcode,
# burst_complete, padding, offset) and the few codes we answer with
FTP_HEADER = struct.Struct("<HBBBBBBI")
FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS = 1, 2
FTP_OPEN_OPCODES = (4, 6, 11, 15)  # OpenFileRO, CreateFile, OpenFileWO, CalcFileCRC32
FTP_ACK, FTP_NAK = 128, 129
FTP_ERR_UNKNOWN_COMMAND, FTP_ERR_FILE_NOT_FOUND = 7, 10

# The parameter table a ground station reads (ArduSub names and defaults; FRAME_CONFIG is set from the
# robot's frame). FS_PILOT_TIMEOUT and SYSID_MYGCS are live: setting them changes the vehicle.
PARAMETERS: dict[str, float] = {
    "SYSID_THISMAV": 1.0,
    "SYSID_MYGCS": float(GCS_SYSTEM_ID),
    "FRAME_CONFIG": 2.0,
    "FS_PILOT_INPUT": 1.0,
    "FS_PILOT_TIMEOUT": 3.0,
    "MOT_PWM_MIN": 1100.0,
    "MOT_PWM_MAX": 1900.0,
    "ATC_ANG_RLL_P": 6.0,
    "ATC_ANG_PIT_P": 6.0,
    "ATC_ANG_YAW_P": 6.0,
    "ATC_RAT_RLL_P": 0.135,
    "ATC_RAT_RLL_I": 0.09,
    "ATC_RAT_RLL_D": 0.0036,
    "ATC_RAT_PIT_P": 0.135,
    "ATC_RAT_PIT_I": 0.09,
    "ATC_RAT_PIT_D": 0.0036,
    "ATC_RAT_YAW_P": 0.18,
    "ATC_RAT_YAW_I": 0.018,
    "ATC_RAT_YAW_D": 0.0,
    # the joystick gain (ArduSub's JS_* parameters; maptidal.controllers.convention.PilotGain). ArduSub's
    # JS_GAIN_DEFAULT is 0.5; the simulated vehicle starts at 1 (SimVehicleParams.pilot_gain), so that a
    # full MANUAL_CONTROL stick is the simulator's full pilot command. As on ArduSub, the gain is taken
    # from these at start; setting them later changes the table, not the live gain
    "JS_GAIN_DEFAULT": 0.5,
    "JS_GAIN_MIN": 0.25,
    "JS_GAIN_MAX": 1.0,
    "JS_GAIN_STEPS": 4.0,
    "JS_THR_GAIN": 1.0,
}


class VehicleEndpointError(RuntimeError):
    """The endpoint cannot start: the address is malformed or the port is in use."""


@dataclass(frozen=True)
class SimVehicleParams:
    """The endpoint's MAVLink ids, pacing and message rates (Hz).

    speedup: simulated seconds per wall-clock second (1 = real time); the loop sleeps to keep it.
    pilot_gain: the JS_GAIN_DEFAULT the vehicle starts with (0.1 to 1.0).
    """

    system_id: int = 1
    component_id: int = 1
    speedup: float = 1.0
    # JS_GAIN_DEFAULT at start (ArduSub's default 0.5 gives half the thrust at full stick)
    pilot_gain: float = 1.0
    rates_hz: dict[str, float] = field(
        default_factory=lambda: {
            "HEARTBEAT": 1.0,
            "SYS_STATUS": 1.0,
            "ATTITUDE": 10.0,
            "LOCAL_POSITION_NED": 10.0,
            "VFR_HUD": 4.0,
            "SCALED_PRESSURE2": 4.0,
            "SERVO_OUTPUT_RAW": 10.0,
        }
    )

    def __post_init__(self) -> None:
        if not (self.speedup > 0 and math.isfinite(self.speedup)):
            raise ValueError(f"speedup must be a positive number, got {self.speedup!r}")
        PilotGain(self.pilot_gain)  # ArduSub's bounds, or a ValueError


@dataclass
class VehicleCounters:
    """What the endpoint dropped or refused, and why."""

    bad_packets: int = 0
    rejected_signatures: int = 0
    ignored_senders: int = 0
    bad_pilot_messages: int = 0
    clamped_pilot_messages: int = 0  # MANUAL_CONTROL out of range, clamped as ArduSub clamps it
    unsupported_commands: int = 0
    pilot_failsafes: int = 0
    parameters_sent: int = 0


class SimVehicle:
    """A :class:`maptidal.envs.simulation.Simulation` robot behind a MAVLink endpoint (module docstring)."""

    def __init__(
        self,
        sim: Simulation,
        robot: str | None = None,
        url: str = "udpin:127.0.0.1:14550",
        params: SimVehicleParams | None = None,
        signing_key: bytes | None = None,
    ) -> None:
        self.sim = sim
        self.robot = robot or sim.robots[0]
        if self.robot not in sim.robots:
            raise ValueError(f"unknown robot {self.robot!r}; robots: {', '.join(sim.robots)}")
        self.url = url
        self.params = params or SimVehicleParams()
        self.signing_key = signing_key
        self.counters = VehicleCounters()
        self.parameters = dict(PARAMETERS)
        spec = sim.scenario.robots[sim.robots.index(self.robot)]
        self.parameters["FRAME_CONFIG"] = 2.0 if spec.vehicle.ardusub_frame == "vectored_6dof" else 1.0
        self.parameters["JS_GAIN_DEFAULT"] = float(self.params.pilot_gain)
        js = self.parameters
        self.pilot_gain = PilotGain(
            boot_gain(js["JS_GAIN_DEFAULT"], js["JS_GAIN_MIN"], js["JS_GAIN_MAX"], int(js["JS_GAIN_STEPS"])),
            js["JS_THR_GAIN"],
        )
        self.has_dvl = "dvl" in spec.sensors
        self.armed = False
        self.mode = "manual"
        self.pilot = np.zeros(6)
        self.pilot_failsafe = False
        self._last_pilot_s = -math.inf
        self._guided_target: PoseReference | None = None
        self._guided = PoseController(spec.vehicle.controller_model())
        self._rates = dict(self.params.rates_hz)
        self._next_send = dict.fromkeys(self._rates, 0.0)
        surface = sim.scenario.tank.height
        truth = sim.ground_truth(self.robot)
        self.estimator = DeadReckoning(
            EstimatorParams(surface, DEPTH_SENSOR_POSITION, spec.vehicle.sensors.dvl_position),
            truth["position"],
            truth["rpy"][2],
        )
        self.estimate = self.estimator.state
        self._readings: dict = {}
        self.connection = None
        self._stop = threading.Event()

    # ----- lifecycle ----------------------------------------------------------------------------
    def open(self) -> SimVehicle:
        """Open the endpoint (binds a udpin or tcpin port at once)."""
        from pymavlink import mavutil

        os.environ.setdefault("MAVLINK20", "1")
        try:
            self.connection = mavutil.mavlink_connection(
                self.url,
                source_system=self.params.system_id,
                source_component=self.params.component_id,
                dialect="ardupilotmega",
            )
        except OSError as error:
            raise VehicleEndpointError(f"cannot open {self.url}: {error}") from None
        except (ValueError, IndexError) as error:
            raise VehicleEndpointError(f"malformed MAVLink address {self.url!r}: {error}") from None
        if self.signing_key is not None:
            self.connection.setup_signing(self.signing_key, sign_outgoing=True)
            self.connection.mav.signing.allow_unsigned_callback = lambda _mav, _msg_id: False
        return self

    def stop(self) -> None:
        """Ask :meth:`run` to return after the current step (thread-safe; also for SIGTERM)."""
        self._stop.set()

    def close(self) -> None:
        """Close the endpoint."""
        if self.connection is not None:
            self.connection.close()
            self.connection = None

    def run(self, duration_s: float | None = None) -> None:
        """Serve until :meth:`stop` (or for ``duration_s`` of simulated time), one control period per
        loop: read every pending packet, step the physics, send what telemetry is due, then sleep to
        keep ``speedup``."""
        if self.connection is None:
            self.open()
        start_sim, start_wall = self.sim.time, time.monotonic()
        while not self._stop.is_set():
            if duration_s is not None and self.sim.time - start_sim >= duration_s - 1e-9:
                break
            self.step()
            ahead = (self.sim.time - start_sim) / self.params.speedup - (time.monotonic() - start_wall)
            if ahead > 0:
                self._stop.wait(ahead)
            elif ahead < -1.0:  # fell behind (a slow machine): do not try to catch up in a burst
                start_wall = time.monotonic() - (self.sim.time - start_sim) / self.params.speedup

    def step(self) -> None:
        """One control period: messages in, physics, estimate, telemetry out."""
        self._receive_all()
        timeout = self.parameters["FS_PILOT_TIMEOUT"]
        if self.armed and self.sim.time - self._last_pilot_s > timeout:
            if not self.pilot_failsafe:
                self.pilot_failsafe = True
                self.counters.pilot_failsafes += 1
                self._status(4, "Lost manual control")  # MAV_SEVERITY_WARNING
            self.pilot = np.zeros(6)
        command = self.pilot if self.armed else np.zeros(6)
        if self.armed and self.mode == "guided":
            target = self._guided_target or _hold(self.estimate.position, self.estimate.yaw)
            self._guided_target = target
            command = self._guided.update(self.estimate, target, self.sim.scenario.control_period_s)
        self.sim.step({self.robot: command})
        self._readings = self.sim.sensors(self.robot)
        self.estimate = self.estimator.update(self._readings, self.sim.scenario.control_period_s)
        self._send_telemetry()

    # ----- receiving ----------------------------------------------------------------------------
    def _receive_all(self) -> None:
        signing = self.connection.mav.signing if self.signing_key is not None else None
        while True:
            try:
                message = self.connection.recv_match(blocking=False)
            except (OSError, ValueError, TypeError) as error:
                self.counters.bad_packets += 1
                log.debug("mavlink receive: %s", error)
                continue
            if message is None:
                break
            try:
                self._handle(message)
            except Exception as error:  # a packet must never take the vehicle down
                self.counters.bad_packets += 1
                log.warning("dropped %s: %s", message.get_type(), error)
        if signing is not None:
            self.counters.rejected_signatures = signing.reject_count

    def _handle(self, message) -> None:
        kind = message.get_type()
        if kind == "BAD_DATA":
            if self.signing_key is None or "signature" not in str(getattr(message, "reason", "")).lower():
                self.counters.bad_packets += 1
            return
        gcs = int(self.parameters["SYSID_MYGCS"])
        source = message.get_srcSystem()
        if kind in ("MANUAL_CONTROL", "RC_CHANNELS_OVERRIDE") and source != gcs:
            self.counters.ignored_senders += 1
            return
        handler = getattr(self, f"_on_{kind.lower()}", None)
        if handler is not None:
            handler(message)

    def _on_manual_control(self, m) -> None:
        if m.target not in (0, self.params.system_id):
            return
        try:
            surge, sway, heave, yaw = decode_manual_control(m.x, m.y, m.z, m.r)
        except WireError:
            self.counters.bad_pilot_messages += 1
            return
        if not manual_control_in_range(m.x, m.y, m.z, m.r):
            self.counters.clamped_pilot_messages += 1
        # ArduSub's joystick-to-RC step: the sticks times the pilot gain (PilotGain); the flight modes read
        # the channels, so the simulation itself runs at gain 1
        channels = self.pilot_gain.apply(np.array([surge, sway, heave, 0.0, 0.0, yaw]))
        self.pilot[[0, 1, 2, 5]] = channels[[0, 1, 2, 5]]
        self._last_pilot_s = self.sim.time
        if self.pilot_failsafe:
            self.pilot_failsafe = False
            self._status(6, "Manual control regained")

    def _on_rc_channels_override(self, m) -> None:
        if m.target_system not in (0, self.params.system_id):
            return
        try:
            pitch, roll = decode_rc_channel(m.chan1_raw), decode_rc_channel(m.chan2_raw)
        except WireError:
            self.counters.bad_pilot_messages += 1
            return
        if roll is not None:
            self.pilot[3] = roll
        if pitch is not None:
            self.pilot[4] = pitch

    def _on_command_long(self, m) -> None:
        if m.target_system not in (0, self.params.system_id):
            return
        command = int(m.command)
        if command == MAV_CMD_COMPONENT_ARM_DISARM:
            result = self._arm(m.param1 > 0.5)
        elif command == MAV_CMD_DO_SET_MODE:
            result = self._set_mode(int(m.param2))
        elif command == MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES or (
            command == MAV_CMD_REQUEST_MESSAGE and int(m.param1) == AUTOPILOT_VERSION_ID
        ):
            self._send_autopilot_version()
            result = MAV_RESULT_ACCEPTED
        elif command == MAV_CMD_SET_MESSAGE_INTERVAL:
            result = self._set_interval(int(m.param1), float(m.param2))
        else:
            self.counters.unsupported_commands += 1
            result = MAV_RESULT_UNSUPPORTED
        self.connection.mav.command_ack_send(command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())

    def _on_set_mode(self, m) -> None:
        if m.target_system not in (0, self.params.system_id):
            return
        result = self._set_mode(int(m.custom_mode))
        self.connection.mav.command_ack_send(11, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())

    def _on_set_position_target_local_ned(self, m) -> None:
        if m.target_system not in (0, self.params.system_id):
            return
        values = (m.x, m.y, m.z, m.yaw)
        if not all(math.isfinite(v) for v in values):
            self.counters.bad_pilot_messages += 1
            return
        position = world_from_ned(m.x, m.y, m.z, self.sim.scenario.tank.height)
        self._guided_target = _hold(position, -float(m.yaw))
        self._guided.reset()

    def _on_param_request_list(self, m) -> None:
        for index, name in enumerate(self.parameters):
            self._send_param(name, index)

    def _on_param_request_read(self, m) -> None:
        names = list(self.parameters)
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id
        if m.param_index >= 0 and m.param_index < len(names) and not name:
            name = names[m.param_index]
        if name in self.parameters:
            self._send_param(name, names.index(name))

    def _on_param_set(self, m) -> None:
        name = m.param_id.rstrip("\x00") if isinstance(m.param_id, str) else m.param_id
        if name not in self.parameters or not math.isfinite(m.param_value):
            return
        if name == "FS_PILOT_TIMEOUT" and not 0.1 <= m.param_value <= 3.0:
            self._send_param(name, list(self.parameters).index(name))  # ArduSub's range: unchanged
            return
        self.parameters[name] = float(m.param_value)
        self._send_param(name, list(self.parameters).index(name))

    def _on_file_transfer_protocol(self, m) -> None:
        # no file system: open requests answer "file not found" and others "unknown command", so a
        # ground station that tries MAVLink FTP first (MAVProxy's parameter download) falls back at once
        payload = bytes(m.payload)
        if len(payload) < FTP_HEADER.size:
            self.counters.bad_packets += 1
            return
        seq, session, opcode = FTP_HEADER.unpack(payload[: FTP_HEADER.size])[:3]
        if opcode in (FTP_TERMINATE_SESSION, FTP_RESET_SESSIONS):
            reply = FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FTP_ACK, 0, opcode, 0, 0, 0)
        else:
            error = FTP_ERR_FILE_NOT_FOUND if opcode in FTP_OPEN_OPCODES else FTP_ERR_UNKNOWN_COMMAND
            reply = FTP_HEADER.pack((seq + 1) & 0xFFFF, session, FTP_NAK, 1, opcode, 0, 0, 0) + bytes([error])
        data = list(reply) + [0] * (251 - len(reply))
        self.connection.mav.file_transfer_protocol_send(0, m.get_srcSystem(), m.get_srcComponent(), data)

    def _on_mission_request_list(self, m) -> None:
        self.connection.mav.mission_count_send(m.get_srcSystem(), m.get_srcComponent(), 0, m.mission_type)

    # ----- arming and modes ---------------------------------------------------------------------
    def _arm(self, arm: bool) -> int:
        if arm == self.armed:
            return MAV_RESULT_ACCEPTED
        self.armed = arm
        self.pilot = np.zeros(6)
        self._last_pilot_s = self.sim.time if arm else -math.inf
        self.pilot_failsafe = False
        self._apply_mode()
        self._status(6, "Arming motors" if arm else "Disarming motors")
        return MAV_RESULT_ACCEPTED

    def _set_mode(self, custom_mode: int) -> int:
        name = MODE_NAMES.get(custom_mode)
        if name not in MODES_FLOWN:
            self.counters.unsupported_commands += 1
            return MAV_RESULT_UNSUPPORTED
        if name in ("poshold", "guided") and not self.has_dvl:
            return MAV_RESULT_DENIED  # ArduSub refuses modes that need a position estimate
        self.mode = name
        self._guided_target = None
        self._apply_mode()
        return MAV_RESULT_ACCEPTED

    def _apply_mode(self) -> None:
        # disarmed, or GUIDED (flown by our pose controller through the mixer): the simulator's MANUAL
        flight_mode = self.mode if self.armed and self.mode != "guided" else "manual"
        if self.sim.flight_mode(self.robot) != flight_mode or self.armed:
            self.sim.set_flight_mode(self.robot, flight_mode)

    def _set_interval(self, message_id: int, interval_us: float) -> int:
        from pymavlink.dialects.v20 import ardupilotmega as dialect

        message = dialect.mavlink_map.get(message_id)
        if message is None:
            return MAV_RESULT_DENIED
        name = message.msgname
        if name not in self._rates:
            return MAV_RESULT_UNSUPPORTED
        if interval_us == -1:
            self._rates[name] = 0.0
        elif interval_us > 0:
            self._rates[name] = 1e6 / interval_us
        else:
            self._rates[name] = self.params.rates_hz.get(name, 0.0)
        return MAV_RESULT_ACCEPTED

    # ----- sending ------------------------------------------------------------------------------
    def _due(self, name: str) -> bool:
        rate = self._rates.get(name, 0.0)
        if rate <= 0 or self.sim.time + 1e-9 < self._next_send[name]:
            return False
        self._next_send[name] = self.sim.time + 1.0 / rate
        return True

    def _send_telemetry(self) -> None:
        mav = self.connection.mav
        t_ms = int(self.sim.time * 1000) & 0xFFFFFFFF
        e = self.estimate
        surface = self.sim.scenario.tank.height
        if self._due("HEARTBEAT"):
            base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
            state = MAV_STATE_ACTIVE if self.armed else MAV_STATE_STANDBY
            mav.heartbeat_send(
                MAV_TYPE_SUBMARINE, MAV_AUTOPILOT_ARDUPILOTMEGA, base, ARDUSUB_MODES[self.mode], state
            )
        if self._due("SYS_STATUS"):
            mav.sys_status_send(SENSOR_BITS, SENSOR_BITS, SENSOR_BITS, 0, 16000, -1, -1, 0, 0, 0, 0, 0, 0)
        if self._due("ATTITUDE"):
            roll, pitch, yaw = rpy_to_ned(e.rpy)
            p, q, r = flu_from_frd(e.angular_velocity_body)
            mav.attitude_send(t_ms, roll, pitch, yaw, p, q, r)
        velocity_world = _world_velocity(e)
        if self.has_dvl and self._due("LOCAL_POSITION_NED"):
            north, east, down = ned_from_world(e.position, surface)
            mav.local_position_ned_send(
                t_ms, north, east, down, velocity_world[0], -velocity_world[1], -velocity_world[2]
            )
        depth = self._readings.get("depth")
        if self._due("VFR_HUD"):
            heading = round((-math.degrees(e.yaw)) % 360.0) % 360
            throttle = round(50 + 50 * float(self.pilot[2])) if self.armed else 0
            mav.vfr_hud_send(
                0.0,
                float(np.hypot(*velocity_world[:2])),
                heading,
                throttle,
                float(e.position[2] - surface),
                float(velocity_world[2]),
            )
        if depth is not None and self._due("SCALED_PRESSURE2"):
            mav.scaled_pressure2_send(t_ms, float(depth["pressure_pa"]) / 100.0, 0.0, 2000)
        if self._due("SERVO_OUTPUT_RAW"):
            pwm = [round(float(v)) for v in command_to_pwm(self.sim.thruster_outputs(self.robot))]
            pwm = (pwm + [0] * 16)[:16]
            mav.servo_output_raw_send(int(self.sim.time * 1e6) & 0xFFFFFFFF, 0, *pwm)

    def _send_param(self, name: str, index: int) -> None:
        self.counters.parameters_sent += 1
        self.connection.mav.param_value_send(
            name.encode("ascii"),
            float(self.parameters[name]),
            MAV_PARAM_TYPE_REAL32,
            len(self.parameters),
            index,
        )

    def _send_autopilot_version(self) -> None:
        # flight_sw_version: major 4, minor 5, patch 0, FIRMWARE_VERSION_TYPE_OFFICIAL (255)
        version = (4 << 24) | (5 << 16) | (0 << 8) | 255
        self.connection.mav.autopilot_version_send(
            CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0
        )

    def _status(self, severity: int, text: str) -> None:
        if self.connection is not None:
            self.connection.mav.statustext_send(severity, text.encode("ascii")[:50])


def _world_velocity(estimate) -> np.ndarray:
    return rotation_from_rpy(*estimate.rpy) @ estimate.velocity_body


def _hold(position, yaw: float) -> PoseReference:
    """A reference that stands still at a pose."""
    return PoseReference(np.array(position, float), np.zeros(3), np.zeros(3), float(yaw))
