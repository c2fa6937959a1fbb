"""REINFORCE's policy parts: the outputs of its network (``networks.StochasticPolicy``) on
observations, sampling an action, and the whole episodes a policy collects (``run_episodes``).
They are told the network, the action bounds and the env by ``rl_jax.agents.reinforce``, whose
``Config`` they do not import.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
import optax

from rl_jax import envs
from rl_jax.training import episodes, networks, normalization


class Trajectory(NamedTuple):
    """``N`` whole episodes, time-major; the steps after an episode ends are masked out."""

    obs: jax.Array  # [T, N, obs_dim]
    action: jax.Array  # [T, N, *action_shape]
    reward: jax.Array  # [T, N], 0 where masked
    mask: jax.Array  # [T, N] float32, 1 on steps inside an episode


#: A rollout's loop state: (time [], env states, obs [N, ...], alive [N], the trajectory so far)
Carry = tuple[jax.Array, object, jax.Array, jax.Array, Trajectory]


def policy_outputs(
    network: networks.StochasticPolicy,
    params: optax.Params,
    obs_stats: normalization.RunningStats | None,
    obs: jax.Array,
    squash_into: envs.Box | None = None,
) -> dict[str, jax.Array]:
    """The network's outputs on (standardised, when there are statistics) observations.

    With ``squash_into`` (the action space; REINFORCE's ``squash_mean``) the Gaussian's mean is
    ``tanh`` of the head mapped onto the action bounds. Why: an unbounded mean can drift past a
    bound in most states; every sample is then clipped to the same action, the return stops
    depending on the sample and the score-function gradient that would bring the mean back
    averages to zero (a double-pendulum seed sat at return ~130 for 100 updates this way, half
    its actions at +-1)."""
    outputs = network.apply(params, normalization.normalize(obs_stats, obs))
    policy = cast(dict[str, jax.Array], outputs)  # the outputs' names -> arrays
    if squash_into is not None and "mean" in policy:
        shape = policy["mean"].shape
        bounds = (squash_into.low, squash_into.high)
        low, high = (jnp.broadcast_to(jnp.float32(b), shape) for b in bounds)
        policy = {**policy, "mean": low + (high - low) * (jnp.tanh(policy["mean"]) + 1.0) / 2.0}
    return policy


def sample_action(policy: dict[str, jax.Array], key: jax.Array) -> jax.Array:
    """A draw from the policy (unclipped for the Gaussian)."""
    if "logits" in policy:
        return jax.random.categorical(key, policy["logits"]).astype(jnp.int32)
    return policy["mean"] + policy["std"] * jax.random.normal(key, policy["mean"].shape)


def to_env_action(action: jax.Array, space: envs.Space) -> jax.Array:
    """``action`` as the env takes it: clipped to a ``Box``'s bounds, else unchanged."""
    if isinstance(space, envs.Box):
        leading = (1,) * (action.ndim - len(space.shape))
        low, high = (jnp.reshape(bound, leading + space.shape) for bound in (space.low, space.high))
        return jnp.clip(action, low, high)
    return action


def run_episodes(
    policy_of: Callable[[jax.Array], dict[str, jax.Array]],
    key: jax.Array,
    env: envs.Environment,
    count: int,
) -> Trajectory:
    """``count`` whole episodes of vmapped ``env``, stopping as soon as all have ended;
    ``policy_of(obs [N, ...])`` is the policy's outputs on the stored observations."""
    space = env.action_space()
    horizon = env.max_episode_steps
    reset_key, key = jax.random.split(key)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(reset_key, count))
    example = episodes.example_transition(env)
    empty = Trajectory(
        obs=jnp.zeros((horizon, count, *ts.obs.shape[1:]), jnp.float32),
        action=jnp.zeros((horizon, count, *space.shape), example.action.dtype),
        reward=jnp.zeros((horizon, count), jnp.float32),
        mask=jnp.zeros((horizon, count), jnp.float32),
    )

    def running(carry: Carry) -> jax.Array:
        time, _, _, alive, _ = carry
        return jnp.logical_and(time < horizon, jnp.any(alive))

    def step(carry: Carry) -> Carry:
        time, env_state, obs, alive, trajectory = carry
        action_key, step_key = jax.random.split(jax.random.fold_in(key, time))
        policy = policy_of(obs)
        action = sample_action(policy, action_key).astype(empty.action.dtype)
        keys = jax.random.split(step_key, count)
        # Envs whose episode ended keep their state; the MuJoCo C backends skip their physics
        # altogether, so a step costs what the envs still running cost.
        env_state, ts = jax.vmap(env.step_active)(
            keys, env_state, to_env_action(action, space), alive
        )
        trajectory = Trajectory(
            obs=trajectory.obs.at[time].set(obs),
            action=trajectory.action.at[time].set(action),
            reward=trajectory.reward.at[time].set(jnp.where(alive, ts.reward, 0.0)),
            mask=trajectory.mask.at[time].set(alive.astype(jnp.float32)),
        )
        ended = jnp.logical_or(ts.terminated, ts.truncated)
        obs = jnp.where(alive[:, None], ts.obs, obs)
        return time + 1, env_state, obs, jnp.logical_and(alive, ~ended), trajectory

    alive = jnp.ones(count, jnp.bool_)
    carry = (jnp.int32(0), env_state, ts.obs, alive, empty)
    return jax.lax.while_loop(running, step, carry)[-1]
