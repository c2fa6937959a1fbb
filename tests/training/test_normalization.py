"""Running observation statistics: exact moments of everything folded in, masks respected."""

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.training import normalization


def test_batches_folded_in_one_by_one_give_the_moments_of_all_rows():
    rng = np.random.default_rng(0)
    batches = [rng.normal(3.0, 2.0, (n, 5)).astype(np.float32) for n in (7, 40, 1, 13)]
    stats = normalization.init(5)
    for batch in batches:
        stats = jax.jit(normalization.update)(stats, batch, jnp.ones(batch.shape[0]))
    rows = np.concatenate(batches)
    np.testing.assert_allclose(stats.mean, rows.mean(0), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(stats.var, rows.var(0), rtol=1e-3)
    np.testing.assert_allclose(stats.count, len(rows), rtol=1e-5)


def test_masked_rows_are_left_out():
    batch = np.array([[[1.0], [100.0]], [[3.0], [-50.0]]], np.float32)  # [T=2, N=2, 1]
    mask = np.array([[1.0, 0.0], [1.0, 0.0]], np.float32)
    stats = normalization.update(normalization.init(1), batch, mask)
    np.testing.assert_allclose(stats.mean, [2.0], rtol=1e-4)
    np.testing.assert_allclose(stats.var, [1.0], rtol=1e-3)


def test_normalize_standardises_clips_and_leaves_obs_without_stats_alone():
    stats = normalization.RunningStats(
        count=jnp.float32(10.0), mean=jnp.array([1.0, -2.0]), var=jnp.array([4.0, 0.25])
    )
    obs = jnp.array([[3.0, -2.5], [1.0, 1000.0]])
    expected = [[1.0, -1.0], [0.0, normalization.CLIP]]
    np.testing.assert_allclose(normalization.normalize(stats, obs), expected, rtol=1e-5)
    assert normalization.normalize(None, obs) is obs
