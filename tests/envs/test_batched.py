"""Batch-level autoreset: the semantics of the AutoReset wrapper, on every branch."""

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax import envs
from rl_jax.envs.core.batched import autoreset_step, reset_where

NUM_ENVS, NUM_STEPS, MAX_RESETS = 64, 120, 4


def _rollout(max_resets: int):
    """``autoreset_step`` on CartPole (time limit 37, random actions), scanned; beside each step,
    the bare env's step from the same states and actions."""
    env = envs.make("rl_jax/CartPole-v1")
    env.max_episode_steps = 37
    bare_step = jax.vmap(env.step, (0, 0, 0, None))
    params = env.default_params

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        actions = jax.random.randint(key_action, (NUM_ENVS,), 0, 2)
        new_state, timestep = autoreset_step(env, key_step, state, actions, max_resets=max_resets)
        _, bare = bare_step(jax.random.split(key_step, NUM_ENVS), state, actions, params)
        return new_state, (timestep, bare, new_state.time)

    @jax.jit
    def run():
        state, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), NUM_ENVS))
        return jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), NUM_STEPS))[1]

    return jax.device_get(run())


def test_autoreset_step_semantics_on_every_branch():
    timestep, bare, time = _rollout(MAX_RESETS)
    done = timestep.terminated | timestep.truncated
    # Reward, flags and the final obs are the bare env's; obs too unless the episode ended.
    np.testing.assert_array_equal(timestep.reward, bare.reward)
    np.testing.assert_array_equal(timestep.terminated, bare.terminated)
    np.testing.assert_array_equal(timestep.truncated, bare.truncated)
    np.testing.assert_array_equal(timestep.info["final_obs"], bare.obs)
    np.testing.assert_array_equal(timestep.obs[~done], bare.obs[~done])
    # Finished envs start afresh: step counter 0, a start state from CartPole's reset
    # distribution (uniform in [-0.05, 0.05]), every one a distinct draw.
    assert np.all(time[done] == 0) and np.all(time[~done] > 0)
    starts = timestep.obs[done]
    assert np.abs(starts).max() <= 0.05
    assert len(np.unique(starts[:, 0])) == len(starts) > 200
    np.testing.assert_allclose(starts.std(axis=0), 0.1 / np.sqrt(12), rtol=0.15)
    np.testing.assert_array_less(np.abs(starts.mean(axis=0)), 5 * 0.029 / np.sqrt(len(starts)))
    # Every branch of the batched reset ran: none, a few (gathered), many (whole batch).
    done_count = done.sum(axis=1)
    assert (done_count == 0).any()
    assert ((done_count > 0) & (done_count <= MAX_RESETS)).any()
    assert (done_count > MAX_RESETS).any()
    assert timestep.terminated.any() and timestep.truncated.any()


def test_reset_where_replaces_exactly_the_masked_envs():
    current = jnp.arange(10.0)
    keys = jnp.arange(10, dtype=jnp.float32)  # a stand-in "key": the reset returns -key

    def reset(batch):
        return -batch

    compiled = jax.jit(reset_where, static_argnums=(0, 4))
    for mask in ([], [3], [0, 9], [1, 2, 4, 5, 7]):
        flags = np.zeros(10, bool)
        flags[mask] = True
        expected = np.where(flags, -np.arange(10.0), np.arange(10.0))
        for max_resets in (1, 2, 10):
            result = compiled(reset, keys, jnp.asarray(flags), current, max_resets)
            np.testing.assert_array_equal(result, expected)
