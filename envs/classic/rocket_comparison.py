"""Rocket controllers side by side: rollouts from one exact start, a table and a plot.

Each ``Entry`` is one controller rolled through the env (``rocket_control.simulate``) and
summarised (``rocket_control.summarize``): the analytic laws (``analytic_entries``: time-optimal
bang-bang and the default saturated LQR) or any ``obs -> action`` callable, such as a learned
policy. ``markdown_table`` gives, per controller, the step from which the state stays inside the
goal box, whether it is still there at the last step, the env's episode return, the final
``(x, v)`` and what ended the env's own episode; ``plot_comparison`` draws x(t) and v(t) of
every entry, on the full scale and zoomed to the goal box. ``experiments/rocket_report.py`` puts
the seeds of training runs next to the analytic laws with these.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from rl_jax.envs.classic import rocket_control

PLOT_FILE = "rocket_comparison.png"
TABLE_FILE = "rocket_comparison.md"


@dataclasses.dataclass(frozen=True)
class Settings:
    """How every controller is rolled out and judged."""

    env_id: str
    start: tuple[float, float]
    steps: int
    tolerance: float  # half-width of the goal box in x and v
    dt: float  # the env's seconds per step


@dataclasses.dataclass(frozen=True)
class Entry:
    """One controller's rollout: an analytic law (``seed`` None) or one seed of a run."""

    controller: str
    seed: int | None
    policy: str  # which policy of the run ("best, step 42,500"); "-" for analytic laws
    trajectory: rocket_control.Trajectory
    summary: rocket_control.Summary
    learned: bool


def entry(
    name: str,
    seed: int | None,
    policy: str,
    controller: rocket_control.Controller,
    settings: Settings,
) -> Entry:
    """``controller`` rolled out and summarised as ``settings`` say; learned if it has a seed."""
    trajectory = rocket_control.simulate(
        controller, settings.start, settings.steps, settings.env_id
    )
    summary = rocket_control.summarize(trajectory, settings.tolerance)
    return Entry(name, seed, policy, trajectory, summary, learned=seed is not None)


def analytic_controllers(dt: float) -> dict[str, rocket_control.Controller]:
    """The reference laws by name: time-optimal bang-bang and the default saturated LQR."""
    lqr = rocket_control.lqr()
    gains = f"K = ({lqr.position_gain:.3g}, {lqr.velocity_gain:.3g})"
    return {"bang-bang (time-optimal)": rocket_control.TimeOptimal(dt), f"LQR, {gains}": lqr}


def analytic_entries(settings: Settings) -> list[Entry]:
    """The reference laws' rollouts, in the order of ``analytic_controllers``."""
    return [
        entry(name, None, "-", controller, settings)
        for name, controller in analytic_controllers(settings.dt).items()
    ]


# ---- table and plot -----------------------------------------------------------------------------


def _settled(summary: rocket_control.Summary, dt: float) -> str:
    if summary.settle_step is None:
        return "never"
    return f"{summary.settle_step} ({summary.settle_step * dt:.2f} s)"


def _kept(summary: rocket_control.Summary) -> str:
    if summary.kept:
        return "yes"
    if summary.first_entry_step is None:
        return "no: never inside"
    return f"no: inside at step {summary.first_entry_step}, then left"


def headline(settings: Settings) -> str:
    """What the table measures, with the time-optimal bound from this start."""
    x, v = settings.start
    bound = rocket_control.time_optimal_arrival_time(x, v)
    return (
        f"Rocket from (x, v) = ({x:g}, {v:g}) in {settings.env_id}, {settings.steps} steps "
        f"of {settings.dt:g} s; goal box |x|, |v| <= {settings.tolerance:g}. The fastest "
        f"any |u| <= 1 law can come to rest: t* = {bound:.2f} s "
        f"(step {bound / settings.dt:.0f})."
    )


def markdown_table(entries: list[Entry], settings: Settings) -> str:
    """One row per controller and seed, as ``rocket_comparison.md`` holds it."""
    steps, dt = settings.steps, settings.dt
    lines = [
        f"| controller | seed | policy | in the box from step (time) | kept to step {steps}? "
        "| return | final (x, v) | env's episode end |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for each in entries:
        summary = each.summary
        cells = [
            each.controller,
            "-" if each.seed is None else str(each.seed),
            each.policy,
            _settled(summary, dt),
            _kept(summary),
            f"{summary.episode_return:,.1f}",
            f"({summary.final_position:+.4f}, {summary.final_velocity:+.4f})",
            summary.episode_end,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


_ANALYTIC_STYLES = ({"color": "black", "linestyle": "-"}, {"color": "dimgray", "linestyle": "--"})


def _style(each: Entry, index: int) -> dict[str, Any]:
    if each.learned:
        return {"color": f"C{index % 10}", "linewidth": 1.2, "alpha": 0.9}
    return {**_ANALYTIC_STYLES[index % len(_ANALYTIC_STYLES)], "linewidth": 2.0}


def plot_comparison(entries: list[Entry], settings: Settings, path: str | Path) -> None:
    """x(t) and v(t) of every entry, full scale (left) and zoomed to the goal box (right).

    A bare ``Figure`` on the Agg canvas, as ``envs.classic.rocket.plot_episode``: headless and
    leaving pyplot's state alone.
    """
    tolerance = settings.tolerance
    figure = Figure(figsize=(12, 7.5), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.subplots(2, 2, sharex=True)
    counters = {True: 0, False: 0}
    for each in entries:
        style = _style(each, counters[each.learned])
        counters[each.learned] += 1
        label = each.controller + ("" if each.seed is None else f", seed {each.seed}")
        trajectory = each.trajectory
        for row, values in enumerate((trajectory.positions, trajectory.velocities)):
            for column in range(2):
                axes[row, column].plot(trajectory.times, values, label=label, **style)
    for row, name in enumerate(("position x", "velocity v")):
        for column, scale in enumerate(("", f", near the box (±{tolerance:g})")):
            ax = axes[row, column]
            ax.axhspan(-tolerance, tolerance, color="green", alpha=0.18, linewidth=0)
            ax.set_title(name + scale, fontsize="medium")
            ax.grid(alpha=0.3)
        axes[row, 1].set_ylim(-5 * tolerance, 5 * tolerance)
    for column in range(2):
        axes[1, column].set_xlabel("time [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="lower center", ncol=4, fontsize="small", frameon=False)
    figure.suptitle(headline(settings), fontsize="small")
    rows = -(-len(labels) // 4)
    figure.tight_layout(rect=(0, 0.03 + 0.03 * rows, 1, 0.96))
    figure.savefig(os.fspath(path), format="png")


def write_report(entries: list[Entry], settings: Settings, out: Path) -> tuple[Path, Path]:
    """``rocket_comparison.png`` and ``rocket_comparison.md`` in ``out`` (created if needed);
    their paths. ``OSError`` if they cannot be written."""
    out.mkdir(parents=True, exist_ok=True)
    table_path, plot_path = out / TABLE_FILE, out / PLOT_FILE
    table_path.write_text(f"{headline(settings)}\n\n{markdown_table(entries, settings)}\n")
    plot_comparison(entries, settings, plot_path)
    return plot_path, table_path
