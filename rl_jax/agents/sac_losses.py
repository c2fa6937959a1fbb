"""SAC's losses (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"): the pure
maths (rlax naming: ``tm1`` is the transition's start, ``t`` its end; testable alone with exact
values) and the losses on networks that the update differentiates. ``nets`` is a
``sac_networks.Networks``.

* Critics: ``J_Q = 1/2 E[(Q_i(s, a) - y)^2]`` for each critic, summed, with the soft target
  ``y = r + discount * (min_i Q'_i(s', a') - alpha log pi(a'|s'))``, ``a' ~ pi(.|s')`` from
  the current actor; ``discount`` is 0 at termination only (a time-limit truncation still
  bootstraps from the true final observation).
* Actor: ``J_pi = E[alpha log pi(a|s) - min_i Q_i(s, a)]``, ``a ~ pi(.|s)`` reparameterised.
* Temperature: ``alpha = exp(log_alpha)`` learned so that the policy's entropy tracks a target.

With n-step windows the target sums the window's rewards and bootstraps once at its end; the
entropy bonuses of the steps inside the window are left out (their actions came from older
policies, so today's ``log pi`` of them is not what those steps earned).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.agents.sac_networks import (
    Networks,
    actor_outputs,
    actor_outputs_train,
    critic_values,
    critic_values_train,
    sampled_action,
)
from rl_jax.training.networks import Params


# ---- loss maths (pure; rlax naming: tm1 = the transition's start, t = its end) -----------------
def soft_td_target(r_t, discount_t, q_t, log_pi_t, alpha) -> jax.Array:
    """``r_t + discount_t * (min_i q_t[i] - alpha * log_pi_t)`` with no gradient; ``q_t``
    ``[num_critics, B]``, the rest ``[B]`` (``alpha`` a scalar) -> ``[B]``."""
    soft_value = jnp.min(q_t, axis=0) - alpha * log_pi_t
    return jax.lax.stop_gradient(r_t + discount_t * soft_value)


def soft_critic_loss(q_tm1, r_t, discount_t, q_t, log_pi_t, alpha) -> jax.Array:
    """``sum_i 1/2 mean_b (q_tm1[i] - y)^2`` against the shared soft target; ``q_tm1`` [C, B]."""
    target = soft_td_target(r_t, discount_t, q_t, log_pi_t, alpha)
    return 0.5 * jnp.sum(jnp.mean((q_tm1 - target[None, :]) ** 2, axis=-1))


def soft_policy_loss(q_tm1, log_pi_tm1, alpha) -> jax.Array:
    """``mean(alpha * log_pi_tm1 - min_i q_tm1[i])``: ``q_tm1`` [C, B] at the policy's own
    sampled actions, ``log_pi_tm1`` [B] their log-densities."""
    return jnp.mean(alpha * log_pi_tm1 - jnp.min(q_tm1, axis=0))


def temperature_loss(log_alpha, log_pi, target_entropy) -> jax.Array:
    """``-log_alpha * (mean(log_pi) + target_entropy)``, the log-densities held fixed.

    Its gradient in ``log_alpha`` is ``-(mean(log_pi) + target_entropy) = entropy - target``:
    alpha falls while the policy's entropy is above the target and rises below it. The paper
    writes ``J(alpha) = E[-alpha (log pi + target)]``, whose gradient in ``alpha`` has the same
    sign and zero; stepping ``log_alpha`` keeps alpha positive, and this form (the authors' own
    code's) scales its step by neither alpha nor its logarithm."""
    return -log_alpha * jax.lax.stop_gradient(jnp.mean(log_pi) + target_entropy)


class CriticAux(NamedTuple):
    """What a critic loss computes besides the loss."""

    q_tm1: jax.Array  # [C, B] the online critics' values
    log_pi_t: jax.Array  # [B] log-densities of the bootstrap actions
    stats: Params | None = None  # batch renormalisation: the critics' statistics after this batch


# ---- losses on networks --------------------------------------------------------------------------
def critic_loss_fn(
    critics: Params,
    target_critics: Params | None,
    actor: Params,
    batch: CriticBatch,
    key: jax.Array,
    alpha: jax.Array,
    nets: Networks,
    critic_stats: Params | None = None,
    actor_stats: Params | None = None,
):
    """``(loss, CriticAux)`` of the soft TD error. ``a' ~ pi(.|s')`` is drawn with ``key`` from
    the actor (evaluation mode) and enters as data. ``target_critics`` None (CrossQ): no target
    networks; the online critics see ``(s, a)`` and ``(s', a')`` in one forward pass, so batch
    renormalisation's statistics cover both, and the bootstrap half gets no gradient (the target
    is stopped)."""
    mean, log_std = actor_outputs(nets, actor, actor_stats, batch.next_obs)
    a_t, log_pi_t = jax.lax.stop_gradient(sampled_action(nets, key, mean, log_std))
    if target_critics is None:
        q_tm1, q_t, stats = joint_values(nets, critics, critic_stats, batch, a_t)
    else:
        q_t = critic_values(nets, target_critics, critic_stats, batch.next_obs, a_t)
        q_tm1, stats = critic_values_train(nets, critics, critic_stats, batch.obs, batch.action)
    loss = soft_critic_loss(q_tm1, batch.r_t, batch.discount_t, q_t, log_pi_t, alpha)
    return loss, CriticAux(q_tm1, log_pi_t, stats)


def joint_values(
    nets: Networks, critics: Params, stats: Params | None, batch: CriticBatch, a_t: jax.Array
):
    """CrossQ: ``(q_tm1, q_t, new stats)`` from one training-mode pass over the batch's
    ``(s, a)`` and ``(s', a')`` stacked, ``[C, B]`` each."""
    obs = jnp.concatenate([batch.obs, batch.next_obs], axis=0)
    action = jnp.concatenate([batch.action, a_t], axis=0)
    q, stats = critic_values_train(nets, critics, stats, obs, action)
    size = batch.obs.shape[0]
    return q[:, :size], q[:, size:], stats


def actor_loss_fn(
    actor: Params,
    critics: Params,
    obs: jax.Array,
    key: jax.Array,
    alpha: jax.Array,
    nets: Networks,
    actor_stats: Params | None = None,
    critic_stats: Params | None = None,
):
    """``(loss, (log_pi [B], new actor stats))``: the soft policy loss at actions drawn with
    ``key``, through every critic (their min; evaluation mode, as CrossQ). Under batch
    renormalisation the actor runs in training mode here, as CrossQ's does."""
    (mean, log_std), stats = actor_outputs_train(nets, actor, actor_stats, obs)
    action, log_pi = sampled_action(nets, key, mean, log_std)
    q = critic_values(nets, critics, critic_stats, obs, action)
    return soft_policy_loss(q, log_pi, alpha), (log_pi, stats)
