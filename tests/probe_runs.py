"""Short TD3/DDPG runs on probe envs, shared by several test modules.

Compiling a train chunk dominates these tests, so every module uses the same jitted functions and
the same small config per env: each (algorithm, env) pair compiles once per session.
"""

import functools

import jax
import jax.numpy as jnp

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents.td3 import ddpg, make_networks, td3
from rl_jax.training import networks

ALGORITHMS = {"td3": td3, "ddpg": ddpg}
CHUNKS = 6
# A short horizon (gamma 0.5) and fast targets (tau 0.05) let values converge in ~1,500 updates;
# everything else is the algorithm's default.
PROBE_HPARAMS = {"gamma": 0.5, "tau": 0.05, "actor_lr": 1e-3, "critic_lr": 1e-3}


def probe_config(env_id: str, algorithm: str = "td3", **overrides):
    return ALGORITHMS[algorithm].default_config(
        env_id,
        **{
            "num_envs": 8,
            "learning_starts": 256,
            "batch_size": 64,
            "buffer_size": 16_384,  # holds the whole run: the warm-up rows stay inspectable
            "iterations_per_chunk": 250,
            "actor_hidden": (32, 32),
            "critic_hidden": (32, 32),
            **overrides,
        },
    )


def probe_hparams(algorithm: str = "td3", **overrides):
    return ALGORITHMS[algorithm].default_hyperparams(**{**PROBE_HPARAMS, **overrides})


@functools.cache
def chunk_function(algorithm: str):
    return jax.jit(ALGORITHMS[algorithm].train_chunk, static_argnums=1)


@functools.cache
def train(
    env_id: str,
    algorithm: str = "td3",
    seed: int = 0,
    chunks: int = CHUNKS,
    hparam_overrides: tuple[tuple[str, float], ...] = (),
    config_overrides: tuple[tuple[str, int], ...] = (),
):
    """``(state, [metrics per chunk])`` after ``chunks`` chunks of one seed (cached)."""
    config = probe_config(env_id, algorithm, **dict(config_overrides))
    hparams = probe_hparams(algorithm, **dict(hparam_overrides))
    state = ALGORITHMS[algorithm].init(jax.random.key(seed), config, hparams)
    history = []
    for _ in range(chunks):
        state, metrics = chunk_function(algorithm)(state, config, hparams)
        history.append(metrics)
    return state, history


def q_values(state, config, obs_values, action_values):
    """``[num_critics, len(obs_values)]`` online critic values at (obs, action) pairs."""
    obs = jnp.asarray(obs_values, jnp.float32)[:, None]
    actions = jnp.asarray(action_values, jnp.float32)[:, None]
    return networks.apply_stacked(make_networks(config).critic, state.agent.critics, obs, actions)


def policy_actions(state, config, obs_values):
    obs = jnp.asarray(obs_values, jnp.float32)[:, None]
    return make_networks(config).actor.apply(state.agent.actor, obs)[:, 0]
