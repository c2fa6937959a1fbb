"""TD3's networks as its losses use them: the actor and twin critics built from a ``td3.Config``
(with the options' architecture choices), the bounds the actions live in, and the functions that
apply them with or without SALE's embeddings.

With ``sale`` the actor and critics read embeddings of a *fixed* copy of the encoder, whose
parameters are passed as ``encoder`` (None: no SALE). Its parameters enter under
``stop_gradient``: gradients reach the actor through the action fed to ``embed_pair``, never the
fixed encoder itself.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from envs.core.spaces import Box
from rl_jax.training import episodes, networks


class Networks(NamedTuple):
    actor: networks.Actor
    critic: networks.Critic
    low: np.ndarray  # [action_dim] action bounds
    high: np.ndarray
    config: Any  # the td3.Config whose options the losses follow
    encoder: networks.StateActionEncoder | None = None  # sale: f(s) and g(z_s, a)

    @property
    def half_range(self) -> np.ndarray:
        return (self.high - self.low) / 2.0


def build_networks(config: Any, action_space: Box) -> Networks:
    """Actor and critic modules for an action space (bounds are baked into the actor)."""
    if (
        not isinstance(action_space, Box)
        or not action_space.bounded
        or len(action_space.shape) != 1
    ):
        raise TypeError(f"TD3/DDPG need a bounded 1-D Box action space, got {action_space}")
    dtype = jnp.dtype(config.compute_dtype)
    low = tuple(float(x) for x in action_space.low)
    high = tuple(float(x) for x in action_space.high)
    actor = networks.Actor(
        config.actor_hidden,
        low,
        high,
        config.network_init,
        dtype,
        config.actor_activation,
        config.actor_norm,
        config.network,
    )
    critic = networks.Critic(
        config.critic_hidden,
        config.network_init,
        dtype,
        config.critic_activation,
        config.critic_norm,
        config.network,
        config.renorm_warmup,
    )
    encoder = None
    if config.sale:
        encoder = networks.StateActionEncoder(
            config.embedding_hidden,
            config.embedding_dim,
            config.network_init,
            dtype,
            config.critic_activation,
        )
    bounds = action_space.low.copy(), action_space.high.copy()
    return Networks(actor, critic, *bounds, config, encoder)


@functools.lru_cache(maxsize=64)
def make_networks(config: Any) -> Networks:
    """The networks for ``config.env_id`` (cached: called at every trace)."""
    return build_networks(config, episodes.make_eval_env(config).action_space())


def row(x: np.ndarray, like: jax.Array) -> jax.Array:
    """Bounds shaped to broadcast against ``like`` [..., action_dim] without rank promotion."""
    return jnp.reshape(jnp.asarray(x, jnp.float32), (1,) * (like.ndim - 1) + (-1,))


# ---- applying them (with SALE's embeddings when an encoder is given) ---------------------------
def embed_state(nets: Networks, encoder: Any, obs: jax.Array) -> jax.Array:
    """``z_s = f(obs)`` of a fixed encoder (no gradient into its parameters)."""
    params = jax.lax.stop_gradient(encoder)
    return nets.encoder.apply(params, obs, method="embed_state")


def embeddings(nets: Networks, encoder: Any, obs, action, zs=None) -> jax.Array | None:
    """The critics' extra input ``[z_sa, z_s]`` (None without an encoder)."""
    if encoder is None:
        return None
    zs = embed_state(nets, encoder, obs) if zs is None else zs
    zsa = nets.encoder.apply(jax.lax.stop_gradient(encoder), zs, action, method="embed_pair")
    return jnp.concatenate([zsa, zs], axis=-1)


def policy_action(nets: Networks, actor: Any, obs: jax.Array, encoder: Any = None) -> jax.Array:
    """The deterministic action of actor parameters ``actor`` (with ``z_s`` under SALE)."""
    if encoder is None:
        return nets.actor.apply(actor, obs)
    return nets.actor.apply(actor, obs, embed_state(nets, encoder, obs))


def _variables(critics: Any, stats: Any) -> Any:
    """Critic parameters with batch renormalisation's statistics beside them (if any)."""
    return critics if stats is None else {**critics, "batch_stats": stats}


def critic_values(nets: Networks, critics: Any, obs, action, extra=None, stats=None) -> jax.Array:
    """``[num_critics, B]``: every stacked critic at ``(obs, action)``; ``extra``: SALE's
    ``embeddings``; ``stats``: batch renormalisation's statistics, used in evaluation mode."""
    inputs = (obs, action) if extra is None else (obs, action, extra)
    return networks.apply_stacked(nets.critic, _variables(critics, stats), *inputs)


def critic_values_train(nets: Networks, critics: Any, stats: Any, obs, action, extra=None):
    """``(q [num_critics, B], new stats)``: batch renormalisation in training mode, its
    statistics of this batch folded into ``stats``."""

    def one(variables):
        out, updated = nets.critic.apply(
            variables, obs, action, extra, train=True, mutable=["batch_stats"]
        )
        return out, updated["batch_stats"]

    return jax.vmap(one)(_variables(critics, stats))


def first_critic_value(nets: Networks, critics: Any, obs, action, extra=None, stats=None):
    """``[B]``: the first critic alone (the one the actor ascends), evaluation mode."""
    first = jax.tree.map(lambda x: x[0], _variables(critics, stats))
    inputs = (obs, action) if extra is None else (obs, action, extra)
    return nets.critic.apply(first, *inputs)
