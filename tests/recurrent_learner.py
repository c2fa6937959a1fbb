"""A tiny recurrent learner and env for the tests of recurrent policies: the policy's state is a
step counter, and the env rewards an action only when it equals the steps since the episode
started. An episode's return is 0 exactly when the policy's state was reset at its start (and
nowhere else), and negative otherwise; episodes end at random (termination) or at the time limit
(truncation), so that resets after an autoreset fall at every step of a rollout.

It learns nothing: ``train_chunk`` acts with the autoreset train env, resetting the policy state
where an episode ended, and evaluates with ``rl_jax.training.episodes.evaluate_recurrent``.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax import envs
from rl_jax.envs.core.core import Environment, EnvParams, EnvState
from rl_jax.envs.core.spaces import Box
from rl_jax.training import episodes
from rl_jax.training.algorithm import ChunkMetrics

ENV_ID = "rl_jax/FakeClock-v0"
name = "fake_recurrent"


@struct.dataclass
class ClockState(EnvState):
    pass


class ClockEnv(Environment):
    """Observes nothing (a zero); reward ``-(action - time)**2``, ``time`` the steps since the
    reset; each step ends the episode with probability 1/4."""

    max_episode_steps = 6

    @property
    def default_params(self) -> EnvParams:
        return EnvParams()

    def reset_env(self, key, params):
        return ClockState(jnp.zeros((), jnp.int32)), jnp.zeros((1,), jnp.float32)

    def step_env(self, key, state, action, params):
        miss = jnp.reshape(action, ()) - state.time.astype(jnp.float32)
        terminated = jax.random.uniform(key) < 0.25
        return ClockState(state.time + 1), jnp.zeros((1,), jnp.float32), -(miss**2), terminated, {}

    def observation_space(self, params=None):
        return Box(-np.inf, np.inf, (1,))

    def action_space(self, params=None):
        return Box(-100.0, 100.0, (1,))


envs.register(ENV_ID, f"{__name__}:ClockEnv")


@dataclasses.dataclass(frozen=True)
class Config:
    env_id: str = ENV_ID
    """Registered id of the environment."""
    num_envs: int = 3
    """Environments stepped in parallel per seed."""
    iterations_per_chunk: int = 20
    """Env steps of every env per compiled chunk."""
    num_eval_envs: int = 4
    """Episodes averaged by each evaluation."""

    def make_env(self) -> Environment:
        return envs.make(self.env_id)


@struct.dataclass
class Hyperparams:
    offset: float = 0.0
    """Added to every action (0: the policy is exact)."""


class TrainState(NamedTuple):
    params: dict
    env_state: object  # [num_envs] of the train env
    obs: jax.Array  # [num_envs, 1]
    policy_state: jax.Array  # [num_envs] float32, each env's counter
    key: jax.Array
    env_steps: jax.Array  # [] int32
    train_return: jax.Array  # [] float32, the summed rewards of the last chunk per env


policy_fields = ("params",)


def default_config(env_id: str = ENV_ID) -> Config:
    return Config(env_id=env_id)


def default_hyperparams(env_id: str | None = None) -> Hyperparams:
    return Hyperparams()


def make_env(config: Config) -> Environment:
    return episodes.make_eval_env(config)


def env_steps_per_chunk(config: Config) -> int:
    return config.num_envs * config.iterations_per_chunk


def initial_policy_state(config: Config) -> jax.Array:
    return jnp.zeros((), jnp.float32)


def step(params: dict, counter: jax.Array, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """One env's ``(counter, obs) -> (action [1], counter + 1)``."""
    return jnp.reshape(counter + params["offset"], (1,)), counter + 1.0


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    env = episodes.make_train_env(config)
    key_env, key = jax.random.split(key)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(key_env, config.num_envs))
    initial = initial_policy_state(config)
    return TrainState(
        params={"offset": jnp.asarray(hparams.offset, jnp.float32)},
        env_state=env_state,
        obs=ts.obs,
        policy_state=episodes.batched_policy_state(initial, config.num_envs),
        key=key,
        env_steps=jnp.zeros((), jnp.int32),
        train_return=jnp.zeros((), jnp.float32),
    )


def _act(params: dict, policy_state: jax.Array, obs: jax.Array, config: Config):
    return jax.vmap(step, in_axes=(None, 0, 0))(params, policy_state, obs)


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    env = episodes.make_train_env(config)
    initial = initial_policy_state(config)

    def body(carry, key):
        env_state, obs, policy_state, total = carry
        action, policy_state = _act(state.params, policy_state, obs, config)
        keys = jax.random.split(key, config.num_envs)
        env_state, ts = jax.vmap(env.step)(keys, env_state, action)
        starts = jnp.logical_or(ts.terminated, ts.truncated)
        policy_state = episodes.reset_policy_state(starts, policy_state, initial)
        return (env_state, ts.obs, policy_state, total + ts.reward), None

    key, key_steps, key_eval = jax.random.split(state.key, 3)
    zero = jnp.zeros(config.num_envs, jnp.float32)
    carry = (state.env_state, state.obs, state.policy_state, zero)
    keys = jax.random.split(key_steps, config.iterations_per_chunk)
    (env_state, obs, policy_state, total), _ = jax.lax.scan(body, carry, keys)
    state = state._replace(
        env_state=env_state,
        obs=obs,
        policy_state=policy_state,
        key=key,
        env_steps=state.env_steps + env_steps_per_chunk(config),
        train_return=jnp.mean(total),
    )
    eval_return = episodes.evaluate_recurrent(_act, initial, state.params, config, key_eval)
    metrics = ChunkMetrics(
        env_steps=state.env_steps,
        updates=jnp.zeros((), jnp.int32),
        eval_return=eval_return,
        train_return=state.train_return,
        extra={},
    )
    return state, metrics


def policy(state: TrainState, config: Config):
    params = state.params
    return lambda counter, obs: step(params, counter, obs)
