"""MuZero's pure maths, apart from the networks and the search: the categorical value and reward
representation, n-step value targets over a stored trajectory, the masks of an unroll that runs
past an episode's end, and the K-step unrolled loss.

Time first throughout (``[T, B]``). A trajectory's step ``t`` acts on ``obs_t`` with
``action_t``, receives ``r_t`` and ends its episode where ``terminated_t`` or ``truncated_t``
(the next stored step then begins a new episode, autoreset). ``v_next_t`` is a value of the true
next observation of step ``t`` (the one that ended the episode, where it ended).

Nothing here builds a network or reads ``rl_jax.agents.muzero``'s settings; the value rescaling
``h`` is R2D2's (``r2d2_parts.value_rescale``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from rl_jax.agents.r2d2_parts import inverse_value_rescale, n_step_targets, value_rescale

#: ``obs [B, ...] -> (latent [B, ...], policy logits [B, A], value logits [B, V])``
InitialFn = Callable[[jax.Array], tuple[jax.Array, jax.Array, jax.Array]]
#: ``(latent, action [B]) -> (latent, reward logits [B, R], policy logits, value logits)``
RecurrentFn = Callable[[jax.Array, jax.Array], tuple[jax.Array, jax.Array, jax.Array, jax.Array]]


# ---- the categorical representation of scalars ----------------------------------------------
def scalar_to_support(x: jax.Array, support_size: int, eps: ArrayLike = 1e-3) -> jax.Array:
    """``[...] -> [..., 2 S + 1]``: the two-hot distribution on the integers ``-S .. S``
    (``S = support_size``) whose mean is ``h(x)`` (``value_rescale``), clipped to the support.

    ``h(x) = 2.3`` puts 0.7 on 2 and 0.3 on 3; a value on an integer is one-hot."""
    scaled = jnp.clip(value_rescale(x, eps), -support_size, support_size)
    low = jnp.floor(scaled)
    upper_weight = scaled - low
    index = (low + support_size).astype(jnp.int32)
    bins = 2 * support_size + 1
    lower = jax.nn.one_hot(index, bins) * (1.0 - upper_weight)[..., None]
    upper = jax.nn.one_hot(jnp.minimum(index + 1, bins - 1), bins) * upper_weight[..., None]
    return lower + upper


def support_to_scalar(probs: jax.Array, support_size: int, eps: ArrayLike = 1e-3) -> jax.Array:
    """``[..., 2 S + 1] -> [...]``: the inverse of ``scalar_to_support``, ``h^-1`` of the mean
    of a distribution on the integers ``-S .. S``."""
    support = jnp.arange(-support_size, support_size + 1, dtype=probs.dtype)
    return inverse_value_rescale(probs @ support, eps)


def logits_to_scalar(logits: jax.Array, support_size: int, eps: ArrayLike = 1e-3) -> jax.Array:
    """``support_to_scalar`` of the softmax of ``logits``: a network head's scalar."""
    return support_to_scalar(jax.nn.softmax(logits, axis=-1), support_size, eps)


def scale_latent(latent: jax.Array) -> jax.Array:
    """MuZero's min-max scaling of a hidden state to ``[0, 1]`` over its last axis, so that the
    dynamics sees it on the scale of its one-hot action input, at every unroll depth."""
    low = jnp.min(latent, axis=-1, keepdims=True)
    high = jnp.max(latent, axis=-1, keepdims=True)
    return (latent - low) / jnp.maximum(high - low, 1e-5)


def scale_gradient(x: jax.Array, scale: ArrayLike) -> jax.Array:
    """``x`` unchanged forward, its gradient multiplied by ``scale`` backward."""
    return x * scale + jax.lax.stop_gradient(x) * (1.0 - scale)


# ---- targets ----------------------------------------------------------------------------------
def value_targets(
    r_t: jax.Array,
    terminated_t: jax.Array,
    truncated_t: jax.Array,
    v_next_t: jax.Array,
    gamma: ArrayLike,
    n: int,
) -> jax.Array:
    """``[T, B]`` n-step value targets of every step of a trajectory, no gradient:
    ``z_t = r_t + gamma r_{t+1} + ... + gamma^(m-t) (r_m + gamma v_next_m)``, ``m`` the first of
    ``t + n - 1``, the first step at or after ``t`` that ends an episode, and the last step.

    A termination contributes nothing after its reward (the episode is over: zero after an
    end); a truncation bootstraps from ``v_next`` of the observation that ended it, so a time
    limit does not look like a failure."""
    discount_t = jnp.asarray(gamma) * (1.0 - terminated_t.astype(r_t.dtype))
    ended = jnp.logical_or(terminated_t, truncated_t)
    return jax.lax.stop_gradient(n_step_targets(r_t, discount_t, v_next_t, ended, n))


def unroll_masks(terminated_t: jax.Array, truncated_t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(alive, absorbing)``, each ``[K + 1, B]`` float, of an unroll of the ``K`` steps
    ``terminated_t``, ``truncated_t`` ``[K, B]`` from a trajectory's step 0.

    ``alive[k]`` is 1 where the state after ``k`` steps is still in step 0's episode (no step
    before ``k`` ended it). ``absorbing[k]`` is 1 past the episode's end where that end was a
    termination: the unrolled model is then in an absorbing state of value 0 and reward 0, which
    it learns as such. Past a truncation the continuation is unknown: both are 0 there."""
    ended = jnp.logical_or(terminated_t, truncated_t).astype(jnp.int32)
    start = jnp.zeros((1, *ended.shape[1:]), ended.dtype)  # K = 0 too: one step, alive
    ends_before = jnp.concatenate([start, jnp.cumsum(ended, axis=0)], axis=0)
    alive = ends_before == 0
    # the first end decides: it was a termination where no step before it ended anything
    first_end = jnp.logical_and(ended == 1, ends_before[:-1] == 0)
    terminated_first = jnp.sum(jnp.where(first_end, terminated_t, False), axis=0) > 0
    absorbing = jnp.logical_and(~alive, terminated_first[None])
    return alive.astype(jnp.float32), absorbing.astype(jnp.float32)


# ---- prioritised starts --------------------------------------------------------------------
def ring_times(written: jax.Array, capacity: int) -> jax.Array:
    """``[capacity]`` the step (counted from the first, 0) that each row of a ring holds after
    ``written`` steps were written in order; negative for rows not yet written."""
    rows = jnp.arange(capacity)
    return written - 1 - jnp.mod(written - 1 - rows, capacity)


def start_probabilities(
    priority: jax.Array, valid: jax.Array, alpha: ArrayLike
) -> tuple[jax.Array, jax.Array]:
    """``(P, count)``: the chance ``p_i^alpha / sum_j p_j^alpha`` of drawing each entry of
    ``priority`` among the ``valid`` ones (flattened), and how many are valid. ``alpha`` 0 is
    uniform; where none is valid, all are drawn uniformly."""
    scaled = jnp.where(valid, jnp.power(priority, alpha), 0.0).ravel()
    total = jnp.sum(scaled)
    scaled = jnp.where(total > 0.0, scaled, 1.0)
    return scaled / jnp.sum(scaled), jnp.maximum(jnp.sum(valid), 1)


def importance_weights(probability: jax.Array, count: jax.Array, beta: ArrayLike) -> jax.Array:
    """``(count P_i)^-beta`` of the drawn entries, divided by their largest (Schaul et al.
    2016): they undo the bias of drawing by priority, ``beta`` 1 fully."""
    weight = jnp.power(count * jnp.maximum(probability, 1e-12), -jnp.asarray(beta))
    return weight / jnp.max(weight)


# ---- the loss ---------------------------------------------------------------------------------
def categorical_cross_entropy(target_probs: jax.Array, logits: jax.Array) -> jax.Array:
    """``-sum_i p_i log softmax(logits)_i`` over the last axis."""
    return -jnp.sum(target_probs * jax.nn.log_softmax(logits, axis=-1), axis=-1)


def unroll_loss(
    initial: InitialFn,
    recurrent: RecurrentFn,
    obs: jax.Array,
    actions: jax.Array,
    policy_targets: jax.Array,
    value_targets: jax.Array,
    reward_targets: jax.Array,
    masks: tuple[jax.Array, jax.Array],
    support: tuple[int, int],
    value_coef: ArrayLike = 1.0,
    sample_weight: jax.Array | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """MuZero's loss of a batch of ``K``-step unrolls, ``(mean over the batch, metrics)``.

    ``obs [B, ...]`` is each unroll's first observation, ``actions [K, B]`` the actions taken
    from it, ``policy_targets [K + 1, B, A]`` the search's improved policies, ``value_targets
    [K + 1, B]`` and ``reward_targets [K, B]`` scalars, ``masks`` ``unroll_masks``'s ``(alive,
    absorbing)``, ``support`` the ``(value, reward)`` support sizes, ``sample_weight [B]`` the
    unrolls' weights in the mean (prioritised replay's importance weights; None: all 1). Per
    unroll::

        sum_k w_k [alive_k CE(pi_k, p_k) + value_coef (alive_k + absorbing_k) CE(phi(z_k), v_k)
                   + (alive_{k-1} + absorbing_{k-1}) CE(phi(u_k), r_k)],

    with ``phi`` ``scalar_to_support`` (targets past a termination are 0), ``w_0 = 1`` and
    ``w_k = 1 / K`` for the unrolled steps, and the hidden state's gradient halved at every
    dynamics step (Schrittwieser et al. 2020, Appendix G)."""
    value_support, reward_support = support
    alive, absorbing = masks
    steps = actions.shape[0]
    latent, policy_logits, value_logits = initial(obs)
    policy_losses, value_losses, reward_losses = [], [], []
    for k in range(steps + 1):
        if k > 0:
            latent = scale_gradient(latent, 0.5)
            latent, reward_logits, policy_logits, value_logits = recurrent(latent, actions[k - 1])
            reward = jnp.where(absorbing[k - 1] > 0, 0.0, reward_targets[k - 1])
            reward_weight = alive[k - 1] + absorbing[k - 1]
            reward_ce = categorical_cross_entropy(
                scalar_to_support(reward, reward_support), reward_logits
            )
            reward_losses.append(reward_weight * reward_ce / steps)
        step_weight = 1.0 if k == 0 else 1.0 / steps
        value = jnp.where(absorbing[k] > 0, 0.0, value_targets[k])
        value_ce = categorical_cross_entropy(scalar_to_support(value, value_support), value_logits)
        value_losses.append(step_weight * (alive[k] + absorbing[k]) * value_ce)
        policy_ce = categorical_cross_entropy(policy_targets[k], policy_logits)
        policy_losses.append(step_weight * alive[k] * policy_ce)
    weight = jnp.ones(obs.shape[:1]) if sample_weight is None else sample_weight
    policy_loss = jnp.mean(weight * jnp.sum(jnp.stack(policy_losses), axis=0))
    value_loss = jnp.mean(weight * jnp.sum(jnp.stack(value_losses), axis=0))
    rewards = jnp.stack([jnp.zeros(obs.shape[:1]), *reward_losses])
    reward_loss = jnp.mean(weight * jnp.sum(rewards, axis=0))
    total = policy_loss + value_coef * value_loss + reward_loss
    metrics = {"policy_loss": policy_loss, "value_loss": value_loss, "reward_loss": reward_loss}
    return total, metrics
