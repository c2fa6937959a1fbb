"""A script's ``--recipe NAME``: which of its learner's recipes (or another built-in learner's,
for the same env) a run starts from, and the settings that recipe gives."""

from __future__ import annotations

import argparse

from rl_jax.errors import UsageError
from rl_jax.run import learners
from rl_jax.run.learners import ALGORITHMS
from rl_jax.training.algorithm import Algorithm, Config, Hyperparams, hooks
from rl_jax.training.recipes import PLAIN, Recipe


def _split_recipe(argv: list[str]) -> tuple[str | None, list[str]]:
    """``--recipe NAME`` taken out of ``argv``: ``(NAME or None, the rest)``."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--recipe", default=None)
    known, rest = pre.parse_known_args(argv)
    return known.recipe, rest


def take_recipe(argv: list[str], algorithm: Algorithm, env_id: str) -> tuple[Recipe, list[str]]:
    """``--recipe NAME`` of ``algorithm``'s recipes for ``env_id`` (else its ``"default"``),
    taken out of ``argv``. ``UsageError`` for an unknown name or with ``--resume`` (a resumed
    run keeps the settings it recorded)."""
    name, rest = _split_recipe(argv)
    book = hooks(algorithm)
    if name is None:
        return book.recipe(env_id), rest
    if any(arg == "--resume" or arg.startswith("--resume=") for arg in rest):
        raise UsageError(
            "--recipe starts a new run; --resume continues a run with the settings it recorded"
        )
    try:
        return book.recipe(env_id, name), rest
    except KeyError:
        names = ", ".join(book.recipes.names(env_id))
        learner, _, own = name.partition("-")
        hint = ""
        if learner in ALGORITHMS and learner != algorithm.name:
            hint = f" ({name} is {learner}'s: --algo {learner} --recipe {own or 'default'})"
        raise UsageError(
            f"--recipe {name}: {algorithm.name} has no such recipe for {env_id}{hint}; "
            f"known: {names}"
        ) from None


def learner_of_recipe(
    argv: list[str], algorithm: Algorithm, env_id: str
) -> tuple[Algorithm, list[str]]:
    """A script's ``--recipe NAME`` may name another built-in learner's recipe for its env:
    ``td7`` (that learner's default) or ``td7-cpu`` (its ``cpu``). ``(the learner to run, argv
    with the recipe's own name)``; the script's learner and ``argv`` where NAME is its own."""
    name, rest = _split_recipe(argv)
    if name is None or name in hooks(algorithm).recipes.names(env_id):
        return algorithm, argv
    learner, _, own = name.partition("-")
    if learner not in ALGORITHMS or learner == algorithm.name:
        return algorithm, argv
    other = learners.resolve(learner)
    return other, [*rest, "--recipe", own or "default"]


def other_learners_recipes(algorithm: Algorithm, env_id: str) -> str:
    """``--help``'s list of the other built-in learners' recipes written for ``env_id`` or for
    any env, by the names ``learner_of_recipe`` takes."""
    names = []
    for learner, where in ALGORITHMS.items():
        if learner == algorithm.name or not str(where).startswith("rl_jax."):
            continue
        book = hooks(learners.resolve(learner)).recipes
        for name in book.names(env_id) if any(r.is_for(env_id) for r in book) else ():
            names.append(learner if name == "default" else f"{learner}-{name}")
    return (
        f". Other learners' recipes (the run is then theirs): {', '.join(names)}" if names else ""
    )


def recipe_settings(
    algorithm: Algorithm, env_id: str, recipe: Recipe
) -> tuple[Config, Hyperparams]:
    """The algorithm's settings under ``recipe`` for ``env_id`` (a learner without recipes
    only ever has its defaults)."""
    named = {} if recipe is PLAIN else {"recipe": recipe.name}
    try:
        config = algorithm.default_config(env_id, **named)
        hparams = algorithm.default_hyperparams(env_id, **named)
    except (ValueError, TypeError, KeyError) as error:
        raise UsageError(f"{algorithm.name} cannot run {env_id}: {error}") from None
    return config, hparams
