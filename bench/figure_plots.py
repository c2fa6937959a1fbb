"""Drawing the figures of ``bench.figures`` and writing them small enough to commit.

Every image is written at most ``MAX_BYTES``: a PNG is drawn by matplotlib (Agg), reduced to a
256-colour palette (plots use few colours, so nothing visible changes) and redrawn at a lower
resolution while still too big; a GIF loses resolution, then every other frame, until it fits.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench import figure_stats
from bench.figure_data import Reference, RunCurves

MAX_BYTES = 150 * 1024
GRAY = "0.35"


def _pyplot() -> Any:
    import matplotlib  # heavy: imported on first use, then set to its headless backend

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(figure: Any, path: Path, dpi: float = 110, limit: int = MAX_BYTES) -> int:
    """Write ``figure`` as a palette PNG of at most ``limit`` bytes; its size."""
    from PIL import Image

    plt = _pyplot()
    while True:
        buffer = io.BytesIO()
        figure.savefig(buffer, format="png", dpi=dpi)
        image = Image.open(buffer).convert("RGB").quantize(colors=256)
        out = io.BytesIO()
        image.save(out, format="PNG", optimize=True)
        if out.tell() <= limit or dpi < 40:
            break
        dpi *= 0.8
    plt.close(figure)
    path.write_bytes(out.getvalue())
    return out.tell()


def _steps_axis(axes: Any) -> None:
    from matplotlib.ticker import FuncFormatter

    def short(value: float, _position: Any) -> str:
        if abs(value) >= 1e6:
            return f"{value / 1e6:g}M"
        return f"{value / 1e3:g}k" if abs(value) >= 1e3 else f"{value:g}"

    axes.xaxis.set_major_formatter(FuncFormatter(short))
    axes.set_xlabel("env steps (per seed)")


def curves_figure(
    runs: Sequence[RunCurves],
    references: Sequence[Reference],
    path: Path,
    title: str,
    max_step: float | None = None,
    line: tuple[float, str] | None = None,
    legend: str = "best",
) -> int:
    """Each run's mean eval return with its 95% bootstrap band over seeds; each reference's
    mean and band (grey tones, dashed, dash-dotted, dotted) up to ``max_step`` (default: the
    runs' last step); ``line``: a horizontal line ``(value, label)``, e.g. an env's maximum
    return. ``legend``: matplotlib's ``loc`` inside the axes, or ``"below"``: under them, in two
    columns, where the curves leave no corner free."""
    plt = _pyplot()
    figure, axes = plt.subplots(figsize=(6.4, 4.6 if legend == "below" else 4.0))
    last = max_step or max(float(run.steps[-1]) for run in runs)
    for index, reference in enumerate(references):
        kept = reference.steps <= last
        mean, low, high = figure_stats.mean_ci(reference.returns[:, kept])
        color = ("0.2", "0.45", "0.6")[index % 3]
        style = ("--", "-.", (0, (1, 1.2)))[index % 3]
        axes.plot(reference.steps[kept], mean, ls=style, color=color, lw=1.6, label=reference.label)
        axes.fill_between(reference.steps[kept], low, high, color=color, alpha=0.18, lw=0)
    for index, run in enumerate(runs):
        mean, low, high = figure_stats.mean_ci(run.returns)
        color = f"C{index % 10}"
        axes.plot(run.steps, mean, color=color, lw=2, label=run.label)
        axes.fill_between(run.steps, low, high, color=color, alpha=0.25, lw=0)
    if line is not None:
        axes.axhline(line[0], color=GRAY, lw=0.8, ls=":", label=line[1])
    axes.set_xlim(0, last)
    _steps_axis(axes)
    axes.set_ylabel("eval return (mean, 95% bootstrap CI)")
    axes.set_title(title, fontsize="medium")
    axes.grid(alpha=0.3)
    if legend == "below":
        axes.legend(
            fontsize="small", loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False
        )
    else:
        axes.legend(fontsize="small", loc=legend)
    figure.tight_layout()
    return save_png(figure, path)


def aggregate_figure(
    scores: dict[str, list[np.ndarray]], path: Path, title: str, scale: str
) -> tuple[int, dict[str, tuple[float, float, float]]]:
    """Per learner (``scores[label]``: one array of normalised scores per env): the IQM with
    its stratified-bootstrap 95% interval, and the performance profile with its band. Returns
    the file size and the IQMs ``{label: (iqm, low, high)}``."""
    plt = _pyplot()
    figure, (left, right) = plt.subplots(1, 2, figsize=(8.4, 3.4), width_ratios=(1, 1.5))
    highest = max(float(np.max(np.concatenate(s))) for s in scores.values())
    taus = np.linspace(0.0, max(1.2, highest * 1.05), 121)
    iqms = {}
    for index, (label, learner_scores) in enumerate(scores.items()):
        color = f"C{index % 10}"
        iqms[label] = figure_stats.iqm_ci(learner_scores)
        center, low, high = iqms[label]
        left.errorbar(
            center,
            index,
            xerr=[[center - low], [high - center]],
            fmt="o",
            color=color,
            capsize=4,
            lw=2,
        )
        fraction, band_low, band_high = figure_stats.profile_ci(learner_scores, taus)
        envs = len(learner_scores)
        runs = sum(np.size(s) for s in learner_scores)
        right.plot(
            taus,
            fraction,
            color=color,
            lw=2,
            label=f"{label} ({envs} env{'s' * (envs > 1)}, {runs} runs)",
        )
        right.fill_between(taus, band_low, band_high, color=color, alpha=0.25, lw=0)
    left.set_yticks(range(len(scores)), list(scores))
    left.set_ylim(-0.6, len(scores) - 0.4)
    left.invert_yaxis()
    left.set_xlabel("IQM of normalised score")
    left.grid(alpha=0.3, axis="x")
    right.set_xlabel(f"normalised score tau ({scale})")
    right.set_ylabel("fraction of runs > tau")
    right.set_ylim(-0.02, 1.02)
    right.grid(alpha=0.3)
    right.legend(fontsize="small")
    figure.suptitle(title, fontsize="medium")
    figure.tight_layout()
    return save_png(figure, path), iqms


def speed_figure(
    labels: list[str],
    series: dict[str, list[float | None]],
    baseline: str | None,
    path: Path,
    title: str,
    unit: str,
    log: bool,
) -> int:
    """Grouped bars: one group per label, one bar per series; each bar of a series other than
    ``baseline`` is annotated with its ratio to the baseline's bar of the same group."""
    plt = _pyplot()
    width = 0.8 / len(series)
    group_width = 0.45 * len(series) + 0.4
    figure, axes = plt.subplots(figsize=(min(12.0, max(7.0, group_width * len(labels))), 4.2))
    positions = np.arange(len(labels))
    for index, (name, values) in enumerate(series.items()):
        offsets = positions - 0.4 + width * (index + 0.5)
        heights = [np.nan if v is None else v for v in values]
        axes.bar(offsets, heights, width, label=name, color=f"C{index % 10}")
        if baseline is None or name == baseline:
            continue
        for x, value, base in zip(offsets, values, series[baseline], strict=True):
            if value is None or not base:
                continue
            axes.annotate(
                f"{value / base:.1f}x",
                (x, value),
                ha="center",
                va="bottom",
                fontsize=6.5,
                rotation=90,
                xytext=(0, 2),
                textcoords="offset points",
            )
    if log:
        axes.set_yscale("log")
    axes.margins(y=0.3 if log else 0.0)
    if not log:
        axes.set_ylim(0, 1.3 * max(v for values in series.values() for v in values if v))
    slanted = len(labels) > 4 or max(len(label) for label in labels) > 12
    axes.set_xticks(
        positions, labels, rotation=20 if slanted else 0, ha="right" if slanted else "center"
    )
    axes.set_ylabel(unit)
    note = f"\nratios over {baseline}" if baseline else ""
    axes.set_title(title + note, fontsize="medium")
    axes.grid(alpha=0.3, axis="y")
    axes.legend(fontsize="small", ncols=min(4, len(series)), loc="upper left")
    figure.tight_layout()
    return save_png(figure, path)


def shrink_gif(source: Path, path: Path, limit: int = MAX_BYTES) -> int:
    """Copy the GIF ``source`` to ``path`` at most ``limit`` bytes: smaller frames first (down
    to half the width), then every other frame (each shown twice as long); its size."""
    from PIL import Image, ImageSequence

    with Image.open(source) as image:
        frames, durations = [], []
        for frame in ImageSequence.Iterator(image):
            frames.append(frame.convert("RGB"))
            durations.append(float(frame.info.get("duration", 40)))
    scale, step = 1.0, 1
    while True:
        size = (max(16, round(frames[0].width * scale)), max(16, round(frames[0].height * scale)))
        kept = [frame.resize(size, Image.Resampling.LANCZOS) for frame in frames[::step]]
        # a kept frame stays on screen for the frames dropped after it: the same playing time
        shown = [sum(durations[i : i + step]) for i in range(0, len(frames), step)]
        out = io.BytesIO()
        kept[0].save(
            out,
            format="GIF",
            save_all=True,
            append_images=kept[1:],
            duration=shown,
            loop=0,
            optimize=True,
        )
        if out.tell() <= limit or len(kept) == 1:  # one frame: as small as it gets
            break
        if scale > 0.5:
            scale *= 0.85
        else:
            step *= 2
    path.write_bytes(out.getvalue())
    return out.tell()
