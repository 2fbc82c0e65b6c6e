"""One step sequence flown through our ArduSub flight modes and, where ``ARDUSUB_SITL`` names an
ArduSub SITL binary, through the real firmware on our physics (ArduPilot's JSON backend), judged on the
true state in both: a depth step in ALT_HOLD, a heading step and a lean while turning in STABILIZE, on
the Heavy. Prints a markdown table of the responses and, with SITL, of their differences.

    python tests/bench/flight_steps.py
    ARDUSUB_SITL=/path/to/ardusub python tests/bench/flight_steps.py

SITL runs in real time (it sets the clock through the JSON backend), so the SITL half takes about a
minute a step. It starts SITL with JS_GAIN_DEFAULT = JS_GAIN_MAX = 1 so that a stick of 1 is ArduSub's
full RC range, as our flight modes read it. Roll reaches ArduSub as an RC override of channel 2
(controllers/mavlink_wire.py), which ArduSub reads only while its joystick roll/pitch flag is off:
our reading, not checked on SITL.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")

from maptidal.envs.simulation import Simulation


@dataclass(frozen=True)
class Step:
    """A named sequence of (pilot command, seconds) flown in one flight mode."""

    name: str
    mode: str
    legs: tuple[tuple[dict, float], ...]


STEPS = (
    Step("depth step", "alt_hold", (({"heave": 0.6}, 2.0), ({}, 10.0))),
    Step("heading step", "stabilize", (({"yaw": 1.0}, 1.5), ({}, 6.0))),
    Step("lean while turning", "stabilize", (({"roll": 0.3, "yaw": 1.0}, 10.0),)),
)


def response(step: Step, times: np.ndarray, states: np.ndarray) -> dict[str, float]:
    """What a pilot would judge: the change the step made, how far it came back from its extreme after
    the stick was centred, and for the lean its mean roll and yaw rate over the last 5 s. ``states``
    rows are (roll, pitch, yaw, x, y, z), true, rad and m."""
    first_leg = step.legs[0][1]
    released = times >= first_leg
    if step.name == "depth step":
        z = states[:, 5]
        extreme = z[released].max()
        return {"change_m": z[-1] - z[0], "return_m": extreme - z[-1]}
    yaw = np.degrees(np.unwrap(states[:, 2]))
    if step.name == "heading step":
        peak = yaw[released].min()  # turning right: yaw falls
        return {"change_deg": yaw[-1] - yaw[0], "bounce_back_deg": yaw[-1] - peak}
    late = times >= times[-1] - 5.0
    rate = np.polyfit(times[late], yaw[late], 1)[0]
    return {"roll_deg": float(np.degrees(states[late, 0]).mean()), "yaw_rate_deg_s": float(rate)}


def fly_ours(step: Step, seed: int = 0) -> dict[str, float]:
    """The step through :mod:`maptidal.controllers.flight_modes` in the simulator."""
    sim = Simulation(flight_mode=step.mode)
    sim.reset(seed=seed)
    robot = sim.robots[0]
    times, states = [], []
    for command, seconds in step.legs:
        for _ in range(round(seconds / sim.scenario.control_period_s)):
            sim.step({robot: command})
            truth = sim.ground_truth(robot)
            times.append(sim.time)
            states.append([*truth["rpy"], *truth["position"]])
    sim.close()
    return response(step, np.array(times), np.array(states))


def fly_sitl(step: Step, binary: str, seed: int = 0) -> dict[str, float]:
    """The step through ArduSub SITL on our physics, sampled from the simulation it steps."""
    from maptidal.controllers.mavlink_bridge import BridgeParams, MavlinkBridge
    from maptidal.envs.ardupilot_json import JsonBackend

    sim = Simulation()
    sim.reset(seed=seed)
    robot = sim.robots[0]
    backend = JsonBackend(sim, port=0, host="127.0.0.1").open()
    thread = threading.Thread(target=backend.run, daemon=True)
    thread.start()
    with tempfile.TemporaryDirectory() as scratch:
        defaults = Path(scratch) / "sub.parm"
        defaults.write_text("FRAME_CONFIG 2\nARMING_CHECK 0\nJS_GAIN_DEFAULT 1.0\nJS_GAIN_MAX 1.0\n")
        command = [binary, "--model", "JSON:127.0.0.1", "--home", "-35.0,149.0,0,0", "-I0"]
        command += ["--sim-port-out", str(backend.port), "--defaults", str(defaults)]
        sitl = subprocess.Popen(command, cwd=scratch, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            with MavlinkBridge("tcp:127.0.0.1:5760", BridgeParams(connect_timeout_s=60)) as bridge:
                deadline = time.monotonic() + 60
                while True:  # ArduSub refuses ALT_HOLD until its barometer and EKF are ready
                    try:
                        bridge.set_mode(step.mode)
                        break
                    except Exception:
                        if time.monotonic() > deadline:
                            raise
                        time.sleep(1.0)
                bridge.arm(timeout_s=30)
                times, states = [], []
                start = sim.time
                for pilot, seconds in step.legs:
                    bridge.set_command(pilot)
                    leg_end = time.monotonic() + seconds
                    while time.monotonic() < leg_end:
                        truth = sim.ground_truth(robot)
                        times.append(truth["time_s"] - start)
                        states.append([*truth["rpy"], *truth["position"]])
                        time.sleep(0.02)
        finally:
            sitl.kill()
            sitl.wait(timeout=10)
            backend.stop()
            thread.join(timeout=5)
            backend.close()
    return response(step, np.array(times), np.array(states))


def main() -> int:
    """Print the table; with ARDUSUB_SITL, both columns and their difference."""
    binary = os.environ.get("ARDUSUB_SITL")
    print("| step | measure | ours |" + (" ArduSub SITL | difference |" if binary else ""))
    print("|---|---|---|" + ("---|---|" if binary else ""))
    for step in STEPS:
        ours = fly_ours(step)
        theirs = fly_sitl(step, binary) if binary else {}
        for key, value in ours.items():
            row = f"| {step.name} | {key} | {value:.3f} |"
            if binary:
                other = theirs[key]
                row += f" {other:.3f} | {value - other:+.3f} |"
            print(row, flush=True)
    if not binary:
        print("\nset ARDUSUB_SITL to an ArduSub SITL binary for the firmware's column", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
