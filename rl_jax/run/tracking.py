"""Optional Weights & Biases logging of a run (``--wandb``, ``rl_jax.train(..., wandb=True)``).

Beside ``metrics.jsonl`` and TensorBoard (which stay), every (config, seed) of the run becomes
one W&B run: named as its TensorBoard run (``seed_3``, or ``lr=0.001/seed_3`` in a sweep),
grouped by the run directory's name, with the run's settings as its config and every numeric
metric of ``metrics.jsonl`` as a curve over ``step`` (env steps per seed). Only the lead process
of a distributed run logs.

W&B's own environment variables apply: ``WANDB_PROJECT`` (default ``rl_jax``), ``WANDB_ENTITY``,
``WANDB_MODE=offline`` (no network; ``wandb sync`` uploads later), ``WANDB_DIR``. The W&B run ids
derive from the run directory's path and the run's name, so a ``--resume`` continues the same
W&B runs; the rows it rewrites after the checkpoint it resumed from appear there a second time,
at the same steps.

wandb is an optional dependency (``pip install "rl_jax[tracking]"``), imported only when asked
for.
"""

from __future__ import annotations

import hashlib
import importlib
import os
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

from rl_jax.errors import RunError
from rl_jax.run.metrics import ID_FIELDS

if TYPE_CHECKING:
    from rl_jax.run.spec import RunSpec

DEFAULT_PROJECT = "rl_jax"
INSTALL_HINT = 'pip install "rl_jax[tracking]" (or pip install wandb)'


def import_wandb() -> ModuleType:
    """The ``wandb`` module, or a one-line ``RunError`` saying how to install it."""
    try:
        return importlib.import_module("wandb")
    except ImportError:
        raise RunError(
            f"W&B logging (--wandb) needs the wandb package, not installed here: {INSTALL_HINT}"
        ) from None


def run_id(run_dir: Path, label: str) -> str:
    """A W&B run id that is the same for the same run directory and run name (so a resume
    continues the W&B run) and differs between them."""
    key = f"{Path(run_dir).resolve()}\n{label}"
    return hashlib.sha256(key.encode()).hexdigest()[:16]


class WandbRuns:
    """One W&B run per (config, seed) of a run, started on its first row and finished by
    ``close``. ``write`` takes the rows ``MetricsLog`` writes, with their TensorBoard labels."""

    def __init__(self, spec: RunSpec):
        self.wandb = import_wandb()
        self.spec = spec
        self.group = Path(spec.out).resolve().name
        self._identity = spec.identity
        self._runs: dict[str, Any] = {}

    def config_of(self, row: dict[str, Any]) -> dict[str, Any]:
        """The settings of the run a row belongs to: learner, env, its seed, the config and the
        hyperparameters of its config index, and where the run directory is."""
        index = int(row.get("config", 0))
        return {
            "algorithm": self._identity["algorithm"],
            "env_id": self._identity["env_id"],
            "seed": row["seed"],
            "config_index": index,
            "config": self._identity["config"],
            "hparams": self._identity["hparams"][index],
            "grid_fields": list(self.spec.grid_fields),
            "run_dir": str(Path(self.spec.out).resolve()),
            "total_steps": self.spec.total_steps,
        }

    def write(self, label: str, row: dict[str, Any]) -> None:
        """Log a row's numeric metrics at its ``step`` to the W&B run of ``label``."""
        run = self._runs.get(label) or self._start(label, row)
        values: dict[str, Any] = {"step": row["step"]}
        for name, value in row.items():
            if name in ID_FIELDS or name in self.spec.grid_fields:
                continue
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                values[name] = value
        run.log(values)

    def close(self) -> None:
        """Finish every W&B run (offline: their files are complete on disk)."""
        runs, self._runs = self._runs, {}
        for run in runs.values():
            run.finish()

    def _start(self, label: str, row: dict[str, Any]) -> Any:
        wandb = self.wandb
        try:
            run = wandb.init(
                project=os.environ.get("WANDB_PROJECT") or DEFAULT_PROJECT,
                group=self.group,
                name=label,
                id=run_id(self.spec.out, label),
                config=self.config_of(row),
                resume="allow",
                reinit="create_new",  # one process holds every seed's run at once
                settings=wandb.Settings(console="off", silent=True),
            )
        except Exception as error:  # wandb raises its own types (auth, network, settings)
            first = str(error).strip().splitlines()[0] if str(error).strip() else ""
            raise RunError(
                f"wandb could not start a run: {first or type(error).__name__}"
            ) from None
        # Curves over env steps, the x-axis of metrics.jsonl and TensorBoard.
        run.define_metric("step")
        run.define_metric("*", step_metric="step")
        self._runs[label] = run
        return run
