"""The tanh-squashed diagonal Gaussian policy of SAC (Haarnoja et al. 2018, appendix C), as pure
maths and as a network head.

A network gives a mean ``mu`` and a log-std ``log_std`` per action dim (the log-std clipped to a
range, so the density stays finite and the std cannot blow up); ``u ~ N(mu, exp(log_std)^2)``
and the action is ``a = tanh(u)`` in (-1, 1), stretched onto the env's bounds afterwards. By the
change of variables, the density of ``a`` in (-1, 1) is

    log pi(a) = sum_i [ log N(u_i; mu_i, std_i) - log(1 - tanh(u_i)^2) ],

with ``log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u))``, a form that stays exact where
``1 - tanh(u)^2`` rounds to 0 in float32 (``|u|`` past ~9). Densities are of the action in
(-1, 1), not in env units: the affine stretch only shifts ``log pi`` by a constant, and SAC's
target entropy ``-|A|`` is stated for actions in (-1, 1). The deterministic policy is
``tanh(mu)``.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from rl_jax.training import networks

LOG_2 = math.log(2.0)
LOG_2PI = math.log(2.0 * math.pi)
#: the log-std range of SAC's reference implementation (softlearning), also CrossQ's
LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0


# ---- maths ---------------------------------------------------------------------------------------
def tanh_log_det_jacobian(u: jax.Array) -> jax.Array:
    """``log |d tanh(u) / du| = log(1 - tanh(u)^2)``, elementwise, in its stable form."""
    return 2.0 * (LOG_2 - u - jax.nn.softplus(-2.0 * u))


def gaussian_log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """``log N(u; mean, exp(log_std)^2)`` summed over the last axis (independent dims)."""
    z = (u - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z**2 - log_std - 0.5 * LOG_2PI, axis=-1)


def log_prob(u: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """``log pi(tanh(u))``: the density of the squashed action, from the pre-tanh ``u``
    (``[..., A] -> [...]``). Taking ``u`` rather than ``a`` avoids ``atanh`` near +-1."""
    return gaussian_log_prob(u, mean, log_std) - jnp.sum(tanh_log_det_jacobian(u), axis=-1)


def sample(key: jax.Array, mean: jax.Array, log_std: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(a [..., A] in (-1, 1), log pi(a) [...])``, reparameterised: ``u = mean + std * eps``
    with ``eps ~ N(0, 1)``, so gradients reach ``mean`` and ``log_std`` through ``a`` and
    ``log pi``. The Gaussian term uses ``eps`` itself (``(u - mean) / std`` is ``eps`` exactly,
    where the subtraction would round it away for a tiny std)."""
    eps = jax.random.normal(key, mean.shape, mean.dtype)
    u = mean + jnp.exp(log_std) * eps
    gaussian = jnp.sum(-0.5 * eps**2 - log_std - 0.5 * LOG_2PI, axis=-1)
    return jnp.tanh(u), gaussian - jnp.sum(tanh_log_det_jacobian(u), axis=-1)


def entropy_estimate(log_pi: jax.Array) -> jax.Array:
    """The policy's entropy estimated from sampled actions' log-densities: ``-mean(log_pi)``
    (one sample per state, averaged over the batch)."""
    return -jnp.mean(log_pi)


def rescale(a: jax.Array, low: ArrayLike, high: ArrayLike) -> jax.Array:
    """``a [..., A]`` in [-1, 1] stretched onto ``[low, high]`` (each ``[A]``)."""
    shape = (1,) * (a.ndim - 1) + (-1,)
    low = jnp.reshape(jnp.asarray(low, a.dtype), shape)
    high = jnp.reshape(jnp.asarray(high, a.dtype), shape)
    return low + (a + 1.0) * 0.5 * (high - low)


# ---- the network head ----------------------------------------------------------------------------
class GaussianActor(nn.Module):
    """``obs [..., obs_dim] -> (mean, log_std)``, each ``[..., action_dim]``, pre-tanh; the
    log-std clipped to ``[log_std_min, log_std_max]``. The hidden ``layers`` are a
    ``networks.MLP`` (with its ``norm``: "layer" or "batch_renorm", the latter taking ``train``)
    or SimBa's blocks; one linear output layer gives both halves."""

    layers: networks.Layers
    action_dim: int
    log_std_min: float = LOG_STD_MIN
    log_std_max: float = LOG_STD_MAX

    @nn.compact
    def __call__(self, obs: jax.Array, train: bool = False) -> tuple[jax.Array, jax.Array]:
        body = networks.torso_and_head(self.layers, 2 * self.action_dim, 0.01)
        raw = body(obs, train) if isinstance(body, networks.MLP) else body(obs)
        mean, log_std = jnp.split(raw, 2, axis=-1)
        return mean, jnp.clip(log_std, self.log_std_min, self.log_std_max)
