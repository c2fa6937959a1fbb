"""The import rule of docs/layout.md, read from the source with ``ast`` (nothing is imported):
imports point one way, ``run`` -> ``agents`` -> ``training`` -> ``envs``; ``rl_jax.envs`` imports
nothing of ``rl_jax`` but itself; ``rl_jax/errors.py`` imports nothing of the package; and no
module imports one that imports it back. Every import counts: at the top of a module, inside a
function and under ``if TYPE_CHECKING:``."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "rl_jax"
ENVS = ROOT / "envs"  # the env package, rl_jax.envs (rl_jax/envs links here)

#: The layers from the top down: a module imports from its own layer and those below it. The
#: public face (``rl_jax/__init__.py``, ``rl_jax/__main__.py``) is the top.
LAYERS = ("rl_jax", "rl_jax.run", "rl_jax.agents", "rl_jax.training", "rl_jax.envs")
ERRORS = "rl_jax.errors"  # any layer but envs may import it


def module_files() -> dict[str, Path]:
    """Every module of the package by its dotted name, those of ``rl_jax.envs`` read from
    ``envs/`` (not through the link, which a checkout may lack)."""
    files: dict[str, Path] = {}
    for top, prefix in ((PACKAGE, ("rl_jax",)), (ENVS, ("rl_jax", "envs"))):
        for path in sorted(top.rglob("*.py")):
            relative = path.relative_to(top)
            if top == PACKAGE and relative.parts[0] == "envs":
                continue
            parts = prefix + relative.with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            files[".".join(parts)] = path
    return files


def _ours(name: str) -> bool:
    return name == "rl_jax" or name.startswith("rl_jax.")


def imported(node: ast.Import | ast.ImportFrom, module: str, package: bool, known: set[str]):
    """The modules of the package that one import statement of ``module`` loads by name:
    ``from rl_jax.run import processes`` is the module ``rl_jax.run.processes``, ``from
    rl_jax.run.plan import Plan`` the module ``rl_jax.run.plan``."""
    if isinstance(node, ast.Import):
        return {alias.name for alias in node.names if _ours(alias.name)}
    base = node.module or ""
    if node.level:  # relative: from the module's own package upwards
        parts = module.split(".") if package else module.split(".")[:-1]
        parts = parts[: len(parts) - node.level + 1]
        base = ".".join([*parts, base] if base else parts)
    if not _ours(base):
        return set()
    names = {f"{base}.{alias.name}" for alias in node.names}
    submodules = names & known
    return submodules if submodules == names else submodules | {base}


@functools.cache
def import_statements() -> dict[str, list[ast.Import | ast.ImportFrom]]:
    """Module -> every import statement in its file: functions and TYPE_CHECKING blocks too."""
    statements = {}
    for module, path in module_files().items():
        tree = ast.parse(path.read_text(), filename=str(path))
        nodes = ast.walk(tree)
        statements[module] = [
            node for node in nodes if isinstance(node, ast.Import | ast.ImportFrom)
        ]
    return statements


@functools.cache
def import_graph() -> dict[str, frozenset[str]]:
    """Module -> the package's modules it imports anywhere in its file."""
    files = module_files()
    known = set(files)
    graph = {}
    for module, nodes in import_statements().items():
        package = files[module].name == "__init__.py"
        targets = set().union(*(imported(node, module, package, known) for node in nodes))
        graph[module] = frozenset(targets - {module})
    return graph


def layer(module: str) -> str:
    return max(
        (name for name in LAYERS if module == name or module.startswith(name + ".")), key=len
    )


def cycles(graph: dict[str, frozenset[str]]) -> list[list[str]]:
    """The groups of modules that import each other, directly or round a loop: the strongly
    connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = stack[stack.index(node) :]
            del stack[stack.index(node) :]
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def upward_imports(graph: dict[str, frozenset[str]]) -> list[str]:
    """``module -> target`` for every import the layer rule forbids."""
    wrong = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            if layer(module) == "rl_jax.envs":
                allowed = layer(target) == "rl_jax.envs"
            elif module == ERRORS:
                allowed = False
            elif target in (ERRORS, "rl_jax"):
                # The root's __init__ imports nothing at load time (its names load lazily)
                # and is loaded before any of its modules: reading rl_jax.__version__ is free.
                allowed = True
            else:
                allowed = LAYERS.index(layer(target)) >= LAYERS.index(layer(module))
            if not allowed:
                wrong.append(f"{module} -> {target}")
    return wrong


def test_the_scan_reads_every_layer_and_every_kind_of_import():
    graph = import_graph()
    assert {layer(module) for module in graph} == set(LAYERS)
    assert {"rl_jax.errors", "rl_jax.envs", "rl_jax.envs.core.registry"} <= set(graph)
    # a function-level import (the `rl-jax` command loads the CLI on use) and one under
    # TYPE_CHECKING (sweep's RunSpec) are edges like any other
    assert "rl_jax.run.cli" in graph["rl_jax.__main__"]
    assert "rl_jax.run.spec" in graph["rl_jax.run.sweep"]


def test_cycles_and_upward_imports_are_found():
    graph = {"a.x": frozenset({"a.y"}), "a.y": frozenset({"a.z"}), "a.z": frozenset({"a.x"})}
    assert cycles({**graph, "a.w": frozenset({"a.x"})}) == [["a.x", "a.y", "a.z"]]
    assert cycles({"a.x": frozenset({"a.y"}), "a.y": frozenset()}) == []
    wrong = {
        "rl_jax.training.t": frozenset({"rl_jax.run.r", ERRORS}),
        "rl_jax.envs.e": frozenset({ERRORS}),
        ERRORS: frozenset({"rl_jax.envs.e"}),
        "rl_jax.agents.a": frozenset({"rl_jax.training.t", "rl_jax.agents.b", "rl_jax"}),
    }
    assert upward_imports(wrong) == [
        "rl_jax.envs.e -> rl_jax.errors",
        "rl_jax.errors -> rl_jax.envs.e",
        "rl_jax.training.t -> rl_jax.run.r",
    ]


def test_no_module_imports_one_that_imports_it_back():
    assert cycles(import_graph()) == []


def test_imports_point_down_the_layers():
    assert upward_imports(import_graph()) == []


def test_envs_core_builds_on_nothing_of_adapters_or_mujoco():
    graph = import_graph()
    wrong = [
        f"{module} -> {target}"
        for module, targets in sorted(graph.items())
        if module.startswith("rl_jax.envs.core")
        for target in sorted(targets)
        if target.startswith(("rl_jax.envs.adapters", "rl_jax.envs.mujoco"))
    ]
    assert wrong == []


def test_the_env_package_is_always_spelt_rl_jax_envs():
    def bare(node: ast.Import | ast.ImportFrom) -> bool:
        if isinstance(node, ast.ImportFrom):
            names = [node.module or ""] if node.level == 0 else []
        else:
            names = [alias.name for alias in node.names]
        return any(name == "envs" or name.startswith("envs.") for name in names)

    statements = import_statements()
    assert [module for module, nodes in sorted(statements.items()) if any(map(bare, nodes))] == []


def test_errors_imports_nothing_of_the_package_and_the_root_nothing_at_load():
    graph = import_graph()
    assert graph[ERRORS] == frozenset()
    assert graph["rl_jax"] == frozenset()
