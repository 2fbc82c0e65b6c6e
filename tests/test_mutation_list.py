"""The mutation list (tests/mutations/run_mutations.py, tables in tests/README.md) stays applicable: each
mutation's text is still in the file it names, in order, and every test a group runs still exists. A
mutation whose text the code has moved away from stops the runner and kills nothing, so the list must
follow the code."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _mutation_module():
    spec = importlib.util.spec_from_file_location("run_mutations", ROOT / "tests/mutations/run_mutations.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_mutation_still_finds_its_text():
    module = _mutation_module()
    stale = []
    for key, (_, edits) in module.MUTATIONS.items():
        texts: dict[str, str] = {}
        for name, old, new in edits:
            text = texts.get(name)
            if text is None:
                text = (ROOT / name).read_text()
            if old not in text:
                stale.append(f"{key} ({name})")
                break
            texts[name] = text.replace(old, new, 1)  # the runner applies a mutation's edits in turn
    assert not stale, f"mutations whose text is gone from the code: {', '.join(stale)}"


def test_every_group_has_tests_that_exist_and_every_mutation_a_group():
    module = _mutation_module()
    for key in module.MUTATIONS:
        assert key[0] in module.TESTS_OF_GROUP, f"{key} belongs to no group"
    for group, targets in module.TESTS_OF_GROUP.items():
        for target in targets:
            path, _, name = target.partition("::")
            assert (ROOT / path).is_file(), f"group {group}: no file {path}"
            if name:
                function = name.split("[")[0]
                source = (ROOT / path).read_text()
                defined = re.search(rf"^def {re.escape(function)}\(", source, re.M)
                assert defined, f"group {group}: no {target}"


def test_every_mutation_is_in_the_readme_tables():
    module = _mutation_module()
    readme = (ROOT / "tests/README.md").read_text()
    listed = set(re.findall(r"^\| ([A-Z]\d+) \|", readme, re.M))
    missing = sorted(set(module.MUTATIONS) - listed, key=lambda k: (k[0], int(k[1:])))
    assert not missing, f"mutations not in tests/README.md's tables: {', '.join(missing)}"
