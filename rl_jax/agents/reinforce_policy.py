"""REINFORCE's policy: its network (``networks.StochasticPolicy`` for the env's action space), its
outputs on observations, sampling an action, and the whole episodes it collects (``rollout``).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from rl_jax import envs
from rl_jax.agents.reinforce_config import Config
from rl_jax.training import episodes, networks, normalization


class Trajectory(NamedTuple):
    obs: jax.Array  # [T, N, obs_dim]
    action: jax.Array  # [T, N, *action_shape]
    reward: jax.Array  # [T, N], 0 where masked
    mask: jax.Array  # [T, N] float32, 1 on steps inside an episode


#: A rollout's loop state: (time [], env states, obs [N, ...], alive [N], the trajectory so far)
Carry = tuple[jax.Array, object, jax.Array, jax.Array, Trajectory]


@functools.lru_cache(maxsize=64)
def make_network(config: Config) -> networks.StochasticPolicy:
    space = episodes.make_eval_env(config).action_space()
    discrete = isinstance(space, envs.Discrete)
    return networks.StochasticPolicy(
        hidden=config.hidden,
        action_dim=1 if discrete else space.shape[0],
        num_actions=space.n if discrete else None,
        std_floor=config.std_floor,
        value=config.baseline == "value",
        activation=config.activation,
        initializer=config.network_init,
        std_mode=config.std_mode,
        initial_std=config.initial_std,
        value_hidden=config.value_hidden,
    )


def policy_outputs(
    params: optax.Params,
    obs_stats: normalization.RunningStats | None,
    obs: jax.Array,
    config: Config,
) -> dict[str, jax.Array]:
    """The network's outputs on (standardised, when there are statistics) observations.

    With ``squash_mean`` the Gaussian's mean is ``tanh`` of the head mapped onto the action
    bounds. Why: an unbounded mean can drift past a bound in most states; every sample is then
    clipped to the same action, the return stops depending on the sample and the score-function
    gradient that would bring the mean back averages to zero (a double-pendulum seed sat at
    return ~130 for 100 updates this way, half its actions at +-1)."""
    policy = make_network(config).apply(params, normalization.normalize(obs_stats, obs))
    if config.squash_mean and "mean" in policy:
        space = episodes.make_eval_env(config).action_space()
        shape = policy["mean"].shape
        low, high = (jnp.broadcast_to(jnp.float32(b), shape) for b in (space.low, space.high))
        policy = {**policy, "mean": low + (high - low) * (jnp.tanh(policy["mean"]) + 1.0) / 2.0}
    return policy


def sample_action(policy: dict[str, jax.Array], key: jax.Array) -> jax.Array:
    """A draw from the policy (unclipped for the Gaussian)."""
    if "logits" in policy:
        return jax.random.categorical(key, policy["logits"]).astype(jnp.int32)
    return policy["mean"] + policy["std"] * jax.random.normal(key, policy["mean"].shape)


def to_env_action(action: jax.Array, space: envs.Space) -> jax.Array:
    if isinstance(space, envs.Box):
        leading = (1,) * (action.ndim - len(space.shape))
        low, high = (jnp.reshape(bound, leading + space.shape) for bound in (space.low, space.high))
        return jnp.clip(action, low, high)
    return action


def rollout(
    params: optax.Params,
    key: jax.Array,
    config: Config,
    obs_stats: normalization.RunningStats | None = None,
    env: envs.Environment | None = None,
) -> Trajectory:
    """``num_envs`` whole episodes, stopping as soon as all have ended (raw observations are
    stored; the policy acts on them standardised by ``obs_stats`` when given). ``env``: the env
    to run instead of the config's (as ``episodes.make_eval_env`` builds it)."""
    env = episodes.make_eval_env(config) if env is None else env
    space, count = env.action_space(), config.num_envs
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
        policy = policy_outputs(params, obs_stats, obs, config)
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
