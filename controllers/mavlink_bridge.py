"""A pymavlink bridge to an ArduSub vehicle, real or simulated: the same 6-DOF pilot command as the
simulator's, streamed as MANUAL_CONTROL and RC overrides, and the vehicle's telemetry as one state.

    with MavlinkBridge("udpin:0.0.0.0:14550") as bridge:   # waits for the vehicle's heartbeat
        bridge.set_mode("stabilize")
        bridge.arm()
        bridge.set_command({"surge": 0.3})                  # streamed at 20 Hz until changed
        estimate = bridge.telemetry.estimate()              # for maptidal.controllers.pose, unchanged
    # leaving the block sends neutral and disarms, also on an exception

**Connection.** Any pymavlink URL: ``udpin:HOST:PORT`` (listen), ``udpout:HOST:PORT``,
``tcp:HOST:PORT`` or a serial device (``/dev/ttyACM0,115200``). The bridge is a ground station: it
sends HEARTBEAT as system 255 (ArduSub's SYSID_MYGCS default, from which alone it takes RC overrides)
once a second.

**Streaming.** ArduSub's pilot failsafe (FS_PILOT_TIMEOUT, default 3 s) trips when pilot input stops,
so the latest command is re-sent every ``command_period_s`` (default 0.05 s, 20 Hz).

**Failsafes.** The thrusters are never left commanded:

- nothing heard from the vehicle for ``stall_timeout_s`` (0.3 s): neutral is streamed instead of the
  command (``link_stalled``) until it speaks again;
- the vehicle's heartbeat missing for ``link_timeout_s`` (3 s): the command is set to neutral,
  ``link_lost`` is set and ``on_link_lost`` is called;
- leaving the ``with`` block, :meth:`close`, or an exception in the caller's code: neutral, then disarm;
- Ctrl-C (KeyboardInterrupt) and SIGTERM (:func:`install_signal_handlers`) leave the ``with`` block
  the same way.

**Pilot gain.** ArduSub scales MANUAL_CONTROL's surge, sway, heave and yaw by its joystick gain
(``transform_manual_control_to_rc_override``), which it takes from JS_GAIN_DEFAULT (bounded by
JS_GAIN_MIN and JS_GAIN_MAX) at boot and changes only on joystick buttons; heave also by JS_THR_GAIN.
:meth:`MavlinkBridge.check_pilot_gain` reads those parameters and refuses a vehicle whose gain is not
what the controller or policy was made for, or writes them (which takes effect at the vehicle's next
boot). The bridge never presses a button, so the gain it checked is the gain it flies.

**Signing.** MAVLink 2 signing with a 32-byte key (:func:`load_signing_key`: from a file or the
environment variable ``MAPTIDAL_MAVLINK_KEY``, never from a command line). With a key, unsigned or
wrongly signed packets from the vehicle are dropped and counted.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .convention import PilotGain, boot_gain, pilot_command
from .estimation import StateEstimate, rotation_from_rpy
from .mavlink_wire import (
    ARDUSUB_MODES,
    BRIDGE_MODES,
    GCS_SYSTEM_ID,
    MODE_NAMES,
    encode_pilot,
    flu_from_frd,
    rpy_from_ned,
    world_from_ned,
    world_velocity_from_ned,
)

log = logging.getLogger(__name__)

SIGNING_KEY_ENV = "MAPTIDAL_MAVLINK_KEY"
MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_TYPE_GCS = 6
MAV_RESULT_ACCEPTED = 0
MAV_PARAM_TYPE_REAL32 = 9
# ArduSub's joystick-gain parameters (PilotGain), in the order boot_gain takes the first four
GAIN_PARAMETERS = ("JS_GAIN_DEFAULT", "JS_GAIN_MIN", "JS_GAIN_MAX", "JS_GAIN_STEPS", "JS_THR_GAIN")
GAIN_TOLERANCE = 0.005  # ArduSub stores the gains as floats; a GCS may round them to 2 decimals
WATER_DENSITY_KG_M3 = 997.0  # fresh water at 25 C; ArduSub's default specific gravity is 1.0
STANDARD_PRESSURE_HPA = 1013.25
GRAVITY = 9.80665
# depth telemetry, best first: the autopilot's fused estimate, its altitude, the raw pressure sensor
DEPTH_SOURCES = ("LOCAL_POSITION_NED", "VFR_HUD", "SCALED_PRESSURE2")
DEPTH_FRESH_S = 1.5  # ArduSub streams these at 2 to 10 Hz: older than this, a source is not current


class BridgeError(RuntimeError):
    """The vehicle did not answer as expected: no heartbeat, a refused or unanswered command."""


@dataclass(frozen=True)
class BridgeParams:
    """Rates and timeouts of the bridge (s), and the ground station's MAVLink ids."""

    heartbeat_period_s: float = 1.0
    command_period_s: float = 0.05
    link_timeout_s: float = 3.0
    # no message at all from the vehicle for this long (its telemetry comes at 4 to 10 Hz): stream
    # neutral until it speaks again, so a vehicle-side crash leaves no thruster commanded for long
    stall_timeout_s: float = 0.3
    connect_timeout_s: float = 10.0
    ack_timeout_s: float = 3.0
    source_system: int = GCS_SYSTEM_ID
    source_component: int = 190  # MAV_COMP_ID_MISSIONPLANNER, what ground stations use


@dataclass
class VehicleTelemetry:
    """What the vehicle last reported (MAVLink frames; :meth:`estimate` converts to ours).

    attitude_ned: ATTITUDE roll, pitch, yaw (rad, FRD); rates_frd: rollspeed, pitchspeed, yawspeed
    (rad/s); position_ned, velocity_ned: LOCAL_POSITION_NED (m, m/s; None until one arrives);
    depth_m: the best fresh depth (:data:`DEPTH_SOURCES`, best first): the autopilot's own estimate in
    LOCAL_POSITION_NED, then its altitude in VFR_HUD, then the raw pressure sensor in SCALED_PRESSURE2
    (in ArduSub SITL that is the second barometer, with about 0.12 m of noise); ``depth_source`` names
    it and ``depth_age_s()`` says how old it is. When none is fresh the last value stays, and the
    bridge warns once that it is stale; servo_pwm: SERVO_OUTPUT_RAW (us, servo 1 first)."""

    system_id: int | None = None
    armed: bool = False
    mode: str | None = None
    attitude_ned: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rates_frd: np.ndarray = field(default_factory=lambda: np.zeros(3))
    position_ned: np.ndarray | None = None
    velocity_ned: np.ndarray | None = None
    depth_m: float | None = None
    depth_source: str | None = None
    depths: dict[str, tuple[float, float]] = field(default_factory=dict)  # source: (depth m, monotonic s)
    heading_deg: float | None = None
    servo_pwm: tuple[int, ...] = ()
    ekf_flags: int | None = None  # EKF_STATUS_REPORT.flags (ArduPilot sends it; our simulator does not)
    last_heartbeat_s: float = 0.0
    last_message_s: float = 0.0
    messages: int = 0
    bad_packets: int = 0

    def update_depth(self, source: str, depth_m: float, now_s: float | None = None) -> None:
        """Record ``source``'s depth reading and choose the best fresh one as :attr:`depth_m`."""
        now = time.monotonic() if now_s is None else now_s
        if math.isfinite(depth_m):
            self.depths[source] = (float(depth_m), now)
        for name in DEPTH_SOURCES:
            reading = self.depths.get(name)
            if reading is not None and now - reading[1] <= DEPTH_FRESH_S:
                self.depth_m, self.depth_source = reading[0], name
                return

    def depth_age_s(self, now_s: float | None = None) -> float | None:
        """How old :attr:`depth_m` is (s), or None before any depth came."""
        if self.depth_source is None:
            return None
        now = time.monotonic() if now_s is None else now_s
        return now - self.depths[self.depth_source][1]

    def estimate(self, surface_z_m: float = 0.0) -> StateEstimate:
        """The telemetry as the :class:`maptidal.controllers.estimation.StateEstimate` the feedback
        controllers take: world x north, y west, z up with the surface at ``surface_z_m``; body velocity
        from LOCAL_POSITION_NED rotated into the body (zero until it arrives); depth from the pressure sensor
        while LOCAL_POSITION_NED has not come (a vehicle without a DVL)."""
        rpy = rpy_from_ned(*self.attitude_ned)
        position = np.zeros(3)
        velocity_body = np.zeros(3)
        if self.position_ned is not None:
            position = world_from_ned(*self.position_ned, surface_z_m=surface_z_m)
        elif self.depth_m is not None:  # the pressure sensor's depth, when no position estimate comes
            position[2] = surface_z_m - self.depth_m
        if self.velocity_ned is not None:
            velocity_body = rotation_from_rpy(*rpy).T @ world_velocity_from_ned(self.velocity_ned)
        return StateEstimate(
            position=position,
            rpy=rpy,
            velocity_body=velocity_body,
            angular_velocity_body=flu_from_frd(self.rates_frd),
            time_s=time.monotonic(),
        )


def load_signing_key(path: str | Path | None = None) -> bytes | None:
    """The 32-byte MAVLink 2 signing key: from ``path`` (32 raw bytes, or 64 hex digits), else from the
    environment variable ``MAPTIDAL_MAVLINK_KEY`` (64 hex digits), else None (no signing)."""
    if path is not None:
        raw = Path(path).read_bytes()
        text = raw.strip()
        if len(raw) == 32:
            return raw
        try:
            key = bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            raise ValueError(f"{path}: a signing key is 32 raw bytes or 64 hex digits") from None
    elif os.environ.get(SIGNING_KEY_ENV):
        try:
            key = bytes.fromhex(os.environ[SIGNING_KEY_ENV].strip())
        except ValueError:
            raise ValueError(f"${SIGNING_KEY_ENV}: a signing key is 64 hex digits") from None
    else:
        return None
    if len(key) != 32:
        raise ValueError(f"a MAVLink signing key has 32 bytes, got {len(key)}")
    return key


class MavlinkBridge:
    """One ground-station link to one ArduSub vehicle (module docstring)."""

    def __init__(
        self,
        url: str,
        params: BridgeParams | None = None,
        signing_key: bytes | None = None,
        on_link_lost: Callable[[], None] | None = None,
    ) -> None:
        self.url = url
        self.params = params or BridgeParams()
        self.signing_key = signing_key
        self.on_link_lost = on_link_lost
        self.telemetry = VehicleTelemetry()
        self.link_lost = False
        self.link_stalled = False
        self.depth_stale = False  # the depth telemetry has stopped (warned once until it returns)
        self._arm_requested = False
        self._command = np.zeros(6)
        self._lock = threading.RLock()
        self._send_lock = threading.RLock()
        self._stop = threading.Event()
        self._acks: dict[int, int] = {}
        self._param_values: dict[str, float] = {}  # PARAM_VALUE answers, by name
        self._threads: list[threading.Thread] = []
        self._connection = None
        self.sent_commands = 0

    # ----- connecting ---------------------------------------------------------------------------
    def connect(self) -> MavlinkBridge:
        """Open the link, wait for the vehicle's heartbeat (``connect_timeout_s``), start streaming."""
        from pymavlink import mavutil

        os.environ.setdefault("MAVLINK20", "1")  # signing and the extended messages need MAVLink 2
        p = self.params
        try:
            self._connection = mavutil.mavlink_connection(
                self.url,
                source_system=p.source_system,
                source_component=p.source_component,
                dialect="ardupilotmega",
            )
        except OSError as error:
            raise BridgeError(f"cannot open {self.url}: {error}") from None
        if self.signing_key is not None:
            self._connection.setup_signing(self.signing_key, sign_outgoing=True, allow_unsigned_callback=None)
            self._connection.mav.signing.allow_unsigned_callback = lambda _mav, _msg_id: False
        deadline = time.monotonic() + p.connect_timeout_s
        next_heartbeat = 0.0
        while self.telemetry.system_id is None:
            now = time.monotonic()
            if now > deadline:
                self._connection.close()
                raise BridgeError(f"no vehicle heartbeat on {self.url} within {p.connect_timeout_s:g} s")
            if now >= next_heartbeat:  # a udpout or tcp vehicle may wait to hear from us first
                self._send_heartbeat()
                next_heartbeat = now + p.heartbeat_period_s
            message = self._connection.recv_match(blocking=True, timeout=0.1)
            if message is not None:
                self._handle(message)
        for target in (self._receive_loop, self._send_loop):
            thread = threading.Thread(target=target, daemon=True, name=f"mavlink-{target.__name__}")
            thread.start()
            self._threads.append(thread)
        return self

    def __enter__(self) -> MavlinkBridge:
        return self if self._connection is not None else self.connect()

    def __exit__(self, *exc_info) -> None:
        self.close()

    def close(self, disarm: bool = True) -> None:
        """Send neutral, disarm (unless told not to), stop streaming and close the link."""
        if self._connection is None:
            return
        try:
            self.neutral()
            # also when an arm command went out but its heartbeat has not come back yet
            if disarm and (self.telemetry.armed or self._arm_requested) and not self.link_lost:
                try:
                    self.disarm(timeout_s=1.0)
                except BridgeError as error:
                    log.warning("disarm on close: %s", error)
        finally:
            self._stop.set()
            for thread in self._threads:
                thread.join(timeout=1.0)
            self._connection.close()
            self._connection = None

    # ----- commanding ---------------------------------------------------------------------------
    def set_command(self, command) -> None:
        """Stream this pilot command from now on (validated: NaN raises, values clip to [-1, 1])."""
        value = pilot_command(command)
        with self._lock:
            self._command = value
        self._send_pilot(np.zeros(6) if self.link_stalled else value)

    def neutral(self) -> None:
        """Stream neutral (all axes 0), at once."""
        with self._lock:
            self._command = np.zeros(6)
        self._send_pilot(np.zeros(6))

    @property
    def command(self) -> np.ndarray:
        """The pilot command being streamed."""
        with self._lock:
            return self._command.copy()

    def arm(self, timeout_s: float | None = None) -> None:
        """Arm with MAV_CMD_COMPONENT_ARM_DISARM and wait for the acknowledgement and the armed flag."""
        self._arm_requested = True
        self._command_long(MAV_CMD_COMPONENT_ARM_DISARM, [1.0], timeout_s)
        self.wait_for(lambda t: t.armed, timeout_s, "the vehicle to report armed")

    def disarm(self, timeout_s: float | None = None) -> None:
        """Disarm (neutral first) and wait for the acknowledgement and the disarmed flag."""
        self.neutral()
        self._command_long(MAV_CMD_COMPONENT_ARM_DISARM, [0.0], timeout_s)
        self._arm_requested = False
        self.wait_for(lambda t: not t.armed, timeout_s, "the vehicle to report disarmed")

    def set_mode(self, mode: str, timeout_s: float | None = None, retry_for_s: float = 0.0) -> None:
        """Switch to ``mode`` (one of :data:`maptidal.controllers.mavlink_wire.BRIDGE_MODES`) with
        MAV_CMD_DO_SET_MODE, and wait for the acknowledgement and the heartbeat to show it. A vehicle
        that refuses (ArduSub refuses ALT_HOLD until its depth estimate is ready) is asked again once a
        second for up to ``retry_for_s`` seconds; then the last refusal is raised."""
        name = mode.lower().replace("-", "_")
        name = {"depth_hold": "alt_hold", "position_hold": "poshold"}.get(name, name)
        if name not in BRIDGE_MODES:
            raise ValueError(f"unknown mode {mode!r}; choose one of {', '.join(BRIDGE_MODES)}")
        if not (math.isfinite(retry_for_s) and retry_for_s >= 0.0):
            raise ValueError(f"retry_for_s must be finite and >= 0, got {retry_for_s!r}")
        deadline = time.monotonic() + retry_for_s
        while True:
            try:
                self._command_long(
                    MAV_CMD_DO_SET_MODE, [MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDUSUB_MODES[name]], timeout_s
                )
                break
            except BridgeError as error:
                if "refused" not in str(error) or time.monotonic() + 1.0 > deadline:
                    raise
                log.info("%s; asking again for mode %s", error, name)
                time.sleep(1.0)
        self.wait_for(lambda t: t.mode == name, timeout_s, f"the vehicle to report mode {name}")

    def set_position_target(self, north_m: float, east_m: float, down_m: float, yaw_rad: float = 0.0) -> None:
        """In GUIDED: fly to a LOCAL_POSITION_NED position (m) and yaw (rad, clockwise from north), with
        SET_POSITION_TARGET_LOCAL_NED (position and yaw used, velocities and accelerations ignored)."""
        values = (north_m, east_m, down_m, yaw_rad)
        if not all(isinstance(v, int | float) and np.isfinite(v) for v in values):
            raise ValueError(f"a position target must be finite numbers, got {values}")
        mask = 8 | 16 | 32 | 64 | 128 | 256 | 2048  # ignore velocity, acceleration and yaw rate
        with self._send_lock:
            self._connection.mav.set_position_target_local_ned_send(
                0, *self._target(), 1, mask, north_m, east_m, down_m, 0, 0, 0, 0, 0, 0, yaw_rad, 0
            )

    def read_param(self, name: str, timeout_s: float | None = None) -> float:
        """The vehicle's parameter ``name`` (PARAM_REQUEST_READ, answered by PARAM_VALUE), asked again
        every half second until ``timeout_s`` (default ``ack_timeout_s``); BridgeError if none comes."""
        return self._param_exchange(name, None, timeout_s)

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float:
        """Set the vehicle's parameter ``name`` (PARAM_SET); returns the value its PARAM_VALUE echoes,
        or raises BridgeError when none comes or the echo differs."""
        echoed = self._param_exchange(name, float(value), timeout_s)
        if not math.isclose(echoed, float(value), rel_tol=1e-6, abs_tol=1e-6):
            raise BridgeError(f"the vehicle kept {name} = {echoed:g}, not the {float(value):g} sent")
        return echoed

    def _param_exchange(self, name: str, value: float | None, timeout_s: float | None) -> float:
        if self._connection is None:
            raise BridgeError("the bridge is not connected")
        wait_s = self.params.ack_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait_s
        with self._lock:
            self._param_values.pop(name, None)
        next_ask = 0.0
        while time.monotonic() < deadline:
            if time.monotonic() >= next_ask:  # a lossy link may drop the request or the answer
                with self._send_lock:
                    if value is None:
                        self._connection.mav.param_request_read_send(*self._target(), name.encode(), -1)
                    else:
                        self._connection.mav.param_set_send(
                            *self._target(), name.encode(), value, MAV_PARAM_TYPE_REAL32
                        )
                next_ask = time.monotonic() + 0.5
            with self._lock:
                answer = self._param_values.get(name)
            if answer is not None:
                return answer
            time.sleep(0.01)
        raise BridgeError(f"no answer for the vehicle's parameter {name} within {wait_s:g} s")

    def check_pilot_gain(self, expected: PilotGain, write: bool = False) -> float:
        """Make sure the vehicle scales the pilot command as ``expected`` (the gain and JS_THR_GAIN the
        controller or policy was made for; the simulator's default is 1, full authority): read
        JS_GAIN_DEFAULT, JS_GAIN_MIN, JS_GAIN_MAX, JS_GAIN_STEPS and JS_THR_GAIN, work out the gain
        ArduSub starts with (:func:`maptidal.controllers.convention.boot_gain`) and return it when it
        matches. Otherwise raise BridgeError saying what to set; with ``write``, set the parameters
        first (JS_GAIN_MIN and JS_GAIN_MAX widened to take the gain), and the error says to reboot the
        vehicle, since ArduSub reads them only at boot."""
        values = {name: self.read_param(name) for name in GAIN_PARAMETERS}
        gain = boot_gain(*(values[name] for name in GAIN_PARAMETERS[:3]), int(values["JS_GAIN_STEPS"]))
        throttle = values["JS_THR_GAIN"]
        if (
            abs(gain - expected.gain) <= GAIN_TOLERANCE
            and abs(throttle - expected.throttle_gain) <= GAIN_TOLERANCE
        ):
            return gain
        found = (
            f"the vehicle scales the pilot command by a gain of {gain:.2f} (JS_GAIN_DEFAULT "
            f"{values['JS_GAIN_DEFAULT']:g} within JS_GAIN_MIN {values['JS_GAIN_MIN']:g} and JS_GAIN_MAX "
            f"{values['JS_GAIN_MAX']:g}) and heave further by JS_THR_GAIN {throttle:g}; the controller "
            f"was made for {expected.gain:g} and {expected.throttle_gain:g}"
        )
        if not write:
            raise BridgeError(
                f"{found}. Set JS_GAIN_DEFAULT {expected.gain:g}, JS_GAIN_MAX at least that, JS_THR_GAIN "
                f"{expected.throttle_gain:g} and reboot the vehicle (or let the bridge write them), or fly "
                f"a controller made for a gain of {gain:.2f}"
            )
        self.set_param("JS_GAIN_MAX", max(values["JS_GAIN_MAX"], expected.gain))
        self.set_param("JS_GAIN_MIN", min(values["JS_GAIN_MIN"], expected.gain))
        self.set_param("JS_GAIN_DEFAULT", expected.gain)
        self.set_param("JS_THR_GAIN", expected.throttle_gain)
        raise BridgeError(
            f"{found}. JS_GAIN_DEFAULT is now {expected.gain:g} and JS_THR_GAIN {expected.throttle_gain:g}; "
            f"ArduSub takes them at boot: reboot the vehicle, then connect again"
        )

    def wait_for(
        self, condition: Callable[[VehicleTelemetry], bool], timeout_s: float | None, what: str
    ) -> None:
        """Wait until ``condition(telemetry)`` holds; :class:`BridgeError` after the timeout."""
        deadline = time.monotonic() + (self.params.ack_timeout_s if timeout_s is None else timeout_s)
        while not condition(self.telemetry):
            if time.monotonic() > deadline:
                raise BridgeError(f"timed out waiting for {what}")
            time.sleep(0.01)

    # ----- internals ----------------------------------------------------------------------------
    def _target(self) -> tuple[int, int]:
        return int(self.telemetry.system_id or 1), 1

    def _command_long(self, command: int, values: list[float], timeout_s: float | None) -> None:
        if self._connection is None:
            raise BridgeError("the bridge is not connected")
        params = (list(values) + [0.0] * 7)[:7]
        with self._lock:
            self._acks.pop(command, None)
        with self._send_lock:
            self._connection.mav.command_long_send(*self._target(), command, 0, *params)
        wait_s = self.params.ack_timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait_s
        while time.monotonic() < deadline:
            with self._lock:
                result = self._acks.get(command)
            if result is not None:
                if result != MAV_RESULT_ACCEPTED:
                    raise BridgeError(f"command {command} refused by the vehicle (MAV_RESULT {result})")
                return
            time.sleep(0.01)
        raise BridgeError(f"no acknowledgement of command {command} within {wait_s:g} s")

    def _send_heartbeat(self) -> None:
        from pymavlink import mavutil

        with self._send_lock:
            self._connection.mav.heartbeat_send(
                mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
            )

    def _send_pilot(self, command: np.ndarray) -> None:
        if self._connection is None or self.telemetry.system_id is None:
            return
        manual, channels = encode_pilot(command)
        target, _ = self._target()
        with self._send_lock:
            self._connection.mav.manual_control_send(
                target, manual["x"], manual["y"], manual["z"], manual["r"], 0
            )
            self._connection.mav.rc_channels_override_send(target, 1, *channels)
        self.sent_commands += 1

    def _handle(self, message) -> None:
        kind = message.get_type()
        t = self.telemetry
        if kind == "BAD_DATA":
            t.bad_packets += 1
            return
        if t.system_id is not None and message.get_srcSystem() == t.system_id:
            t.last_message_s = time.monotonic()
        t.messages += 1
        if kind == "HEARTBEAT":
            if message.type == MAV_TYPE_GCS:
                return
            if t.system_id is None:
                t.system_id = message.get_srcSystem()
                t.last_message_s = time.monotonic()
            if message.get_srcSystem() != t.system_id:
                return
            t.last_heartbeat_s = time.monotonic()
            t.armed = bool(message.base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
            t.mode = MODE_NAMES.get(message.custom_mode, str(message.custom_mode))
            if self.link_lost:
                log.warning("vehicle heartbeat back on %s", self.url)
                self.link_lost = False
        elif kind == "COMMAND_ACK":
            with self._lock:
                self._acks[message.command] = message.result
        elif kind == "PARAM_VALUE":
            with self._lock:
                self._param_values[str(message.param_id)] = float(message.param_value)
        elif kind == "ATTITUDE":
            t.attitude_ned = np.array([message.roll, message.pitch, message.yaw])
            t.rates_frd = np.array([message.rollspeed, message.pitchspeed, message.yawspeed])
        elif kind == "LOCAL_POSITION_NED":
            t.position_ned = np.array([message.x, message.y, message.z])
            t.velocity_ned = np.array([message.vx, message.vy, message.vz])
            t.update_depth("LOCAL_POSITION_NED", float(message.z))
        elif kind == "SCALED_PRESSURE2":
            depth = (message.press_abs - STANDARD_PRESSURE_HPA) * 100.0 / (WATER_DENSITY_KG_M3 * GRAVITY)
            t.update_depth("SCALED_PRESSURE2", depth)
        elif kind == "VFR_HUD":
            t.heading_deg = float(message.heading)
            t.update_depth("VFR_HUD", -float(message.alt))
        elif kind == "EKF_STATUS_REPORT":
            t.ekf_flags = int(message.flags)
        elif kind == "SERVO_OUTPUT_RAW":
            t.servo_pwm = tuple(int(getattr(message, f"servo{k}_raw", 0)) for k in range(1, 17))

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            try:
                message = self._connection.recv_match(blocking=True, timeout=0.05)
            except (OSError, ValueError) as error:  # a closed socket or a garbled stream
                log.warning("mavlink receive: %s", error)
                time.sleep(0.05)
                continue
            if message is not None:
                self._handle(message)

    def _send_loop(self) -> None:
        p = self.params
        next_heartbeat = next_command = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_heartbeat:
                self._send_heartbeat()
                next_heartbeat = now + p.heartbeat_period_s
            if not self.link_lost and now - self.telemetry.last_heartbeat_s > p.link_timeout_s:
                self.link_lost = True
                log.warning("no vehicle heartbeat for %.1f s on %s: neutral", p.link_timeout_s, self.url)
                with self._lock:
                    self._command = np.zeros(6)
                if self.on_link_lost is not None:
                    self.on_link_lost()
            self.link_stalled = now - self.telemetry.last_message_s > p.stall_timeout_s
            age = self.telemetry.depth_age_s(now)
            if age is not None and age > DEPTH_FRESH_S and not self.depth_stale:
                self.depth_stale = True
                log.warning("no depth telemetry for %.1f s on %s: the depth is stale", age, self.url)
            elif age is not None and age <= DEPTH_FRESH_S and self.depth_stale:
                self.depth_stale = False
                log.warning("depth telemetry back on %s (%s)", self.url, self.telemetry.depth_source)
            if now >= next_command:
                self._send_pilot(np.zeros(6) if self.link_stalled else self.command)
                next_command = now + p.command_period_s
            self._stop.wait(min(next_heartbeat, next_command) - time.monotonic())


def install_signal_handlers() -> None:
    """Make SIGTERM raise SystemExit(143) in the main thread, as Ctrl-C raises KeyboardInterrupt, so that
    the ``with`` block (or the caller's ``finally``) sends neutral, disarms and closes the bridge. The
    handler itself does no I/O: it may interrupt the main thread inside a send."""

    def handler(signum, _frame):
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, handler)
