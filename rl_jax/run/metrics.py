"""Per-chunk metrics of a run: ``metrics.jsonl`` and TensorBoard event files, both resumable.

Every row is one (config, seed) after one chunk: ``step`` (env steps per seed), ``seed``,
``eval_return``, and more (``train_return``, ``updates``, ``wall_time``, algorithm extras; for a
sweep the ``config`` index and the values of the swept hyperparameters).

Resuming from the checkpoint at step S must neither lose nor repeat rows. Rows are flushed to disk
before each checkpoint is written, so every row up to S exists; rows after S (written before an
interruption) are dropped from ``metrics.jsonl`` on resume, and TensorBoard is told to hide its
events after S through the writer's ``purge_step`` (a SessionLog START event: TensorBoard discards
earlier events with a step at or beyond it).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

if TYPE_CHECKING:
    from tensorboardX import SummaryWriter

METRICS_FILE = "metrics.jsonl"
TENSORBOARD_DIR = "tensorboard"
#: Row fields that identify a row rather than measure something (not sent to TensorBoard).
ID_FIELDS = ("step", "seed", "config", "chunk")


def _plain(value: object) -> object:
    """A JSON-safe value: numpy scalars unwrapped, NaN/inf as null (strict JSON has neither)."""
    if isinstance(value, (np.generic, np.ndarray)):
        value = value.item() if np.ndim(value) == 0 else np.asarray(value).tolist()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """All rows of a metrics file; a line cut short by a crash is skipped."""
    path = Path(path)
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        if isinstance(row, dict) and "step" in row:
            rows.append(row)
    return rows


def truncate_rows(path: str | Path, max_step: int) -> int:
    """Keep only rows with ``step <= max_step`` (and whole lines). Returns rows dropped."""
    path = Path(path)
    if not path.is_file():
        return 0
    lines = path.read_text().splitlines()
    rows = read_rows(path)
    kept = [row for row in rows if row["step"] <= max_step]
    if len(kept) == len(lines):
        return 0
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text("".join(json.dumps(row) + "\n" for row in kept))
    os.replace(temporary, path)
    return len(lines) - len(kept)


def run_label(row: dict[str, Any], grid_fields: tuple[str, ...] = ()) -> str:
    """TensorBoard run name of a row: ``seed_3``, or ``lr=0.001,tau=0.02/seed_3`` in a sweep."""
    seed = f"seed_{row['seed']}"
    if "config" not in row:
        return seed
    values = ",".join(f"{name}={row.get(name)}" for name in grid_fields)
    return f"{values or 'config_' + str(row['config'])}/{seed}"


def _summary_writer_class() -> type[SummaryWriter]:
    """tensorboardX's ``SummaryWriter``, imported without torch.

    tensorboardX imports torch whenever it is installed (seconds and hundreds of MB, where the
    PyTorch baseline of bench/ is installed) only to accept torch tensors, which we never log.
    """
    hide_torch = "torch" not in sys.modules
    if hide_torch:
        sys.modules["torch"] = None  # makes `import torch` raise ImportError
    try:
        from tensorboardX import SummaryWriter
    finally:
        if hide_torch:
            del sys.modules["torch"]
    return SummaryWriter


class RowSink(Protocol):
    """Another destination of the rows (``rl_jax.run.tracking.WandbRuns``)."""

    def write(self, label: str, row: dict[str, Any]) -> None:
        """Take one JSON-safe row of the run named ``label`` (its TensorBoard run name)."""

    def close(self) -> None:
        """Finish: no more rows come."""


class MetricsLog:
    """Appends rows to ``metrics.jsonl`` and TensorBoard, and to ``tracker`` when given;
    ``resume_step`` drops later rows."""

    def __init__(
        self,
        run_dir: str | Path,
        resume_step: int | None = None,
        grid_fields: tuple[str, ...] = (),
        tracker: RowSink | None = None,
    ):
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / METRICS_FILE
        self.grid_fields = tuple(grid_fields)
        if resume_step is not None:
            truncate_rows(self.path, resume_step)
        self._purge_step = None if resume_step is None else resume_step + 1
        # tensorboardX names event files by the second; a later session must sort after (and
        # never overwrite) an earlier one's file, whose rows up to resume_step are kept.
        self._file_suffix = f".from{max(resume_step or 0, 0):012d}"
        self._summary_writer = _summary_writer_class()  # imported here, not in the timed loop
        self._writers: dict[str, SummaryWriter] = {}
        self._file = open(self.path, "a")  # noqa: SIM115 (kept open for the run)
        self.tracker = tracker

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Append rows (one JSON line each) and log their numeric fields to TensorBoard."""
        for row in rows:
            row = {key: _plain(value) for key, value in row.items()}
            self._file.write(json.dumps(row, allow_nan=False) + "\n")
            label = run_label(row, self.grid_fields)
            writer = self._writer(label)
            for name, value in row.items():
                if name in ID_FIELDS or name in self.grid_fields:
                    continue
                if isinstance(value, (int, float)) and not isinstance(value, bool):
                    writer.add_scalar(name, value, global_step=row["step"])
            if self.tracker is not None:
                self.tracker.write(label, row)
        self._file.flush()  # visible to readers at once; durable at the next checkpoint

    def flush(self) -> None:
        """Everything written so far is on disk (called before every checkpoint)."""
        self._file.flush()
        os.fsync(self._file.fileno())
        for writer in self._writers.values():
            writer.flush()

    def _writer(self, label: str) -> SummaryWriter:
        if label not in self._writers:
            self._writers[label] = self._summary_writer(
                str(self.run_dir / TENSORBOARD_DIR / label),
                purge_step=self._purge_step,
                flush_secs=30,
                filename_suffix=self._file_suffix,
            )
        return self._writers[label]

    def close(self) -> None:
        """Flush the rows and close the metrics file, the TensorBoard writers and the tracker."""
        self.flush()
        self._file.close()
        for writer in self._writers.values():
            writer.close()
        if self.tracker is not None:
            self.tracker.close()

    def __enter__(self) -> MetricsLog:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
