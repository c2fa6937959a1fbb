"""scripts/count_any.py: the annotations of rl_jax/ that say Any, aliases of it included, and
the ceiling that count is held to."""

import importlib.util
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: Honest Any (every occurrence in an annotation, aliases resolved) may only go down.
CEILING = 120

spec = importlib.util.spec_from_file_location("count_any", ROOT / "scripts" / "count_any.py")
count_any = importlib.util.module_from_spec(spec)
spec.loader.exec_module(count_any)


def test_rl_jax_stays_under_the_ceiling():
    total = sum(counts["all"] for counts in count_any.count().values())
    assert total <= CEILING, f"{total} annotations in rl_jax/ say Any (at most {CEILING})"


def test_aliases_of_any_are_resolved_across_modules(tmp_path, monkeypatch):
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "types_.py").write_text(
        textwrap.dedent(
            """
            from typing import Any, TypeAlias
            from flax.typing import ArrayPytree
            State: TypeAlias = Any
            A = B = ArrayPytree
            Params = dict[str, int]
            """
        )
    )
    (package / "use.py").write_text(
        textwrap.dedent(
            """
            import typing
            from pkg.types_ import A, Params, State
            def f(x: State, y: dict[str, A], z: Params, w: "typing.Any | None") -> A: ...
            def g(x: int, y: list[object]) -> Params: ...
            """
        )
    )
    monkeypatch.setattr(count_any, "ROOT", tmp_path)
    counts = count_any.count(package)["pkg/use.py"]
    # State, A in dict[str, A], the quoted typing.Any and the return A; not Params or object
    assert (counts["all"], counts["bare"]) == (4, 3)
