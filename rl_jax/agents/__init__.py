"""The learners, one module each: ``td3`` (TD3 and DDPG), ``td7``, ``crossq``, ``sac``, ``ppo``,
``recurrent_ppo``, ``dqn``, ``r2d2`` (recurrent DQN), ``pqn``, ``reinforce``, ``alphazero`` (Gumbel
search on pgx games) and ``muzero`` (Gumbel search on a learned model). A learner's module
holds the whole learner: its settings (``Config``, ``Hyperparams``), its networks built for a
config, its update, its recipes per env and the learner object. Beside it at most one
``<name>_parts`` module holds its pure maths and building blocks, tested value by value and free of
the learner's settings (it never imports its learner): ``td7_parts`` (LAP, SALE, value clipping,
TD7's state beside its networks), ``sac_parts`` (the soft target and losses), ``ppo_parts``
(advantages, losses and the actor-critic network), ``dqn_parts`` (the replay, uniform or
prioritized, flat or of frames), ``distributional_parts`` (the losses of ``distributional``, C51 and
QR-DQN), ``r2d2_parts`` (value rescaling, sequence targets and priorities, the sequence replay),
``reinforce_parts`` (the policy's outputs, sampling and the episodes it collects),
``alphazero_parts`` (self-play's targets and losses), ``muzero_parts`` (the categorical value
transform, n-step targets and the unrolled loss).

What several learners share: ``actor_critic`` (the deterministic actor-critics' settings, networks,
exploration and targets), ``common`` (the optimizer step, rate schedules, gradient clipping, target
steps) and pure maths (``q_learning``, ``policy_gradient``).

Modules folded into their learner's (``dqn_config``, ``ppo_recipes``, ...) are not importable;
importing one raises ``ModuleNotFoundError`` saying where its contents live now."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
from collections.abc import Sequence
from types import ModuleType

#: Modules folded into a learner's module or its parts: old name -> where the contents live now.
MOVED_MODULES: dict[str, tuple[str, ...]] = {
    f"{__name__}.{old}": tuple(f"{__name__}.{home}" for home in homes)
    for old, homes in {
        "dqn_config": ("dqn",),
        "dqn_recipes": ("dqn",),
        "dqn_replay": ("dqn_parts", "dqn"),
        "ppo_config": ("ppo",),
        "ppo_losses": ("ppo_parts",),
        "ppo_networks": ("ppo_parts", "ppo"),
        "ppo_recipes": ("ppo",),
        "reinforce_config": ("reinforce",),
        "reinforce_policy": ("reinforce_parts", "reinforce"),
        "reinforce_recipes": ("reinforce",),
        "td3_recipes": ("td3",),
        "td7_recipes": ("td7",),
    }.items()
}


def moved_message(name: str) -> str:
    """The one line that an import of the moved module ``name`` fails with."""
    return f"{name} is now part of {' and '.join(MOVED_MODULES[name])}: import from there"


class _MovedModuleFinder(importlib.abc.MetaPathFinder):
    """Fails the import of a moved module with ``moved_message`` instead of a bare "No module
    named" (the error's ``name`` is left unset: ``from rl_jax.agents import dqn_config`` would
    otherwise swallow the message into "cannot import name")."""

    def find_spec(
        self,
        fullname: str,
        path: Sequence[str] | None = None,
        target: ModuleType | None = None,
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname in MOVED_MODULES:
            raise ModuleNotFoundError(moved_message(fullname))
        return None


# First on the path, so that a stale copy of a moved file cannot be imported in its place.
if not any(type(finder).__qualname__ == "_MovedModuleFinder" for finder in sys.meta_path):
    sys.meta_path.insert(0, _MovedModuleFinder())
