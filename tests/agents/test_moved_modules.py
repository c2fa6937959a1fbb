"""The modules folded into a learner's module (``dqn_config`` into ``dqn``, ...) fail to import
with one line saying where their contents live now, however they are imported."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

import rl_jax.agents
from rl_jax.agents import MOVED_MODULES

AGENTS = Path(rl_jax.agents.__file__).parent


def test_every_moved_module_names_its_new_home():
    assert set(MOVED_MODULES) == {
        f"rl_jax.agents.{name}"
        for name in [
            "dqn_config",
            "dqn_recipes",
            "dqn_replay",
            "ppo_config",
            "ppo_losses",
            "ppo_networks",
            "ppo_recipes",
            "reinforce_config",
            "reinforce_policy",
            "reinforce_recipes",
            "td3_recipes",
            "td7_recipes",
        ]
    }
    for old, homes in MOVED_MODULES.items():
        assert not (AGENTS / f"{old.rpartition('.')[2]}.py").exists()
        for home in homes:
            importlib.import_module(home)  # the new home exists and imports
        with pytest.raises(ModuleNotFoundError) as raised:
            importlib.import_module(old)
        assert str(raised.value) == f"{old} is now part of {' and '.join(homes)}: import from there"


def test_each_spelling_of_an_import_gets_the_message():
    message = "rl_jax.agents.dqn_config is now part of rl_jax.agents.dqn: import from there"
    for statement in (
        "import rl_jax.agents.dqn_config",
        "from rl_jax.agents import dqn_config",
        "from rl_jax.agents.dqn_config import Config",
    ):
        with pytest.raises(ModuleNotFoundError) as raised:
            exec(statement, {})
        assert str(raised.value) == message
    two = "rl_jax.agents.ppo_networks is now part of rl_jax.agents.ppo_parts and rl_jax.agents.ppo"
    with pytest.raises(ModuleNotFoundError, match=f"^{two}: import from there$"):
        exec("from rl_jax.agents import ppo, ppo_networks", {})


def test_other_missing_modules_fail_as_usual():
    with pytest.raises(
        ModuleNotFoundError, match="No module named 'rl_jax.agents.no_such_learner'"
    ):
        importlib.import_module("rl_jax.agents.no_such_learner")
