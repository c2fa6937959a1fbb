"""Count the annotations in rl_jax/ that say ``Any``, aliases of ``Any`` included.

``grep ": Any"`` misses ``Any`` inside ``dict[str, Any]`` and every alias of it
(``flax.typing.ArrayPytree``, a module's own ``X: TypeAlias = Any``). This script reads each
module with ``ast`` and counts every name in an annotation (a parameter, a return, a variable
or field, the right side of a ``TypeAlias``) that resolves to ``typing.Any``:

* ``Any`` itself (``from typing import Any``, ``typing.Any``);
* a name imported from a module outside rl_jax whose object *is* ``typing.Any``
  (found by importing that module: ``flax.typing.ArrayPytree`` is one);
* a name a module of rl_jax binds to one of the above at module level (``X = Any``,
  ``X: TypeAlias = Any``), and any import of such a name from that module.

Two numbers: ``bare``, the annotations that are Any or an alias of it alone (``x: Any``,
``-> ArrayPytree``, ``x: Any | None``), and ``all``, every occurrence (``dict[str, Any]`` counts
one too). Each occurrence once, per file with ``-v``:

    python scripts/count_any.py            # totals
    python scripts/count_any.py -v         # per file, and the aliases found
    python scripts/count_any.py --max 120  # exit 1 if ``all`` is above 120
"""

from __future__ import annotations

import argparse
import ast
import importlib
import sys
import typing
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "rl_jax"


def module_name(path: Path) -> str:
    """``rl_jax/training/replay.py`` -> ``rl_jax.training.replay``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def external_is_any(module: str, name: str) -> bool:
    """Whether ``module.name`` (a module outside rl_jax) is ``typing.Any``."""
    if module == "typing" or module == "typing_extensions":
        return name == "Any"
    try:
        return getattr(importlib.import_module(module), name, None) is typing.Any
    except Exception:  # a module that does not import here says nothing about Any
        return False


def resolve_from(module: str, node: ast.ImportFrom) -> str:
    """The absolute module name of ``from ... import`` in ``module`` (relative imports too)."""
    if not node.level:
        return node.module or ""
    base = module.split(".")[: -node.level] if node.level else []
    return ".".join([*base, node.module] if node.module else base)


class Module:
    """One parsed file: its imports and its module-level aliases."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.name = module_name(path)
        self.tree = ast.parse(path.read_text(), filename=str(path))
        self.imports: dict[str, tuple[str, str]] = {}  # local name -> (module, name)
        self.module_aliases: dict[str, str] = {}  # local name -> module (``import typing as t``)
        self.assigned: dict[str, ast.expr] = {}  # module-level ``X = value``
        for node in ast.walk(self.tree):
            if isinstance(node, ast.ImportFrom):
                source = resolve_from(self.name, node)
                for alias in node.names:
                    self.imports[alias.asname or alias.name] = (source, alias.name)
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    self.module_aliases[alias.asname or alias.name] = alias.name
        for node in self.tree.body:
            if isinstance(node, ast.Assign):  # ``X = Y = value`` binds both
                for target in node.targets:
                    if isinstance(target, ast.Name):
                        self.assigned[target.id] = node.value
            elif (
                isinstance(node, ast.AnnAssign)
                and node.value is not None
                and isinstance(node.target, ast.Name)
                and is_type_alias(node.annotation)
            ):
                self.assigned[node.target.id] = node.value


def is_type_alias(annotation: ast.expr) -> bool:
    """Whether an annotation is ``TypeAlias`` (``typing.TypeAlias`` too)."""
    return (isinstance(annotation, ast.Name) and annotation.id == "TypeAlias") or (
        isinstance(annotation, ast.Attribute) and annotation.attr == "TypeAlias"
    )


Seen = frozenset[tuple[str, str]]


class Resolver:
    """Which names of which module mean ``Any``."""

    def __init__(self, modules: dict[str, Module]) -> None:
        self.modules = modules
        self.cache: dict[tuple[str, str], bool] = {}

    def name_is_any(self, module: str, name: str, seen: Seen = frozenset()) -> bool:
        """Whether ``name`` as bound in ``module`` is ``Any`` or an alias of it."""
        key = (module, name)
        if key in self.cache:
            return self.cache[key]
        if key in seen:
            return False
        seen = seen | {key}
        mod = self.modules.get(module)
        if mod is None:  # outside rl_jax
            result = external_is_any(module, name)
        elif name in mod.assigned:
            result = self.expr_is_any(mod, mod.assigned[name], seen)
        elif name in mod.imports:
            result = self.name_is_any(*mod.imports[name], seen)
        else:
            result = False
        self.cache[key] = result
        return result

    def expr_is_any(self, mod: Module, node: ast.expr, seen: Seen = frozenset()) -> bool:
        """Whether an expression (a name or ``module.name``) in ``mod`` is ``Any`` itself."""
        if isinstance(node, ast.Name):
            return self.name_is_any(mod.name, node.id, seen)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            owner = node.value.id
            if owner in mod.module_aliases:
                return self.name_is_any(mod.module_aliases[owner], node.attr, seen)
            if owner in mod.imports:  # ``from flax import typing as ft`` then ``ft.ArrayPytree``
                source, name = mod.imports[owner]
                return self.name_is_any(f"{source}.{name}", node.attr, seen)
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            try:
                parsed = ast.parse(node.value, mode="eval").body
            except SyntaxError:
                return False
            return self.expr_is_any(mod, parsed, seen)
        return False

    def is_bare(self, mod: Module, annotation: ast.expr) -> bool:
        """Whether ``annotation`` is Any alone, or ``Any | None``."""
        if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
            try:
                annotation = ast.parse(annotation.value, mode="eval").body
            except SyntaxError:
                return False
        if isinstance(annotation, ast.BinOp) and isinstance(annotation.op, ast.BitOr):
            sides = [annotation.left, annotation.right]
            if any(isinstance(side, ast.Constant) and side.value is None for side in sides):
                return any(self.expr_is_any(mod, side) for side in sides)
        return self.expr_is_any(mod, annotation)

    def occurrences(self, mod: Module, annotation: ast.expr) -> int:
        """How many names in ``annotation`` mean ``Any`` (string annotations parsed)."""
        if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
            try:
                annotation = ast.parse(annotation.value, mode="eval").body
            except SyntaxError:
                return 0
        count = 0
        for node in ast.walk(annotation):
            if isinstance(node, (ast.Name, ast.Attribute)) and self.expr_is_any(mod, node):
                count += 1
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                count += self.occurrences(mod, node)
        return count


def annotations(tree: ast.Module) -> typing.Iterator[ast.expr]:
    """Every annotation of a module: parameters, returns, variables and fields, and the right
    side of ``X: TypeAlias = ...``."""
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            args = node.args
            for arg in [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]:
                if arg is not None and arg.annotation is not None:
                    yield arg.annotation
            if not isinstance(node, ast.Lambda) and node.returns is not None:
                yield node.returns
        elif isinstance(node, ast.AnnAssign):
            if is_type_alias(node.annotation):
                if node.value is not None:
                    yield node.value
            else:
                yield node.annotation


def count(root: Path = ROOT / PACKAGE) -> dict[str, Counter[str]]:
    """Per file (relative path): ``{"bare": n, "all": n}``."""
    modules = {m.name: m for m in (Module(p) for p in sorted(root.rglob("*.py")))}
    resolver = Resolver(modules)
    result: dict[str, Counter[str]] = {}
    for mod in modules.values():
        counts: Counter[str] = Counter()
        for annotation in annotations(mod.tree):
            n = resolver.occurrences(mod, annotation)
            counts["all"] += n
            counts["bare"] += int(resolver.is_bare(mod, annotation))
        result[str(mod.path.relative_to(ROOT))] = counts
    return result


def aliases(root: Path = ROOT / PACKAGE) -> list[str]:
    """``module.name`` of each alias of Any bound or imported in rl_jax (not ``Any`` itself)."""
    modules = {m.name: m for m in (Module(p) for p in sorted(root.rglob("*.py")))}
    resolver = Resolver(modules)
    found = set()
    for mod in modules.values():
        for name in [*mod.imports, *mod.assigned]:
            if name != "Any" and resolver.name_is_any(mod.name, name):
                found.add(f"{mod.name}.{name}")
    return sorted(found)


def main() -> None:
    """Print the counts (per file with -v); exit 1 above --max."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="per file, and the aliases")
    parser.add_argument("--max", type=int, help="exit 1 if the total of `all` is above this")
    args = parser.parse_args()
    per_file = count()
    total: Counter[str] = sum(per_file.values(), Counter())
    if args.verbose:
        for path, counts in sorted(per_file.items(), key=lambda item: -item[1]["all"]):
            if counts["all"]:
                print(f"{counts['all']:4d} {counts['bare']:4d}  {path}")
        print("aliases of Any:", ", ".join(aliases()) or "none")
    print(f"Any in annotations of {PACKAGE}/: all {total['all']}, bare {total['bare']}")
    if args.max is not None and total["all"] > args.max:
        sys.exit(f"{total['all']} annotations say Any, more than {args.max}")


if __name__ == "__main__":
    main()
