"""The settings of a recipe by learner and name, as ``tests/agents/test_learner_records.py`` reads
them: TD7's and CrossQ's recipes are TD3's options here, until they are learners of their own."""

from __future__ import annotations

from typing import Any

from rl_jax.agents import td3 as td3_module
from rl_jax.run.cli import resolve_algorithm

CROSSQ_CPU = {
    **td3_module.FAST_CHEETAH_CONFIG,
    "critic_norm": "batch_renorm",
    "target_networks": False,
    "policy_delay": 3,
    "adam_b1": 0.5,
}


def settings(learner: str, env_id: str, recipe: str | None) -> tuple[Any, dict, dict]:
    """``(algorithm, config overrides, hyperparameter overrides)`` of ``learner``'s ``recipe``
    (None: the env's own)."""
    if learner == "td7":
        chosen = td3_module.td3.recipe(env_id, {"cpu": "td7-cpu", None: "td7"}[recipe])
        return td3_module.td3, dict(chosen.config), dict(chosen.hparams)
    if learner == "crossq":
        return td3_module.td3, dict(CROSSQ_CPU), dict(td3_module.FAST_CHEETAH_HPARAMS)
    return resolve_algorithm(learner), {}, {}
