"""Every `maptidal` command the README and the docs pages show runs verbatim, in order, from a fresh folder
that has only the bundled assets beside it (as a new user's checkout has); the pages' links lead to
files that exist."""

import os
import re
import shlex
from pathlib import Path

import pytest

from maptidal.cli import main

ROOT = Path(__file__).resolve().parent.parent
# the README, then the docs pages in the order a reader meets them (a command may use an earlier one's output)
PAGES = [
    "README.md",
    "docs/discovery.md",
    "docs/evaluation.md",
    "docs/perception.md",
    "docs/simulation.md",
    "docs/controllers.md",
    "docs/gym.md",
    "docs/mission.md",
    "docs/mavlink.md",
    "docs/allocation.md",
]


def documentation() -> str:
    """The README and the docs pages, one after the other."""
    return "\n".join((ROOT / page).read_text() for page in PAGES)


def readme_commands() -> list[list[str]]:
    """The `maptidal ...` lines of the pages' ```sh blocks, in order, without comments."""
    text = documentation()
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

    text = documentation()
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
    text = documentation()
    (block,) = [
        b for b in re.findall(r"```python\n(.*?)```", text, flags=re.S) if "from maptidal.controllers" in b
    ]
    scope: dict = {}
    exec(compile(block, "docs/controllers.md", "exec"), scope)
    assert scope["status"] == "capture"


def test_every_docs_page_is_read_and_every_link_leads_somewhere():
    """Each page in docs/ is in PAGES (so its commands run), the README links to each, every relative
    link of the README and the pages (text or image) names a file that exists, and every link within a
    page names one of its headings."""
    import re

    pages = {f"docs/{path.name}" for path in (ROOT / "docs").glob("*.md")} - {"docs/references.md"}
    assert pages <= set(PAGES), pages - set(PAGES)
    readme = (ROOT / "README.md").read_text()
    for page in pages | {"docs/references.md"}:
        assert f"]({page})" in readme, page
    for page in [*PAGES, "docs/references.md"]:
        text = (ROOT / page).read_text()
        # a heading's anchor as GitHub makes it: lower case, punctuation dropped, spaces to hyphens
        anchors = {
            re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
            for heading in re.findall(r"^#+ (.+)$", text, flags=re.M)
        }
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if "://" in target:
                continue
            if target.startswith("#"):
                assert target[1:] in anchors, (page, target)
                continue
            assert (ROOT / page).parent.joinpath(target.split("#")[0]).exists(), (page, target)
