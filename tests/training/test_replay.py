"""Circular replay buffer: insertion, wrap-around, uniform sampling.

What the train step stores in it (terminated apart from truncated, the true final observation)
is checked end to end in test_td3_probes.py, on the runs that learn the truncation probe."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from rl_jax.training import replay


def _item(value):
    return {"x": jnp.float32(value), "i": jnp.int32(value), "v": jnp.zeros(3)}


def _row(values):
    values = jnp.asarray(values)
    return {
        "x": values.astype(jnp.float32),
        "i": values.astype(jnp.int32),
        "v": jnp.tile(values[:, None], (1, 3)).astype(jnp.float32),
    }


def test_add_fills_rows_then_wraps_over_the_oldest():
    buffer = replay.init(_item(0), capacity=5, width=2)  # rounds up to 3 rows of 2
    assert (buffer.rows, buffer.width, buffer.capacity) == (3, 2, 6)
    add = jax.jit(replay.add)
    for step in range(4):
        buffer = add(buffer, _row([10 * step, 10 * step + 1]))
        assert int(buffer.rows_filled) == min(step + 1, 3)
    assert int(buffer.position) == 1 and int(buffer.size()) == 6
    # Row 0 was overwritten by step 3; rows 1 and 2 hold steps 1 and 2.
    np.testing.assert_array_equal(buffer.data["i"], [[30, 31], [10, 11], [20, 21]])
    np.testing.assert_array_equal(buffer.data["v"][:, :, 0], buffer.data["x"])
    assert buffer.data["i"].dtype == jnp.int32


def test_sampling_is_uniform_over_stored_items_only():
    buffer = replay.init(_item(0), capacity=100, width=4)
    for step in range(3):  # 12 of 100 slots filled
        buffer = replay.add(buffer, _row(jnp.arange(4) + 4 * step + 1))
    draws = jax.jit(replay.sample, static_argnums=2)(buffer, jax.random.key(0), 24_000)
    values = np.asarray(draws["i"])
    assert set(np.unique(values)) == set(range(1, 13))  # never an empty (zero) slot
    np.testing.assert_array_equal(draws["x"], values)  # leaves stay aligned
    counts = np.bincount(values, minlength=13)[1:]
    assert stats.chisquare(counts).pvalue > 1e-3


def test_nbytes_matches_the_allocation():
    example = _item(0)
    buffer = replay.init(example, capacity=10, width=3)
    allocated = sum(leaf.nbytes for leaf in jax.tree.leaves(buffer.data))
    assert replay.nbytes(example, 10, 3) == allocated == 4 * 3 * (4 + 4 + 12)
