"""The dependency rules of the source tree (README, Layout), read from every module's import statements:

- everything installs under one namespace, ``maptidal``: nothing imports a top-level ``envs`` or
  ``controllers``;
- ``controllers/`` imports nothing of ours but itself, so it lifts out whole onto a real vehicle;
- ``envs/`` may import the controllers and maptidal's pure modules, never the mission loop or the CLI;
- only ``maptidal/mission/`` and ``maptidal/cli/`` import the simulator (``maptidal.envs``, MuJoCo);
- the algorithm modules (discovery, perception, allocation, comms, coverage, geometry) import only
  numpy, scipy, trimesh and OpenCV beyond the standard library, so they run on real recordings (a
  plot may import matplotlib inside the function that draws it).
"""

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
INSTALLED_AS = {"maptidal": "maptidal", "envs": "maptidal.envs", "controllers": "maptidal.controllers"}
ALGORITHMS = (
    "discovery",
    "map_discovery",
    "exploration",
    "perception",
    "allocation",
    "comms",
    "evaluation.coverage",
    "geometry",
)
ALGORITHM_THIRD_PARTY = {"numpy", "scipy", "trimesh", "cv2"}


def module_name(path: Path) -> str:
    """The installed dotted name of a source file (``envs/world.py`` is ``maptidal.envs.world``)."""
    top, *rest = path.relative_to(ROOT).with_suffix("").parts
    parts = [INSTALLED_AS[top], *rest]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(path: Path, *, in_functions: bool = True) -> set[str]:
    """Every absolute module name a file imports, relative imports resolved against its package;
    with ``in_functions=False`` only those its import runs (not the lazy ones inside functions)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    tree = ast.parse(path.read_text(), filename=str(path))
    if not in_functions:
        for function in [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]:
            function.body = []
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                stem = ".".join([*base, node.module] if node.module else base)
            else:
                stem = node.module or ""
            found.add(stem)
            # `from pkg import module` imports a module too
            found.update(f"{stem}.{alias.name}" for alias in node.names)
    return found


def sources(top: str) -> list[Path]:
    """The Python files of one top-level folder of the source tree."""
    return sorted((ROOT / top).rglob("*.py"))


def under(name: str, prefix: str) -> bool:
    """Whether ``name`` is the module ``prefix`` or inside it."""
    return name == prefix or name.startswith(prefix + ".")


def test_module_names_resolve_relative_imports():
    """The reader itself, on a file written here, so the rules below read what they claim to."""
    assert module_name(ROOT / "envs" / "gym" / "core.py") == "maptidal.envs.gym.core"
    assert module_name(ROOT / "controllers" / "__init__.py") == "maptidal.controllers"
    assert "maptidal.controllers.convention" in imports_of(ROOT / "controllers" / "mixing.py")


@pytest.mark.parametrize("top", sorted(INSTALLED_AS))
def test_nothing_imports_a_generic_top_level_name(top):
    for path in sources(top):
        generic = {name for name in imports_of(path) if name.split(".")[0] in ("envs", "controllers")}
        assert not generic, f"{path.relative_to(ROOT)} imports {sorted(generic)}: use maptidal.envs / ..."


def offending_imports(top: str, banned) -> dict[str, list[str]]:
    """Each file of ``top`` that imports a module ``banned(name)`` holds true for, with those modules."""
    found = {}
    for path in sources(top):
        names = sorted(name for name in imports_of(path) if banned(name))
        if names:
            found[str(path.relative_to(ROOT))] = names
    return found


def test_controllers_import_nothing_of_ours_but_themselves():
    assert not offending_imports(
        "controllers", lambda name: under(name, "maptidal") and not under(name, "maptidal.controllers")
    )


def test_the_simulator_never_imports_the_mission_loop_or_the_cli():
    assert not offending_imports(
        "envs", lambda name: under(name, "maptidal.mission") or under(name, "maptidal.cli")
    )


def test_only_the_mission_loop_and_the_cli_import_the_simulator():
    for path in sources("maptidal"):
        if module_name(path).startswith(("maptidal.mission", "maptidal.cli")):
            continue
        simulator = {
            name
            for name in imports_of(path)
            if under(name, "maptidal.envs") or under(name, "maptidal.mission") or under(name, "mujoco")
        }
        assert not simulator, f"{path.relative_to(ROOT)} imports {sorted(simulator)}"


def test_the_algorithm_modules_need_only_numpy_scipy_trimesh_and_opencv():
    paths = [
        path
        for path in sources("maptidal")
        if any(
            module_name(path) == f"maptidal.{a}" or under(module_name(path), f"maptidal.{a}")
            for a in ALGORITHMS
        )
    ]
    assert len(paths) >= len(ALGORITHMS)
    for path in paths:
        third_party = {
            name.split(".")[0]
            for name in imports_of(path, in_functions=False)
            if name.split(".")[0] not in sys.stdlib_module_names
            and name.split(".")[0] not in ("maptidal", "")
        }
        assert third_party <= ALGORITHM_THIRD_PARTY, f"{path.relative_to(ROOT)} needs {sorted(third_party)}"


def _import_graph() -> dict[str, set[str]]:
    """Module to the modules of ours it imports, lazy and TYPE_CHECKING imports included (a package's
    ``__init__`` is left out: importing a submodule runs it, which is no dependency of the submodule)."""
    files = [path for top in INSTALLED_AS for path in sources(top) if path.name != "__init__.py"]
    names = {module_name(path) for path in files}
    graph = {}
    for path in files:
        name = module_name(path)
        graph[name] = {m for m in imports_of(path) if m in names} - {name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Every strongly connected group of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for other in sorted(graph.get(node, ())):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in on_stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return groups


def test_the_cycle_finder_finds_a_cycle_built_by_hand():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_two_modules_import_each_other_even_lazily():
    """A circle of imports (discovery and files, the mission loop and its video once) means two modules
    that cannot be understood, tested or moved apart; a lazy import only hides it."""
    assert _cycles(_import_graph()) == []
