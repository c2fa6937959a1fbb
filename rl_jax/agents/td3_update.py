"""One TD3 update, whatever the options: a batch from the replay (uniform, or LAP's priorities),
SALE's encoder step, the critic step (with LAP's new priorities), every ``policy_delay``-th an
actor step and Polyak target step, and with ``target_update_period`` TD7's hard target copies.
``config``/``hparams`` are ``td3.Config``/``td3.Hyperparams``.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import optax

from rl_jax.agents import td7_parts
from rl_jax.agents.common import linearly_decayed, optimizer_step, polyak_update
from rl_jax.agents.td3_agent import (
    Agent,
    AgentWithOptions,
    fixed_encoders,
    hard_target_update,
    normalized_batch,
)
from rl_jax.agents.td3_losses import CriticBatch, actor_loss_fn, critic_loss_fn, encoder_loss_fn
from rl_jax.agents.td3_networks import Networks, make_networks
from rl_jax.training import offpolicy, prioritized, replay
from rl_jax.training.replay import ReplayBuffer, Transition

Config = Hyperparams = Any  # td3's (td3 imports this module)


# ---- replay ------------------------------------------------------------------------------------
def sample(buffer, key, config: Config, hparams: Hyperparams):
    """``(CriticBatch, (rows, columns))``: a uniform batch, or with ``lap`` one drawn in
    proportion to the priorities (LAP uses no importance weights)."""
    if config.lap:
        rows, columns, _ = prioritized.sample_indices(buffer, key, config.batch_size, 0.0)
        storage = buffer.buffer
    else:
        rows, columns = replay.sample_indices(buffer, key, config.batch_size)
        storage = buffer
    if config.n_step == 1:
        batch = CriticBatch.one_step(replay.gather(storage, rows, columns), hparams.gamma)
    else:
        window, stored = replay.gather_windows(storage, rows, columns, config.n_step)
        batch = CriticBatch.n_step(replay.n_step_batch(window, stored, hparams.gamma))
    return batch, (rows, columns)


def init_buffer(example: Transition, config: Config):
    if config.lap:
        return prioritized.init(example, config.buffer_size, config.num_envs)
    return offpolicy.uniform_buffer(example, config)


def add_to_buffer(buffer, transitions: Transition, config: Config, hparams: Hyperparams):
    """Store one row; with ``lap`` at the largest priority so far."""
    if config.lap:
        return prioritized.add(buffer, transitions, hparams.lap_alpha)
    return replay.add(buffer, transitions)


# ---- one update ---------------------------------------------------------------------------------
_ADAM = optax.inject_hyperparams(optax.adam)(learning_rate=3e-4)


def _adam_step(grads, opt_state, params, learning_rate, b1: float = 0.9):
    """Adam at the hyperparameter's rate and ``Config.adam_b1``. The injected state holds every
    numeric argument of Adam and the step reads them from it, so a ``b1`` other than Adam's 0.9
    is written into it first (and a checkpoint records it). At 0.9 the state's own value is used
    as before: a constant ``b1`` would let XLA fold it and round plain TD3 differently."""
    rates = {"learning_rate": learning_rate}
    if b1 != 0.9:
        rates["b1"] = jnp.asarray(b1, jnp.float32)
    return optimizer_step(_ADAM, grads, opt_state, params, **rates)


def _critic_step(
    agent: Agent, batch: CriticBatch, key, hparams: Hyperparams, nets: Networks, decay
):
    """``(agent, loss, CriticAux)`` after one critic step (and, under batch renormalisation,
    the statistics of its batch folded in)."""
    noise = jax.random.normal(key, batch.action.shape, jnp.float32)
    targets = nets.config.target_networks
    (loss, aux), grads = jax.value_and_grad(critic_loss_fn, has_aux=True)(
        agent.critics,
        agent.target_actor if targets else agent.actor,
        agent.target_critics if targets else agent.critics,
        batch,
        noise,
        hparams,
        nets,
        fixed_encoders(agent),
        getattr(agent, "critic_stats", None),
        _value_bounds(agent),
    )
    rate = decay(hparams.critic_lr)
    critics, critic_opt = _adam_step(
        grads, agent.critic_opt, agent.critics, rate, nets.config.adam_b1
    )
    agent = agent.replace(critics=critics, critic_opt=critic_opt)
    if aux.batch_stats is not None:
        agent = agent.replace(critic_stats=aux.batch_stats)
    if aux.target_range is not None:
        agent = agent.replace(value_range=agent.value_range.seeing(aux.target_range))
    return agent, loss, aux


def _value_bounds(agent: Agent):
    """TD7's ``(low, high)`` on bootstrap values, or None without value clipping."""
    values = getattr(agent, "value_range", None)
    return None if values is None else (values.low, values.high)


def _actor_and_target_step(agent: Agent, obs, hparams: Hyperparams, nets: Networks, decay):
    """An actor step, then (unless targets are copied every ``target_update_period``) a Polyak
    step of the targets."""
    stats = getattr(agent, "critic_stats", None)
    loss, grads = jax.value_and_grad(actor_loss_fn)(
        agent.actor, agent.critics, obs, nets, fixed_encoders(agent)[0], stats
    )
    actor_rate, b1 = decay(hparams.actor_lr), nets.config.adam_b1
    actor, actor_opt = _adam_step(grads, agent.actor_opt, agent.actor, actor_rate, b1)
    agent = agent.replace(actor=actor, actor_opt=actor_opt)
    if nets.config.target_update_period:
        return agent, loss
    if nets.config.target_networks:
        agent = agent.replace(
            target_actor=polyak_update(agent.target_actor, actor, hparams.tau),
            target_critics=polyak_update(agent.target_critics, agent.critics, hparams.tau),
        )
    if nets.config.sale:  # the fixed copies follow at the targets' pace
        encoders = agent.encoders
        agent = agent.replace(
            encoders=encoders.replace(
                fixed=polyak_update(encoders.fixed, encoders.online, hparams.tau),
                fixed_target=polyak_update(encoders.fixed_target, encoders.fixed, hparams.tau),
            )
        )
    return agent, loss


def _encoder_step(agent: AgentWithOptions, batch: CriticBatch, hparams, nets: Networks, decay):
    """One Adam step of SALE's online encoder: ``(agent, loss)``."""
    encoders = agent.encoders
    loss, grads = jax.value_and_grad(encoder_loss_fn)(encoders.online, batch, nets)
    rate = decay(hparams.encoder_lr)
    online, opt = _adam_step(grads, encoders.opt, encoders.online, rate, nets.config.adam_b1)
    return agent.replace(encoders=encoders.replace(online=online, opt=opt)), loss


def update(
    agent: Agent,
    buffer: ReplayBuffer,
    key,
    config: Config,
    hparams: Hyperparams,
    update_index: jax.Array,
):
    """One critic update (after, with ``sale``, an encoder update; then, with ``lap``, new
    priorities for its batch); every ``policy_delay``-th also an actor and target update."""
    nets = make_networks(config)
    sample_key, noise_key = jax.random.split(key)
    batch, (rows, columns) = sample(buffer, sample_key, config, hparams)
    batch = normalized_batch(agent, batch)
    env_steps = offpolicy.env_steps_at_update(update_index, config)

    def decay(rate):
        return linearly_decayed(rate, env_steps, hparams.lr_decay_steps)

    metrics = {}
    if config.sale:
        agent, metrics["encoder_loss"] = _encoder_step(agent, batch, hparams, nets, decay)
    agent, critic_loss_value, aux = _critic_step(agent, batch, noise_key, hparams, nets, decay)
    q = jnp.mean(aux.q_tm1)
    if config.lap:
        priorities = td7_parts.lap_priorities(aux.td_tm1)
        buffer = prioritized.update_priorities(buffer, rows, columns, priorities, hparams.lap_alpha)
    delayed = (update_index + 1) % config.policy_delay == 0
    agent, actor_loss_value = jax.lax.cond(
        delayed,
        lambda agent: _actor_and_target_step(agent, batch.obs, hparams, nets, decay),
        lambda agent: (agent, jnp.full((), jnp.nan, jnp.float32)),
        agent,
    )
    if config.target_update_period:
        agent, buffer = _maybe_copy_targets(agent, buffer, config, hparams, update_index)
    metrics.update(critic_loss=critic_loss_value, actor_loss=actor_loss_value, q=q)
    return agent, buffer, metrics


def _maybe_copy_targets(agent, buffer, config: Config, hparams: Hyperparams, update_index):
    """At every ``target_update_period``-th update: the hard target copies and, with LAP, the
    priority of new transitions reset to the largest stored (TD7)."""
    due = (update_index + 1) % config.target_update_period == 0
    copy = functools.partial(hard_target_update, networks=config.target_networks)
    agent = jax.lax.cond(due, copy, lambda agent: agent, agent)
    if config.lap:
        reset = functools.partial(prioritized.reset_max_priority, alpha=hparams.lap_alpha)
        buffer = jax.lax.cond(due, reset, lambda buffer: buffer, buffer)
    return agent, buffer


def metric_names(config: Config) -> tuple[str, ...]:
    """The keys of ``update``'s metrics under ``config``."""
    return ("encoder_loss",) * config.sale + ("critic_loss", "actor_loss", "q")
