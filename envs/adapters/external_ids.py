"""Env ids that say where the env comes from, registered on first use (``envs.make``, ``--env``):

``gymnasium:ID``
    gymnasium's own env ``ID`` (anything ``gymnasium.make`` knows), stepped on the host through
    ``envs.from_gymnasium``: ``--env gymnasium:Pendulum-v1``.
``MODULE:ID``
    imports ``MODULE``, which registers ``ID`` with ``envs.register``, then that env:
    ``--env examples.hover_rocket:examples/HoverRocket-v0``. ``ID`` may also name an attribute
    of the module, an ``Environment`` class or a function returning one, registered or not:
    ``--env examples.hover_rocket:HoverRocket``.

The whole string is the env's id, and a run records it in config.json. A record is data: an id
read from it is resolved with ``imports=False``, so ``--resume``, ``rl_jax.open_run`` and
``rl_jax.load_policy`` never import ``MODULE`` by themselves; the user names the env again
(``--env MODULE:ID``, ``env="MODULE:ID"``), which imports it as below. ``gymnasium:ID`` needs no
import of ours when ``ID`` is in gymnasium's registry, and is accepted from a record then.
``MODULE`` is imported as Python imports it; when it is not found there, the current directory
is searched as well (``python experiments/x.py`` puts only ``experiments/`` on the path, where
``python -m`` would have put the current directory).
"""

from __future__ import annotations

import importlib
import os
import sys
from types import ModuleType

import gymnasium

from rl_jax.envs.adapters.gymnasium_host import register_gymnasium_id
from rl_jax.envs.core import registry

GYMNASIUM_PREFIX = "gymnasium:"


def resolve_external_id(name: str, imports: bool = True) -> str:
    """Register ``gymnasium:ID`` or ``MODULE:ID`` under the whole ``name``; return ``name``.
    Without ``imports``, ``EnvNotNamedError`` for any name that would import a module."""
    if name.startswith(GYMNASIUM_PREFIX):
        inner = name.removeprefix(GYMNASIUM_PREFIX)
        if not imports and not _in_gymnasium_registry(inner):
            # gymnasium.make imports the module of a "module:Env" id, or fails on an unknown one
            raise registry.EnvNotNamedError(name, inner.partition(":")[0] or inner)
        return register_gymnasium_id(name)
    module_name, _, inner = name.partition(":")
    if not imports:
        raise registry.EnvNotNamedError(name, module_name)
    module = _import(module_name, name)
    if _is_registered(inner):
        inner_id = registry.resolve_id(inner)
        limit = registry.max_episode_steps(inner_id)
        registry.register(name, registry.factory(inner_id), max_episode_steps=limit)
        return name
    if callable(getattr(module, inner, None)):
        registry.register(name, getattr(module, inner))
        return name
    raise registry.UnknownEnvError(
        f"module {module_name!r} registers no environment {inner!r} and has no attribute of that "
        f"name; known environments: {', '.join(registry.registered_ids())}"
    )


def _in_gymnasium_registry(env_id: str) -> bool:
    """Whether gymnasium's registry holds ``env_id`` itself: gymnasium makes it from its own
    entry point, importing nothing that the id names."""
    return ":" not in env_id and env_id in gymnasium.registry


def _is_registered(env_id: str) -> bool:
    if ":" in env_id:  # not a plain id: no second round of imports
        return False
    try:
        registry.resolve_id(env_id)
    except registry.UnknownEnvError:
        return False
    return True


def _import(module_name: str, name: str) -> ModuleType:
    """``module_name`` imported, from the current directory if it is not on the path."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        if os.getcwd() in sys.path or not _is_missing(error, module_name):
            raise registry.UnknownEnvError(_import_failure(module_name, name, error)) from None
    sys.path.append(os.getcwd())
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as error:
        raise registry.UnknownEnvError(_import_failure(module_name, name, error)) from None


def _is_missing(error: ModuleNotFoundError, module_name: str) -> bool:
    """The module itself (or a package above it) is missing, not something it imports."""
    missing = error.name or ""
    return module_name == missing or module_name.startswith(missing + ".")


def _import_failure(module_name: str, name: str, error: ModuleNotFoundError) -> str:
    return (
        f"environment {name!r}: cannot import module {module_name!r} ({error}); give MODULE:ID "
        "with MODULE importable from the current directory or the Python path"
    )


registry.set_external_resolver(resolve_external_id)
