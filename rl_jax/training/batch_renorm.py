"""Batch renormalisation (Ioffe 2017) as CrossQ (Bhatt et al. 2024) uses it in its critics.

Batch normalisation standardises each feature by the statistics of the batch it sees; in a
critic, a batch of ``(s, a)`` and one of ``(s', a')`` have different statistics, which is why
CrossQ evaluates both in one forward pass (``joint_pass``, as the ``crossq`` learner calls it).
Batch *re*normalisation corrects the batch statistics towards running ones, so that training
(batch statistics) and acting or evaluating (running statistics) see the same function:

    train:  x_hat = (x - mean_B) / std_B * r + d,  r = clip(std_B / std, 1/r_max, r_max),
            d = clip((mean_B - mean) / std, -d_max, d_max)    (r and d without gradient)
    eval:   x_hat = (x - mean) / std

with ``std = sqrt(var + epsilon)``. The running ``mean``/``var`` take a step ``1 - momentum``
towards the batch's after every training call. For the first ``warmup`` training calls ``r = 1``
and ``d = 0`` (plain batch normalisation) while the running statistics settle, as in CrossQ's
implementation (the BRN paper instead relaxes ``r_max``/``d_max`` from 1/0 gradually). Defaults
are CrossQ's: momentum 0.99 (flax's convention: 0.01 in PyTorch's), epsilon 0.001, r_max 3,
d_max 5, warm-up 100,000 calls.

The statistics live in flax's ``batch_stats`` collection: a learner keeps them in its state (so
they checkpoint) apart from the parameters (which its optimizer steps).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeAlias

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.typing import DTypeLike

#: flax variables (as ``networks.Params``, which imports this module)
Variables: TypeAlias = Mapping[str, Any]

MOMENTUM, EPSILON, R_MAX, D_MAX, WARMUP = 0.99, 1e-3, 3.0, 5.0, 100_000


def _row(x: jax.Array, like: jax.Array) -> jax.Array:
    return jnp.reshape(x, (1,) * (like.ndim - 1) + x.shape)


def renorm_train(
    x: jax.Array,
    mean: jax.Array,
    var: jax.Array,
    steps: jax.Array,
    warmup: int = WARMUP,
    r_max: float = R_MAX,
    d_max: float = D_MAX,
    epsilon: float = EPSILON,
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Training mode on ``x`` [..., F] with running ``mean``/``var`` [F] after ``steps`` training
    calls: ``(x_hat, batch mean [F], batch var [F])``."""
    axes = tuple(range(x.ndim - 1))
    batch_mean = jnp.mean(x, axis=axes)
    batch_var = jnp.mean((x - _row(batch_mean, x)) ** 2, axis=axes)
    batch_std = jnp.sqrt(batch_var + epsilon)
    std = jnp.sqrt(var + epsilon)
    r = jax.lax.stop_gradient(jnp.clip(batch_std / std, 1.0 / r_max, r_max))
    d = jax.lax.stop_gradient(jnp.clip((batch_mean - mean) / std, -d_max, d_max))
    warm = steps >= warmup
    r, d = jnp.where(warm, r, 1.0), jnp.where(warm, d, 0.0)
    x_hat = (x - _row(batch_mean, x)) / _row(batch_std, x) * _row(r, x) + _row(d, x)
    return x_hat, batch_mean, batch_var


def renorm_eval(
    x: jax.Array, mean: jax.Array, var: jax.Array, epsilon: float = EPSILON
) -> jax.Array:
    """Evaluation mode: ``(x - mean) / sqrt(var + epsilon)`` with the running statistics."""
    return (x - _row(mean, x)) / _row(jnp.sqrt(var + epsilon), x)


def running_update(
    mean: jax.Array,
    var: jax.Array,
    batch_mean: jax.Array,
    batch_var: jax.Array,
    momentum: float = MOMENTUM,
) -> tuple[jax.Array, jax.Array]:
    """``(mean, var)`` one step of ``1 - momentum`` towards the batch's (no gradient)."""
    batch_mean, batch_var = jax.lax.stop_gradient((batch_mean, batch_var))
    return (
        momentum * mean + (1.0 - momentum) * batch_mean,
        momentum * var + (1.0 - momentum) * batch_var,
    )


class BatchRenorm(nn.Module):
    """The layer: ``scale * x_hat + bias`` over the last axis; ``train`` picks the mode. In
    training mode (outside ``init``) the ``batch_stats`` collection must be mutable."""

    warmup: int = WARMUP
    dtype: DTypeLike = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool = False) -> jax.Array:
        features = x.shape[-1]
        mean = self.variable("batch_stats", "mean", jnp.zeros, (features,), jnp.float32)
        var = self.variable("batch_stats", "var", jnp.ones, (features,), jnp.float32)
        steps = self.variable("batch_stats", "steps", lambda: jnp.zeros((), jnp.int32))
        scale = self.param("scale", nn.initializers.ones, (features,), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros, (features,), jnp.float32)
        x = x.astype(jnp.float32)
        if train and not self.is_initializing():
            x_hat, batch_mean, batch_var = renorm_train(
                x, mean.value, var.value, steps.value, self.warmup
            )
            mean.value, var.value = running_update(mean.value, var.value, batch_mean, batch_var)
            steps.value = steps.value + 1
        else:
            x_hat = renorm_eval(x, mean.value, var.value)
        return (x_hat * _row(scale, x) + _row(bias, x)).astype(self.dtype)


def joint_pass(
    critic: nn.Module,
    critics: Variables,
    stats: Variables,
    obs_tm1: jax.Array,
    action_tm1: jax.Array,
    obs_t: jax.Array,
    action_t: jax.Array,
) -> tuple[jax.Array, jax.Array, Variables]:
    """CrossQ's critic pass: stacked critics (parameters ``critics`` and statistics ``stats``,
    leaves ``[num_critics, ...]``) in training mode over the batch's ``(s, a)`` and ``(s', a')``
    stacked into one batch, so that batch renormalisation's statistics cover both halves.
    ``(q_tm1 [num_critics, B], q_t [num_critics, B], the statistics with this batch folded in)``.
    ``critic`` is a ``networks.Critic`` (``(obs, action, train=...)``)."""
    obs = jnp.concatenate([obs_tm1, obs_t], axis=0)
    action = jnp.concatenate([action_tm1, action_t], axis=0)

    def one(variables: Variables) -> tuple[jax.Array, Variables]:
        q, updated = critic.apply(variables, obs, action, train=True, mutable=["batch_stats"])
        return q, updated["batch_stats"]

    q, stats = jax.vmap(one)({**critics, "batch_stats": stats})
    size = obs_tm1.shape[0]
    return q[:, :size], q[:, size:], stats
