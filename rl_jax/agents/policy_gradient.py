"""REINFORCE's maths, pure and network-free: the masked reward-to-go and its standardisation, the
log-probabilities and entropy of the Gaussian and categorical policies, and the score-function
loss. Arrays are ``[T, N]`` (time, envs) with a 0/1 ``mask`` of the steps inside episodes.

For envs with a legal-action mask (``info["action_mask"]``, ``rl_jax.envs.core.preprocessing``):
the categorical policy restricted to legal actions (``masked_*``; ``legal`` is bool, True where
an action is legal) for acting, its log-probabilities and its entropy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike


def reward_to_go(r_t: jax.Array, mask: jax.Array, gamma: ArrayLike) -> jax.Array:
    """``G_t = mask_t (r_t + gamma G_{t+1})`` backwards over axis 0: ``[T, N] -> [T, N]``."""

    def back(g_next: jax.Array, inputs: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        r, m = inputs
        g = m * (r + gamma * g_next)
        return g, g

    return jax.lax.scan(back, jnp.zeros_like(r_t[0]), (r_t, mask), reverse=True)[1]


def normalize(x: jax.Array, mask: jax.Array, eps: float = 1e-8) -> jax.Array:
    """``(x - mean) / (std + eps)`` over the entries where ``mask`` is 1 (others become 0)."""
    count = jnp.maximum(jnp.sum(mask), 1.0)
    mean = jnp.sum(x * mask) / count
    std = jnp.sqrt(jnp.sum(((x - mean) * mask) ** 2) / count)
    return mask * (x - mean) / (std + eps)


def gaussian_log_prob(action: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    """Diagonal Gaussian log-density, summed over the last axis: ``[..., D] -> [...]``."""
    z = (action - mean) / std
    return jnp.sum(-0.5 * z**2 - jnp.log(std) - 0.5 * jnp.log(2.0 * jnp.pi), axis=-1)


def categorical_log_prob(logits: jax.Array, action: jax.Array) -> jax.Array:
    """``log softmax(logits)[action]``: ``[..., A], [...] -> [...]``."""
    log_probs = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(log_probs, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def masked_logits(logits: jax.Array, legal: jax.Array) -> jax.Array:
    """``logits`` with the illegal actions' set to the lowest float, so that their probability is
    0 and every log-probability, entropy and gradient stays finite: ``[..., A] -> [..., A]``. A
    row with no legal action keeps all its logits."""
    legal = jnp.asarray(legal, jnp.bool_)
    legal = legal | ~jnp.any(legal, axis=-1, keepdims=True)
    return jnp.where(legal, logits, jnp.finfo(logits.dtype).min)


def masked_categorical_log_prob(
    logits: jax.Array, action: jax.Array, legal: jax.Array
) -> jax.Array:
    """``log pi(action)`` of the softmax over the legal actions: ``[..., A], [...] -> [...]``."""
    return categorical_log_prob(masked_logits(logits, legal), action)


def masked_categorical_sample(key: jax.Array, logits: jax.Array, legal: jax.Array) -> jax.Array:
    """An action drawn from the softmax over the legal actions: ``[..., A] -> [...]`` int32."""
    return jax.random.categorical(key, masked_logits(logits, legal)).astype(jnp.int32)


def masked_categorical_entropy(logits: jax.Array, legal: jax.Array) -> jax.Array:
    """Entropy of the softmax over the legal actions: ``[..., A] -> [...]``."""
    log_probs = jax.nn.log_softmax(masked_logits(logits, legal), axis=-1)
    return -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)


def policy_gradient_loss(log_prob: jax.Array, advantage: jax.Array, mask: jax.Array) -> jax.Array:
    """``-1/N sum_{t,i} mask log_prob stop_gradient(advantage)`` for ``[T, N]`` inputs: the
    negated score-function estimate of the gradient of the mean episode return."""
    weighted = mask * log_prob * jax.lax.stop_gradient(advantage)
    return -jnp.sum(weighted) / log_prob.shape[1]


def entropy(policy: dict[str, jax.Array]) -> jax.Array:
    """Entropy of each distribution: ``[...]`` (a diagonal Gaussian's sums over its dims)."""
    if "logits" in policy:
        log_probs = jax.nn.log_softmax(policy["logits"], axis=-1)
        return -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1)
    return jnp.sum(jnp.log(policy["std"]) + 0.5 * jnp.log(2.0 * jnp.pi * jnp.e), axis=-1)


def log_prob(policy: dict[str, jax.Array], action: jax.Array) -> jax.Array:
    """Log-probability of ``action`` under each distribution: ``[...]`` (a diagonal
    Gaussian's sums over its dims)."""
    if "logits" in policy:
        return categorical_log_prob(policy["logits"], action)
    return gaussian_log_prob(action, policy["mean"], policy["std"])
