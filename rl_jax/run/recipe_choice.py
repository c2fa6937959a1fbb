"""A run's ``--recipe NAME``: which of its learner's recipes a run starts from, and the settings
that recipe gives.

``--algo`` picks the learner and ``--recipe`` one of that learner's recipes, nothing else. The
scripts that fix their learner (``td3_cheetah.py``) once also took another built-in learner's
recipe, spelled ``LEARNER-RECIPE`` (``td3_cheetah.py --recipe td7-cpu``); the spellings that
recorded commands use keep working through ``RECIPE_ALIASES``, an explicit table, and every other
former spelling is one line saying what to type instead.
"""

from __future__ import annotations

from rl_jax.errors import UsageError
from rl_jax.run import learners
from rl_jax.run.learners import ALGORITHMS
from rl_jax.training.algorithm import Algorithm, Config, Hyperparams, hooks
from rl_jax.training.recipes import PLAIN, Recipe

#: ``--recipe`` spellings of another learner's recipe that a script of a fixed learner takes:
#: spelling -> (learner, its recipe). The run is then that learner's (``python
#: experiments/train.py --algo LEARNER --recipe RECIPE`` says the same directly).
RECIPE_ALIASES: dict[str, tuple[str, str]] = {
    "td7": ("td7", "default"),
    "td7-cpu": ("td7", "cpu"),
    "crossq": ("crossq", "default"),
    "crossq-cpu": ("crossq", "cpu"),
}


def script_recipe(algorithm: Algorithm, name: str | None) -> tuple[Algorithm, str | None]:
    """A fixed-learner script's ``--recipe NAME``: its own recipe, or through ``RECIPE_ALIASES``
    another learner's (the learner to run, and the recipe's name in that learner's table)."""
    if name is None or name not in RECIPE_ALIASES or name in _own_names(algorithm):
        return algorithm, name
    learner, recipe = RECIPE_ALIASES[name]
    if learner == algorithm.name:
        return algorithm, recipe
    return learners.resolve(learner), recipe


def resumed_learner(algorithm: Algorithm, recorded: str) -> Algorithm:
    """The learner a fixed-learner script resumes a built-in run of ``recorded`` with: the run's
    own where the script's ``RECIPE_ALIASES`` could have started it, else the script's (whose
    resume then says the run is another learner's)."""
    reachable = {learner for learner, _ in RECIPE_ALIASES.values()}
    if recorded != algorithm.name and recorded in reachable:
        return learners.resolve(recorded)
    return algorithm


def _own_names(algorithm: Algorithm) -> set[str]:
    return {recipe.name for recipe in hooks(algorithm).recipes.recipes}


def recipe_named(
    algorithm: Algorithm, env_id: str, name: str | None, resuming: bool = False
) -> Recipe:
    """Recipe ``name`` of ``algorithm`` for ``env_id`` (None: its ``"default"``). ``UsageError``
    for an unknown name, naming the learner whose recipe it is where it is another's, and with
    ``resuming`` (a resumed run keeps the settings it recorded)."""
    book = hooks(algorithm)
    if name is None:
        return book.recipe(env_id)
    if resuming:
        raise UsageError(
            "--recipe starts a new run; --resume continues a run with the settings it recorded"
        )
    try:
        return book.recipe(env_id, name)
    except KeyError:
        known = ", ".join(book.recipes.names(env_id))
        owner = _former_spellings().get(name)
        hint = ""
        if owner is not None and owner[0] != algorithm.name:
            hint = f" ({name} is {owner[0]}'s: --algo {owner[0]} --recipe {owner[1]})"
        raise UsageError(
            f"--recipe {name}: {algorithm.name} has no such recipe for {env_id}{hint}; "
            f"known: {known}"
        ) from None


def _former_spellings() -> dict[str, tuple[str, str]]:
    """Every ``LEARNER`` / ``LEARNER-RECIPE`` by which a script once named a built-in learner's
    recipe, looked up whole (for the line that says what to type instead)."""
    spellings = dict(RECIPE_ALIASES)
    for learner, where in ALGORITHMS.items():
        if not str(where).startswith("rl_jax."):
            continue
        for recipe in _own_names(learners.resolve(learner)):
            spelling = learner if recipe == "default" else f"{learner}-{recipe}"
            spellings.setdefault(spelling, (learner, recipe))
    return spellings


def other_learners_recipes(algorithm: Algorithm, env_id: str) -> str:
    """``--help``'s list of the other learners' recipes a fixed-learner script still takes
    (``RECIPE_ALIASES``)."""
    names = [name for name, (learner, _) in RECIPE_ALIASES.items() if learner != algorithm.name]
    names = [name for name in names if name not in _own_names(algorithm)]
    return (
        f". Other learners' recipes (the run is then theirs; --algo LEARNER --recipe NAME in "
        f"experiments/train.py says so directly): {', '.join(names)}"
        if names
        else ""
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
