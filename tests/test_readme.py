"""Every `maptidal` command the README shows runs verbatim, in order, from a fresh folder that has only
the bundled assets beside it (as a new user's checkout has)."""

import os
import re
import shlex
from pathlib import Path

import pytest

from maptidal.cli import main

ROOT = Path(__file__).resolve().parent.parent


def readme_commands() -> list[list[str]]:
    """The `maptidal ...` lines of the README's ```sh blocks, in order, without comments."""
    text = (ROOT / "README.md").read_text()
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            if words and words[0] == "maptidal":
                commands.append(words[1:])
    return commands


def test_readme_console_commands_parse():
    """The README's ```console blocks show commands that need something running (a vehicle): they are
    not run, but each `maptidal` line must parse."""
    from maptidal.cli import build_parser

    text = (ROOT / "README.md").read_text()
    lines = [
        shlex.split(line, comments=True)
        for block in re.findall(r"```console\n(.*?)```", text, flags=re.S)
        for line in block.splitlines()
    ]
    shown = [words[1:] for words in lines if words and words[0] == "maptidal"]
    assert shown, "no console commands found"
    for words in shown:
        build_parser().parse_args(words)


def test_readme_shows_the_main_commands():
    shown = {words[0] for words in readme_commands()}
    assert shown >= {"demo", "discover", "compare", "coverage", "sweep", "sim", "allocate", "export-mjcf"}


def test_readme_commands_run_verbatim(tmp_path, monkeypatch, capsys):
    (tmp_path / "assets").symlink_to(ROOT / "assets")
    monkeypatch.chdir(tmp_path)
    os.environ.setdefault("MUJOCO_GL", "egl")
    for words in readme_commands():
        status = main(words)
        captured = capsys.readouterr()
        if status != 0:
            pytest.fail(f"`maptidal {shlex.join(words)}` exited {status}: {captured.err.strip()}")
    assert (tmp_path / "runs" / "frame1.png").exists()
    assert list((tmp_path / "runs" / "frames").glob("rov0_*.png"))


def test_readme_controller_example_runs_to_capture():
    text = (ROOT / "README.md").read_text()
    (block,) = [
        b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "from maptidal.controllers" in b
    ]
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)
    assert scope["status"] == "capture"
