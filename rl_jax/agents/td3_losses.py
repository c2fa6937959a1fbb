"""TD3's losses: the pure maths (rlax naming: ``tm1`` is the transition's start, ``t`` its end;
testable alone with exact values) and the losses on networks that the update differentiates.
``hparams`` is a ``td3.Hyperparams``; ``nets`` a ``td3_networks.Networks``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from rl_jax.agents import td7_parts
from rl_jax.agents.td3_networks import (
    Networks,
    critic_values,
    critic_values_train,
    embeddings,
    first_critic_value,
    policy_action,
    row,
)
from rl_jax.training import replay
from rl_jax.training.replay import Transition

Hyperparams = Any  # td3.Hyperparams (td3 imports this module)


# ---- loss maths (pure; rlax naming: tm1 = the transition's start, t = its end) -----------------
def smoothed_target_action(a_t, noise, noise_clip, low, high) -> jax.Array:
    """Target policy smoothing: ``clip(a_t + clip(noise, -noise_clip, noise_clip), low, high)``."""
    return jnp.clip(a_t + jnp.clip(noise, -noise_clip, noise_clip), low, high)


def clipped_double_q_target(r_t, discount_t, q_t) -> jax.Array:
    """``r_t + discount_t * min_i q_t[i]`` with no gradient; ``q_t`` [num_critics, B] -> [B].
    With one critic this is the plain DDPG target. ``discount_t`` is 0 at termination."""
    return jax.lax.stop_gradient(r_t + discount_t * jnp.min(q_t, axis=0))


def critic_loss(q_tm1, r_t, discount_t, q_t) -> jax.Array:
    """Sum over critics of the mean squared error to the shared target; ``q_tm1`` [C, B]."""
    target = clipped_double_q_target(r_t, discount_t, q_t)
    return jnp.sum(jnp.mean((q_tm1 - target[None, :]) ** 2, axis=-1))


def deterministic_policy_loss(q_tm1) -> jax.Array:
    """The actor ascends Q at its own action: loss ``-mean(q_tm1)``."""
    return -jnp.mean(q_tm1)


# ---- losses on networks ----------------------------------------------------------------------
def target_action(
    target_actor_params, next_obs, noise, hparams: Hyperparams, nets: Networks, encoder=None
):
    """The target actor's action plus smoothing noise ``target_noise * noise`` clipped to
    ``+-target_noise_clip`` (both x the action half-range); ``noise`` is standard normal.
    ``encoder``: SALE's fixed target encoder."""
    a_t = policy_action(nets, target_actor_params, next_obs, encoder)
    scale = row(nets.half_range, a_t)
    return smoothed_target_action(
        a_t,
        hparams.target_noise * scale * noise,
        hparams.target_noise_clip * scale,
        row(nets.low, a_t),
        row(nets.high, a_t),
    )


class CriticBatch(NamedTuple):
    """What a critic update reads: the target is ``r_t + discount_t * min_i q_t[i]`` at
    ``next_obs`` (one step: ``gamma`` or 0 at termination; n steps: the folded window)."""

    obs: jax.Array
    action: jax.Array
    r_t: jax.Array  # [B]
    discount_t: jax.Array  # [B]
    next_obs: jax.Array

    @classmethod
    def one_step(cls, batch: Transition, gamma) -> CriticBatch:
        discount_t = gamma * (1.0 - batch.terminated.astype(jnp.float32))
        return cls(batch.obs, batch.action, batch.reward, discount_t, batch.next_obs)

    @classmethod
    def n_step(cls, batch: replay.NStepBatch) -> CriticBatch:
        r_t, discount_t = replay.fold_n_step(batch.r_t, batch.discount_t)
        return cls(batch.obs, batch.action, r_t, discount_t, batch.next_obs)


class CriticAux(NamedTuple):
    """What a critic loss computes besides the loss."""

    q_tm1: jax.Array  # [C, B] the online critics' values
    td_tm1: jax.Array  # [C, B] their errors against the (stopped-gradient) target
    batch_stats: Any = None  # batch_renorm: the statistics after this batch
    target_range: Any = None  # value_clipping: (min, max) of this batch's targets


def critic_loss_fn(
    critic_params,
    target_actor_params,
    target_critic_params,
    batch: Transition | CriticBatch,
    noise: jax.Array,
    hparams: Hyperparams,
    nets: Networks,
    encoders: tuple[Any, Any] = (None, None),
    stats: Any = None,
    value_range: tuple[Any, Any] | None = None,
):
    """Critic loss on a batch (a ``Transition`` is a one-step ``CriticBatch``); ``noise``
    [B, action_dim] is standard normal; ``encoders``: SALE's ``(fixed, fixed_target)``;
    ``stats``: batch renormalisation's statistics; ``value_range``: TD7's ``(low, high)`` bounds
    on the bootstrap value. Returns ``(loss, CriticAux)``: the mean
    squared TD error, or with ``lap`` LAP's loss. Target networks (and encoders) enter only
    through the stopped-gradient target. Without target networks (CrossQ) the "target"
    parameters are the online actor's and critics'."""
    if isinstance(batch, Transition):
        batch = CriticBatch.one_step(batch, hparams.gamma)
    fixed, fixed_target = encoders
    a_t = target_action(target_actor_params, batch.next_obs, noise, hparams, nets, fixed_target)
    extra_t = embeddings(nets, fixed_target, batch.next_obs, a_t)
    extra_tm1 = embeddings(nets, fixed, batch.obs, batch.action)
    if nets.config.target_networks:
        q_t = critic_values(nets, target_critic_params, batch.next_obs, a_t, extra_t, stats)
        q_tm1, stats = _online_values(nets, critic_params, stats, batch, extra_tm1)
    else:  # a' joins the batch statistics, but as data: no gradient reaches the actor
        a_t, extra_t = jax.lax.stop_gradient((a_t, extra_t))
        q_tm1, q_t, stats = _joint_values(
            nets, critic_params, stats, batch, a_t, extra_tm1, extra_t
        )
    loss, td_tm1, target_range = _loss_and_errors(q_tm1, q_t, batch, value_range, nets.config.lap)
    return loss, CriticAux(q_tm1, td_tm1, stats, target_range)


def _loss_and_errors(q_tm1, q_t, batch: CriticBatch, value_range, lap: bool):
    """``(loss, td_tm1, (min, max) of the targets or None)``: TD3's target (TD7's clipped one
    with a ``value_range``), then the squared error or LAP's loss."""
    if value_range is None:
        target = clipped_double_q_target(batch.r_t, batch.discount_t, q_t)
    else:
        target = td7_parts.value_clipped_target(batch.r_t, batch.discount_t, q_t, *value_range)
    td_tm1 = q_tm1 - target[None, :]
    if lap:
        loss = td7_parts.lap_loss(td_tm1)
    elif value_range is None:  # as it always was: plain TD3 stays bit-identical
        loss = critic_loss(q_tm1, batch.r_t, batch.discount_t, q_t)
    else:
        loss = jnp.sum(jnp.mean(td_tm1**2, axis=-1))
    target_range = None if value_range is None else (jnp.min(target), jnp.max(target))
    return loss, td_tm1, target_range


def _online_values(nets: Networks, critics, stats, batch: CriticBatch, extra):
    """``(q_tm1, new stats)``: training mode under batch renormalisation."""
    if stats is None:
        return critic_values(nets, critics, batch.obs, batch.action, extra), None
    return critic_values_train(nets, critics, stats, batch.obs, batch.action, extra)


def _joint_values(nets: Networks, critics, stats, batch: CriticBatch, a_t, extra_tm1, extra_t):
    """CrossQ: ``(q_tm1, q_t, new stats)`` from one forward pass over the batch's ``(s, a)``
    and ``(s', a')`` together, so batch renormalisation's statistics cover both."""
    join = lambda a, b: None if a is None else jnp.concatenate([a, b], axis=0)  # noqa: E731
    joined = CriticBatch(
        join(batch.obs, batch.next_obs), join(batch.action, a_t), batch.r_t, batch.discount_t, None
    )
    q, stats = _online_values(nets, critics, stats, joined, join(extra_tm1, extra_t))
    size = batch.obs.shape[0]
    return q[:, :size], q[:, size:], stats


def actor_loss_fn(
    actor_params, critic_params, obs: jax.Array, nets: Networks, encoder=None, stats=None
) -> jax.Array:
    """Deterministic policy gradient through the *first* critic only (as TD3 prescribes);
    ``encoder``: SALE's fixed encoder, which the gradient passes through but never changes;
    ``stats``: batch renormalisation's statistics (evaluation mode, as CrossQ)."""
    action = policy_action(nets, actor_params, obs, encoder)
    extra = embeddings(nets, encoder, obs, action)
    return deterministic_policy_loss(
        first_critic_value(nets, critic_params, obs, action, extra, stats)
    )


def encoder_loss_fn(encoder_params, batch: CriticBatch, nets: Networks) -> jax.Array:
    """SALE's loss: ``g(f(s), a)`` against ``f(s')`` of the same (online) encoder, stopped."""
    zs_t = nets.encoder.apply(encoder_params, batch.next_obs, method="embed_state")
    zsa_tm1 = nets.encoder.apply(encoder_params, batch.obs, batch.action)[1]
    return td7_parts.sale_loss(zsa_tm1, zs_t)
