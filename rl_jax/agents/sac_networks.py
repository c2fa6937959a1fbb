"""SAC's networks as its losses use them: the squashed-Gaussian actor and the stacked critics
built from a ``sac.Config``, the bounds the actions live in, and the functions that apply them.

Under batch renormalisation (``critic_norm`` / ``actor_norm`` ``"batch_renorm"``, CrossQ) a
network's running statistics are passed beside its parameters (``stats``; None without): the
``*_train`` functions run training mode and return the statistics with this batch folded in,
the others evaluation mode (running statistics).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.agents.sac_config import Config
from rl_jax.envs.core.spaces import Box
from rl_jax.training import episodes, networks, squashed_gaussian
from rl_jax.training.networks import Params
from rl_jax.training.squashed_gaussian import GaussianActor


class Networks(NamedTuple):
    actor: GaussianActor
    critic: networks.Critic
    low: np.ndarray  # [action_dim] action bounds
    high: np.ndarray
    config: Config  # the sac.Config whose options the losses follow


def build_networks(config: Config, action_space: Box) -> Networks:
    """Actor and critic modules for a bounded 1-D Box action space."""
    if (
        not isinstance(action_space, Box)
        or not action_space.bounded
        or len(action_space.shape) != 1
    ):
        raise TypeError(f"SAC needs a bounded 1-D Box action space, got {action_space}")
    dtype = jnp.dtype(config.compute_dtype)
    actor = GaussianActor(
        config.actor_hidden,
        action_space.shape[0],
        config.network_init,
        dtype,
        config.actor_activation,
        config.actor_norm,
        config.network,
        config.renorm_warmup,
        config.log_std_min,
        config.log_std_max,
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
    return Networks(actor, critic, action_space.low.copy(), action_space.high.copy(), config)


@functools.lru_cache(maxsize=64)
def make_networks(config: Config) -> Networks:
    """The networks for ``config.env_id`` (cached: called at every trace)."""
    return build_networks(config, episodes.make_eval_env(config).action_space())


def _variables(params: Params, stats: Params | None) -> Params:
    """Parameters with batch renormalisation's statistics beside them (if any)."""
    return params if stats is None else {**params, "batch_stats": stats}


# ---- the actor -----------------------------------------------------------------------------------
def actor_outputs(nets: Networks, actor: Params, stats: Params | None, obs: jax.Array):
    """``(mean, log_std)`` pre-tanh, evaluation mode."""
    return nets.actor.apply(_variables(actor, stats), obs)


def actor_outputs_train(nets: Networks, actor: Params, stats: Params | None, obs: jax.Array):
    """``((mean, log_std), new stats)``: training mode under batch renormalisation (else the
    same as ``actor_outputs``, statistics None)."""
    if stats is None:
        return actor_outputs(nets, actor, None, obs), None
    out, updated = nets.actor.apply(
        _variables(actor, stats), obs, train=True, mutable=["batch_stats"]
    )
    return out, updated["batch_stats"]


def env_action(nets: Networks, a: jax.Array) -> jax.Array:
    """A squashed action in (-1, 1) in the env's units."""
    return squashed_gaussian.rescale(a, nets.low, nets.high)


def deterministic_action(
    nets: Networks, actor: Params, stats: Params | None, obs: jax.Array
) -> jax.Array:
    """``tanh(mean)`` in the env's units: the policy that is evaluated and exported."""
    mean, _ = actor_outputs(nets, actor, stats, obs)
    return env_action(nets, jnp.tanh(mean))


def sampled_action(nets: Networks, key: jax.Array, mean: jax.Array, log_std: jax.Array):
    """``(action in env units [B, A], log pi [B])``, reparameterised (``squashed_gaussian``)."""
    a, log_pi = squashed_gaussian.sample(key, mean, log_std)
    return env_action(nets, a), log_pi


# ---- the critics ---------------------------------------------------------------------------------
def critic_values(nets: Networks, critics: Params, stats: Params | None, obs, action) -> jax.Array:
    """``[num_critics, B]``: every stacked critic at ``(obs, action)``, evaluation mode."""
    return networks.apply_stacked(nets.critic, _variables(critics, stats), obs, action)


def critic_values_train(nets: Networks, critics: Params, stats: Params | None, obs, action):
    """``(q [num_critics, B], new stats)``: training mode under batch renormalisation (else
    ``critic_values`` and None)."""
    if stats is None:
        return critic_values(nets, critics, None, obs, action), None

    def one(variables):
        out, updated = nets.critic.apply(
            variables, obs, action, None, train=True, mutable=["batch_stats"]
        )
        return out, updated["batch_stats"]

    return jax.vmap(one)(_variables(critics, stats))
