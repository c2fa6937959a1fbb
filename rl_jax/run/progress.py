"""Live progress of a run: env steps/s, updates/s, ETA and the latest eval return over seeds.

On a terminal it is a tqdm bar redrawn in place; when the output is a file or a pipe (``nohup``,
a cluster log) it prints one plain line per ``log_interval`` seconds instead of carriage returns.
Compilation happens before the first chunk and is reported separately, so the rates and the ETA
measure training only.
"""

from __future__ import annotations

import os
import sys
import time
from typing import IO

import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from rl_jax.run.plots import format_duration

BAR_FORMAT = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}, ETA {remaining}]{postfix}"


def _rate(value: float) -> str:
    """``9.8k``-style rate."""
    for unit, scale in (("M", 1e6), ("k", 1e3)):
        if abs(value) >= scale:
            return f"{value / scale:.1f}{unit}"
    return f"{value:.0f}"


def _is_terminal(file: IO[str]) -> bool:
    """A terminal with a known width (a zero-width pty would get an invisible bar)."""
    try:
        return file.isatty() and os.get_terminal_size(file.fileno()).columns > 0
    except (AttributeError, OSError, ValueError):
        return False


def eval_summary(eval_returns: npt.ArrayLike) -> str:
    """``eval -150.3 [-170.2, -140.1]``: mean and range over seeds (and configs)."""
    values = np.asarray(eval_returns, np.float64).reshape(-1)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return "eval n/a"
    if values.size == 1:
        return f"eval {values[0]:.1f}"
    return f"eval {values.mean():.1f} [{values.min():.1f}, {values.max():.1f}]"


class Progress:
    """Reports chunk after chunk; ``runs`` is how many seeds x configs train side by side.

    Call ``start()`` when training starts (after compiling); messages before it print plainly.

    ``start_steps``/``start_updates`` are the per-seed counters at the start of this session
    (non-zero after a resume), so rates count only what this session did.
    """

    def __init__(
        self,
        total_steps: int,
        start_steps: int = 0,
        start_updates: int = 0,
        runs: int = 1,
        file: IO[str] | None = None,
        tty: bool | None = None,
        log_interval: float = 30.0,
    ):
        self.file = file or sys.stdout
        self.tty = _is_terminal(self.file) if tty is None else tty
        self.total_steps, self.start_steps, self.runs = total_steps, start_steps, runs
        self.log_interval = log_interval
        self._start_time = time.perf_counter()
        self.start_updates = start_updates
        self._last_print = -np.inf
        self._steps, self._updates = start_steps, start_updates
        self._bar = None

    def start(self) -> None:
        """Training starts now (after compilation): rates and ETA count from here."""
        self._start_time = time.perf_counter()
        if self.tty and self._bar is None:
            self._bar = tqdm(
                total=self.total_steps,
                initial=self.start_steps,
                unit="step",
                unit_scale=True,
                file=self.file,
                dynamic_ncols=True,
                bar_format=BAR_FORMAT,
            )

    def write(self, message: str) -> None:
        """A message line that does not break the bar."""
        if self._bar is not None:
            self._bar.write(message, file=self.file)
        else:
            print(message, file=self.file, flush=True)

    def update(self, env_steps: int, updates: int, eval_returns: npt.ArrayLike) -> None:
        """After a chunk: per-seed ``env_steps`` and ``updates`` so far, evals of every run."""
        self._steps, self._updates = env_steps, updates
        status = self.status(eval_returns)
        if self._bar is not None:
            self._bar.set_postfix_str(status, refresh=False)
            self._bar.update(env_steps - self._bar.n)
            return
        now = time.perf_counter()
        if now - self._last_print >= self.log_interval or env_steps >= self.total_steps:
            self._last_print = now
            print(self.line(eval_returns), file=self.file, flush=True)

    def rates(self) -> tuple[float, float]:
        """Env steps/s and updates/s summed over all runs, since training started."""
        elapsed = max(time.perf_counter() - self._start_time, 1e-9)
        steps = (self._steps - self.start_steps) * self.runs / elapsed
        updates = (self._updates - self.start_updates) * self.runs / elapsed
        return steps, updates

    def eta(self) -> float | None:
        """Seconds left at the average speed so far."""
        done = self._steps - self.start_steps
        if done <= 0:
            return None
        elapsed = time.perf_counter() - self._start_time
        return elapsed * max(self.total_steps - self._steps, 0) / done

    def status(self, eval_returns: npt.ArrayLike) -> str:
        """The status line: env steps/s and updates/s so far, and the latest eval returns over
        seeds.
        """
        steps_per_s, updates_per_s = self.rates()
        return (
            f"{_rate(steps_per_s)} env steps/s | {_rate(updates_per_s)} updates/s | "
            f"{eval_summary(eval_returns)}"
        )

    def line(self, eval_returns: npt.ArrayLike) -> str:
        """The plain-text progress line used when the output is not a terminal."""
        percent = 100.0 * self._steps / max(self.total_steps, 1)
        elapsed = time.perf_counter() - self._start_time
        eta = self.eta()
        eta_text = "?" if eta is None else format_duration(eta)
        return (
            f"step {self._steps:,}/{self.total_steps:,} ({percent:.0f}%) | "
            f"{self.status(eval_returns)} | elapsed {format_duration(elapsed)}, ETA {eta_text}"
        )

    def close(self) -> None:
        """Close the progress bar, if one is shown."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
