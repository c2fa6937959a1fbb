"""Distributional Q-learning's maths, pure and network-free: C51's categorical projection and
cross-entropy (Bellemare et al. 2017), QR-DQN's quantile midpoints and quantile Huber loss
(Dabney et al. 2018), and the n-step return both bootstrap from. rlax naming: ``tm1`` is a
transition's start, ``t`` its end.

Both learn a distribution of returns per action in place of its mean: C51 as probabilities on a
fixed ``support`` of ``N`` atoms between ``v_min`` and ``v_max``, QR-DQN as ``N`` values at fixed
quantile levels. An n-step target is ``G + D z`` for each atom or quantile ``z`` of the bootstrap
action's distribution, with ``G`` the discounted n-step reward and ``D`` the product of the
window's discounts (0 after a termination, so a terminal target is ``G`` alone). The mean of a
distribution is its Q-value: what the greedy action, Double DQN's selection and logging read.

Nothing here imports a learner; ``rl_jax.agents.distributional`` builds on it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from rl_jax.agents.q_learning import huber_loss


# ---- both -----------------------------------------------------------------------------------
def n_step_return(r_t: jax.Array, discount_t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(G [B], D [B])`` of n-step windows ``r_t``, ``discount_t`` ``[B, n]``:
    ``G = r[0] + d[0] (r[1] + d[1] (... r[n-1]))`` and ``D = d[0] d[1] ... d[n-1]``, so that
    ``G + D v`` is the n-step target of a bootstrap value ``v`` (as ``q_learning.n_step_target``:
    steps after a window's end carry ``r = 0, d = 1``, a termination ``d = 0``)."""
    total = jnp.zeros_like(r_t[:, 0])
    discount = jnp.ones_like(discount_t[:, 0])
    for k in reversed(range(r_t.shape[1])):
        total = r_t[:, k] + discount_t[:, k] * total
        discount = discount_t[:, k] * discount
    return total, discount


def select_action(values: jax.Array, a: jax.Array) -> jax.Array:
    """The distribution of action ``a`` [B] from ``values`` [B, A, N]: ``[B, N]``."""
    return jnp.take_along_axis(values, a.astype(jnp.int32)[:, None, None], axis=1)[:, 0]


# ---- C51 ------------------------------------------------------------------------------------
def categorical_support(v_min: float, v_max: float, num_atoms: int) -> jax.Array:
    """The atoms ``z_j = v_min + j (v_max - v_min) / (N - 1)``, ``j = 0..N-1``: ``[N]``."""
    return jnp.linspace(v_min, v_max, num_atoms, dtype=jnp.float32)


def categorical_q_values(logits: jax.Array, support: jax.Array) -> jax.Array:
    """Q-values ``sum_j softmax(logits)_j z_j``: ``[..., A, N] -> [..., A]``."""
    probs = jax.nn.softmax(logits, axis=-1)
    return jnp.sum(probs * jnp.broadcast_to(support, probs.shape), axis=-1)


def categorical_projection(
    support: jax.Array, probs_t: jax.Array, return_t: jax.Array, discount_t: jax.Array
) -> jax.Array:
    """The target distribution ``[B, N]`` on ``support`` [N]: each atom ``z_i`` of ``probs_t``
    [B, N] moves to ``G + D z_i`` (``return_t``, ``discount_t`` [B]), clipped to
    ``[v_min, v_max]``, and its probability is split between the two atoms around it in
    proportion to closeness (all of it to an atom it lands on exactly). As a kernel: atom ``j``
    receives ``sum_i p_i max(0, 1 - |clip(G + D z_i) - z_j| / dz)``, ``dz`` the atom spacing.
    No gradient flows through it."""
    num_atoms = support.shape[0]
    v_min, v_max = support[0], support[-1]
    spacing = (v_max - v_min) / (num_atoms - 1)
    moved = return_t[:, None] + discount_t[:, None] * support[None, :]  # [B, N] source atoms
    moved = jnp.clip(moved, v_min, v_max)
    distance = jnp.abs(moved[:, :, None] - support[None, None, :])  # [B, source, target]
    share = jnp.clip(1.0 - distance / spacing, 0.0, 1.0)
    return jax.lax.stop_gradient(jnp.sum(probs_t[:, :, None] * share, axis=1))


def categorical_loss(
    logits_tm1: jax.Array, a_tm1: jax.Array, target_tm1: jax.Array, weights: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """C51's loss: the cross-entropy ``-sum_j m_j log p_j(s, a)`` of the taken action's
    predicted distribution (``logits_tm1`` [B, A, N], ``a_tm1`` [B]) against the projected
    target ``m`` (``target_tm1`` [B, N]), weighted by ``weights`` [B] and averaged over the
    batch. Returns ``(loss, per-sample cross-entropy [B])``; the latter is what prioritized
    replay ranks by (it differs from the KL divergence of Rainbow's priorities by the target's
    entropy, which the network does not change)."""
    log_probs = jax.nn.log_softmax(select_action(logits_tm1, a_tm1), axis=-1)
    cross_entropy = -jnp.sum(target_tm1 * log_probs, axis=-1)
    return jnp.mean(weights * cross_entropy), cross_entropy


# ---- QR-DQN ---------------------------------------------------------------------------------
def quantile_midpoints(num_quantiles: int) -> jax.Array:
    """The quantile levels ``tau_i = (2 i + 1) / (2 N)``, ``i = 0..N-1``: ``[N]``, the midpoints
    of ``N`` equal slices of [0, 1] (the levels the paper's projection is exact at)."""
    return (2.0 * jnp.arange(num_quantiles, dtype=jnp.float32) + 1.0) / (2.0 * num_quantiles)


def quantile_q_values(quantiles: jax.Array) -> jax.Array:
    """Q-values, the mean of the equally weighted quantiles: ``[..., A, N] -> [..., A]``."""
    return jnp.mean(quantiles, axis=-1)


def quantile_huber_loss(
    quantiles_tm1: jax.Array,
    a_tm1: jax.Array,
    target_tm1: jax.Array,
    weights: jax.Array,
    kappa: ArrayLike,
) -> tuple[jax.Array, jax.Array]:
    """QR-DQN's loss. For the taken action's quantiles ``theta_i`` (``quantiles_tm1`` [B, A, N],
    ``a_tm1`` [B]) and the target samples ``T theta_j`` (``target_tm1`` [B, M]), with
    ``u_ij = T theta_j - theta_i``:

        rho_i(u) = |tau_i - 1{u < 0}| L_kappa(u) / kappa,   per sample: sum_i mean_j rho_i(u_ij)

    (the paper's eq. 10), ``L_kappa`` the Huber loss of threshold ``kappa``. Weighted by
    ``weights`` [B] and averaged over the batch. Returns ``(loss, per-sample loss [B])``; the
    latter is what prioritized replay ranks by. ``target_tm1`` carries no gradient."""
    theta = select_action(quantiles_tm1, a_tm1)  # [B, N]
    tau = quantile_midpoints(theta.shape[-1])
    u = jax.lax.stop_gradient(target_tm1)[:, None, :] - theta[:, :, None]  # [B, N(i), M(j)]
    below = (u < 0.0).astype(u.dtype)
    rho = jnp.abs(tau[None, :, None] - below) * huber_loss(u, kappa) / kappa
    per_sample = jnp.sum(jnp.mean(rho, axis=2), axis=1)
    return jnp.mean(weights * per_sample), per_sample
