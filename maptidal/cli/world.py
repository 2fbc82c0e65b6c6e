"""``maptidal sim`` and ``maptidal export-mjcf``: the MuJoCo world from the command line."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from maptidal.cli.common import (
    RunError,
    add_output_folder,
    output_dir,
    pilot_gain,
    positive_float,
    positive_int,
)
from maptidal.controllers.flight_modes import FLIGHT_MODES
from maptidal.files import atomic_write_bytes
from maptidal.progress import ProgressBar

MAX_DURATION_S = 1e6  # s; a constant command for longer than 11 days is a typo


def register(commands) -> None:
    """Add the ``sim`` and ``export-mjcf`` subcommands."""
    sim = commands.add_parser(
        "sim",
        help="run the MuJoCo world headless with a constant pilot command",
        description="Load a scenario, hold a normalised 6-DOF pilot command (surge, sway, heave, roll, "
        "pitch, yaw, each in [-1, 1], ArduSub's meaning: forward, right, up, right side down, nose up, "
        "turn right) on every robot for the duration, flown in an ArduSub flight mode (--mode, STABILIZE "
        "by default) after ArduSub's pilot gain (--pilot-gain), and report each robot's final "
        "ground-truth state, the contacts it made and the run's speed.",
    )
    sim.add_argument("--scenario", metavar="FILE", help="scenario TOML (default: the bundled default.toml)")
    sim.add_argument(
        "--frame", choices=("heavy", "standard"), help="switch every robot to this BlueROV2 frame"
    )
    sim.add_argument(
        "--command",
        dest="pilot_command",
        default="",
        metavar="AXIS=V,...",
        help="e.g. surge=0.5,yaw=0.3; each axis once, values in [-1, 1] (default idle)",
    )
    sim.add_argument(
        "--duration",
        type=positive_float,
        default=5.0,
        metavar="S",
        help="simulated seconds (default %(default)s)",
    )
    sim.add_argument("--render-dir", type=output_dir, metavar="DIR", help="save stereo pairs (PNG) into DIR")
    sim.add_argument(
        "--render-every",
        type=positive_int,
        default=25,
        metavar="N",
        help="control steps between saved pairs, >= 1 (default %(default)s)",
    )
    sim.add_argument(
        "--water-backend",
        choices=("auto", "gl", "cpu"),
        default="auto",
        help="where the underwater image model runs: a GL shader, the CPU, or auto (GL on a GPU, "
        "CPU on a software rasteriser; default %(default)s)",
    )
    sim.add_argument(
        "--mode",
        choices=FLIGHT_MODES,
        default="stabilize",
        help="the ArduSub flight mode the command is flown in (default %(default)s; poshold needs a DVL)",
    )
    sim.add_argument(
        "--pilot-gain",
        type=pilot_gain,
        default=1.0,
        metavar="G",
        help="ArduSub's joystick gain JS_GAIN, 0.1 to 1.0, on surge, sway, heave and yaw (default "
        "%(default)s; ArduSub's own default is 0.5)",
    )
    sim.add_argument("--seed", type=int, default=0, help="noise seed (default %(default)s)")
    sim.add_argument("--json", action="store_true", help="print the result as JSON")
    sim.set_defaults(handler=run_sim)

    export = commands.add_parser(
        "export-mjcf",
        help="write a scenario's world as MJCF files (Menagerie style)",
        description="Write scene.xml (tank and robots), tank.xml, one bluerov2_<frame>.xml per frame, the "
        "procedural textures as PNG and a README into DIR, for MuJoCo's viewer and other tools. The "
        "hydrodynamics and thrust are a callback of maptidal's Simulation and are not in the files.",
    )
    export.add_argument(
        "--scenario", metavar="FILE", help="scenario TOML (default: the bundled default.toml)"
    )
    export.add_argument("--frame", choices=("heavy", "standard"), help="switch every robot to this frame")
    add_output_folder(export, "runs/mjcf")
    export.set_defaults(handler=run_export)


def _robot_state(truth: dict) -> dict:
    """One robot's final state for the JSON, every field named with its unit."""
    return {
        "position_m": truth["position"],
        "velocity_body_m_s": truth["velocity_body"],
        "angular_velocity_body_rad_s": truth["angular_velocity_body"],
        "rpy_rad": truth["rpy"],
        "rpy_deg": np.degrees(truth["rpy"]).tolist(),
    }


class _ContactLog:
    """Per robot: when it first touched something, what, and the largest normal force seen."""

    def __init__(self, robots: list[str]) -> None:
        self.entries: dict[str, dict[str, dict]] = {robot: {} for robot in robots}

    def record(self, contacts, time_s: float) -> None:
        """Add this control step's contacts (:meth:`maptidal.envs.simulation.Simulation.contacts`)."""
        for contact in contacts:
            entry = self.entries[contact.robot].setdefault(
                contact.other, {"with": contact.other, "first_s": time_s, "max_force_n": 0.0, "steps": 0}
            )
            entry["max_force_n"] = max(entry["max_force_n"], contact.normal_force_n)
            entry["last_s"] = time_s
            entry["steps"] += 1

    def of(self, robot: str) -> list[dict]:
        """The robot's contacts for the JSON: with what, first and last time (s), largest force (N)."""
        return [
            {**entry, "max_force_n": round(entry["max_force_n"], 3)} for entry in self.entries[robot].values()
        ]


def run_sim(args: argparse.Namespace) -> int:
    """Handler of ``maptidal sim``."""
    import cv2

    from maptidal.controllers.convention import PilotGain, parse_command
    from maptidal.controllers.flight_modes import ModeParams
    from maptidal.envs.scenario import load_scenario, with_frame
    from maptidal.envs.simulation import Simulation, SimulationError

    command = parse_command(args.pilot_command)
    scenario = load_scenario(args.scenario)
    if args.frame:
        scenario = with_frame(scenario, args.frame)
    if args.duration > MAX_DURATION_S:
        raise ValueError(f"--duration must be at most {MAX_DURATION_S:g} s, got {args.duration:g}")
    period = scenario.substeps * scenario.timestep_s
    gain = ModeParams(pilot_gain=PilotGain(args.pilot_gain))
    sim = Simulation(scenario, water_backend=args.water_backend, flight_mode=args.mode, mode_params=gain)
    sim.reset(seed=args.seed)
    if args.render_dir:
        try:
            sim.water_backend  # noqa: B018 - a 'gl' that cannot run here fails now, before any work
        except RuntimeError as err:
            raise RunError(str(err)) from None
    steps = max(1, round(args.duration / period))
    render_dir = Path(args.render_dir) if args.render_dir else None
    commands = {robot: command for robot in sim.robots}
    contacts = _ContactLog(sim.robots)
    progress = ProgressBar(steps, "sim", enabled=not args.json)
    start = time.perf_counter()
    for k in range(steps):
        try:
            sim.step(commands)
        except SimulationError as err:
            raise RunError(str(err)) from None
        contacts.record(sim.contacts(), sim.time)
        if render_dir and k % args.render_every == 0:
            for robot in sim.robots:
                left, right = sim.render_stereo(robot)
                _ok, png = cv2.imencode(".png", np.hstack([left, right])[..., ::-1])
                atomic_write_bytes(render_dir / f"{robot}_{k:05d}.png", png.tobytes())
        progress.advance(note=f"{sim.time:.1f} s simulated")
    wall = time.perf_counter() - start
    physics_steps = steps * scenario.substeps
    result = {
        "robots": {
            robot: {**_robot_state(sim.ground_truth(robot)), "contacts": contacts.of(robot)}
            for robot in sim.robots
        },
        "command": dict(
            zip(("surge", "sway", "heave", "roll", "pitch", "yaw"), command.tolist(), strict=True)
        ),
        "sim_time_s": sim.time,
        "wall_time_s": wall,
        "steps_per_s": physics_steps / sim.wall_time_s if sim.wall_time_s > 0 else float("inf"),
        "realtime_factor": sim.time / wall if wall > 0 else float("inf"),
        "hydrodynamics": sim.backend,
        "flight_mode": args.mode,
        "pilot_gain": args.pilot_gain,
    }
    if render_dir:
        result["water_backend"] = sim.water_backend
        result["render_dir"] = str(render_dir)
    sim.close()
    if args.json:
        print(json.dumps(result))
        return 0
    for robot, state in result["robots"].items():
        p, v = (np.round(state[k], 3).tolist() for k in ("position_m", "velocity_body_m_s"))
        rpy = np.round(state["rpy_deg"], 1).tolist()
        print(
            f"{robot} after {sim.time:.2f} s: position {p} m, body velocity {v} m/s, roll-pitch-yaw {rpy} deg"
        )
        for entry in state["contacts"]:
            print(
                f"  touched {entry['with']} from {entry['first_s']:.2f} s to {entry['last_s']:.2f} s "
                f"(largest normal force {entry['max_force_n']:.1f} N)"
            )
    print(
        f"{result['steps_per_s']:.0f} physics steps/s, {result['realtime_factor']:.1f}x real time "
        f"({result['hydrodynamics']} hydrodynamics)"
    )
    if render_dir:
        print(f"frames: {render_dir}")
    return 0


def run_export(args: argparse.Namespace) -> int:
    """Handler of ``maptidal export-mjcf``."""
    from maptidal.envs.export import export_world
    from maptidal.envs.scenario import load_scenario, with_frame

    scenario = load_scenario(args.scenario)
    if args.frame:
        scenario = with_frame(scenario, args.frame)
    for name, path in export_world(scenario, args.out).items():
        print(f"{name}: {path}")
    return 0
