"""ArduPilot SITL's JSON physics interface on our MuJoCo physics, so real ArduSub firmware can fly a
simulated BlueROV2 (``sim_vehicle.py -v ArduSub -f vectored_6dof --model JSON``, or
``ardusub --model JSON``), as bluerov2_gz users do with Gazebo.

The protocol (ArduPilot ``libraries/SITL/SIM_JSON.cpp`` and ``SIM_JSON.h``, ``libraries/SITL/examples/
JSON/``):

- SITL sends each physics frame a little-endian UDP packet ``<HHI16H``: magic 18458, frame_rate (Hz),
  frame_count (uint32, restarts from 0 when SITL restarts) and 16 servo pulse widths (us); with
  SERVO_32_ENABLE it is ``<HHI32H`` with magic 29569. It comes from an ephemeral port: the answer goes
  back to that address.
- Lockstep: the physics steps 1 / frame_rate seconds and answers once. A repeated frame_count means our
  answer was lost and SITL resends (about once a second, its clock frozen until an answer comes): it
  gets the same answer again, without a second step. A lower frame_count means SITL restarted: the
  simulation is reset to the scenario's start, and the backend says so (``on_event``). A first
  frame_count past one second of frames means SITL was already running when this backend started (the
  backend restarted under it): the firmware, armed or not, meets a world at the start pose, and the
  backend says that too.
- The answer is one JSON object, with a newline before and after, and no space after a colon (ArduPilot's
  parser rejects it): ``timestamp`` (s of physics time), ``imu.gyro`` (rad/s, body FRD),
  ``imu.accel_body`` (m/s^2, body FRD, the specific force: about (0, 0, -9.81) at rest, level),
  ``position`` (m, NED), ``velocity`` (m/s, NED) and ``quaternion`` (w, x, y, z, FRD to NED).

Frames: NED has its origin at the water surface above our world origin, north along our +x (so east is
our -y and down our -z); ArduSub SITL's pressure sensor reads depth as minus the altitude, so start it
with a home altitude of 0 (``--home -35.0,149.0,0,0``). Servo k drives motor k (ArduSub's default
SERVOk_FUNCTION), through ArduSub's PWM range (MOT_PWM_MIN/MAX 1100 / 1900) back to the thruster command.
Malformed packets are counted and dropped; nothing that arrives can stop the loop.
"""

from __future__ import annotations

import json
import math
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from maptidal.controllers.mavlink_wire import flu_from_frd, ned_from_world
from maptidal.controllers.thrusters import pwm_to_command
from maptidal.envs.simulation import Simulation

SERVO_16 = struct.Struct("<HHI16H")
SERVO_32 = struct.Struct("<HHI32H")
MAGIC_16, MAGIC_32 = 18458, 29569
WORLD_TO_NED = np.diag([1.0, -1.0, -1.0])  # also FLU body to FRD body


class JsonBackendError(RuntimeError):
    """The backend cannot start (the UDP port is in use or cannot be bound)."""


@dataclass
class JsonCounters:
    """Packets seen, answered, repeated (answer lost: the last answer sent again, not stepped again) and
    dropped as malformed; SITL restarts."""

    packets: int = 0
    answered: int = 0
    repeated: int = 0
    bad_packets: int = 0
    restarts: int = 0


@dataclass(frozen=True)
class ServoPacket:
    """One decoded servo packet."""

    frame_rate: int
    frame_count: int
    pwm: tuple[int, ...]


def parse_servo_packet(data: bytes) -> ServoPacket:
    """Decode a 16- or 32-channel servo packet; ValueError for anything else."""
    for layout, magic in ((SERVO_16, MAGIC_16), (SERVO_32, MAGIC_32)):
        if len(data) == layout.size:
            fields = layout.unpack(data)
            if fields[0] != magic:
                raise ValueError(f"bad magic {fields[0]} for a {layout.size}-byte packet (want {magic})")
            if fields[1] == 0:
                raise ValueError("frame_rate 0")
            return ServoPacket(fields[1], fields[2], tuple(fields[3:]))
    raise ValueError(f"a servo packet has {SERVO_16.size} or {SERVO_32.size} bytes, got {len(data)}")


def servo_packet(frame_rate: int, frame_count: int, pwm, channels: int = 16) -> bytes:
    """Encode a servo packet as SITL sends it (for tests and fake autopilots)."""
    values = (list(pwm) + [0] * channels)[:channels]
    layout, magic = (SERVO_16, MAGIC_16) if channels == 16 else (SERVO_32, MAGIC_32)
    return layout.pack(magic, frame_rate, frame_count, *values)


class JsonBackend:
    """Our physics as ArduPilot SITL's JSON backend for one robot (module docstring)."""

    def __init__(
        self,
        sim: Simulation,
        robot: str | None = None,
        port: int = 9002,
        host: str = "0.0.0.0",
        on_event: Callable[[str], None] | None = None,
    ) -> None:
        """``on_event`` is called with one line for each thing a user should know: a SITL restart, a
        SITL that was already running, no packets yet (default: kept in :attr:`events` only)."""
        self.sim = sim
        self.events: list[str] = []
        self._on_event = on_event
        self._last_answer: bytes | None = None
        self.robot = robot or sim.robots[0]
        if self.robot not in sim.robots:
            raise ValueError(f"unknown robot {self.robot!r}; robots: {', '.join(sim.robots)}")
        self.port, self.host = port, host
        self.counters = JsonCounters()
        self.n_thrusters = sim.scenario.robots[sim.robots.index(self.robot)].vehicle.n_thrusters
        self.surface_z = sim.scenario.tank.height
        self._last_frame: int | None = None
        self._target_time = sim.time
        self._socket: socket.socket | None = None
        self._stop = threading.Event()

    def open(self) -> JsonBackend:
        """Bind the UDP port."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self.port))
        except OSError as error:
            sock.close()
            raise JsonBackendError(f"cannot bind UDP port {self.port}: {error.strerror or error}") from None
        sock.settimeout(0.1)
        self._socket = sock
        self.port = sock.getsockname()[1]
        return self

    def stop(self) -> None:
        """Ask :meth:`run` to return (thread-safe; also for SIGTERM)."""
        self._stop.set()

    def close(self) -> None:
        """Close the socket."""
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def _event(self, line: str) -> None:
        self.events.append(line)
        if self._on_event is not None:
            self._on_event(line)

    def run(
        self,
        duration_s: float | None = None,
        idle_timeout_s: float | None = None,
        notice_after_s: float = 5.0,
    ) -> bool:
        """Answer servo packets until :meth:`stop`, ``duration_s`` of simulated time, or
        ``idle_timeout_s`` of wall time without a packet (None: wait for ever). Says once when no packet
        has come after ``notice_after_s``. Returns False when it stopped for want of packets."""
        if self._socket is None:
            self.open()
        start = self.sim.time
        last_packet = time.monotonic()
        noticed = False
        while not self._stop.is_set():
            if duration_s is not None and self.sim.time - start >= duration_s:
                break
            try:
                data, address = self._socket.recvfrom(4096)
            except TimeoutError:
                idle = time.monotonic() - last_packet
                if not noticed and idle >= notice_after_s:
                    noticed = True
                    self._event(
                        f"no servo packets from ArduPilot SITL on UDP port {self.port} after "
                        f"{notice_after_s:g} s: start it with --model JSON (docs/mavlink.md, ArduSub SITL)"
                    )
                if idle_timeout_s is not None and idle >= idle_timeout_s:
                    self._event(f"no servo packet for {idle_timeout_s:g} s: stopped")
                    return False
                continue
            except OSError:
                if self._socket is None:
                    break
                continue
            last_packet = time.monotonic()
            answer = self.handle(data)
            if answer is not None:
                self._socket.sendto(answer, address)
        return True

    def handle(self, data: bytes) -> bytes | None:
        """One packet in, the answer out (None for a malformed packet; a repeat gets the last answer
        again, without a step)."""
        self.counters.packets += 1
        try:
            packet = parse_servo_packet(data)
        except ValueError:
            self.counters.bad_packets += 1
            return None
        if self._last_frame is None:
            if packet.frame_count > packet.frame_rate:
                self._event(
                    f"SITL was already running (its first frame here is {packet.frame_count}): it meets a "
                    f"world at the scenario's start pose and physics time {self.sim.time:.3f} s; if it "
                    "was armed, disarm it and let its EKF settle before flying"
                )
        elif packet.frame_count == self._last_frame:
            # SITL resends a frame whose answer it did not get: the answer was lost, so send it again
            self.counters.repeated += 1
            return self._last_answer
        elif packet.frame_count < self._last_frame:
            self.counters.restarts += 1
            self._event(
                f"SITL restarted (frame {packet.frame_count} after {self._last_frame}): the world was reset "
                f"to the scenario's start pose at t = 0 (it was at t = {self.sim.time:.3f} s)"
            )
            self.sim.reset()
            self._target_time = self.sim.time
        self._last_frame = packet.frame_count
        pwm = np.array(packet.pwm[: self.n_thrusters], float)
        commands = np.where(pwm == 0, 0.0, pwm_to_command(np.where(pwm == 0, 1500.0, pwm)))
        self.sim.set_thrusters(self.robot, commands)
        # lockstep: advance whole physics steps up to the frame's end time
        self._target_time += 1.0 / packet.frame_rate
        timestep = self.sim.scenario.timestep_s
        n_steps = math.floor((self._target_time - self.sim.time) / timestep + 1e-9)
        if n_steps > 0:
            self.sim.advance_physics(n_steps)
        self.counters.answered += 1
        self._last_answer = self.state_json().encode("ascii")
        return self._last_answer

    def state(self) -> dict:
        """The robot's true state in ArduPilot's frames (the answer's fields)."""
        truth = self.sim.ground_truth(self.robot)
        rotation = np.zeros(9)
        mujoco.mju_quat2Mat(rotation, np.asarray(truth["quaternion"], float))
        rotation_ned = WORLD_TO_NED @ rotation.reshape(3, 3) @ WORLD_TO_NED
        quaternion = np.zeros(4)
        mujoco.mju_mat2Quat(quaternion, rotation_ned.ravel())
        velocity_world = rotation.reshape(3, 3) @ np.asarray(truth["velocity_body"], float)
        return {
            "timestamp": self.sim.time,
            "imu": {
                "gyro": flu_from_frd(truth["angular_velocity_body"]).tolist(),
                "accel_body": flu_from_frd(truth["specific_force_body"]).tolist(),
            },
            "position": list(ned_from_world(truth["position"], self.surface_z)),
            "velocity": (WORLD_TO_NED @ velocity_world).tolist(),
            "quaternion": quaternion.tolist(),
        }

    def state_json(self) -> str:
        """The answer line: compact JSON (no spaces), a newline before and after."""
        return "\n" + json.dumps(self.state(), separators=(",", ":")) + "\n"
