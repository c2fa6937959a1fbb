"""rl_jax: pure-functional RL learners (TD3, DDPG, TD7, CrossQ, SAC, PPO, recurrent PPO, DQN, R2D2,
PQN, REINFORCE), jit-compiled with vmapped envs.

What a user imports: ``train``, ``resume``, ``open_run`` and ``Run`` (``rl_jax.run.api``),
``load_policy`` (``rl_jax.run.policy``) and the learners ``td3``, ``ddpg``, ``td7``, ``crossq``,
``sac``, ``ppo``, ``recurrent_ppo``, ``dqn``, ``r2d2``, ``pqn`` and ``reinforce``
(``rl_jax.agents``). The package: ``agents`` (the learners), ``training`` (what makes the
compiled program), ``run`` (what touches disk, terminal and processes) and ``envs`` (the
environments: ``from rl_jax import envs``, then ``envs.make``).
"""

import importlib
import os

# XLA's C++ runtime logs on every persistent-cache hit: a warning ("Assume version
# compatibility") and, in jaxlib 0.9.2, two error-level lines claiming the cached program was
# built for other CPU features ("+prefer-no-gather is not supported ... could lead to SIGILL").
# The latter is XLA reading its own tuning flags as CPU features; the program loads and runs
# correctly, but a second run of any script would open with pages of alarming stderr (and a bad
# flag would no longer be one line). Level 3 keeps only fatal C++ logs; failures still reach
# Python as exceptions. It must be set before jax is imported. Set the variable to override.
# Whether the user chose the level: rl_jax.run.aborts turns the log off in runs over several
# processes unless they did.
_cpp_log_level_chosen = "TF_CPP_MIN_LOG_LEVEL" in os.environ
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

__version__ = "0.1.0"

__all__ = [
    "Run",
    "c51",
    "crossq",
    "ddpg",
    "dqn",
    "load_policy",
    "open_run",
    "ppo",
    "pqn",
    "qrdqn",
    "r2d2",
    "recurrent_ppo",
    "reinforce",
    "resume",
    "sac",
    "td3",
    "td7",
    "train",
]
_LAZY = {
    "td3": "rl_jax.agents.td3",
    "ddpg": "rl_jax.agents.td3",
    "td7": "rl_jax.agents.td7",
    "crossq": "rl_jax.agents.crossq",
    "dqn": "rl_jax.agents.dqn",
    "reinforce": "rl_jax.agents.reinforce",
    "ppo": "rl_jax.agents.ppo",
    "recurrent_ppo": "rl_jax.agents.recurrent_ppo",
    "pqn": "rl_jax.agents.pqn",
    "c51": "rl_jax.agents.distributional",
    "qrdqn": "rl_jax.agents.distributional",
    "r2d2": "rl_jax.agents.r2d2",
    "sac": "rl_jax.agents.sac",
    "load_policy": "rl_jax.run.policy",
    "train": "rl_jax.run.api",
    "resume": "rl_jax.run.api",
    "open_run": "rl_jax.run.api",
    "Run": "rl_jax.run.api",
}


def __getattr__(name: str):
    # Imported on first use: ``import rl_jax`` stays cheap (no JAX until it is needed).
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'rl_jax' has no attribute {name!r}")
