"""SAC's update as the peers benchmark counts and times it: its exact matmul FLOPs and its matrix
products, traced from ``rl_jax.agents.sac``'s update the way ``bench.td3_programs`` traces TD3's.

SAC's update does more products than TD3's at the same widths and batch: the critic step also
runs the actor forward on the next observations (the bootstrap action is sampled, not a
target actor's), and the actor step (actor forward and backward through the twin critics'
minimum, where TD3 reads only the first critic) runs every update, not every second one. The
temperature step is a scalar and has no products.
"""

from __future__ import annotations

from typing import Any

import jax

from bench.td3_programs import _dot_equations, jaxpr_matmul_flops
from rl_jax.agents import sac as sac_module
from rl_jax.agents.sac import Config, make_networks, sac


def _steps(config: Config):
    """``(critic(agent, batch, key), actor(agent, batch, key))``: one seed's two steps."""
    hparams = sac.default_hyperparams()
    nets = make_networks(config)

    def critic(agent, batch, key):
        return sac_module.critic_step(agent, batch, key, hparams, nets)

    def actor(agent, batch, key):
        step = sac_module.actor_and_temperature_step
        return step(agent, batch.obs, key, config, hparams, nets)

    return critic, actor


def _state_and_batch(config: Config, key: jax.Array):
    hparams = sac.default_hyperparams()
    state = sac.init(key, config, hparams)
    batch = sac_module.sample(state.buffer, jax.random.fold_in(key, 1), config, hparams)
    return state.agent, batch


def update_flops(config: Config) -> dict[str, float]:
    """Matmul FLOPs of one seed's SAC update: the critic step (actor forward on s', twin target
    critics forward, twin critics forward and backward), the actor-and-temperature step (actor
    forward, twin critics forward, backward through both), and their sum per update (the actor
    step every ``policy_delay`` updates)."""
    # shapes are all the tracing needs (an eager init would compile each of its ops)
    agent, batch = jax.eval_shape(lambda key: _state_and_batch(config, key), jax.random.key(0))
    critic, actor = _steps(config)
    key = jax.random.key(2)
    critic_flops = jaxpr_matmul_flops(jax.make_jaxpr(critic)(agent, batch, key).jaxpr)
    actor_flops = jaxpr_matmul_flops(jax.make_jaxpr(actor)(agent, batch, key).jaxpr)
    return {
        "critic_step": critic_flops,
        "actor_step": actor_flops,
        "per_update": critic_flops + actor_flops / config.policy_delay,
    }


def update_dots(config: Config, seeds: int) -> list[tuple[Any, float]]:
    """Every matrix product of one SAC update of ``seeds`` seeds vmapped: ``(dot_general
    equation, runs per update)``, as ``bench.td3_programs.update_dots`` gives TD3's (the
    argument ``dots_program`` takes)."""
    agents, batches = jax.eval_shape(
        jax.vmap(lambda key: _state_and_batch(config, key)),
        jax.random.split(jax.random.key(0), seeds),
    )
    critic, actor = _steps(config)
    keys = jax.random.split(jax.random.key(2), seeds)
    traced = [
        (jax.make_jaxpr(jax.vmap(critic))(agents, batches, keys), 1.0),
        (jax.make_jaxpr(jax.vmap(actor))(agents, batches, keys), 1.0 / config.policy_delay),
    ]
    return [(eqn, weight) for jaxpr, weight in traced for eqn in _dot_equations(jaxpr.jaxpr)]
