"""Statistics against scipy/numpy, curves and tables from metrics rows, deterministic plots."""

import hashlib

import numpy as np
import pytest
from scipy import stats

from rl_jax.run import plots


@pytest.mark.parametrize("count", range(1, 13))
def test_interquartile_mean_matches_scipy_trim_mean(count):
    values = np.random.default_rng(count).normal(size=(count, 7))
    np.testing.assert_allclose(
        plots.interquartile_mean(values), stats.trim_mean(values, 0.25, axis=0), rtol=1e-12
    )


def test_interquartile_mean_by_hand():
    # 8 seeds: drop 2 lowest and 2 highest, average the middle 4.
    values = np.array([100.0, -50.0, 1.0, 2.0, 3.0, 4.0, 7.0, -3.0])
    assert plots.interquartile_mean(values) == pytest.approx((1 + 2 + 3 + 4) / 4)
    assert plots.interquartile_mean(values[:3]) == pytest.approx(np.mean(values[:3]))


@pytest.mark.parametrize("statistic, function", [("mean", np.mean), ("iqm", None)])
def test_bootstrap_ci_matches_scipy_percentile_bootstrap(statistic, function):
    if function is None:
        function = lambda x, axis: stats.trim_mean(x, 0.25, axis=axis)  # noqa: E731
    sample = np.random.default_rng(0).gamma(2.0, 3.0, size=12)
    low, high = plots.bootstrap_ci(sample[:, None], statistic, resamples=20_000, seed=1)
    reference = stats.bootstrap(
        (sample,), function, n_resamples=20_000, method="percentile", random_state=2
    ).confidence_interval
    # Two independent Monte Carlo estimates of the same quantiles: they agree to ~1% of the
    # sample's spread at 20k resamples (the standard error of a 2.5% quantile estimate).
    tolerance = 0.03 * np.std(sample)
    assert low[0] == pytest.approx(reference.low, abs=tolerance)
    assert high[0] == pytest.approx(reference.high, abs=tolerance)


def test_bootstrap_is_deterministic_and_degenerates_on_constant_data():
    values = np.random.default_rng(3).normal(size=(5, 40))
    first = plots.bootstrap_ci(values)
    second = plots.bootstrap_ci(values)
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1], second[1])
    assert np.all(first[0] <= plots.interquartile_mean(values) + 1e-12)
    low, high = plots.bootstrap_ci(np.full((4, 3), 2.5))
    np.testing.assert_array_equal(low, 2.5)
    np.testing.assert_array_equal(high, 2.5)


def test_bootstrap_blocks_give_the_same_answer_as_one_pass():
    values = np.random.default_rng(4).normal(size=(6, 3000))  # long curve: several blocks
    low, high = plots.bootstrap_ci(values, "mean", resamples=500)
    rng = np.random.default_rng(0)
    indices = rng.integers(0, 6, size=(500, 6))
    means = values[indices].mean(axis=1)
    np.testing.assert_allclose(low, np.quantile(means, 0.025, axis=0), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(high, np.quantile(means, 0.975, axis=0), rtol=1e-12, atol=1e-12)


def make_rows(configs=(None,), seeds=(0, 1, 2, 3), steps=(100, 200, 300)):
    rows = []
    for config in configs:
        for step in steps:
            for seed in seeds:
                row = {
                    "step": step,
                    "seed": seed,
                    "eval_return": step / 100 + seed + 10 * (config or 0),
                }
                if config is not None:
                    row.update(config=config, lr=[0.1, 0.2][config])
                rows.append(row)
    return rows


def test_curves_from_rows_shapes_and_values():
    (curve,) = plots.curves_from_rows(make_rows())
    np.testing.assert_array_equal(curve.steps, [100, 200, 300])
    assert curve.seeds == [0, 1, 2, 3]
    np.testing.assert_array_equal(curve.returns[:, 0], [1.0, 2.0, 3.0, 4.0])
    configs = plots.curves_from_rows(make_rows(configs=(0, 1)), grid_fields=("lr",))
    assert [c.label for c in configs] == ["lr=0.1", "lr=0.2"]
    np.testing.assert_array_equal(configs[1].returns[0], [11.0, 12.0, 13.0])


def test_missing_eval_is_nan():
    rows = make_rows(seeds=(0, 1))
    rows[0]["eval_return"] = None
    (curve,) = plots.curves_from_rows(rows)
    assert np.isnan(curve.returns[0, 0]) and not np.isnan(curve.returns[1, 0])


def test_final_results_and_table():
    (result,) = plots.final_results(plots.curves_from_rows(make_rows()))
    finals = np.array([3.0, 4.0, 5.0, 6.0])
    assert result.step == 300
    np.testing.assert_array_equal(result.returns, finals)
    assert result.mean == pytest.approx(finals.mean())
    low, high = plots.bootstrap_ci(finals[:, None], "mean")
    assert (result.ci_low, result.ci_high) == (pytest.approx(low[0]), pytest.approx(high[0]))
    assert result.iqm == pytest.approx(stats.trim_mean(finals, 0.25))
    table = plots.results_table(result, wall_clock=3725)
    assert "final eval return at step 300 (4 seeds)" in table
    assert "4.50" in table and f"[{low[0]:.2f}, {high[0]:.2f}]" in table
    assert "wall-clock 1:02:05" in table
    for seed, value in zip(range(4), finals, strict=True):
        # The returns rise with the step here, so each seed's best eval is its final one.
        assert f"{seed:>4}   {value:>10.2f}   {f'{value:.2f} (300)':>19}" in table


def test_best_eval_is_each_seeds_highest_and_its_first_step():
    rows = make_rows(seeds=(0, 1, 2))
    for row in rows:
        if row["seed"] == 1:  # peaks at step 200, then falls
            row["eval_return"] = {100: 5.0, 200: 9.0, 300: 2.0}[row["step"]]
        if row["seed"] == 2:  # a tie: the earlier step is kept
            row["eval_return"] = {100: 7.0, 200: 7.0, 300: None}[row["step"]]
    (result,) = plots.final_results(plots.curves_from_rows(rows))
    np.testing.assert_array_equal(result.best, [3.0, 9.0, 7.0])
    np.testing.assert_array_equal(result.best_steps, [300, 200, 100])
    assert result.best_mean == pytest.approx(19.0 / 3)
    assert "9.00 (200)" in plots.results_table(result)
    nothing = make_rows(seeds=(0,))
    for row in nothing:
        row["eval_return"] = None
    (empty,) = plots.final_results(plots.curves_from_rows(nothing))
    assert np.isnan(empty.best[0]) and empty.best_steps[0] == -1


def test_single_seed_table_has_no_interval():
    (result,) = plots.final_results(plots.curves_from_rows(make_rows(seeds=(7,))))
    table = plots.results_table(result)
    assert "CI" not in table and "7" in table


def test_sweep_table_ranks_by_mean():
    curves = plots.curves_from_rows(make_rows(configs=(0, 1)), grid_fields=("lr",))
    table = plots.sweep_table(plots.final_results(curves))
    lines = [line for line in table.splitlines() if line.strip()[:1].isdigit()]
    assert lines[0].split()[1] == "lr=0.2" and lines[1].split()[1] == "lr=0.1"


def test_plots_are_written_and_deterministic(tmp_path):
    curves = plots.curves_from_rows(make_rows(seeds=(0, 1, 2, 3, 4)))
    digests = []
    for name in ("a.png", "b.png"):
        plots.plot_curves(curves, tmp_path / name, title="fake")
        digests.append(hashlib.sha256((tmp_path / name).read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    sweep = plots.curves_from_rows(make_rows(configs=(0, 1)), grid_fields=("lr",))
    plots.plot_curves(sweep, tmp_path / "sweep.png")
    assert (tmp_path / "sweep.png").stat().st_size > 1000


def test_plot_draws_statistic_band_and_faint_seed_lines(tmp_path, monkeypatch):
    import matplotlib.axes

    calls = {"plot": [], "fill": []}
    original_plot, original_fill = matplotlib.axes.Axes.plot, matplotlib.axes.Axes.fill_between

    def record_plot(self, *args, **kwargs):
        calls["plot"].append((np.asarray(args[1]), kwargs))
        return original_plot(self, *args, **kwargs)

    def record_fill(self, x, low, high, **kwargs):
        calls["fill"].append((np.asarray(low), np.asarray(high)))
        return original_fill(self, x, low, high, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", record_plot)
    monkeypatch.setattr(matplotlib.axes.Axes, "fill_between", record_fill)
    (curve,) = plots.curves_from_rows(make_rows(seeds=(0, 1, 2, 3, 4)))
    plots.plot_curves([curve], tmp_path / "c.png")
    faint = [kwargs for _, kwargs in calls["plot"] if kwargs.get("alpha", 1) < 0.5]
    assert len(faint) == 5
    center = calls["plot"][-1][0]
    np.testing.assert_allclose(center, stats.trim_mean(curve.returns, 0.25, axis=0))
    low, high = plots.bootstrap_ci(curve.returns)
    np.testing.assert_allclose(calls["fill"][0][0], low)
    np.testing.assert_allclose(calls["fill"][0][1], high)
