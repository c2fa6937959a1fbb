"""Statistics over a suite of envs for the aggregate figure: normalised scores, their
interquartile mean (IQM) and performance profile, with stratified-bootstrap confidence intervals.

These follow Agarwal et al., "Deep RL at the Edge of the Statistical Precipice" (NeurIPS 2021):

* A learner's scores are one array per env (one final score per seed), each normalised by its
  env's scale, so that envs of different reward ranges can be pooled.
* The IQM is the mean of the middle 50% of all pooled scores (``floor(n / 4)`` dropped at each
  end, as ``scipy.stats.trim_mean(x, 0.25)``).
* The performance profile at ``tau`` is the fraction of runs scoring above ``tau``: per env,
  then averaged over envs (each env weighs the same however many seeds it has; with equal seed
  counts this is the fraction of all runs).
* A stratified bootstrap resamples the seeds of each env with replacement, separately, keeping
  every env in every resample; the 95% interval is the 2.5 and 97.5 percentiles of the
  statistic over resamples. The RNG is fixed: the same scores always give the same figure.

``tests/test_bench_figures.py`` checks them on cases with known answers, and against
``rliable`` where it is installed.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

from rl_jax.run.plots import interquartile_mean

#: Seeds resampled per bootstrap draw are indexed in one array: this many draws by default.
RESAMPLES = 2000


def normalize(scores: np.ndarray, low: float, high: float) -> np.ndarray:
    """``(scores - low) / (high - low)``: 0 at ``low`` (e.g. a random policy), 1 at ``high``
    (e.g. the reference's mean at its budget)."""
    if high == low:
        raise ValueError(f"a normalisation needs low != high (both {low})")
    return (np.asarray(scores, np.float64) - low) / (high - low)


def iqm(scores: Sequence[np.ndarray]) -> float:
    """The IQM of all scores of all envs pooled."""
    return float(interquartile_mean(np.concatenate([np.ravel(s) for s in scores])))


def profile(scores: Sequence[np.ndarray], taus: np.ndarray) -> np.ndarray:
    """Performance profile ``[len(taus)]``: per env the fraction of runs with score > tau, then
    the mean over envs."""
    taus = np.asarray(taus, np.float64)
    per_env = [np.mean(np.ravel(s)[:, None] > taus[None, :], axis=0) for s in scores]
    return np.mean(per_env, axis=0)


def _resampled(scores: Sequence[np.ndarray], resamples: int, seed: int) -> list[np.ndarray]:
    """Per env ``[resamples, n_env]``: its seeds drawn with replacement, each env on its own."""
    rng = np.random.default_rng(seed)
    draws = []
    for env_scores in scores:
        values = np.ravel(np.asarray(env_scores, np.float64))
        if values.size == 0:
            raise ValueError("every env needs at least one score")
        draws.append(values[rng.integers(0, values.size, size=(resamples, values.size))])
    return draws


def _interval(stats: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    tail = (1 - confidence) / 2 * 100
    return np.percentile(stats, tail, axis=0), np.percentile(stats, 100 - tail, axis=0)


def iqm_ci(
    scores: Sequence[np.ndarray],
    confidence: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[float, float, float]:
    """``(iqm, low, high)``: the IQM and its stratified-bootstrap percentile interval."""
    pooled = np.concatenate(_resampled(scores, resamples, seed), axis=1)  # [resamples, n]
    low, high = _interval(interquartile_mean(pooled, axis=1), confidence)
    return iqm(scores), float(low), float(high)


def profile_ci(
    scores: Sequence[np.ndarray],
    taus: np.ndarray,
    confidence: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(profile, low, high)``, each ``[len(taus)]``: the performance profile and its
    stratified-bootstrap percentile band."""
    taus = np.asarray(taus, np.float64)
    per_env = [
        np.mean(draw[:, :, None] > taus[None, None, :], axis=1)  # [resamples, taus]
        for draw in _resampled(scores, resamples, seed)
    ]
    low, high = _interval(np.mean(per_env, axis=0), confidence)
    return profile(scores, taus), low, high


def mean_ci(
    values: np.ndarray, confidence: float = 0.95, resamples: int = RESAMPLES, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, low, high)`` over axis 0 (seeds) of ``values [n, T]``, each ``[T]``: a curve's
    mean and its percentile-bootstrap band; NaN entries (a seed not evaluated there) are left
    out. One seed gives a band of zero width."""
    values = np.asarray(values, np.float64)
    rng = np.random.default_rng(seed)
    indices = rng.integers(0, values.shape[0], size=(resamples, values.shape[0]))
    with warnings.catch_warnings():  # an all-NaN column (no seed evaluated there) stays NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        stats = np.nanmean(values[indices], axis=1)  # [resamples, T]
        low, high = _interval_nan(stats, confidence)
        return np.nanmean(values, axis=0), low, high


def _interval_nan(stats: np.ndarray, confidence: float) -> tuple[np.ndarray, np.ndarray]:
    tail = (1 - confidence) / 2 * 100
    return np.nanpercentile(stats, tail, axis=0), np.nanpercentile(stats, 100 - tail, axis=0)
