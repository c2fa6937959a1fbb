"""TD3's networks as its losses use them: the actor and twin critics built from a ``td3.Config``
(with the options' architecture choices), and the bounds the actions live in.
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
    )
    critic = networks.Critic(
        config.critic_hidden,
        config.network_init,
        dtype,
        config.critic_activation,
        config.critic_norm,
    )
    return Networks(actor, critic, action_space.low.copy(), action_space.high.copy(), config)


@functools.lru_cache(maxsize=64)
def make_networks(config: Any) -> Networks:
    """The networks for ``config.env_id`` (cached: called at every trace)."""
    return build_networks(config, episodes.make_eval_env(config).action_space())


def row(x: np.ndarray, like: jax.Array) -> jax.Array:
    """Bounds shaped to broadcast against ``like`` [..., action_dim] without rank promotion."""
    return jnp.reshape(jnp.asarray(x, jnp.float32), (1,) * (like.ndim - 1) + (-1,))
