"""SAC's pure maths (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"): the
soft target, the critics', actor's and temperature's losses of the ``sac`` learner
(``rl_jax.agents.sac``), each testable alone with exact values.

Naming as rlax: ``tm1`` is a transition's start, ``t`` its end; ``q_*`` are ``[num_critics, B]``,
``r_t``, ``discount_t`` and the log-densities ``[B]``, ``alpha`` the temperature (a scalar).

* Critics: ``J_Q = 1/2 E[(Q_i(s, a) - y)^2]`` for each critic, summed, with the soft target
  ``y = r + discount * (min_i Q'_i(s', a') - alpha log pi(a'|s'))``, ``a' ~ pi(.|s')`` from the
  current actor; ``discount`` is 0 at termination only (a time-limit truncation still
  bootstraps from the true final observation).
* Actor: ``J_pi = E[alpha log pi(a|s) - min_i Q_i(s, a)]``, ``a ~ pi(.|s)`` reparameterised.
* Temperature: ``alpha = exp(log_alpha)`` learned so that the policy's entropy tracks a target.

With n-step windows the target sums the window's rewards and bootstraps once at its end; the
entropy bonuses of the steps inside the window are left out (their actions came from older
policies, so today's ``log pi`` of them is not what those steps earned).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike


def soft_td_target(
    r_t: jax.Array, discount_t: jax.Array, q_t: jax.Array, log_pi_t: jax.Array, alpha: ArrayLike
) -> jax.Array:
    """``r_t + discount_t * (min_i q_t[i] - alpha * log_pi_t)`` with no gradient -> ``[B]``."""
    soft_value = jnp.min(q_t, axis=0) - alpha * log_pi_t
    return jax.lax.stop_gradient(r_t + discount_t * soft_value)


def soft_critic_loss(
    q_tm1: jax.Array,
    r_t: jax.Array,
    discount_t: jax.Array,
    q_t: jax.Array,
    log_pi_t: jax.Array,
    alpha: ArrayLike,
) -> jax.Array:
    """``sum_i 1/2 mean_b (q_tm1[i] - y)^2`` against the shared soft target ``y``."""
    target = soft_td_target(r_t, discount_t, q_t, log_pi_t, alpha)
    return 0.5 * jnp.sum(jnp.mean((q_tm1 - target[None, :]) ** 2, axis=-1))


def soft_policy_loss(q_tm1: jax.Array, log_pi_tm1: jax.Array, alpha: ArrayLike) -> jax.Array:
    """``mean(alpha * log_pi_tm1 - min_i q_tm1[i])``: ``q_tm1`` at the policy's own sampled
    actions, ``log_pi_tm1`` their log-densities."""
    return jnp.mean(alpha * log_pi_tm1 - jnp.min(q_tm1, axis=0))


def temperature_loss(
    log_alpha: jax.Array, log_pi: jax.Array, target_entropy: ArrayLike
) -> jax.Array:
    """``-log_alpha * (mean(log_pi) + target_entropy)``, the log-densities held fixed.

    Its gradient in ``log_alpha`` is ``-(mean(log_pi) + target_entropy) = entropy - target``:
    alpha falls while the policy's entropy is above the target and rises below it. The paper
    writes ``J(alpha) = E[-alpha (log pi + target)]``, whose gradient in ``alpha`` has the same
    sign and zero; stepping ``log_alpha`` keeps alpha positive, and this form (the authors' own
    code's) scales its step by neither alpha nor its logarithm."""
    return -log_alpha * jax.lax.stop_gradient(jnp.mean(log_pi) + target_entropy)
