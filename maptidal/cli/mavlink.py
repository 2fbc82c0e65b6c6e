"""``maptidal mavlink`` (fly a real or simulated ArduSub vehicle) and ``maptidal sim-vehicle`` (the
simulator as a MAVLink vehicle, or as ArduPilot SITL's JSON physics backend)."""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path

import numpy as np

from maptidal.cli.common import RunError, finite_float, pilot_gain, positive_float
from maptidal.controllers.convention import PilotGain, boot_gain
from maptidal.controllers.mavlink_bridge import GAIN_PARAMETERS, BridgeError

MAX_WAYPOINTS = 1000
CONTROL_PERIOD_S = 0.05  # 20 Hz, the bridge's streaming rate
MODES = ("depth-hold", "stabilize", "manual", "alt_hold", "poshold")
# the deepest target the bridge takes by default: the BlueROV2's rated depth, 100 m (Blue Robotics'
# BlueROV2 specifications); --max-depth sets the water at hand (a 2 m tank: --max-depth 2)
RATED_DEPTH_M = 100.0
LINK_SCHEMES = ("udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin")


def connection_string(text: str) -> str:
    """An argparse type: a pymavlink address, SCHEME:HOST:PORT with a scheme of :data:`LINK_SCHEMES`
    and a port from 1 to 65535, or a serial device path (``/dev/ttyACM0`` or ``/dev/ttyACM0,115200``)."""
    if text.startswith("/") or text.upper().startswith("COM"):
        _device, _, baud = text.partition(",")
        if baud and not (baud.isdigit() and int(baud) > 0):
            raise argparse.ArgumentTypeError(
                f"{text!r}: the baud rate after the comma must be a whole number"
            )
        return text
    scheme, _, rest = text.partition(":")
    host, _, port = rest.rpartition(":")
    if scheme not in LINK_SCHEMES or not host or not (port.isdigit() and 1 <= int(port) <= 65535):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a MAVLink address: use {'|'.join(LINK_SCHEMES)}:HOST:PORT (port 1 to 65535) or "
            "a serial device such as /dev/ttyACM0,115200"
        )
    return text


def register(commands) -> None:
    """Add the ``mavlink`` and ``sim-vehicle`` subcommands."""
    mavlink = commands.add_parser(
        "mavlink",
        help="fly an ArduSub vehicle (real or simulated) over MAVLink with maptidal's controllers",
        description="Connect to an ArduSub vehicle as a ground station (system 255), then either report "
        "its state (status) or fly it (fly, the default): hold a depth and heading (--mode depth-hold "
        "--depth M), or fly a list of waypoints (--waypoints FILE), with maptidal's feedback controllers "
        "on the vehicle's telemetry, streaming the pilot command at 20 Hz. The vehicle flies STABILIZE "
        "underneath. Before flying it checks that the vehicle's pilot gain (JS_GAIN_DEFAULT within "
        "JS_GAIN_MIN/MAX, and JS_THR_GAIN) is 1, as the controllers are tuned in the simulator, and "
        "refuses to fly otherwise (--write-gain sets them; ArduSub takes them at its next boot). On exit, "
        "Ctrl-C, SIGTERM or an error it sends neutral and disarms.",
    )
    mavlink.add_argument("action", nargs="?", choices=("fly", "status"), default="fly", help="default: fly")
    mavlink.add_argument(
        "--connect",
        required=True,
        type=connection_string,
        metavar="URL",
        help="pymavlink address: udpin:0.0.0.0:14550, "
        "udpout:HOST:PORT, tcp:HOST:PORT or a serial device (/dev/ttyACM0,115200)",
    )
    mavlink.add_argument(
        "--mode", choices=MODES, default="depth-hold", help="what to fly (default %(default)s)"
    )
    mavlink.add_argument(
        "--depth", type=positive_float, metavar="M", help="depth to hold (m); required with --mode depth-hold"
    )
    mavlink.add_argument(
        "--max-depth",
        type=positive_float,
        default=RATED_DEPTH_M,
        metavar="M",
        help="refuse targets deeper than this: the water at hand (default %(default)g m, the BlueROV2's "
        "rated depth)",
    )
    mavlink.add_argument(
        "--heading", type=float, metavar="DEG", help="heading to hold (deg; default: as found)"
    )
    mavlink.add_argument(
        "--waypoints",
        metavar="FILE",
        help="JSON list of {north_m, east_m, depth_m, heading_deg} to fly in turn",
    )
    mavlink.add_argument("--duration", type=positive_float, default=30.0, metavar="S", help="hold time (s)")
    mavlink.add_argument(
        "--dwell", type=positive_float, default=2.0, metavar="S", help="hold at each waypoint"
    )
    mavlink.add_argument(
        "--frame", choices=("heavy", "standard"), default="heavy", help="the vehicle's frame"
    )
    mavlink.add_argument(
        "--timeout", type=positive_float, default=10.0, metavar="S", help="heartbeat wait (s)"
    )
    mavlink.add_argument(
        "--signing-key-file",
        metavar="FILE",
        help="MAVLink 2 signing key (32 bytes or 64 hex digits); or set $MAPTIDAL_MAVLINK_KEY",
    )
    mavlink.add_argument(
        "--write-gain",
        action="store_true",
        help="when the vehicle's pilot gain is not 1, set JS_GAIN_DEFAULT 1 (JS_GAIN_MAX at least 1) and "
        "JS_THR_GAIN 1, then stop: reboot the vehicle for ArduSub to take them",
    )
    mavlink.add_argument("--json", action="store_true", help="print the result as JSON")
    mavlink.set_defaults(handler=run_mavlink)

    vehicle = commands.add_parser(
        "sim-vehicle",
        help="run a simulated BlueROV2 behind a MAVLink endpoint (or as ArduPilot's JSON physics)",
        description="Run one MuJoCo BlueROV2 of a scenario as a MAVLink vehicle that behaves like ArduSub "
        "for arming, modes (MANUAL, STABILIZE, ALT_HOLD, POSHOLD, GUIDED), pilot input, the pilot "
        "failsafe, telemetry and parameters, so `maptidal mavlink`, MAVProxy or QGroundControl can fly it. "
        "With --ardupilot-json it is instead the physics backend of ArduSub SITL (--model JSON). Runs until "
        "killed; SIGTERM and Ctrl-C stop it cleanly.",
    )
    vehicle.add_argument("--connect", default="udpin:127.0.0.1:14550", metavar="URL", help="MAVLink endpoint")
    vehicle.add_argument(
        "--scenario", metavar="FILE", help="scenario TOML (default: the bundled default.toml)"
    )
    vehicle.add_argument("--robot", metavar="NAME", help="which robot of the scenario (default: the first)")
    vehicle.add_argument("--speedup", type=positive_float, default=1.0, metavar="K", help="sim s per wall s")
    vehicle.add_argument(
        "--pilot-gain",
        type=pilot_gain,
        default=1.0,
        metavar="G",
        help="JS_GAIN_DEFAULT at start, 0.1 to 1.0 (default %(default)s; ArduSub's own default is 0.5, which "
        "halves what a full MANUAL_CONTROL stick asks of the thrusters)",
    )
    vehicle.add_argument("--duration", type=positive_float, metavar="S", help="stop after S simulated s")
    vehicle.add_argument(
        "--signing-key-file", metavar="FILE", help="MAVLink 2 signing key (or $MAPTIDAL_MAVLINK_KEY)"
    )
    vehicle.add_argument(
        "--ardupilot-json", action="store_true", help="be ArduPilot SITL's JSON physics backend"
    )
    vehicle.add_argument("--port", type=int, default=9002, help="JSON backend UDP port (default %(default)s)")
    vehicle.add_argument(
        "--idle-timeout",
        type=finite_float,
        default=300.0,
        metavar="S",
        help="with --ardupilot-json: stop, with status 1, after S wall seconds without a servo packet "
        "(0: wait for ever; default %(default)s)",
    )
    vehicle.add_argument("--seed", type=int, default=0, help="noise seed (default %(default)s)")
    vehicle.set_defaults(handler=run_sim_vehicle)


# ----- maptidal mavlink ---------------------------------------------------------------------------
def load_waypoints(path: str | Path) -> list[dict]:
    """Waypoints from a JSON file: a list (or ``{"waypoints": [...]}``) of objects with north_m, east_m,
    depth_m (>= 0) and optionally heading_deg. Raises ValueError naming the first bad entry."""
    try:
        document = json.loads(Path(path).read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not JSON ({error.msg}, line {error.lineno})") from None
    entries = document.get("waypoints") if isinstance(document, dict) else document
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: expected a non-empty list of waypoints")
    if len(entries) > MAX_WAYPOINTS:
        raise ValueError(f"{path}: at most {MAX_WAYPOINTS} waypoints, got {len(entries)}")
    waypoints = []
    for index, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise ValueError(f"{path}: waypoint {index} is not an object")
        unknown = set(entry) - {"north_m", "east_m", "depth_m", "heading_deg"}
        if unknown:
            raise ValueError(f"{path}: waypoint {index} has unknown keys {sorted(unknown)}")
        try:
            values = {key: float(entry[key]) for key in ("north_m", "east_m", "depth_m")}
            values["heading_deg"] = float(entry.get("heading_deg", 0.0))
        except KeyError as error:
            raise ValueError(f"{path}: waypoint {index} lacks {error.args[0]}") from None
        except (TypeError, ValueError):
            raise ValueError(f"{path}: waypoint {index} has a value that is not a number") from None
        if not all(math.isfinite(v) for v in values.values()) or values["depth_m"] < 0:
            raise ValueError(f"{path}: waypoint {index} needs finite values and depth_m >= 0")
        waypoints.append(values)
    return waypoints


def run_mavlink(args: argparse.Namespace) -> int:
    """Handler of ``maptidal mavlink``."""
    from maptidal.controllers.mavlink_bridge import (
        BridgeParams,
        MavlinkBridge,
        install_signal_handlers,
        load_signing_key,
    )

    waypoints = load_waypoints(args.waypoints) if args.waypoints and args.action == "fly" else None
    if args.action == "fly" and waypoints is None and args.mode == "depth-hold":
        if args.depth is None:
            raise ValueError(
                "--mode depth-hold needs --depth M: the bridge dives to no depth it was not given"
            )
        if args.depth > args.max_depth:
            raise ValueError(f"--depth {args.depth:g} m is deeper than --max-depth {args.max_depth:g} m")
    deepest = max((w["depth_m"] for w in waypoints or []), default=0.0)
    if deepest > args.max_depth:
        raise ValueError(
            f"{args.waypoints}: a waypoint at {deepest:g} m is deeper than --max-depth {args.max_depth:g} m"
        )
    key = load_signing_key(args.signing_key_file)
    bridge = MavlinkBridge(args.connect, BridgeParams(connect_timeout_s=args.timeout), signing_key=key)
    try:
        bridge.connect()
    except BridgeError as error:
        raise RunError(str(error)) from None
    install_signal_handlers()
    try:
        if args.action == "status":
            result = _status(bridge)
        else:
            # the controllers are tuned at full authority, as the simulator flies by default
            bridge.check_pilot_gain(PilotGain(1.0), write=args.write_gain)
            result = _fly(bridge, args, waypoints)
    except BridgeError as error:
        raise RunError(str(error)) from None
    finally:
        bridge.close()
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")
    return 0


def _status(bridge, listen_s: float = 2.0) -> dict:
    time.sleep(listen_s)
    try:
        js = {name: bridge.read_param(name, timeout_s=1.0) for name in GAIN_PARAMETERS}
        bounds = (js["JS_GAIN_DEFAULT"], js["JS_GAIN_MIN"], js["JS_GAIN_MAX"], int(js["JS_GAIN_STEPS"]))
        gain = round(boot_gain(*bounds), 3)
        throttle_gain = js["JS_THR_GAIN"]
    except BridgeError:  # a vehicle without ArduSub's joystick parameters
        gain = throttle_gain = None
    t = bridge.telemetry
    roll, pitch, yaw = (math.degrees(v) for v in t.attitude_ned)
    return {
        "system_id": t.system_id,
        "armed": t.armed,
        "mode": t.mode,
        "attitude_deg": {"roll": round(roll, 2), "pitch": round(pitch, 2), "yaw": round(yaw, 2)},
        "depth_m": None if t.depth_m is None else round(t.depth_m, 3),
        "position_ned_m": None if t.position_ned is None else [round(v, 3) for v in t.position_ned],
        "servo_pwm_us": list(t.servo_pwm[:8]),
        "pilot_gain": gain,
        "throttle_gain": throttle_gain,
        "messages": t.messages,
        "bad_packets": t.bad_packets,
    }


def _fly(bridge, args, waypoints) -> dict:
    from maptidal.controllers.pose import DepthHold, HeadingHold, PoseController
    from maptidal.controllers.task import TaskExecutor, TaskParams
    from maptidal.envs.vehicle import load_vehicle

    model = load_vehicle(args.frame).controller_model()
    mode = "stabilize" if args.mode == "depth-hold" or waypoints else args.mode
    bridge.set_mode(mode)
    bridge.arm()
    started = time.monotonic()
    report: dict = {"mode": args.mode if not waypoints else "waypoints", "vehicle_mode": mode}
    if waypoints:
        if bridge.telemetry.position_ned is None:
            bridge.wait_for(
                lambda t: t.position_ned is not None, 3.0, "LOCAL_POSITION_NED (waypoints need it)"
            )
        controller = PoseController(model, hold_roll_pitch=False)  # STABILIZE holds roll and pitch
        results = []
        for index, waypoint in enumerate(waypoints):
            goal = np.array([waypoint["north_m"], -waypoint["east_m"], -waypoint["depth_m"]])
            estimate = bridge.telemetry.estimate()
            executor = TaskExecutor(
                controller,
                estimate,
                goal,
                -math.radians(waypoint["heading_deg"]),
                TaskParams(dwell_s=args.dwell),
            )
            status = "approach"
            while status not in ("capture", "timeout"):
                _check_link(bridge)
                command, status = executor.update(bridge.telemetry.estimate(), CONTROL_PERIOD_S)
                bridge.set_command(command)
                time.sleep(CONTROL_PERIOD_S)
            results.append({"index": index, "status": status, "time_s": round(time.monotonic() - started, 2)})
            print(f"waypoint {index}: {status}", file=sys.stderr)
        report["waypoints"] = results
    elif args.mode == "depth-hold":
        depth_hold, heading_hold = DepthHold(model), HeadingHold(model)
        heading = bridge.telemetry.estimate().yaw if args.heading is None else -math.radians(args.heading)
        while time.monotonic() - started < args.duration:
            _check_link(bridge)
            estimate = bridge.telemetry.estimate()
            command = np.zeros(6)
            command[2] = depth_hold.update(args.depth, estimate, 0.0, CONTROL_PERIOD_S)
            command[5] = heading_hold.update(heading, estimate, CONTROL_PERIOD_S)
            bridge.set_command(command)
            time.sleep(CONTROL_PERIOD_S)
    else:  # the vehicle's own mode holds; stream neutral so its pilot failsafe stays quiet
        while time.monotonic() - started < args.duration:
            _check_link(bridge)
            bridge.neutral()
            time.sleep(CONTROL_PERIOD_S)
    t = bridge.telemetry
    report.update(
        {
            "duration_s": round(time.monotonic() - started, 2),
            "final_depth_m": None if t.depth_m is None else round(t.depth_m, 3),
            "final_position_ned_m": None if t.position_ned is None else [round(v, 3) for v in t.position_ned],
            "final_heading_deg": round(math.degrees(t.attitude_ned[2]) % 360.0, 2),
            "link_lost": bridge.link_lost,
        }
    )
    return report


def _check_link(bridge) -> None:
    from maptidal.controllers.mavlink_bridge import BridgeError

    if bridge.link_lost:
        raise BridgeError("lost the vehicle's heartbeat: sent neutral and stopped")


# ----- maptidal sim-vehicle -----------------------------------------------------------------------
def _say(line: str) -> None:
    """One line for the user on standard error, at once."""
    print(line, file=sys.stderr, flush=True)


def run_sim_vehicle(args: argparse.Namespace) -> int:
    """Handler of ``maptidal sim-vehicle``."""
    from maptidal.controllers.mavlink_bridge import load_signing_key
    from maptidal.envs.scenario import load_scenario
    from maptidal.envs.simulation import Simulation

    if args.idle_timeout < 0:
        raise ValueError(f"--idle-timeout must be >= 0, got {args.idle_timeout}")
    scenario = load_scenario(args.scenario)
    sim = Simulation(scenario)
    sim.reset(seed=args.seed)
    if args.robot is not None and args.robot not in sim.robots:
        raise ValueError(f"--robot {args.robot!r} is not in the scenario; robots: {', '.join(sim.robots)}")
    if args.ardupilot_json:
        from maptidal.envs.ardupilot_json import JsonBackend, JsonBackendError

        try:
            server = JsonBackend(sim, args.robot, port=args.port, on_event=_say).open()
        except JsonBackendError as error:
            raise RunError(str(error)) from None
        print(f"ArduPilot JSON physics on UDP port {args.port} (robot {server.robot})", file=sys.stderr)
    else:
        from maptidal.envs.mavlink_vehicle import SimVehicle, SimVehicleParams, VehicleEndpointError

        key = load_signing_key(args.signing_key_file)
        server = SimVehicle(
            sim,
            args.robot,
            args.connect,
            SimVehicleParams(speedup=args.speedup, pilot_gain=args.pilot_gain),
            key,
        )
        try:
            server.open()
        except VehicleEndpointError as error:
            raise RunError(str(error)) from None
        print(f"simulated BlueROV2 {server.robot} on {args.connect}", file=sys.stderr)
    signal.signal(signal.SIGTERM, lambda *_: server.stop())
    heard = True
    try:
        if args.ardupilot_json:
            heard = server.run(args.duration, idle_timeout_s=args.idle_timeout or None)
        else:
            server.run(args.duration)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    print(json.dumps({"sim_time_s": round(sim.time, 3), "counters": vars(server.counters)}), file=sys.stderr)
    return 0 if heard else 1
