"""Batch-level autoreset: reset only the envs whose episode ended.

Under ``jax.vmap`` the ``AutoReset`` wrapper computes a reset for every env on every step and
selects per env (vmap turns a ``cond`` into a ``select``). Sampling a start state hashes PRNG keys,
which costs far more than a classic env's physics (``bench/bench_classic.py`` compares the two). The
functions here work on the whole batch instead: they gather the (usually few) envs that need a
reset, reset only those and scatter the results back; on a call where more than ``max_resets`` envs
need one they reset them all.

``reset_where`` (per-env keys) gives exactly the per-env result; ``autoreset_step`` (one key per
call) also splits keys only for the envs it resets, which is what makes it cheap.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

from rl_jax.envs.core.core import Array, Environment, TimeStep
from rl_jax.envs.core.wrappers import ACTION_MASK, FINAL_ACTION_MASK, reset_after

#: What ``_reset_some``'s ``keys_for`` gives and its ``reset`` takes: keys, or keys and slots.
KeysT = TypeVar("KeysT")


def select_envs(mask: Array, on_true: Any, on_false: Any) -> Any:
    """Per-env choice between two batched pytrees; ``mask`` is ``[num_envs]`` bool."""

    def pick(a: Array, b: Array) -> Array:
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, on_true, on_false)


def default_max_resets(num_envs: int) -> int:
    """Resets computed per call on the fast path: 1/16 of the batch (at least 1)."""
    return max(1, -(-num_envs // 16))


def _reset_some(
    reset: Callable[[KeysT], object],
    keys_for: Callable[[int, Array | None], KeysT],
    mask: Array,
    current: Any,
    max_resets: int | None,
) -> Any:
    """``current`` with the masked envs replaced by ``reset(keys_for(slots))``.

    ``keys_for(n, index)`` gives the keys for ``n`` reset slots; ``index`` holds the env of each
    slot (``None`` when all envs are reset).
    """
    num_envs = mask.shape[0]
    max_resets = default_max_resets(num_envs) if max_resets is None else max_resets

    def none():
        return current

    def few():
        # Masked env indices first; the unused slots hold num_envs, dropped by the scatter.
        index = jnp.nonzero(mask, size=max_resets, fill_value=num_envs)[0]
        fresh = reset(keys_for(max_resets, jnp.minimum(index, num_envs - 1)))
        return jax.tree.map(lambda old, new: old.at[index].set(new, mode="drop"), current, fresh)

    def all_envs():
        return select_envs(mask, reset(keys_for(num_envs, None)), current)

    count = jnp.sum(mask)
    branch = jnp.where(count == 0, 0, jnp.where(count <= max_resets, 1, 2))
    return jax.lax.switch(branch, (none, few, all_envs))


def reset_where(
    reset: Callable[[Array], Any],
    keys: Array,
    mask: Array,
    current: Any,
    max_resets: int | None = None,
) -> Any:
    """``current`` with every env ``i`` where ``mask[i]`` replaced by env ``i``'s reset from its
    own key ``keys[i]``: equal to ``select(mask, reset(keys), current)``, only cheaper.

    ``reset`` maps a batch of keys ``[k, ...]`` to a batched pytree shaped like ``current``
    (leading axis ``k``). No env is reset when none is masked; up to ``max_resets`` masked envs
    are gathered and reset alone; more than that resets the whole batch and selects.
    """

    def keys_for(count: int, index: Array | None) -> Array:
        return keys if index is None else keys[index]

    return _reset_some(reset, keys_for, mask, current, max_resets)


def autoreset_step(
    env: Environment,
    key: Array,
    states: Any,
    actions: Array,
    params: Any = None,
    max_resets: int | None = None,
) -> tuple[Any, TimeStep]:
    """Step a batch of envs and reset the ones whose episode ended, from one key.

    Same-step autoreset with the semantics of ``jax.vmap(AutoReset(env).step)``: the returned
    obs of a finished env is its new episode's first, ``info["final_obs"]`` holds the finished
    episode's last obs (equal to ``obs`` otherwise), reward and flags are the finishing step's;
    an env with an action mask has its new episode's in ``info["action_mask"]`` and the
    ended one's in ``info["final_action_mask"]``. The resets are ``reset_after``'s (a game
    goes on after a lost life).
    Each reset draws a fresh start state, but keys are split only for the envs reset, so the
    draws differ from ``AutoReset``'s (which derives one per env per step). ``states`` and
    ``actions`` have a leading ``num_envs`` axis; ``params`` is shared.
    """
    params = env.default_params if params is None else params
    num_envs = actions.shape[0]
    key_step, key_reset = jax.random.split(key)
    # Deterministic envs ignore their step key; XLA then drops this split entirely.
    step_keys = jax.random.split(key_step, num_envs)
    next_states, timestep = jax.vmap(env.step, (0, 0, 0, None))(step_keys, states, actions, params)
    done = jnp.logical_or(timestep.terminated, timestep.truncated)
    masked = ACTION_MASK in timestep.info

    def reset(slots: tuple[Array, Array | None]):
        # reset_after continues where an env goes on after an episode's end (a lost life); the
        # ended states and timesteps of the reset envs are gathered for it.
        reset_keys, index = slots
        ended = (next_states, timestep)
        if index is not None:
            ended = jax.tree.map(lambda leaf: leaf[index], ended)
        reset_states, reset_timestep = jax.vmap(
            lambda k, s, ts: reset_after(env, k, s, ts, params)
        )(reset_keys, *ended)
        if masked:
            return reset_states, reset_timestep.obs, reset_timestep.info[ACTION_MASK]
        return reset_states, reset_timestep.obs

    def keys_for(count: int, index: Array | None) -> tuple[Array, Array | None]:
        return jax.random.split(key_reset, count), index

    info = {**timestep.info, "final_obs": timestep.obs}
    if not masked:
        states, obs = _reset_some(reset, keys_for, done, (next_states, timestep.obs), max_resets)
        return states, timestep._replace(obs=obs, info=info)
    current = (next_states, timestep.obs, timestep.info[ACTION_MASK])
    states, obs, mask = _reset_some(reset, keys_for, done, current, max_resets)
    info = {**info, ACTION_MASK: mask, FINAL_ACTION_MASK: timestep.info[ACTION_MASK]}
    return states, timestep._replace(obs=obs, info=info)
