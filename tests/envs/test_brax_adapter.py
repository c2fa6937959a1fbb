"""Brax interop both ways: a brax env (MJX inverted pendulum) driven as one of ours, and one of our
envs (C-backend inverted pendulum) driven by brax's own training wrappers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax import envs

brax_envs = pytest.importorskip("brax.envs")
from rl_jax.envs.adapters.brax_adapter import FromBrax, ToBrax, make_brax  # noqa: E402


def test_brax_env_steps_as_ours_with_autoreset():
    env = make_brax("inverted_pendulum", backend="mjx", max_episode_steps=7)
    assert isinstance(env, envs.Environment)
    wrapped = envs.EpisodeStatistics(envs.AutoReset(env))
    n_envs, n_steps = 4, 12

    @jax.jit
    def run(key):
        state, ts = jax.vmap(wrapped.reset)(jax.random.split(key, n_envs))

        def body(state, key):
            action = jax.random.uniform(key, (n_envs, env.action_space().shape[0]), minval=-1)
            state, ts = jax.vmap(wrapped.step)(jax.random.split(key, n_envs), state, action)
            return state, ts

        return jax.lax.scan(body, state, jax.random.split(key, n_steps))[1]

    trajectory = run(jax.random.PRNGKey(0))
    assert trajectory.obs.shape == (n_steps, n_envs, *env.observation_space().shape)
    assert np.isfinite(np.asarray(trajectory.obs)).all()
    done = np.asarray(trajectory.terminated | trajectory.truncated)
    assert done.any()  # random actions topple the pole, or the 7-step limit cuts the episode
    lengths = np.asarray(trajectory.info["episode_length"])[done]
    assert (lengths <= 7).all() and (lengths >= 1).all()


@jax.numpy_rank_promotion("allow")  # brax's wrappers broadcast implicitly
def test_our_env_steps_under_brax_training_wrappers():
    from brax.envs.wrappers import training

    ours = envs.make("rl_jax/InvertedPendulum-v5", backend="mujoco")
    brax_env = training.wrap(ToBrax(ours, rescale_actions=True), episode_length=5, action_repeat=1)
    assert isinstance(brax_env.unwrapped, brax_envs.Env)
    assert brax_env.observation_size == 4 and brax_env.action_size == 1
    state = jax.jit(brax_env.reset)(jax.random.split(jax.random.PRNGKey(1), 3))
    step = jax.jit(brax_env.step)
    for _ in range(5):
        state = step(state, jnp.zeros((3, 1)))
    # brax's EpisodeWrapper cut every (balanced, unterminated) episode at 5 steps, as truncation
    np.testing.assert_array_equal(np.asarray(state.info["truncation"]), np.ones(3))
    assert np.isfinite(np.asarray(state.obs)).all()
    assert np.asarray(state.metrics["reward_survive"]).shape == (3,)


def test_round_trip_matches_direct_stepping():
    """ours -> brax -> ours steps exactly like ours."""
    ours = envs.make("rl_jax/InvertedPendulum-v5", backend="mujoco")
    round_trip = FromBrax(ToBrax(ours))
    key = jax.random.PRNGKey(2)
    direct_state, direct = ours.reset(jax.random.split(key)[0])
    state, ts = round_trip.reset(key)
    np.testing.assert_array_equal(ts.obs, direct.obs)
    action = jnp.array([0.5])
    state, ts = jax.jit(round_trip.step)(key, state, action)
    key_step = jax.random.split(jax.random.split(key)[1])[0]
    _, direct = ours.step(key_step, direct_state, action)
    np.testing.assert_array_equal(ts.obs, direct.obs)
    assert float(ts.reward) == float(direct.reward)
