"""Env core and wrappers on a tiny env whose every step is known in advance."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

import envs
from envs.core import Environment, EnvParams, EnvState


@struct.dataclass
class CounterState(EnvState):
    position: jax.Array


@struct.dataclass
class CounterParams(EnvParams):
    goal: jax.Array = struct.field(default_factory=lambda: jnp.float32(3.0))


class Counter(Environment):
    """obs = position; action is added; terminates at ``goal``; reward = action; limit 5 steps."""

    max_episode_steps = 5

    @property
    def default_params(self):
        return CounterParams()

    def reset_env(self, key, params):
        start = jax.random.uniform(key, (), minval=-0.5, maxval=0.0)
        return CounterState(time=jnp.int32(0), position=start), start[None]

    def step_env(self, key, state, action, params):
        position = state.position + jnp.squeeze(action)
        state = CounterState(time=state.time + 1, position=position)
        return state, position[None], jnp.squeeze(action), position >= params.goal, {}

    def observation_space(self, params=None):
        return envs.Box(-10.0, 10.0, (1,))

    def action_space(self, params=None):
        return envs.Box(-2.0, 2.0, (1,))


def rollout(env, actions, seed=0):
    key = jax.random.PRNGKey(seed)
    state, ts = env.reset(key)
    out = []
    for i, action in enumerate(actions):
        state, ts = env.step(jax.random.fold_in(key, i), state, jnp.asarray([action]))
        out.append(ts)
    return out


def test_truncation_and_termination_are_separate():
    env = Counter()
    steps = rollout(env, [0.0] * 5)
    assert [bool(t.truncated) for t in steps] == [False] * 4 + [True]
    assert not any(bool(t.terminated) for t in steps)
    steps = rollout(env, [2.0, 2.0])
    assert bool(steps[1].terminated) and not bool(steps[1].truncated)


def test_terminal_on_last_step_sets_both_flags_like_gymnasium():
    steps = rollout(Counter(), [0.0, 0.0, 0.0, 0.0, 4.0])
    assert bool(steps[-1].terminated) and bool(steps[-1].truncated)


def test_autoreset_keeps_final_obs_and_statistics_span_resets():
    env = envs.EpisodeStatistics(envs.AutoReset(Counter()))
    steps = rollout(env, [2.0, 2.0, 1.0, 1.0, 1.0, 1.0])
    first_done = steps[1]
    assert bool(first_done.terminated)
    # The obs is the new episode's start (in [-0.5, 0]), the final obs is the terminal one.
    assert float(first_done.obs[0]) <= 0.0
    assert float(first_done.info["final_obs"][0]) >= 3.0
    assert bool(first_done.info["episode_done"])
    np.testing.assert_allclose(first_done.info["episode_return"], 4.0)
    assert int(first_done.info["episode_length"]) == 2
    # Not done: final_obs equals obs, and the last finished episode's stats stay reported.
    np.testing.assert_array_equal(steps[2].info["final_obs"], steps[2].obs)
    assert not bool(steps[2].info["episode_done"])
    np.testing.assert_allclose(steps[2].info["episode_return"], 4.0)


def test_reset_and_step_info_have_the_same_structure():
    env = envs.EpisodeStatistics(envs.AutoReset(Counter()))
    key = jax.random.PRNGKey(1)
    state, first = env.reset(key)
    _, second = env.step(key, state, jnp.ones((1,)))
    assert jax.tree.structure(first) == jax.tree.structure(second)
    for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(second), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype


def test_wrappers_jit_and_vmap():
    env = envs.EpisodeStatistics(envs.AutoReset(envs.RescaleAction(Counter())))
    keys = jax.random.split(jax.random.PRNGKey(2), 8)
    state, _ = jax.vmap(env.reset)(keys)
    step = jax.jit(jax.vmap(env.step))
    state, ts = step(keys, state, jnp.ones((8, 1)))
    assert ts.obs.shape == (8, 1) and ts.info["final_obs"].shape == (8, 1)


def test_rescale_action_maps_unit_box_onto_bounds():
    env = envs.RescaleAction(Counter())
    assert env.action_space() == envs.Box(-1.0, 1.0, (1,))
    np.testing.assert_allclose(env.to_env_action(jnp.array([-1.0, 0.0, 1.0])), [-2.0, 0.0, 2.0])


def test_discretize_actions_grid():
    env = envs.DiscretizeActions(Counter(), num_bins=3)
    assert env.action_space() == envs.Discrete(3)
    np.testing.assert_allclose(env.action_values[:, 0], [-2.0, 0.0, 2.0])
    state, _ = env.reset(jax.random.PRNGKey(0))
    start = float(state.position)
    state, _ = env.step(jax.random.PRNGKey(0), state, jnp.int32(2))
    np.testing.assert_allclose(float(state.position), start + 2.0, rtol=1e-6)


def test_unknown_env_lists_known_ids():
    with pytest.raises(envs.UnknownEnvError, match="rl_jax/Rocket-v0"):
        envs.make("rl_jax/Nope-v0")
