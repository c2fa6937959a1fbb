"""Running mean and variance of observations, for learners that standardise their inputs.

The statistics are part of the learner's state (so they checkpoint, vmap over seeds and go with
the policy when it is exported): ``normalize(stats, obs)`` is what the network sees, and
``update(stats, batch, mask)`` folds a batch in with the parallel-variance formula of Chan et al.
(1979), so a batch of any size is one exact update of the population moments. Acting and learning
from one batch both use the statistics from *before* that batch, so the update is a function of
the data the policy saw.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

EPSILON = 1e-8  # added to the variance before the square root
CLIP = 10.0  # standardised observations are clipped to +-CLIP (outliers early in training)


@struct.dataclass
class RunningStats:
    count: jax.Array  # [] float32, samples folded in so far (a small prior count at start)
    mean: jax.Array  # [obs_dim] float32
    var: jax.Array  # [obs_dim] float32, population variance


def init(size: int) -> RunningStats:
    """Mean 0 and variance 1 with a negligible weight: the first batch sets the moments."""
    return RunningStats(
        count=jnp.float32(1e-4),
        mean=jnp.zeros(size, jnp.float32),
        var=jnp.ones(size, jnp.float32),
    )


def update(stats: RunningStats, batch: jax.Array, mask: jax.Array) -> RunningStats:
    """Fold the rows of ``batch [..., obs_dim]`` where ``mask [...]`` is 1 into ``stats``."""
    rows = batch.reshape(-1, batch.shape[-1])
    weights = mask.reshape(-1, 1).astype(jnp.float32)
    count = jnp.sum(weights)
    safe = jnp.maximum(count, 1.0)
    mean = jnp.sum(rows * weights, axis=0) / safe
    var = jnp.sum(weights * (rows - mean[None]) ** 2, axis=0) / safe
    total = stats.count + count
    delta = mean - stats.mean
    new_mean = stats.mean + delta * count / total
    moment = stats.var * stats.count + var * count + delta**2 * stats.count * count / total
    return RunningStats(count=total, mean=new_mean, var=moment / total)


def normalize(stats: RunningStats | None, obs: jax.Array) -> jax.Array:
    """``clip((obs - mean) / sqrt(var + eps))``; ``stats=None`` leaves ``obs`` as it is."""
    if stats is None:
        return obs
    leading = (1,) * (obs.ndim - 1)
    mean = jnp.reshape(stats.mean, leading + stats.mean.shape)
    std = jnp.reshape(jnp.sqrt(stats.var + EPSILON), leading + stats.var.shape)
    return jnp.clip((obs - mean) / std, -CLIP, CLIP)
