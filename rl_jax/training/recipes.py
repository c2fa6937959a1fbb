"""Recipes: named, whole sets of settings of one learner for an env, defined once beside it.

A learner's settings come from three places, in this order: its ``Config`` and ``Hyperparams``
defaults, one recipe, and the flags (or keyword arguments) the user gives. A recipe is *whole*:
it is written out (by composing dicts in the learner's recipe module) rather than stacked on
another recipe at run time, so what a run used is one name.

Every learner has a ``Recipes`` table. For an env, ``"default"`` is the recipe a run gets
when it names none; the others are alternatives chosen with ``--recipe NAME`` or
``rl_jax.train(..., recipe=NAME)``. A recipe lists the envs it is written for; one with no envs
is for any env, and an env's own recipe of the same name takes its place there::

    RECIPES = Recipes(
        Recipe("default", "64x64 networks, 4 envs", config={...}, envs=("rl_jax/Pendulum-v1",)),
        Recipe("paper", "the paper's loop and networks", config={...}, hparams={...}),
    )
    RECIPES.get("rl_jax/Pendulum-v1")            # its "default"
    RECIPES.get("rl_jax/Hopper-v5", "paper")
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TypeAlias

DEFAULT = "default"

#: What a recipe sets a config field or a hyperparameter to.
Setting: TypeAlias = "bool | int | float | str | None | tuple[Setting, ...]"


@dataclasses.dataclass(frozen=True)
class Recipe:
    """One named set of settings: ``config`` and ``hparams`` override the learner's defaults."""

    name: str
    about: str  # one line, for --help and the docs
    config: Mapping[str, Setting] = dataclasses.field(default_factory=dict)
    hparams: Mapping[str, Setting] = dataclasses.field(default_factory=dict)
    envs: tuple[str, ...] = ()  # the envs it is written for; () any env
    total_steps: int | None = None  # a script's default budget (env steps per seed) under it
    # (env steps/s per seed, seeds) measured with it, for a run plan's time estimate
    throughput: tuple[float, int] | None = None

    def is_for(self, env_id: str) -> bool:
        """Whether the recipe applies to ``env_id`` (a recipe with no envs applies to all)."""
        return not self.envs or env_id in self.envs


#: The learner's own defaults, where it has no recipe of that name for an env.
PLAIN = Recipe(DEFAULT, "the learner's own defaults")


class Recipes:
    """A learner's recipes, looked up by env and name."""

    def __init__(self, *recipes: Recipe) -> None:
        seen = set()
        for recipe in recipes:
            for env_id in recipe.envs or (None,):
                if (recipe.name, env_id) in seen:
                    raise ValueError(f"recipe {recipe.name!r} defined twice for {env_id}")
                seen.add((recipe.name, env_id))
        self.recipes = recipes

    def get(self, env_id: str, name: str | None = None) -> Recipe:
        """Recipe ``name`` (None: ``"default"``) for ``env_id``: the env's own before one for
        any env; ``KeyError`` where there is neither (but ``"default"``: the plain defaults)."""
        name = name or DEFAULT
        matches = [r for r in self.recipes if r.name == name and r.is_for(env_id)]
        own = [r for r in matches if r.envs]
        if own or matches:
            return (own or matches)[0]
        if name == DEFAULT:
            return PLAIN
        raise KeyError(name)

    def names(self, env_id: str) -> dict[str, str]:
        """``{name: about}`` of every recipe for ``env_id``, ``"default"`` first."""
        names = {DEFAULT: self.get(env_id).about}
        for recipe in self.recipes:
            if recipe.is_for(env_id) and recipe.name not in names:
                names[recipe.name] = self.get(env_id, recipe.name).about
        return names

    def __iter__(self):
        return iter(self.recipes)
