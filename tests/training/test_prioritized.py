"""Proportional prioritized replay: draws follow priorities (chi-square), importance weights follow
the formula, trees stay consistent, and a DQN update writes |TD error| + eps back."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import dqn
from rl_jax.training import prioritized
from rl_jax.training.replay import Transition

ALPHA = 0.6
WIDTH, ROWS = 2, 5  # 10 transitions in a 12-slot buffer: two slots stay empty (16 tree leaves)


def _rows(count, width=WIDTH):
    items = []
    for row in range(count):
        base = float(row * width)
        items.append(
            Transition(
                obs=jnp.arange(width, dtype=jnp.float32)[:, None] + base,
                action=jnp.zeros(width, jnp.int32),
                reward=jnp.ones(width),
                next_obs=jnp.zeros((width, 1)),
                terminated=jnp.zeros(width, bool),
                truncated=jnp.zeros(width, bool),
            )
        )
    return items


@pytest.fixture(scope="module")
def filled():
    """10 stored transitions with priorities 1..10 (slot order)."""
    example = jax.tree.map(lambda x: x[0], _rows(1)[0])
    buffer = prioritized.init(example, 12, WIDTH)
    add = jax.jit(prioritized.add)
    for row in _rows(ROWS):
        buffer = add(buffer, row, ALPHA)
    slots = np.arange(ROWS * WIDTH)
    priorities = jnp.asarray(slots + 1.0, jnp.float32)
    buffer = jax.jit(prioritized.update_priorities)(
        buffer, jnp.asarray(slots // WIDTH), jnp.asarray(slots % WIDTH), priorities, ALPHA
    )
    return buffer, np.asarray(priorities, np.float64)


def _check_tree(buffer):
    sums, mins = np.asarray(buffer.sums), np.asarray(buffer.mins)
    for node in range(1, buffer.leaves):
        np.testing.assert_allclose(sums[node], sums[2 * node] + sums[2 * node + 1], rtol=1e-5)
        assert mins[node] == min(mins[2 * node], mins[2 * node + 1])


def test_new_transitions_enter_with_the_largest_priority_and_trees_stay_consistent(filled):
    buffer, priorities = filled
    _check_tree(buffer)
    np.testing.assert_allclose(buffer.max_priority, 10.0)
    leaves = np.asarray(buffer.sums[buffer.leaves :])
    np.testing.assert_allclose(leaves[:10], priorities**ALPHA, rtol=1e-6)
    assert np.all(leaves[10:] == 0.0) and np.all(np.isinf(np.asarray(buffer.mins)[26:]))
    added = prioritized.add(buffer, _rows(1)[0], ALPHA)  # row 5: slots 10, 11
    np.testing.assert_allclose(added.sums[added.leaves + 10 : added.leaves + 12], 10.0**ALPHA)
    _check_tree(added)


@pytest.fixture(scope="module")
def draws(filled):
    buffer, _ = filled
    sample = jax.jit(jax.vmap(lambda key: prioritized.sample_indices(buffer, key, 16, 0.5)))
    rows, columns, weights = sample(jax.random.split(jax.random.key(0), 2000))
    return np.asarray(rows * WIDTH + columns).ravel(), np.asarray(weights).ravel()


def test_sampling_frequencies_match_priorities_chi_square(draws, filled):
    slots, _ = draws
    _, priorities = filled
    counts = np.bincount(slots, minlength=12)
    assert counts[10:].sum() == 0  # empty slots are never drawn
    expected = priorities**ALPHA / np.sum(priorities**ALPHA) * slots.size
    _, p_value = stats.chisquare(counts[:10], expected)
    assert p_value > 1e-3, (counts, expected)
    # The test has power: the same counts reject plain uniform sampling outright.
    _, p_uniform = stats.chisquare(counts[:10], np.full(10, slots.size / 10))
    assert p_uniform < 1e-12


def test_importance_weights_match_the_formula(draws, filled):
    slots, weights = draws
    _, priorities = filled
    probabilities = priorities**ALPHA / np.sum(priorities**ALPHA)
    n, beta = 10, 0.5
    expected = (n * probabilities[slots]) ** -beta / (n * probabilities.min()) ** -beta
    np.testing.assert_allclose(weights, expected, rtol=1e-5)
    assert weights.max() <= 1.0 + 1e-6


def test_annealed_beta_rises_linearly_to_one():
    got = [float(prioritized.annealed_beta(0.4, t, 1000.0)) for t in (0, 250, 1000, 5000)]
    np.testing.assert_allclose(got, [0.4, 0.55, 1.0, 1.0], rtol=1e-6)


def test_tree_find_matches_a_cumulative_sum_search():
    values = jax.random.uniform(jax.random.key(1), (13,))
    sums = prioritized.tree_set(
        jnp.zeros(32), jnp.arange(13), values, jnp.add
    )  # 16 leaves, 3 empty
    targets = jax.random.uniform(jax.random.key(2), (500,)) * sums[1]
    got = prioritized.tree_find(sums, targets)
    expected = np.searchsorted(np.cumsum(np.asarray(values)), np.asarray(targets), side="right")
    np.testing.assert_array_equal(got, expected)


def test_a_dqn_update_writes_abs_td_error_plus_eps_back():
    config = dqn.default_config(
        "rl_jax/ProbeActionRewardDiscrete-v0",
        hidden=(8,),
        batch_size=4,
        buffer_size=16,
        num_envs=2,
        prioritized=True,
        learning_starts=0,
    )
    hparams = dqn.default_hyperparams(priority_eps=0.01)
    state = dqn.init(jax.random.key(3), config, hparams)
    buffer = state.buffer
    add = jax.jit(dqn.add_to_buffer, static_argnums=2)
    for row in _rows(5):
        buffer = add(buffer, row, config, hparams)
    key = jax.random.key(4)

    @jax.jit
    def sample_and_td_error(agent, buffer):
        replay = dqn.replay_for(config)
        batch, weights, indices = replay.sample(buffer, key, hparams, jnp.int32(0))
        td_error = dqn.loss_fn(agent.online, agent.target, batch, weights, hparams, config)[1][0]
        return indices, td_error

    (rows, columns), td_error = sample_and_td_error(state.agent, buffer)
    update = jax.jit(dqn.update, static_argnums=3)
    _, updated, _ = update(state.agent, buffer, key, config, hparams, jnp.int32(0))
    slots = np.asarray(rows * WIDTH + columns)
    assert len(set(slots.tolist())) == slots.size  # distinct draws: each slot has one new value
    expected = (np.abs(np.asarray(td_error)) + 0.01) ** float(hparams.priority_alpha)
    np.testing.assert_allclose(updated.sums[updated.leaves + slots], expected, rtol=1e-5)
    untouched = np.setdiff1d(np.arange(10), slots)
    np.testing.assert_array_equal(
        updated.sums[updated.leaves + untouched], buffer.sums[buffer.leaves + untouched]
    )
    np.testing.assert_allclose(
        updated.max_priority, max(1.0, np.max(np.abs(np.asarray(td_error)) + 0.01)), rtol=1e-6
    )
    _check_tree(updated)
