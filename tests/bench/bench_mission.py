"""Benchmark the closed-loop mission (issue [mission]): its real-time factor and where the wall time goes,
against the floor it cannot beat, measured in the same process: the same Simulation stepping the same
robots at the same control rate, each rendering its stereo pair at the mission's frame rate, with no
perception, discovery, allocation or control.

    python tests/bench/bench_mission.py [--duration S] [--seed N]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

# the simulator and the mission are imported inside the functions: the mission's perception worker is a
# spawned process, which imports this script again as its main module, and should not pay for them (as
# it does not under the `maptidal` command)


def floor_factor(scenario, params, duration_s: float) -> float:
    """Real-time factor of bare stepping and rendering (the mission's floor)."""
    from maptidal.camera import StereoCameraParams
    from maptidal.envs.simulation import Simulation

    width, height = params.image_size
    sim = Simulation(
        scenario,
        camera=StereoCameraParams(width=width, height=height),
        flight_mode="stabilize",
        render_samples=params.render_samples,
        water_backend=params.water_backend,
    )
    sim.reset(seed=params.seed)
    names = [r.name for r in scenario.robots]
    commands = {name: np.zeros(6) for name in names}
    next_frame, every = 0.0, 1.0 / params.frame_rate_hz
    sim.render_stereo(names[0])  # the renderer's one-off start
    start = time.perf_counter()
    while sim.time < duration_s:
        sim.step(commands)
        if sim.time >= next_frame:
            next_frame += every
            for name in names:
                sim.render_stereo(name)
    factor = sim.time / (time.perf_counter() - start)
    sim.close()
    return factor


def main() -> None:
    """Print the mission's real-time factor, its timing breakdown and the ratio to the floor."""
    from maptidal.mission.config import prepare_mission
    from maptidal.mission.outputs import read_events
    from maptidal.mission.run import Mission

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--duration", type=float, default=120.0, help="simulated seconds (default 120)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--sparse-keyframes",
        action="store_true",
        help="keyframes on motion, as the mission made them until session 12 (one per 25 cm or 20 deg, at "
        "most one a second, one every 4 s while still: 0.3 Hz), rather than at every 1 Hz frame",
    )
    parser.add_argument(
        "--inline-perception",
        action="store_true",
        help="run perception and discovery in the mission's own process rather than a worker process",
    )
    parser.add_argument(
        "--render-samples",
        type=int,
        default=None,
        help="the images' anti-aliasing samples, for the mission and its floor (default: the mission's, 4)",
    )
    args = parser.parse_args()
    scenario, params = prepare_mission(None, duration_s=args.duration, seed=args.seed)
    if args.render_samples is not None:
        params = dataclasses.replace(params, render_samples=args.render_samples)
    if args.inline_perception:
        params = dataclasses.replace(params, perception_process=False)
    if args.sparse_keyframes:
        keyframes = dataclasses.replace(
            params.keyframes, max_interval_s=4.0, min_translation_m=0.25, min_rotation_deg=20.0
        )
        params = dataclasses.replace(params, keyframes=keyframes)
    floor = floor_factor(scenario, params, args.duration)
    scratch = tempfile.TemporaryDirectory()
    out_dir = Path(scratch.name)
    mission = Mission(scenario, params, out_dir)
    document = mission.run()
    renderer = document["renderer"]
    timing = document["timing"]
    wall = document["wall_time_s"]
    print(f"renderer: {renderer}")
    print(
        f"default mission, {len(scenario.robots)} robots, {document['sim_time_s']:.0f} s simulated (cap "
        f"{args.duration:.0f} s), frames at {params.frame_rate_hz:g} Hz, "
        f"{params.image_size[0]}x{params.image_size[1]}"
    )
    print(f"floor (stepping + stereo renders only): {floor:6.1f}x real time")
    print(f"mission:                                {document['realtime_factor']:6.1f}x real time")
    print(f"mission / floor: {document['realtime_factor'] / floor:.2f} (the goal is 10x real time)")
    parallel = document["parallel"]
    beside = parallel["beside_the_loop_s"]
    loop = {name: s - beside.get(name, 0.0) for name, s in timing.items()}
    loop = {name: s for name, s in loop.items() if s > 1e-6}
    loop["waiting"] = parallel["loop_waited_s"]  # for a frame's drawing and its answer
    print("where the loop's wall time goes:")
    for name, seconds in sorted(loop.items(), key=lambda kv: -kv[1]):
        print(f"  {name:<11} {seconds:6.2f} s  {100 * seconds / wall:5.1f} %")
    rest = wall - sum(loop.values())
    print(f"  {'the loop':<11} {rest:6.2f} s  {100 * rest / wall:5.1f} %  (activities, logs, snapshots)")
    where = "a worker process" if parallel["perception"] == "process" else "the GL thread"
    print(f"beside it: the frames drawn on the GL thread, perception and discovery on {where}:")
    for name, seconds in beside.items():
        print(f"  {name:<11} {seconds:6.2f} s  {100 * seconds / wall:5.1f} % of the wall time")
    events = read_events(out_dir)
    for robot in mission.robots:
        count = sum(1 for e in events if e["kind"] == "keyframe" and e["robot"] == robot)
        print(f"keyframes, {robot}: {count} ({count / document['sim_time_s']:.2f} Hz)")
    done = sum(1 for t in document["tasks"] if t["completed"])
    print(f"tasks found {len(document['tasks'])}, done {done}; messages {document['comms']['messages']}")
    scratch.cleanup()


if __name__ == "__main__":
    main()
