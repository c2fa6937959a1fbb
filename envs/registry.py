"""Name -> environment registry. Entry points are imported lazily so that the pure-JAX envs do
not pay for importing MuJoCo."""

from __future__ import annotations

import importlib
from typing import Any

from envs.core import Environment

# id -> "module:factory". Factories take keyword arguments (e.g. ``backend=`` for MuJoCo envs).
_ENTRY_POINTS: dict[str, str] = {
    "rl_jax/Rocket-v0": "envs.rocket:Rocket",
    "rl_jax/CartPole-v1": "envs.cartpole:CartPole",
    "rl_jax/Pendulum-v1": "envs.pendulum:Pendulum",
    "rl_jax/InvertedPendulum-v5": "envs.inverted_pendulum:InvertedPendulum",
    "rl_jax/InvertedDoublePendulum-v5": "envs.inverted_double_pendulum:InvertedDoublePendulum",
    "rl_jax/HalfCheetah-v5": "envs.half_cheetah:HalfCheetah",
}


class UnknownEnvError(ValueError):
    """Raised for a name that is not registered; the message lists the known ids."""


def register(env_id: str, entry_point: str) -> None:
    """Add an env: ``entry_point`` is ``"package.module:Factory"``."""
    _ENTRY_POINTS[env_id] = entry_point


def registered_ids() -> list[str]:
    return sorted(_ENTRY_POINTS)


def resolve_id(name: str) -> str:
    """Accept the full id (``rl_jax/Rocket-v0``) or the id without namespace, any case."""
    if name in _ENTRY_POINTS:
        return name
    wanted = name.lower().removeprefix("rl_jax/")
    for env_id in _ENTRY_POINTS:
        if env_id.lower().removeprefix("rl_jax/") == wanted:
            return env_id
    known = ", ".join(registered_ids())
    raise UnknownEnvError(f"unknown environment {name!r}; known environments: {known}")


def make(name: str, **kwargs: Any) -> Environment:
    """Build a registered env, e.g. ``envs.make("rl_jax/Rocket-v0")``."""
    env_id = resolve_id(name)
    module_name, factory_name = _ENTRY_POINTS[env_id].split(":")
    factory = getattr(importlib.import_module(module_name), factory_name)
    env = factory(**kwargs)
    env.id = env_id
    return env
