"""Learning curves and result tables from ``metrics.jsonl`` rows.

Across seeds we report the interquartile mean (IQM: the mean of the middle 50% of seeds, robust
to one lucky or broken seed; equal to the mean below 4 seeds) with a 95% percentile-bootstrap
confidence interval over seeds. The bootstrap uses a fixed RNG, so the same metrics always give
the same plot and table.

Why not rliable, which computes these intervals (and aggregates across tasks): a run here is
one task, and ``bootstrap_ci`` is a few lines of numpy that also bootstraps every point of a
curve at once, in blocks that bound its memory, without another dependency.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

TRIM = 0.25  # IQM: drop this fraction of seeds at each end, as scipy.stats.trim_mean


def interquartile_mean(values: np.ndarray, axis: int = 0) -> np.ndarray:
    """Mean of ``values`` after dropping ``floor(n / 4)`` lowest and highest along ``axis``."""
    values = np.sort(np.asarray(values, np.float64), axis=axis)
    count = values.shape[axis]
    cut = int(TRIM * count)
    kept = np.take(values, np.arange(cut, count - cut), axis=axis)
    return kept.mean(axis=axis)


def _statistic(name: str):
    if name == "iqm":
        return interquartile_mean
    if name == "mean":
        return lambda values, axis=0: np.mean(values, axis=axis)
    raise ValueError(f"unknown statistic {name!r}; use 'iqm' or 'mean'")


def bootstrap_ci(
    values: np.ndarray,
    statistic: str = "iqm",
    confidence: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile-bootstrap CI of ``statistic`` over axis 0 (seeds) of ``values [n, ...]``.

    Seeds are resampled with replacement ``resamples`` times with a fixed RNG; returns the
    ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles, each shaped ``values[0]``.
    """
    values = np.asarray(values, np.float64)
    rng = np.random.default_rng(seed)
    indices = rng.integers(0, values.shape[0], size=(resamples, values.shape[0]))
    function = _statistic(statistic)
    flat = values.reshape(values.shape[0], -1)
    # Blocks of columns keep the [resamples, n, columns] array small for long curves.
    block = max(1, 4_000_000 // (resamples * values.shape[0]))
    low, high = [], []
    for start in range(0, flat.shape[1], block):
        samples = flat[:, start : start + block][indices]  # [resamples, n, block]
        stats = function(samples, axis=1)
        low.append(np.quantile(stats, (1 - confidence) / 2, axis=0))
        high.append(np.quantile(stats, (1 + confidence) / 2, axis=0))
    shape = values.shape[1:]
    return np.concatenate(low).reshape(shape), np.concatenate(high).reshape(shape)


@dataclasses.dataclass
class Curves:
    """Eval return of one config: ``returns[seed, eval]`` at ``steps[eval]`` (NaN where absent)."""

    label: str
    steps: np.ndarray  # [T] int
    seeds: list[int]
    returns: np.ndarray  # [S, T] float

    def summary(self, statistic: str = "iqm") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(center, low, high)`` per eval step (NaN where a seed has no value there)."""
        center = _statistic(statistic)(self.returns, axis=0)
        if self.returns.shape[0] < 2:
            return center, center, center
        low, high = bootstrap_ci(self.returns, statistic)
        return center, low, high


def _label(
    config: int | None, row: dict[str, Any], grid_fields: tuple[str, ...], names: tuple[str, ...]
) -> str:
    if config is None:
        return "all seeds"
    shown = names or grid_fields
    values = ", ".join(
        f"{name}={row.get(field)}" for name, field in zip(shown, grid_fields, strict=True)
    )
    return values or f"config {config}"


def curves_from_rows(
    rows: list[dict[str, Any]], grid_fields: tuple[str, ...] = (), names: tuple[str, ...] = ()
) -> list[Curves]:
    """One ``Curves`` per config (in config order) from metrics rows, labelled by the values of
    its ``grid_fields``, each shown by its name in ``names`` where given (the name a sweep's grid
    was asked by: ``lr`` for ``actor_lr``), else by the field's own."""
    by_config: dict[int | None, list[dict]] = {}
    for row in rows:
        by_config.setdefault(row.get("config"), []).append(row)
    curves = []
    for config in sorted(by_config, key=lambda c: -1 if c is None else c):
        group = by_config[config]
        steps = np.array(sorted({row["step"] for row in group}))
        seeds = sorted({row["seed"] for row in group})
        returns = np.full((len(seeds), len(steps)), np.nan)
        step_index = {step: i for i, step in enumerate(steps)}
        seed_index = {seed: i for i, seed in enumerate(seeds)}
        for row in group:
            value = row.get("eval_return")
            returns[seed_index[row["seed"]], step_index[row["step"]]] = (
                np.nan if value is None else value
            )
        label = _label(config, group[0], grid_fields, names)
        curves.append(Curves(label, steps, seeds, returns))
    return curves


def plot_curves(
    curves: list[Curves],
    path: str | Path,
    title: str = "",
    statistic: str = "iqm",
    per_seed: bool | None = None,
) -> None:
    """Eval return vs env steps: the statistic over seeds, its 95% CI band, faint seed lines.

    ``per_seed`` defaults to drawing seed lines only when there is one curve.
    """
    import matplotlib  # heavy: imported on first use, then set to its headless backend

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per_seed = len(curves) == 1 if per_seed is None else per_seed
    figure, axes = plt.subplots(figsize=(7, 4.5), dpi=110)
    for index, curve in enumerate(curves):
        color = f"C{index % 10}"
        center, low, high = curve.summary(statistic)
        if per_seed:
            for seed_returns in curve.returns:
                axes.plot(curve.steps, seed_returns, color=color, alpha=0.25, linewidth=0.8)
        name = _statistic_name(statistic, len(curve.seeds))
        label = f"{curve.label}: {name}" if len(curves) > 1 else name
        axes.plot(curve.steps, center, color=color, linewidth=2, label=label)
        if len(curve.seeds) > 1:
            axes.fill_between(curve.steps, low, high, color=color, alpha=0.2, linewidth=0)
    axes.set_xlabel("env steps (per seed)")
    axes.set_ylabel("eval return")
    axes.set_title(title)
    axes.grid(alpha=0.3)
    axes.legend(fontsize="small")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def _statistic_name(statistic: str, seeds: int) -> str:
    name = "IQM" if statistic == "iqm" and seeds >= 4 else "mean"
    if seeds == 1:
        return "1 seed"
    return f"{name} of {seeds} seeds, 95% bootstrap CI"


# ---- tables ---------------------------------------------------------------------------------


@dataclasses.dataclass
class FinalResult:
    """The last eval return of every seed of one config, and its summary."""

    label: str
    step: int
    seeds: list[int]
    returns: np.ndarray  # [S]
    mean: float
    ci_low: float
    ci_high: float
    iqm: float
    best: np.ndarray | None = None  # [S] each seed's best eval return (its kept best policy)
    best_steps: np.ndarray | None = None  # [S] the step of that eval

    @property
    def best_mean(self) -> float:
        """Mean over seeds of the best eval returns (NaN when there are none)."""
        return float(np.mean(self.best)) if self.best is not None else math.nan


def final_results(curves: list[Curves]) -> list[FinalResult]:
    """Per config: each seed's return at the last eval step, mean with its 95% bootstrap CI."""
    results = []
    for curve in curves:
        returns = curve.returns[:, -1]
        mean = float(np.mean(returns))
        if len(returns) > 1:
            low, high = bootstrap_ci(returns[:, None], "mean")
            ci = (float(low[0]), float(high[0]))
        else:
            ci = (math.nan, math.nan)
        iqm = float(interquartile_mean(returns))
        best, best_steps = best_evals(curve)
        results.append(
            FinalResult(
                curve.label,
                int(curve.steps[-1]),
                curve.seeds,
                returns,
                mean,
                *ci,
                iqm,
                best,
                best_steps,
            )
        )
    return results


def best_evals(curve: Curves) -> tuple[np.ndarray, np.ndarray]:
    """Per seed: the highest eval return (the first, on ties) and its step; NaN and -1 for a
    seed without a finite eval. The runner keeps the policy of exactly that eval."""
    finite = np.where(np.isfinite(curve.returns), curve.returns, -np.inf)
    index = np.argmax(finite, axis=1)
    best = finite[np.arange(len(index)), index]
    has = np.isfinite(best)
    return np.where(has, best, np.nan), np.where(has, curve.steps[index], -1)


def _number(value: float) -> str:
    return "n/a" if not np.isfinite(value) else f"{value:.2f}"


def format_duration(seconds: float) -> str:
    """Seconds as ``H:MM:SS``."""
    seconds = int(round(seconds))
    return f"{seconds // 3600}:{seconds % 3600 // 60:02d}:{seconds % 60:02d}"


def count_of(number: int, noun: str) -> str:
    """A count and its noun, plural unless the count is one: ``1 seed``, ``5 seeds``."""
    return f"{number:,} {noun}{'' if number == 1 else 's'}"


def results_table(result: FinalResult, wall_clock: float | None = None) -> str:
    """The final-return table of a single-config run, as text."""
    seeds = count_of(len(result.seeds), "seed")
    lines = [f"final eval return at step {result.step:,} ({seeds})", ""]
    best = result.best if result.best is not None else np.full(len(result.seeds), np.nan)
    steps = result.best_steps if result.best_steps is not None else np.full(len(best), -1)
    lines += ["  seed   final eval   best eval (at step)"]
    lines += ["  ----   ----------   -------------------"]
    for s, r, b, at in zip(result.seeds, result.returns, best, steps, strict=True):
        where = f" ({int(at):,})" if at >= 0 else ""
        lines.append(f"  {s:>4}   {_number(r):>10}   {_number(b) + where:>19}")
    lines += ["", f"  mean   {_number(result.mean):>10}   {_number(result.best_mean):>19}"]
    if len(result.seeds) > 1:
        ci = f"[{_number(result.ci_low)}, {_number(result.ci_high)}]"
        lines += [f"  95% CI of the mean (bootstrap over seeds): {ci}"]
        lines += [f"  IQM    {_number(result.iqm):>11}"]
    if wall_clock is not None:
        lines += [f"  wall-clock {format_duration(wall_clock)}"]
    return "\n".join(lines)


def sweep_table(results: list[FinalResult], wall_clock: float | None = None) -> str:
    """Configs ranked by mean final eval return, with 95% CIs, as text."""
    ranked = sorted(results, key=lambda r: -np.nan_to_num(r.mean, nan=-np.inf))
    width = max(len("config"), *(len(r.label) for r in ranked))
    header = (
        f"  rank  {'config':<{width}}  {'mean':>10}  {'95% CI':>22}  {'IQM':>10}  "
        f"{'best mean':>10}  seeds"
    )
    lines = [f"final eval return at step {ranked[0].step:,}, ranked", "", header]
    for rank, r in enumerate(ranked, 1):
        ci = f"[{_number(r.ci_low)}, {_number(r.ci_high)}]"
        lines.append(
            f"  {rank:>4}  {r.label:<{width}}  {_number(r.mean):>10}  {ci:>22}  "
            f"{_number(r.iqm):>10}  {_number(r.best_mean):>10}  {len(r.seeds)}"
        )
    if wall_clock is not None:
        lines += ["", f"  wall-clock {format_duration(wall_clock)}"]
    return "\n".join(lines)
