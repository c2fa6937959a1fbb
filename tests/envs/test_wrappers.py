"""Env core and wrappers on a tiny env whose every step is known in advance."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct

from rl_jax import envs
from rl_jax.envs.classic.rocket import Rocket
from rl_jax.envs.core.core import Environment, EnvParams, EnvState


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


# ---- the same guarantees on a real env ----------------------------------------------------------
def _rocket_rollout(num_steps: int):
    """Two rocket envs under EpisodeStatistics(AutoReset(.)), vmapped and scanned: env 0 runs a
    damped controller (never terminates: truncated at 500), env 1 full thrust (crashes)."""
    bare = Rocket()
    env = envs.EpisodeStatistics(envs.AutoReset(bare))
    reset, step = jax.vmap(env.reset), jax.vmap(env.step)

    def policy(obs):
        damped = jnp.clip(-obs[0, 0] - 2 * obs[0, 1], -1.0, 1.0)
        return jnp.stack([damped, jnp.float32(1.0)])[:, None]

    def body(carry, key):
        state, obs = carry
        action = policy(obs)
        new_state, ts = step(jax.random.split(key, 2), state, action)
        # The bare env from the same pre-step state: what the wrapper must report as final.
        _, bare_ts = jax.vmap(bare.step)(jax.random.split(key, 2), state.env_state, action)
        return (new_state, ts.obs), (obs, ts, bare_ts)

    @jax.jit
    def run(key):
        state, ts = reset(jax.random.split(key, 2))
        keys = jax.random.split(jax.random.fold_in(key, 1), num_steps)
        return jax.lax.scan(body, (state, ts.obs), keys)[1]

    return jax.device_get(run(jax.random.PRNGKey(0)))


def test_autoreset_and_statistics_on_the_rocket():
    prev_obs, ts, bare_ts = _rocket_rollout(1100)
    done = ts.terminated | ts.truncated
    # Final obs is the bare env's next obs on every step; obs differs from it only at resets.
    np.testing.assert_array_equal(ts.info["final_obs"], bare_ts.obs)
    np.testing.assert_array_equal(ts.reward, bare_ts.reward)
    np.testing.assert_array_equal(ts.obs[~done], ts.info["final_obs"][~done])
    reset_obs = np.abs(ts.obs[done])
    assert np.all((reset_obs >= 0.5) & (reset_obs <= 1.0))  # a fresh start, not a terminal state
    # The new episode really starts from the reset obs: stepping the bare env from that state
    # with the next action gives the next step's result.
    bare = Rocket()
    for t, column in zip(*np.nonzero(done[:-1]), strict=True):
        start, _ = bare.reset_to(ts.obs[t, column])
        policy_input = prev_obs[t + 1, column]
        np.testing.assert_array_equal(policy_input, ts.obs[t, column])
        x, v = policy_input
        thrust = np.clip(-x - 2 * v, -1, 1) if column == 0 else 1.0
        _, expected = bare.step(jax.random.PRNGKey(0), start, jnp.array([thrust], jnp.float32))
        np.testing.assert_allclose(ts.info["final_obs"][t + 1, column], expected.obs, rtol=1e-6)
    # Env 0 truncates at exactly 500 and 1000; env 1 crashes (terminated, -500) again and again.
    assert list(np.nonzero(done[:, 0])[0] + 1) == [500, 1000]
    assert ts.truncated[[499, 999], 0].all() and not ts.terminated[:, 0].any()
    crashes = np.nonzero(done[:, 1])[0]
    assert len(crashes) >= 5 and ts.terminated[crashes, 1].all()
    assert np.all(ts.reward[crashes, 1] < -400)
    # Returns and lengths: recomputed from the per-step rewards between dones.
    for column in range(2):
        start = 0
        for end in np.nonzero(done[:, column])[0]:
            expected = ts.reward[start : end + 1, column].astype(np.float64).sum()
            np.testing.assert_allclose(ts.info["episode_return"][end, column], expected, rtol=1e-5)
            assert ts.info["episode_length"][end, column] == end + 1 - start
            assert ts.info["episode_done"][end, column]
            start = end + 1
        # Between dones the last finished episode's statistics stay reported.
        last = np.nonzero(done[:, column])[0][-1]
        assert np.all(
            ts.info["episode_return"][last:, column] == ts.info["episode_return"][last, column]
        )


# ---- MaskObservation ----------------------------------------------------------------------------
def _cartpole_pair(**mask_keywords):
    from rl_jax.envs.classic.cartpole import CartPole

    return CartPole(), envs.MaskObservation(CartPole(), **mask_keywords)


def test_mask_observation_keeps_the_chosen_entries_and_their_bounds():
    bare, masked = _cartpole_pair(keep=(2, 0))
    space = bare.observation_space()
    assert masked.observation_space() == envs.Box(space.low[[2, 0]], space.high[[2, 0]], (2,))
    key = jax.random.PRNGKey(3)
    (bare_state, bare_ts), (state, ts) = bare.reset(key), masked.reset(key)
    np.testing.assert_array_equal(ts.obs, bare_ts.obs[np.array([2, 0])])
    for t in range(5):
        key = jax.random.fold_in(key, t)
        bare_state, bare_ts = bare.step(key, bare_state, jnp.int32(t % 2))
        state, ts = masked.step(key, state, jnp.int32(t % 2))
        np.testing.assert_array_equal(ts.obs, bare_ts.obs[np.array([2, 0])])
        assert (ts.reward, ts.terminated, ts.truncated) == (
            bare_ts.reward,
            bare_ts.terminated,
            bare_ts.truncated,
        )
    assert jax.tree.structure(state) == jax.tree.structure(bare_state)


def test_mask_observation_can_zero_the_others_and_keep_the_shape():
    bare, masked = _cartpole_pair(keep=(0, 2), zero_others=True)
    assert masked.observation_space() == bare.observation_space()
    _, ts = masked.reset_to(jnp.array([0.1, -0.2, 0.03, 0.4]))
    np.testing.assert_array_equal(ts.obs, np.array([0.1, 0.0, 0.03, 0.0], np.float32))
    # reset_to with leading axes, as the MuJoCo envs take it
    obs = masked.mask(jnp.ones((3, 4)))
    np.testing.assert_array_equal(obs, np.tile([1.0, 0.0, 1.0, 0.0], (3, 1)))


@pytest.mark.parametrize("mask_outside", [True, False])
def test_mask_observation_masks_the_final_obs_of_autoreset(mask_outside):
    from rl_jax.envs.classic.cartpole import CartPole

    keep = (0, 2)
    env = (
        envs.MaskObservation(envs.AutoReset(CartPole()), keep)
        if mask_outside
        else envs.AutoReset(envs.MaskObservation(CartPole(), keep))
    )
    reference = envs.AutoReset(CartPole())
    assert env.empty_info()["final_obs"].shape == (2,)
    keys = jax.random.split(jax.random.PRNGKey(4), 6)
    state, ts = jax.vmap(env.reset)(keys)
    ref_state, ref_ts = jax.vmap(reference.reset)(keys)
    assert ts.info["final_obs"].shape == (6, 2)
    step, ref_step = jax.jit(jax.vmap(env.step)), jax.jit(jax.vmap(reference.step))
    ended = 0
    for t in range(40):  # always push right: every episode ends and restarts within 40 steps
        step_keys = jax.random.split(jax.random.fold_in(keys[0], t), 6)
        state, ts = step(step_keys, state, jnp.ones(6, jnp.int32))
        ref_state, ref_ts = ref_step(step_keys, ref_state, jnp.ones(6, jnp.int32))
        np.testing.assert_array_equal(ts.obs, ref_ts.obs[:, np.array(keep)])
        np.testing.assert_array_equal(ts.info["final_obs"], ref_ts.info["final_obs"][:, keep])
        np.testing.assert_array_equal(ts.terminated, ref_ts.terminated)
        ended += int(np.sum(ts.terminated))
    assert ended >= 6


def test_mask_observation_passes_step_active_and_the_episode_limit_through():
    bare, masked = _cartpole_pair(keep=(0,))
    state, _ = masked.reset(jax.random.PRNGKey(5))
    new_state, ts = masked.step_active(jax.random.PRNGKey(6), state, jnp.int32(1), False)
    assert ts.obs.shape == (1,)
    np.testing.assert_array_equal(new_state.x, state.x)  # inactive: the state is kept
    # Setting the limit sets the wrapped env's, which decides truncation (as make_vec does).
    masked.max_episode_steps = 2
    assert masked.env.max_episode_steps == 2
    state, _ = masked.reset(jax.random.PRNGKey(5))
    truncated = []
    for t in range(2):
        state, ts = masked.step(jax.random.PRNGKey(t), state, jnp.int32(t % 2))
        truncated.append(bool(ts.truncated))
    assert truncated == [False, True]


@pytest.mark.parametrize(
    ("keep", "error"), [((), ValueError), ((0, 0), ValueError), ((4,), ValueError)]
)
def test_mask_observation_refuses_bad_indices(keep, error):
    from rl_jax.envs.classic.cartpole import CartPole

    with pytest.raises(error):
        envs.MaskObservation(CartPole(), keep)
