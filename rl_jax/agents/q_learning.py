"""DQN's maths, pure and network-free: bootstrap values (plain and double), n-step targets and
windows, the Huber TD loss, and the linear epsilon schedule. rlax naming: ``tm1`` is a
transition's start, ``t`` its end.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from rl_jax.training.replay import Transition


def linear_schedule(start, end, step, duration) -> jax.Array:
    """``start`` moving linearly to ``end`` over ``duration`` steps, then ``end``."""
    return start + (end - start) * jnp.clip(step / jnp.maximum(duration, 1.0), 0.0, 1.0)


def greedy_values(q_t) -> jax.Array:
    """Plain DQN bootstrap ``max_a q_t[a]``: ``[B, A] -> [B]``."""
    return jnp.max(q_t, axis=-1)


def double_q_values(q_t_value, q_t_selector) -> jax.Array:
    """Double DQN bootstrap: the selector's (online net's) greedy action, valued by ``q_t_value``
    (the target net's); ``[B, A], [B, A] -> [B]``."""
    a_t = jnp.argmax(q_t_selector, axis=-1)
    return jnp.take_along_axis(q_t_value, a_t[:, None], axis=-1)[:, 0]


def n_step_target(r_t, discount_t, v_t) -> jax.Array:
    """``r_t[0] + d[0] (r_t[1] + d[1] (... + d[n-1] v_t))`` with no gradient; ``r_t``,
    ``discount_t`` [B, n], ``v_t`` [B]. Steps after a window's end carry ``r = 0, d = 1``;
    ``d = 0`` after a termination. With ``n = 1`` this is the one-step Q-learning target."""
    target = v_t
    for k in reversed(range(r_t.shape[1])):
        target = r_t[:, k] + discount_t[:, k] * target
    return jax.lax.stop_gradient(target)


def huber_loss(x, delta) -> jax.Array:
    """``x^2 / 2`` for ``|x| <= delta``, ``delta (|x| - delta / 2)`` beyond, elementwise."""
    quadratic = jnp.minimum(jnp.abs(x), delta)
    return 0.5 * quadratic**2 + delta * (jnp.abs(x) - quadratic)


def q_learning_loss(q_tm1, a_tm1, target_tm1, weights, huber_delta):
    """Weighted mean Huber loss of the TD errors ``target_tm1 - q_tm1[a_tm1]``: ``q_tm1`` [B, A],
    ``a_tm1``/``target_tm1``/``weights`` [B]. Returns ``(loss, td_error [B])``."""
    q_taken = jnp.take_along_axis(q_tm1, a_tm1[:, None].astype(jnp.int32), axis=-1)[:, 0]
    td_error = target_tm1 - q_taken
    return jnp.mean(weights * huber_loss(td_error, huber_delta)), td_error


# ---- n-step windows ----------------------------------------------------------------------------
class NStepBatch(NamedTuple):
    obs: jax.Array  # [B, *obs_shape], where each window starts
    action: jax.Array  # [B]
    r_t: jax.Array  # [B, n], 0 after the window's end
    discount_t: jax.Array  # [B, n], gamma (0 at termination), 1 after the window's end
    next_obs: jax.Array  # [B, *obs_shape], the true next obs of the window's last step


def n_step_batch(window: Transition, stored: jax.Array, gamma) -> NStepBatch:
    """Cut each window (leaves [B, n, ...], ``stored`` [B, n]) after its first episode end."""
    ended = jnp.logical_or(window.terminated, window.truncated)
    ended_before = (jnp.cumsum(ended, axis=1) - ended) > 0
    included = jnp.logical_and(stored, ~ended_before)
    not_terminal = 1.0 - window.terminated.astype(jnp.float32)
    last = jnp.sum(included, axis=1) - 1
    return NStepBatch(
        obs=window.obs[:, 0],
        action=window.action[:, 0],
        r_t=jnp.where(included, window.reward, 0.0),
        discount_t=jnp.where(included, gamma * not_terminal, 1.0),
        next_obs=jnp.take_along_axis(
            window.next_obs, last.reshape((-1,) + (1,) * (window.next_obs.ndim - 1)), axis=1
        )[:, 0],
    )
