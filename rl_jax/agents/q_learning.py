"""DQN's maths, pure and network-free: bootstrap values (plain and double), n-step targets, the
Huber TD loss, and the linear epsilon schedule (the n-step windows they read are
``rl_jax.training.replay``'s). rlax naming: ``tm1`` is a transition's start, ``t`` its end.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike


def linear_schedule(
    start: ArrayLike, end: ArrayLike, step: ArrayLike, duration: ArrayLike
) -> jax.Array:
    """``start`` moving linearly to ``end`` over ``duration`` steps, then ``end``."""
    return start + (end - start) * jnp.clip(step / jnp.maximum(duration, 1.0), 0.0, 1.0)


def greedy_values(q_t: jax.Array) -> jax.Array:
    """Plain DQN bootstrap ``max_a q_t[a]``: ``[B, A] -> [B]``."""
    return jnp.max(q_t, axis=-1)


def double_q_values(q_t_value: jax.Array, q_t_selector: jax.Array) -> jax.Array:
    """Double DQN bootstrap: the selector's (online net's) greedy action, valued by ``q_t_value``
    (the target net's); ``[B, A], [B, A] -> [B]``."""
    a_t = jnp.argmax(q_t_selector, axis=-1)
    return jnp.take_along_axis(q_t_value, a_t[:, None], axis=-1)[:, 0]


def n_step_target(r_t: jax.Array, discount_t: jax.Array, v_t: jax.Array) -> jax.Array:
    """``r_t[0] + d[0] (r_t[1] + d[1] (... + d[n-1] v_t))`` with no gradient; ``r_t``,
    ``discount_t`` [B, n], ``v_t`` [B]. Steps after a window's end carry ``r = 0, d = 1``;
    ``d = 0`` after a termination. With ``n = 1`` this is the one-step Q-learning target."""
    target = v_t
    for k in reversed(range(r_t.shape[1])):
        target = r_t[:, k] + discount_t[:, k] * target
    return jax.lax.stop_gradient(target)


def huber_loss(x: jax.Array, delta: ArrayLike) -> jax.Array:
    """``x^2 / 2`` for ``|x| <= delta``, ``delta (|x| - delta / 2)`` beyond, elementwise."""
    quadratic = jnp.minimum(jnp.abs(x), delta)
    return 0.5 * quadratic**2 + delta * (jnp.abs(x) - quadratic)


def q_learning_loss(
    q_tm1: jax.Array,
    a_tm1: jax.Array,
    target_tm1: jax.Array,
    weights: jax.Array,
    huber_delta: ArrayLike,
) -> tuple[jax.Array, jax.Array]:
    """Weighted mean Huber loss of the TD errors ``target_tm1 - q_tm1[a_tm1]``: ``q_tm1`` [B, A],
    ``a_tm1``/``target_tm1``/``weights`` [B]. Returns ``(loss, td_error [B])``."""
    q_taken = jnp.take_along_axis(q_tm1, a_tm1[:, None].astype(jnp.int32), axis=-1)[:, 0]
    td_error = target_tm1 - q_taken
    return jnp.mean(weights * huber_loss(td_error, huber_delta)), td_error
