"""An experiment script's defaults, declared once: ``Script(td3, env_id, seeds=...)``, its
``main(__doc__)`` runs ``rl_jax.run.cli.main`` with them, and ``recipes`` offer named
alternatives to them (``--recipe NAME``)."""

from __future__ import annotations

import dataclasses
import sys
from typing import Any, NamedTuple, NoReturn

from rl_jax.errors import UsageError, exit_now
from rl_jax.run import cli
from rl_jax.run.flags import take_recipe


class Recipe(NamedTuple):
    """Another set of defaults a script offers as ``--recipe NAME``: overrides of the algorithm's
    env recipe in place of the script's own, and their measured throughput."""

    about: str  # one line for --help
    config: dict[str, Any] = {}
    hparams: dict[str, Any] = {}
    throughput: tuple[float, int] | None = None
    total_steps: int | None = None  # in place of the script's default budget


@dataclasses.dataclass(frozen=True)
class Script:
    """An experiment script's defaults, declared once and run by ``main``::

        SCRIPT = Script(td3, "rl_jax/Pendulum-v1", seeds=5, total_steps=20_000)
        if __name__ == "__main__":
            SCRIPT.main(__doc__)

    ``config``/``hparams`` override the algorithm's recipe for the env; ``throughput`` is
    (env steps/s per seed, seeds) measured with these defaults, for the plan's time estimate.
    ``recipes`` name alternatives to them, chosen with ``--recipe NAME``. Another script can
    derive its own with ``dataclasses.replace``.
    """

    algorithm: Any
    env_id: str
    seeds: int = 1
    total_steps: int = 100_000
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    hparams: dict[str, Any] = dataclasses.field(default_factory=dict)
    throughput: tuple[float, int] | None = None
    recipes: dict[str, Recipe] = dataclasses.field(default_factory=dict)

    def main(self, description: str | None, argv: list[str] | None = None) -> NoReturn:
        argv = list(sys.argv[1:] if argv is None else argv)
        typed = list(argv)  # recorded as the run's command, --recipe included
        script = self
        if self.recipes:
            lines = [f"  {name}: {recipe.about}" for name, recipe in self._choices().items()]
            description = "\n".join(
                [description or "", "--recipe NAME (default: default):", *lines]
            )
            try:
                script, argv = self.with_recipe(argv)
            except UsageError as error:
                print(f"error: {error}", file=sys.stderr)
                exit_now(2)
        cli.main(
            script.algorithm,
            script.env_id,
            description,
            seeds=script.seeds,
            total_steps=script.total_steps,
            config=script.config,
            hparams=script.hparams,
            argv=argv,
            throughput=script.throughput,
            named_recipes=not self.recipes,
            typed_argv=typed,
        )

    def _choices(self) -> dict[str, Recipe]:
        return {"default": Recipe("this script's defaults"), **self.recipes}

    def with_recipe(self, argv: list[str]) -> tuple[Script, list[str]]:
        """This script with the defaults of ``--recipe NAME`` (if given), and the other flags;
        ``UsageError`` for an unknown name."""
        name, rest = take_recipe(argv, self._choices(), "default")
        if name == "default":
            return self, rest
        chosen = self.recipes[name]
        total_steps = chosen.total_steps or self.total_steps
        return dataclasses.replace(
            self,
            config=chosen.config,
            hparams=chosen.hparams,
            throughput=chosen.throughput,
            total_steps=total_steps,
        ), rest
