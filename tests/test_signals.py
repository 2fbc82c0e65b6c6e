"""Ctrl-C and SIGTERM at any moment (issue [signals]): from the first instruction, through the imports
(where trimesh's import guards used to swallow a Ctrl-C, and a half-made scipy raised a NameError), the
start of the perception worker and of a batch's worker processes, to the run itself. Every outcome is
one line on stderr (besides progress lines), status 130 for SIGINT and 143 for SIGTERM, no traceback
from the command or any child, and no process of the command's left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from maptidal.cli.interrupts import Interrupts, at_a_bad_moment

SCRIPT = Path(sys.executable).with_name("maptidal")


def _command(*args: str) -> list[str]:
    # the console script a user runs, where it is installed; else the same entry point through -m
    return [str(SCRIPT), *args] if SCRIPT.exists() else [sys.executable, "-m", "maptidal.cli", *args]


def _group_gone(pgid: int, within_s: float) -> bool:
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def _group_size(pgid: int) -> int:
    """How many live processes are in process group ``pgid`` (read from /proc)."""
    count = 0
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            count += fields[0] != "Z" and int(fields[2]) == pgid
    return count


def _signal_at(
    args: list[str], number: int, delay_s: float, after_processes: int = 0
) -> tuple[int, list[str], str, bool]:
    """Run the command in a session of its own, send ``number`` after ``delay_s`` (counted from the
    moment its group holds ``after_processes`` processes, when given: a slow machine imports slowly);
    its status, the stderr lines that are not progress lines, all of stderr, and whether every process
    of it has ended."""
    process = subprocess.Popen(
        _command(*args), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    deadline = time.monotonic() + 60.0
    while after_processes and _group_size(process.pid) < after_processes and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(delay_s)
    process.send_signal(number)
    _signal_at.sent_at = time.monotonic()  # for a test that times the way out
    try:
        _, err = process.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        _, err = process.communicate()
        return -1, ["<hung>"], err, False
    gone = _group_gone(process.pid, 10.0)
    if not gone:
        os.killpg(process.pid, signal.SIGKILL)
    lines = [line for line in err.splitlines() if line.strip() and " [" not in line.split(":")[0]]
    return process.returncode, lines, err, gone


# moments drawn once over 0 to 3 s (seeded, so that a failure can be repeated), the import's first
# second sampled densely: that is where the command used to lose the signal. The missions are given a
# 600 s cap, far more than they fly in 3 s on any machine, so that the signal never comes after the end
MOMENTS = sorted(
    np.random.default_rng(20261204).uniform([0.0] * 4 + [1.0] * 3, [1.0] * 4 + [3.0] * 3).round(2)
)


@pytest.mark.parametrize("delay_s", MOMENTS)
def test_ctrl_c_at_any_moment_of_a_mission_is_one_line_and_130(delay_s, tmp_path):
    status, lines, err, gone = _signal_at(
        ["run", "--duration", "600", "--out", str(tmp_path / "mission")], signal.SIGINT, delay_s
    )
    assert status == 130, err
    assert len(lines) == 1 and "interrupted" in lines[0], err
    assert "Traceback" not in err and "Error" not in err, err
    assert gone, "a process of the mission outlived it"


@pytest.mark.parametrize("delay_s", [0.4, 2.0])
def test_sigterm_on_a_mission_is_one_line_and_143(delay_s, tmp_path):
    status, lines, err, gone = _signal_at(
        ["run", "--duration", "600", "--out", str(tmp_path / "mission")], signal.SIGTERM, delay_s
    )
    assert status == 143, err
    assert len(lines) == 1 and "terminated (SIGTERM)" in lines[0], err
    assert "Traceback" not in err, err
    assert gone


# every long command besides run and batch, with arguments that keep it busy well past 3 s on a fast
# machine (each took 9 to 23 s unsignalled on one where the defaults ended in 1.4 to 4 s, before the
# signal came); the signal ends them all within 3 s, so the extra work costs nothing
FINE = ["--occlusion", "--voxel", "0.02", "--capture", "sweep"]
LONG_COMMANDS = {
    "compare": ["compare", "--no-write", "--json", "--keyframes", "rendered", *FINE],
    "sim": ["sim", "--duration", "3000", "--json"],
    "noise-curve": [
        "noise-curve",
        "--json",
        "--levels",
        "0,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9",
        *FINE,
        "--out",
        "{out}",
    ],
    "sweep": ["sweep", "--jobs", "2", "--no-plots", *FINE, "--out", "{out}"],
    "capture": ["capture", "--frame-rate", "20", "--out", "{out}"],
}
# two moments per command, drawn once (seeded): one in the imports and set-up (0.2 to 1 s), one in the
# work itself (2.5 to 3 s, before the quickest of them, compare, ends on a fast machine)
COMMAND_CASES = [
    (name, float(moment))
    for name, rng in zip(
        sorted(LONG_COMMANDS), np.random.default_rng(17).spawn(len(LONG_COMMANDS)), strict=True
    )
    for moment in (round(rng.uniform(0.2, 1.0), 2), round(rng.uniform(2.5, 3.0), 2))
]


@pytest.mark.parametrize(("name", "delay_s"), COMMAND_CASES)
def test_ctrl_c_on_every_long_command_is_one_line_and_130(name, delay_s, tmp_path):
    args = [arg.replace("{out}", str(tmp_path / "out")) for arg in LONG_COMMANDS[name]]
    status, lines, err, gone = _signal_at(args, signal.SIGINT, delay_s)
    assert status == 130, err
    assert len(lines) == 1 and "interrupted" in lines[0], err
    assert "Traceback" not in err and "Error" not in err, err
    assert gone, f"a process of {name} outlived it"


def test_ctrl_c_on_a_parallel_batch_stops_its_workers_at_once(tmp_path):
    # the batch's missions are long (120 s simulated each): waiting for them would take a minute or more.
    # The signal goes 1.5 s after both workers exist (the command and its two workers), whatever the
    # machine's speed: a fixed delay once landed in the imports of a slow machine, before any worker.
    status, lines, err, gone = _signal_at(
        ["batch", "--seeds", "1-2", "--duration", "120", "--jobs", "2", "--out", str(tmp_path / "batch")],
        signal.SIGINT,
        1.5,
        after_processes=3,
    )
    assert status == 130, err
    assert len(lines) == 1 and "maptidal batch: interrupted" in lines[0], err
    assert "Traceback" not in err, err
    assert gone, "a worker of the batch outlived it"
    assert time.monotonic() - _signal_at.sent_at < 30.0


def test_a_run_interrupted_in_the_loop_says_how_to_rebuild_its_report(tmp_path):
    out = tmp_path / "mission"
    process = subprocess.Popen(
        _command("run", "--duration", "60", "--out", str(out)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    first = process.stderr.readline()  # the progress bar's first line: the loop is running
    assert first.startswith("mission ["), first
    process.send_signal(signal.SIGINT)
    rest = process.stderr.read()
    assert process.wait(timeout=60) == 130
    assert f"`maptidal report {out}` rebuilds the report" in rest
    assert (out / "events.jsonl").exists()


def test_a_signal_during_an_import_waits_for_the_import_to_end():
    # the handler itself, in this process: a SIGINT that comes while a module is being imported is held
    # back until the import is over (a retry on SIGALRM), then raised once; a second is ignored
    import importlib
    import textwrap

    folder = Path(__import__("tempfile").mkdtemp())
    (folder / "slow_module_for_signals.py").write_text(
        textwrap.dedent(
            """
            import os, signal, time
            try:
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.1)  # the signal's handler has run by now
                REACHED_THE_END = True
            except BaseException:  # as trimesh's import guards do
                REACHED_THE_END = "swallowed"
            """
        )
    )
    sys.path.insert(0, str(folder))
    caught = False
    before = signal.getsignal(signal.SIGINT)  # not always Python's default in a pytest-xdist worker
    try:
        with Interrupts() as interrupts:
            try:
                module = importlib.import_module("slow_module_for_signals")
                time.sleep(0.5)  # the retry raises here, once the import is over
            except KeyboardInterrupt:
                caught = True
            os.kill(os.getpid(), signal.SIGINT)  # a second signal while winding down: ignored
            time.sleep(0.05)
    finally:
        sys.path.remove(str(folder))
        sys.modules.pop("slow_module_for_signals", None)
    assert module.REACHED_THE_END is True  # the import was not cut short
    assert caught and interrupts.received == signal.SIGINT and interrupts.status == 130
    assert signal.getsignal(signal.SIGINT) is before  # the handlers are put back


def test_a_signal_at_the_end_of_an_import_is_not_raised_again_while_the_line_is_printed():
    # the race CI met once: SIGINT in the last 20 ms of the imports, the import ends before the retry,
    # the command sees ``received`` and prints its line; the pending retry must not raise in the middle
    import importlib
    import textwrap

    folder = Path(__import__("tempfile").mkdtemp())
    (folder / "last_moment_module_for_signals.py").write_text(
        textwrap.dedent(
            """
            import os, signal
            os.kill(os.getpid(), signal.SIGINT)  # the handler runs here, inside the import: a retry is set
            """
        )
    )
    sys.path.insert(0, str(folder))
    before = signal.getsignal(signal.SIGINT)
    try:
        with Interrupts() as interrupts:
            importlib.import_module("last_moment_module_for_signals")  # ends well inside the 20 ms
            assert interrupts.received == signal.SIGINT
            line = interrupts.message("maptidal sweep")
            try:
                time.sleep(0.1)  # five retry periods: a pending retry would raise KeyboardInterrupt here
            except KeyboardInterrupt:
                pytest.fail("the retry raised KeyboardInterrupt after the command had printed its line")
    finally:
        sys.path.remove(str(folder))
        sys.modules.pop("last_moment_module_for_signals", None)
    assert line == "maptidal sweep: interrupted; files written so far are complete"
    assert signal.getsignal(signal.SIGINT) is before


def _main_in_process(argv: list[str], capsys) -> tuple[int, list[str]]:
    """``maptidal.cli.main(argv)`` in this process: its status and the lines it printed on stderr. A
    KeyboardInterrupt escaping it fails the test (rather than stopping pytest)."""
    import maptidal.cli as cli

    try:
        status = cli.main(argv)
    except KeyboardInterrupt:
        pytest.fail(f"a KeyboardInterrupt escaped maptidal.cli.main({argv})")
    return status, capsys.readouterr().err.strip().splitlines()


def test_a_retry_pending_when_the_command_imports_end_does_not_raise_while_it_names_the_command(
    monkeypatch, capsys
):
    # the race a clean-clone CI run met: SIGINT in the imports' last 20 ms, the imports end before the
    # retry, and the retry fired while `maptidal` was still working out the command's name for its line
    # (status -2 and a traceback). Here the signal is made to come at a bad moment, the imports then end
    # at once, and naming the command takes 100 ms, five retry periods
    import importlib

    import maptidal.cli as cli
    import maptidal.cli.interrupts as interrupts_module

    calls = []

    def bad_only_the_first_time(frame):
        calls.append(frame)
        return len(calls) == 1

    real_import = importlib.import_module
    real_import("maptidal.cli.app")  # imported already, so that the fake below is not called from inside it

    def importing_then_signalled(name):
        module = real_import(name)
        os.kill(os.getpid(), signal.SIGINT)
        (lambda: None)()  # a call: the handler runs here, at what it is told is a bad moment
        return module

    real_prefix = interrupts_module.prefix_from_argv

    def slow_prefix(argv):
        time.sleep(0.1)
        return real_prefix(argv)

    monkeypatch.setattr(interrupts_module, "at_a_bad_moment", bad_only_the_first_time)
    monkeypatch.setattr(cli.importlib, "import_module", importing_then_signalled)
    monkeypatch.setattr(cli, "prefix_from_argv", slow_prefix)
    status, lines = _main_in_process(["sweep", "--help"], capsys)
    assert len(calls) == 1  # the retry was cancelled, not merely caught
    assert status == 130 and lines == ["maptidal sweep: interrupted; files written so far are complete"]


def test_an_interrupt_before_the_command_has_its_own_handler_still_ends_in_one_line(monkeypatch, capsys):
    # a signal whose KeyboardInterrupt comes in the first instructions of app.main, before its try
    import maptidal.cli.app as app

    def interrupted_on_entry(argv, interrupts):
        interrupts._handle(signal.SIGTERM, None)  # what the signal handler does, at a safe moment
        raise AssertionError("not reached: the handler raises KeyboardInterrupt")

    monkeypatch.setattr(app, "main", interrupted_on_entry)
    status, lines = _main_in_process(["run", "--help"], capsys)
    assert status == 143
    assert lines == ["maptidal run: terminated (SIGTERM); files written so far are complete"]


def test_bad_moments_are_imports_and_starting_a_child():
    import inspect

    assert not at_a_bad_moment(inspect.currentframe())
    seen = {}

    class Probe:
        def __reduce__(self):  # pickled by multiprocessing's Popen while it starts the child
            seen["frame"] = at_a_bad_moment(inspect.currentframe())
            return (int, (0,))

    import multiprocessing

    context = multiprocessing.get_context("spawn")
    process = context.Process(target=int, args=(Probe(),))
    process.start()
    process.join(timeout=60)
    assert seen["frame"] is True


def test_an_interrupted_video_is_left_playable_and_the_report_says_it_was_cut_short(tmp_path):
    import cv2

    out = tmp_path / "mission"
    process = subprocess.Popen(
        _command("run", "--duration", "60", "--video", "--out", str(out)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    for _ in range(3):  # a few simulated seconds in: some frames of the video are written
        line = process.stderr.readline()
        assert line.startswith("mission ["), line
    process.send_signal(signal.SIGINT)
    rest = process.stderr.read()
    assert process.wait(timeout=60) == 130
    assert "Traceback" not in rest and "Exception ignored" not in rest, rest  # the renderer freed in time
    assert not (out / "mission.mp4").exists()
    video = cv2.VideoCapture(str(out / "mission.part.mp4"))
    frames = 0
    while video.read()[0]:
        frames += 1
    assert frames > 0
    rebuilt = subprocess.run(_command("report", str(out)), capture_output=True, text=True, timeout=120)
    assert rebuilt.returncode == 0, rebuilt.stderr
    assert "`mission.part.mp4`, cut short" in (out / "report.md").read_text()


@pytest.mark.parametrize("signalled", [True, False])
def test_a_signal_that_an_extension_turns_into_its_own_error_still_ends_as_interrupted(
    signalled, monkeypatch, capsys, tmp_path
):
    # pybind11 (MuJoCo's bindings, building the model) reports a KeyboardInterrupt raised while it
    # converts an argument as a TypeError of its own: a Ctrl-C there ended `maptidal run` as an internal
    # error (status 1) in a clean-clone run. Whatever error the interrupt comes out as, the command ends
    # with the interrupt's line and status; the same error without a signal is still an internal error
    import maptidal.cli.mission as mission_cli
    from maptidal.cli import main

    def converting(args):
        try:
            if signalled:
                os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)  # the signal's KeyboardInterrupt is raised here
        except KeyboardInterrupt:
            pass
        raise TypeError("(): incompatible function arguments")

    monkeypatch.setattr(mission_cli, "run_report", converting)
    status = main(["report", str(tmp_path)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    if signalled:
        assert status == 130 and "maptidal report: interrupted" in lines[0]
    else:
        assert status == 1 and "internal error: TypeError" in lines[0]
