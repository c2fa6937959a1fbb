"""rl_jax: pure-functional TD3, DDPG, DQN and REINFORCE, jit-compiled with vmapped envs."""

import os

# XLA's C++ runtime logs a warning on every persistent-cache hit ("Assume version
# compatibility"); it must be silenced before jax is imported. Set the variable to override.
os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

__version__ = "0.1.0"

__all__ = ["Run", "load_policy", "open_run", "resume", "train"]
_LAZY = {
    "load_policy": "rl_jax.policy",
    "train": "rl_jax.api",
    "resume": "rl_jax.api",
    "open_run": "rl_jax.api",
    "Run": "rl_jax.api",
}


def __getattr__(name: str):
    # Imported on first use: ``import rl_jax`` stays cheap (no JAX until it is needed).
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'rl_jax' has no attribute {name!r}")
