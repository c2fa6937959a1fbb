"""A tiny learner and env implementing ``rl_jax.training.algorithm.Algorithm`` for the
run-machinery tests.

It compiles in about a second yet has everything a real learner's train state has: params and an
optax optimizer (learning rate injected as a hyperparameter), a replay buffer, a batch of env
states, a typed PRNG key, counters, and a zero-size array (orbax cannot save those). Every update
draws random numbers and does float maths, so a resume that is not bit-exact shows.

The env is a point on a line pushed by the action; reward is minus the squared distance to 0.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct

from rl_jax import envs
from rl_jax.envs.core.core import Environment, EnvParams, EnvState
from rl_jax.envs.core.spaces import Box
from rl_jax.training.algorithm import ChunkMetrics

ENV_ID = "rl_jax/FakePoint-v0"
name = "fake"


@struct.dataclass
class PointState(EnvState):
    position: jax.Array  # [] float32
    velocity: jax.Array  # [] float32


@struct.dataclass
class PointParams(EnvParams):
    dt: jax.Array = 0.1


class PointEnv(Environment):
    """A unit mass on a line; action is a force in [-1, 1]."""

    max_episode_steps = 20

    @property
    def default_params(self) -> PointParams:
        return PointParams()

    def reset_env(self, key, params):
        position = jax.random.uniform(key, (), jnp.float32, -1.0, 1.0)
        state = PointState(jnp.zeros((), jnp.int32), position, jnp.zeros((), jnp.float32))
        return state, self._obs(state)

    def step_env(self, key, state, action, params):
        force = jnp.clip(jnp.reshape(action, ()), -1.0, 1.0)
        velocity = state.velocity + params.dt * force
        position = state.position + params.dt * velocity
        new_state = PointState(state.time + 1, position, velocity)
        reward = -(position**2)
        return new_state, self._obs(new_state), reward, jnp.abs(position) > 5.0, {}

    def _obs(self, state: PointState) -> jax.Array:
        return jnp.stack([state.position, state.velocity]).astype(jnp.float32)

    def observation_space(self, params=None):
        return Box(-np.inf, np.inf, (2,))

    def action_space(self, params=None):
        return Box(-1.0, 1.0, (1,))

    def render(self, state, params=None):
        """A 32x64 frame with the point drawn as a white square."""
        frame = np.zeros((32, 64, 3), np.uint8)
        column = int(np.clip((float(state.position) + 2.0) / 4.0 * 63, 0, 63))
        frame[12:20, max(0, column - 2) : column + 2] = 255
        return frame


envs.register(ENV_ID, f"{__name__}:PointEnv")


@dataclasses.dataclass(frozen=True)
class Config:
    env_id: str = ENV_ID
    """Registered id of the environment."""
    num_envs: int = 4
    """Environments stepped in parallel per seed."""
    iterations_per_chunk: int = 5
    """Train iterations (one env step of every env, then one update) per compiled chunk."""
    buffer_size: int = 64
    """Replay buffer capacity in transitions."""
    batch_size: int = 8  # transitions per gradient update
    eval_envs: int = 2  # episodes averaged by each evaluation
    hidden_sizes: tuple[int, ...] = (8,)
    """Widths of the policy's hidden layers."""
    deterministic_init: bool = False
    """Start every seed from the same params (exercises bool flags)."""


@struct.dataclass
class Hyperparams:
    learning_rate: float = 1e-2
    """Adam learning rate."""
    noise: float = 0.3
    """Std of the Gaussian exploration noise."""
    updates_per_step: int = 1
    """Gradient updates per iteration (an int hyperparameter)."""


class TrainState(NamedTuple):
    params: dict
    opt_state: Any
    buffer: jax.Array  # [buffer_size, obs_size + 1] obs and action
    buffer_count: jax.Array  # [] int32
    env_state: PointState  # [num_envs]
    obs: jax.Array  # [num_envs, 2]
    key: jax.Array  # typed PRNG key
    env_steps: jax.Array  # [] int32
    updates: jax.Array  # [] int32
    train_return: jax.Array  # [] float32
    nothing: jax.Array  # [0] float32: zero-size on purpose


#: The train-state fields ``policy`` reads: what a run keeps of each seed's best policy.
policy_fields = ("params",)


def default_config(env_id: str = ENV_ID) -> Config:
    return Config(env_id=env_id)


def default_hyperparams(env_id: str | None = None) -> Hyperparams:
    return Hyperparams()


def make_env(config: Config) -> Environment:
    return envs.make(config.env_id)


def env_steps_per_chunk(config: Config) -> int:
    return config.num_envs * config.iterations_per_chunk


def replay_capacity(config: Config) -> int:
    """Its buffer's rows (a state too big for memory is refused naming the --buffer-size that
    fits)."""
    return config.buffer_size


def _optimizer(hparams: Hyperparams) -> optax.GradientTransformation:
    return optax.inject_hyperparams(optax.adam)(learning_rate=hparams.learning_rate)


def _obs_size(config: Config) -> int:
    return make_env(config).observation_space().shape[0]


def _init_params(key: jax.Array, config: Config) -> dict:
    sizes = (_obs_size(config), *config.hidden_sizes, 1)
    keys = jax.random.split(key, len(sizes) - 1)
    return {
        f"layer{i}": jax.random.normal(k, (a, b), jnp.float32) / np.sqrt(a)
        for i, (k, a, b) in enumerate(zip(keys, sizes[:-1], sizes[1:], strict=True))
    }


def _forward(params: dict, obs: jax.Array) -> jax.Array:
    x = obs
    for i in range(len(params)):
        x = x @ params[f"layer{i}"]
        if i < len(params) - 1:
            x = jnp.tanh(x)
    return jnp.tanh(x)


def init(key: jax.Array, config: Config, hparams: Hyperparams) -> TrainState:
    key_params, key_env, key = jax.random.split(key, 3)
    if config.deterministic_init:
        key_params = jax.random.key(0)
    params = _init_params(key_params, config)
    env = make_env(config)
    env_state, timestep = jax.vmap(env.reset)(jax.random.split(key_env, config.num_envs))
    return TrainState(
        params=params,
        opt_state=_optimizer(hparams).init(params),
        buffer=jnp.zeros((config.buffer_size, _obs_size(config) + 1), jnp.float32),
        buffer_count=jnp.zeros((), jnp.int32),
        env_state=env_state,
        obs=timestep.obs,
        key=key,
        env_steps=jnp.zeros((), jnp.int32),
        updates=jnp.zeros((), jnp.int32),
        train_return=jnp.zeros((), jnp.float32),
        nothing=jnp.zeros((0,), jnp.float32),
    )


def _loss(params: dict, batch: jax.Array) -> jax.Array:
    # Push the action towards the force that stops the point: a made-up but smooth objective.
    obs, action = batch[:, :-1], batch[:, -1:]
    target = -jnp.clip(obs[:, :1] + obs[:, 1:], -1.0, 1.0)
    return jnp.mean((_forward(params, obs) - target) ** 2) + 0.0 * jnp.mean(action)


def _iteration(state: TrainState, config: Config, hparams: Hyperparams) -> TrainState:
    env = envs.core.wrappers.AutoReset(make_env(config))
    key, key_noise, key_step, key_batch = jax.random.split(state.key, 4)
    action = _forward(state.params, state.obs)
    action = action + hparams.noise * jax.random.normal(key_noise, action.shape)
    step_keys = jax.random.split(key_step, config.num_envs)
    env_state, timestep = jax.vmap(env.step)(step_keys, state.env_state, action)
    rows = jnp.concatenate([state.obs, action], axis=1)
    slots = (state.buffer_count + jnp.arange(config.num_envs)) % config.buffer_size
    buffer = state.buffer.at[slots].set(rows)
    filled = jnp.minimum(state.buffer_count + config.num_envs, config.buffer_size)
    indices = jax.random.randint(key_batch, (config.batch_size,), 0, filled)
    grads = jax.grad(_loss)(state.params, buffer[indices])
    updates, opt_state = _optimizer(hparams).update(grads, state.opt_state, state.params)
    return state._replace(
        params=optax.apply_updates(state.params, updates),
        opt_state=opt_state,
        buffer=buffer,
        buffer_count=state.buffer_count + config.num_envs,
        env_state=env_state,
        obs=timestep.obs,
        key=key,
        env_steps=state.env_steps + config.num_envs,
        updates=state.updates + hparams.updates_per_step,
        train_return=0.9 * state.train_return + 0.1 * jnp.mean(timestep.reward),
    )


def evaluate(state: TrainState, config: Config, key: jax.Array) -> jax.Array:
    env = make_env(config)
    act = policy(state, config)

    def step(carry, _):
        env_state, obs, key, total = carry
        key, key_step = jax.random.split(key)
        keys = jax.random.split(key_step, config.eval_envs)
        env_state, timestep = jax.vmap(env.step)(keys, env_state, jax.vmap(act)(obs))
        return (env_state, timestep.obs, key, total + timestep.reward), None

    key_reset, key = jax.random.split(key)
    env_state, timestep = jax.vmap(env.reset)(jax.random.split(key_reset, config.eval_envs))
    total = jnp.zeros((config.eval_envs,), jnp.float32)
    carry, _ = jax.lax.scan(step, (env_state, timestep.obs, key, total), None, 20)
    return jnp.mean(carry[3])


def train_chunk(
    state: TrainState, config: Config, hparams: Hyperparams
) -> tuple[TrainState, ChunkMetrics]:
    def body(state, _):
        return _iteration(state, config, hparams), None

    state, _ = jax.lax.scan(body, state, None, config.iterations_per_chunk)
    key, key_eval = jax.random.split(state.key)
    state = state._replace(key=key)
    metrics = ChunkMetrics(
        env_steps=state.env_steps,
        updates=state.updates,
        eval_return=evaluate(state, config, key_eval),
        train_return=state.train_return,
        extra={"loss": _loss(state.params, state.buffer[: config.batch_size])},
    )
    return state, metrics


def policy(state: TrainState, config: Config):
    params = state.params
    return lambda obs: _forward(params, obs)
