"""DQN's maths, pure and network-free: bootstrap values (plain and double), n-step targets, the
Huber TD loss, and the linear epsilon schedule (the n-step windows they read are
``rl_jax.training.replay``'s). rlax naming: ``tm1`` is a transition's start, ``t`` its end.

For envs with a legal-action mask (``info["action_mask"]``, ``rl_jax.envs.core.preprocessing``):
the greedy action, the bootstrap values and epsilon-greedy over legal actions only (``masked_*``;
``legal`` is bool, True where an action is legal).
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


def _some_legal(legal: jax.Array) -> jax.Array:
    """``legal``, with a row that allows nothing read as allowing everything (an env without a
    mask, or a terminal state's mask, whose bootstrap value is discounted to 0 anyway)."""
    legal = jnp.asarray(legal, jnp.bool_)
    return legal | ~jnp.any(legal, axis=-1, keepdims=True)


def masked_argmax(q_t: jax.Array, legal_t: jax.Array) -> jax.Array:
    """The greedy legal action ``argmax_{a legal} q_t[a]`` (the first of equal values):
    ``[..., A], [..., A] bool -> [...]`` int32. A row with no legal action counts all legal."""
    masked = jnp.where(_some_legal(legal_t), q_t, -jnp.inf)
    return jnp.argmax(masked, axis=-1).astype(jnp.int32)


def masked_max(q_t: jax.Array, legal_t: jax.Array) -> jax.Array:
    """DQN's bootstrap over legal actions, ``max_{a legal} q_t[a]``: ``[..., A] -> [...]``. A row
    with no legal action takes the max over all, so the value stays finite."""
    return jnp.max(jnp.where(_some_legal(legal_t), q_t, -jnp.inf), axis=-1)


def masked_double_q_values(
    q_t_value: jax.Array, q_t_selector: jax.Array, legal_t: jax.Array
) -> jax.Array:
    """Double DQN's bootstrap over legal actions: the selector's greedy legal action, valued by
    ``q_t_value``; ``[B, A], [B, A], [B, A] bool -> [B]``."""
    a_t = masked_argmax(q_t_selector, legal_t)
    return jnp.take_along_axis(q_t_value, a_t[:, None], axis=-1)[:, 0]


def epsilon_greedy(
    key: jax.Array, greedy: jax.Array, num_actions: int, epsilon: ArrayLike
) -> jax.Array:
    """With probability ``epsilon`` a uniform action of ``num_actions``, else ``greedy`` (int32
    ``[...]``); one draw per entry."""
    coin_key, action_key = jax.random.split(key)
    uniform = jax.random.randint(action_key, greedy.shape, 0, num_actions, jnp.int32)
    explore_now = jax.random.uniform(coin_key, greedy.shape) < epsilon
    return jnp.where(explore_now, uniform, greedy)


def masked_epsilon_greedy(
    key: jax.Array, q: jax.Array, legal: jax.Array, epsilon: ArrayLike
) -> jax.Array:
    """Epsilon-greedy over legal actions: with probability ``epsilon`` a uniform legal action,
    else ``masked_argmax``; ``[..., A] -> [...]`` int32, one draw per row."""
    legal = _some_legal(legal)
    coin_key, action_key = jax.random.split(key)
    uniform = jax.random.categorical(action_key, jnp.where(legal, 0.0, -jnp.inf))
    explore = jax.random.uniform(coin_key, uniform.shape) < epsilon
    return jnp.where(explore, uniform, masked_argmax(q, legal)).astype(jnp.int32)


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
