"""Bad input to the command line ends with one line on stderr and exit status 2 (130 for Ctrl-C), never a
traceback or a hang: one table of cases, each run the way a user would type it."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from maptidal.cli import build_parser, main
from maptidal.files import save_mesh, save_tasks
from maptidal.synthetic import wall_keyframe_mesh

GOOD_TANK = "water_depth = 2.0\n[end_wall]\nwidth = 2.4\n"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Inputs the cases refer to by name: a mesh, a task list, tanks, scenarios, a file and a folder."""
    root = tmp_path_factory.mktemp("inputs")
    save_mesh(root / "frame.ply", *wall_keyframe_mesh(0.0, seed=1))
    save_tasks(root / "tasks.json", np.array([[-1.0, 0.0, 1.0, 1.0, 0.0, 0.0]]))
    (root / "wide_window.toml").write_text(GOOD_TANK + "[window]\nwidth = 5.0\n")
    (root / "empty.toml").write_text("")
    (root / "a_file").write_text("not a folder\n")
    (root / "a_folder").mkdir()
    (root / "folder.png").mkdir()
    robot = '[[robots]]\nname = "{name}"\nframe = "heavy"\nposition = [-1.5, 0.0, 1.0]\n'
    (root / "same_place.toml").write_text(robot.format(name="rov0") + robot.format(name="rov1"))
    mission = (Path(__file__).parents[1] / "assets" / "scenarios" / "mission.toml").read_text()
    (root / "period.toml").write_text(mission.replace("control_period_s = 0.02", "control_period_s = 0.005"))
    (root / "slow_period.toml").write_text(
        mission.replace("control_period_s = 0.02", "control_period_s = 5.0")
    )
    (root / "yaw.toml").write_text(mission.replace("yaw_deg = 0.0", "yaw_deg = 1e308", 1))
    before_mission = mission.split("[mission]")[0]
    (root / "fast_commands.toml").write_text(before_mission + "[mission]\ncommand_rate_hz = 1e9\n")
    (root / "fast_frames.toml").write_text(before_mission + "[mission]\nframe_rate_hz = 51\n")
    (root / "never_lost.toml").write_text(before_mission + "[mission]\nlost_after_s = -1.0\n")
    (root / "unsure.toml").write_text(before_mission + "[mission]\nlost_sigma_m = nan\n")
    (root / "give_up_half.toml").write_text(before_mission + "[mission]\nlost_give_up = 1.5\n")
    (root / "clear_never.toml").write_text(before_mission + "[mission]\nclear_after_s = -0.5\n")
    (root / "fast_current.toml").write_text(
        before_mission
        + '[mission]\n[[mission.events]]\ntime_s = 2\nkind = "current"\ncurrent = [1e6, 0, 0]\n'
    )
    return {"root": root} | {p.stem: p for p in root.iterdir()}


# (case, argv with {name} for the files above, what the error line must say)
CASES = [
    ("huge exclusion radius", "discover {frame} --r-ex 1e308", "r_ex must be at most 100 m"),
    ("huge frustum range", "discover {frame} --range 1e308", "range_m must be a distance"),
    ("nan standoff", "discover {frame} --standoff nan", "not a finite number"),
    ("huge standoff", "discover {frame} --standoff 1e6", "standoff must be at most 100 m"),
    ("--out is a folder", "discover {frame} --out {a_folder}", "is a folder"),
    ("--plot is a folder", "discover {frame} --plot {folder}", "is a folder"),
    ("--plot is a folder too", "discover {frame} --plot {a_folder}", "is a folder"),
    ("--plot x.jpgx", "discover {frame} --plot {root}/x.jpgx", "must end in .png"),
    ("output under a file", "discover {frame} --out {a_file}/tasks.json", "is a file, not a folder"),
    ("output folder is a file", "demo --out {a_file}", "is a file; give a folder"),
    ("compare --out is a file", "compare --out {a_file}", "is a file; give a folder"),
    ("unwritable output", "discover {frame} --out /proc/maptidal/tasks.json", "cannot"),
    ("render every 0", "sim --render-every 0 --duration 0.1", "must be at least 1"),
    ("render every -1", "sim --render-every -1 --duration 0.1", "must be at least 1"),
    ("negative duration", "sim --duration -1", "must be greater than 0"),
    ("endless duration", "sim --duration 1e300", "at most 1e+06 s"),
    ("tiny voxel", "coverage {tasks} --voxel 1e-3", "at most 1,000,000 are allowed"),
    ("tinier voxel", "coverage {tasks} --voxel 1e-4", "at most 1,000,000 are allowed"),
    ("huge far plane", "coverage {tasks} --far 1e308", "range_m must be a distance"),
    ("5 m window", "coverage {tasks} --tank {wide_window}", "does not fit in the 2.4 m end wall"),
    ("empty tank file", "coverage {tasks} --tank {empty}", "the tank config is empty"),
    ("robots on top of each other", "sim --scenario {same_place} --duration 0.1", "hulls overlapping"),
    ("command above 1", "sim --command surge=1.5 --duration 0.1", "outside [-1, 1]"),
    ("command below -1", "sim --command yaw=-2 --duration 0.1", "outside [-1, 1]"),
    ("axis twice", "sim --command surge=1,surge=-1 --duration 0.1", "given twice"),
    ("unknown axis", "sim --command warp=1 --duration 0.1", "unknown command axis"),
    ("sweep jobs 0", "sweep --jobs 0 --out {root}/sweep0", "must be at least 1"),
    ("endless mission", "run --duration 1e12 --out {root}/endless", "at most 86400 s"),
    ("control period of 2.5 steps", "run --scenario {period} --out {root}/p", "whole number of timesteps"),
    ("control period of 5 s", "run --scenario {slow_period} --out {root}/p", "must be in [timestep_s, 1] s"),
    (
        "yaw 1e308",
        "run --scenario {yaw} --out {root}/y",
        "yaw_deg must be a number of degrees in [-360, 360]",
    ),
    ("commands at 1e9 Hz", "run --scenario {fast_commands} --out {root}/c", "command_rate_hz = 1e+09 Hz"),
    ("lost after -1 s", "run --scenario {never_lost} --out {root}/n", "lost_after_s must be positive"),
    ("lost beyond nan", "run --scenario {unsure} --out {root}/u", "lost_sigma_m must be positive"),
    ("give up after 1.5 losses", "run --scenario {give_up_half} --out {root}/g", "lost_give_up must be"),
    ("clear after -0.5 s", "run --scenario {clear_never} --out {root}/cl", "clear_after_s must be"),
    (
        "frames at 51 Hz",
        "run --scenario {fast_frames} --out {root}/f",
        "faster than the control period allows",
    ),
    (
        "capture at 1e6 Hz",
        "capture --frame-rate 1e6 --out {root}/cap",
        "faster than the control period allows",
    ),
    ("voxel of 100 m", "compare --voxel 100 --out {root}/cmp", "at least 100 are needed"),
    ("voxel of 0.4 m", "coverage {tasks} --voxel 0.4", "at least 100 are needed"),
    ("a grid name twice", "sweep --grid t=0.7 t=0.8 --out {root}/sw", "t is given twice"),
    ("a current of 1e6 m/s", "run --scenario {fast_current} --out {root}/cur", "beyond 5 m/s"),
    ("unknown subcommand", "fly", "invalid choice"),
    ("missing mesh", "discover {root}/missing.ply", "not found"),
]


def _argv(template: str, files: dict[str, Path]) -> list[str]:
    return template.format(**{key: str(path) for key, path in files.items()}).split()


@pytest.mark.parametrize("case, template, message", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gets_one_line_and_exit_2(case, template, message, files, capsys):
    argv = _argv(template, files)
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert lines[0].startswith(f"maptidal {argv[0]}: error:") or "invalid choice" in message
    assert message in lines[0]
    assert "Traceback" not in captured.err


def test_bad_input_loses_no_earlier_output(files, tmp_path):
    # a failing run must not leave a half-written file or replace a good one
    out = tmp_path / "tasks.json"
    assert main(["discover", str(files["frame"]), "--out", str(out)]) == 0
    before = out.read_bytes()
    assert main(["discover", str(files["frame"]), "--out", str(out), "--r-ex", "1e308"]) == 2
    assert out.read_bytes() == before
    assert not list(tmp_path.glob(".*"))


def test_sweep_caps_its_processes_at_the_grid_and_lists_only_what_it_wrote(tmp_path, capsys):
    out = tmp_path / "sweep"
    argv = ["sweep", "--grid", "t=0.75", "r_ex=1.7", "theta_ex=0.25", "--jobs", "10000", "--no-plots"]
    assert main([*argv, "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "using 1 processes" in captured.err
    assert "sweep.png" not in captured.out and not (out / "sweep.png").exists()
    assert (out / "sweep.csv").exists()


def _run(argv: list[str], **popen) -> subprocess.Popen:
    environment = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.Popen(
        [sys.executable, "-m", "maptidal.cli", *argv],
        stderr=subprocess.PIPE,
        text=True,
        env=environment,
        **popen,
    )


def test_a_closed_output_pipe_is_one_line_not_a_traceback(files):
    process = _run(["discover", str(files["frame"]), "--json"], stdout=subprocess.PIPE)
    process.stdout.close()  # the reader is gone before a byte is written, as with `| head -c 0`
    _, err = process.communicate(timeout=60)
    assert process.returncode == 2
    assert "Traceback" not in err and "Exception ignored" not in err
    assert err.strip().splitlines() == [
        "maptidal discover: error: the output pipe was closed before all output was written"
    ]


@pytest.mark.parametrize(
    ("value", "message"),
    [("osmesa", "needs the OSMesa library"), ("vulkan", "is not a renderer MuJoCo knows")],
)
def test_a_gl_backend_that_cannot_work_is_one_line(value, message, monkeypatch, capsys):
    import ctypes.util

    real = ctypes.util.find_library
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: None if name == "OSMesa" else real(name))
    monkeypatch.setenv("MUJOCO_GL", value)
    assert main(["sim", "--duration", "0.1"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "MUJOCO_GL=egl, the default" in lines[0]


def test_ctrl_c_during_sim_exits_130_with_one_line():
    process = _run(["sim", "--duration", "3600"], stdout=subprocess.DEVNULL)
    # wait for the progress bar's first line: the simulation is running
    first = process.stderr.readline()
    assert first.startswith("sim ["), first
    time.sleep(0.3)
    process.send_signal(signal.SIGINT)
    rest = process.stderr.read()
    assert process.wait(timeout=60) == 130
    assert "Traceback" not in rest
    assert "maptidal sim: interrupted" in rest


def test_every_command_has_help(capsys):
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices
    assert set(commands) >= {
        "discover",
        "demo",
        "run",
        "report",
        "batch",
        "coverage",
        "compare",
        "sweep",
        "sim",
        "export-mjcf",
        "allocate",
    }
    for name in commands:
        with pytest.raises(SystemExit) as exit_info:
            main([name, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        assert text.startswith(f"usage: maptidal {name}") and "%%" not in text and "%(" not in text
    assert "what `make run` runs" not in commands["demo"].format_help()
    assert "`make run` runs this" in commands["run"].format_help()
    assert "`make run`" not in commands["compare"].format_help()


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out.strip() == f"maptidal {version('maptidal')}"


def test_sim_reports_every_robot_and_its_contacts(capsys):
    # the default robot faces the end wall 1.5 m away: full surge reaches it within 4 s
    assert main(["sim", "--command", "surge=1", "--duration", "4", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    contacts = result["robots"]["rov0"]["contacts"]
    assert contacts and contacts[0]["with"] == "tank" and contacts[0]["max_force_n"] > 0
    assert main(["sim", "--scenario", "two_robots", "--duration", "0.2", "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)["robots"]) == {"rov0", "rov1"}
