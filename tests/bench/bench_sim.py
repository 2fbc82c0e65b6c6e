"""Benchmark the simulator: physics steps/s and stereo pairs/s, each as a ratio to bare MuJoCo.

- Physics: the same compiled model stepped with ``mj_step`` (a) bare, with no
  passive-force callback and no gravity (robots float in place), and (b) with the
  Fossen hydrodynamics and thrusters on, for 1, 2 and 4 robots. Goal: (b)/(a) >= 0.5.
- Rendering: 640 x 400 stereo pairs through ``Simulation.render_stereo`` (one
  render pass per camera, water model applied as a GL shader and on the CPU)
  against a bare ``mujoco.Renderer`` rendering the same two cameras. Goal >= 0.8.

Run: ``make bench`` (or ``python tests/bench/bench_sim.py [--pairs N]``). Prints a
markdown table; the device line says which GL backend drew the frames.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco

from maptidal.envs import hydrodynamics
from maptidal.envs.rendering import CAMERA_SCENE_OPTION, describe_renderer
from maptidal.envs.scenario import RobotSpec, Scenario
from maptidal.envs.simulation import Simulation
from maptidal.envs.vehicle import load_vehicle
from maptidal.envs.water import WaterModel, WaterParams
from maptidal.tank import TankModel


def gl_renderer_name() -> str:
    """GL_RENDERER of this process's EGL context (the GPU, or llvmpipe on a CPU)."""
    with Simulation(scenario(1)) as sim:
        sim.render_stereo("rov0", water=False)
        return describe_renderer(sim.model, sim.camera.height, sim.camera.width)


def scenario(n_robots: int) -> Scenario:
    """``n_robots`` Heavies in a row across the OSB tank, 2 m from the end wall."""
    ys = [0.9 - 1.8 * k / max(n_robots - 1, 1) for k in range(n_robots)] if n_robots > 1 else [0.0]
    robots = tuple(RobotSpec(f"rov{k}", load_vehicle("heavy"), (-2.0, y, 1.0)) for k, y in enumerate(ys))
    return Scenario("bench", TankModel(), robots)


def steps_per_s(model, data, steps: int) -> float:
    start = time.perf_counter()
    mujoco.mj_step(model, data, nstep=steps)
    return steps / (time.perf_counter() - start)


def bench_physics(n_robots: int, steps: int = 20000) -> tuple[float, float]:
    sim = Simulation(scenario(n_robots))
    for name in sim.robots:
        sim.data.ctrl[sim.model.actuator(f"{name}/thruster1").id :][:8] = [
            0.3,
            -0.2,
            0.1,
            0.4,
            0.2,
            0.2,
            0.2,
            0.2,
        ]
    # bare: no callback and no gravity, so the robots float in place as they do with
    # buoyancy on; otherwise the bare run would pay for floor contacts after 0.5 s
    hydrodynamics.uninstall_callback()
    gravity = sim.model.opt.gravity.copy()
    sim.model.opt.gravity[:] = 0.0
    bare = steps_per_s(sim.model, sim.data, steps)
    sim.model.opt.gravity[:] = gravity
    sim.reset()
    hydrodynamics.install_callback()
    hydro = steps_per_s(sim.model, sim.data, steps)
    assert not sim.contacts(), "the robots touched something: the comparison would be unfair"
    return bare, hydro


def bench_control(n_robots: int, seconds: float = 20.0, flight_mode: str = "manual") -> tuple[float, float]:
    """Simulation.step (pilot command through the mixer and the T200 curve, optionally a flight mode on
    the estimated state) against bare mj_step for the same physics steps: (bare steps/s, ours)."""
    sim = Simulation(scenario(n_robots), flight_mode=flight_mode)
    sim.reset(seed=0)
    hydrodynamics.uninstall_callback()
    gravity = sim.model.opt.gravity.copy()
    sim.model.opt.gravity[:] = 0.0
    steps = round(seconds / sim.scenario.timestep_s)
    bare = steps_per_s(sim.model, sim.data, steps)
    sim.model.opt.gravity[:] = gravity
    hydrodynamics.install_callback()
    sim.reset(seed=0)
    commands = {name: {"surge": 0.3, "yaw": 0.1} for name in sim.robots}
    periods = round(seconds / sim.scenario.control_period_s)
    start = time.perf_counter()
    for _ in range(periods):
        sim.step(commands)
    ours = periods * sim.scenario.substeps / (time.perf_counter() - start)
    return bare, ours


def bench_render(pairs: int, rounds: int = 10) -> dict[str, float]:
    """Pairs/s of a bare mujoco.Renderer and of render_stereo without water, and with the water model
    on each backend (GL shader, CPU), plain and with noise and vignetting.

    The variants take turns in `rounds` blocks and each keeps its best block, so drift in the
    machine's speed hits all of them alike."""
    noisy = WaterModel(WaterParams(turbidity=0.3, noise_sigma=2.0, vignetting=0.2))
    sims = {backend: Simulation(scenario(1), water_backend=backend) for backend in ("cpu", "gl")}
    sim = sims["cpu"]
    cam = sim.camera
    renderer = mujoco.Renderer(sim.model, cam.height, cam.width)

    def bare() -> None:
        for side in ("left", "right"):
            # the cameras' own visual options (scene only), so that both draw the same picture
            renderer.update_scene(sim.data, camera=f"rov0/{side}", scene_option=CAMERA_SCENE_OPTION)
            renderer.render()

    def with_noise(backend: str) -> None:
        chosen = sims[backend]
        plain = chosen.water
        chosen.water = noisy
        chosen.render_stereo("rov0")
        chosen.water = plain

    variants = {
        "bare mujoco.Renderer": bare,
        "render_stereo, no water": lambda: sim.render_stereo("rov0", water=False),
    }
    for backend, chosen in sims.items():
        variants[f"render_stereo + water ({backend})"] = lambda chosen=chosen: chosen.render_stereo("rov0")
        variants[f"render_stereo + water, noise, vignetting ({backend})"] = lambda b=backend: with_noise(b)
    best = dict.fromkeys(variants, 0.0)
    for job in variants.values():
        job()  # warm up: creates the shared renderers and the GL water pass
    block = max(1, pairs // rounds)
    for _ in range(rounds):
        for name, job in variants.items():
            start = time.perf_counter()
            for _ in range(block):
                job()
            best[name] = max(best[name], block / (time.perf_counter() - start))
    renderer.close()
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=100, help="stereo pairs per variant (default 100)")
    parser.add_argument("--steps", type=int, default=20000, help="physics steps per measurement")
    args = parser.parse_args()
    print(
        f"MUJOCO_GL={os.environ['MUJOCO_GL']}, mujoco {mujoco.__version__}, hydrodynamics "
        f"{hydrodynamics.install_callback()}, GL renderer {gl_renderer_name()}"
    )
    print("\n| robots | bare mj_step steps/s | with hydrodynamics | ratio |\n|---|---|---|---|")
    for n in (1, 2, 4):
        bare, hydro = bench_physics(n, args.steps)
        print(f"| {n} | {bare:,.0f} | {hydro:,.0f} | {hydro / bare:.2f} |")
    print("\n| robots | flight mode | bare steps/s | Simulation.step, physics steps/s | ratio |")
    print("|---|---|---|---|---|")
    for n in (1, 2):
        for mode in ("manual", "stabilize"):
            bare, ours = bench_control(n, flight_mode=mode)
            print(f"| {n} | {mode} | {bare:,.0f} | {ours:,.0f} | {ours / bare:.2f} |")
    rates = bench_render(args.pairs)
    bare = rates["bare mujoco.Renderer"]
    print("\n| 640x400 stereo pairs | pairs/s | ratio to bare |\n|---|---|---|")
    for name, rate in rates.items():
        print(f"| {name} | {rate:.1f} | {rate / bare:.2f} |")


if __name__ == "__main__":
    main()
