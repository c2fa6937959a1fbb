"""What a run is asked to do (``RunSpec``) and what it returns (``RunResult``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from rl_jax.run import plots
from rl_jax.run.run_dir import identity
from rl_jax.training.algorithm import Algorithm, Config, Hyperparams, TrainState


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything a run needs. ``hparams`` holds one ``Hyperparams`` per config of a grid."""

    algorithm: Algorithm
    env_id: str
    config: Config
    hparams: tuple[Hyperparams, ...]
    out: Path
    seeds: int = 1
    total_steps: int = 100_000
    resume: bool = False
    base_seed: int = 0
    grid_fields: tuple[str, ...] = ()  # hyperparameters a grid varies (logged on every row)
    # the name each of grid_fields is shown by in the plan, tables and curves: the one its grid
    # was asked by (a sweep's lr sets actor_lr and critic_lr). Empty: the fields' own names.
    grid_names: tuple[str, ...] = ()
    # least seconds between checkpoints (also one at the end and when stopped); None: the
    # default spacing, rl_jax.run.start.checkpoint_interval
    checkpoint_interval: float | None = None
    keep_checkpoints: int = 3
    log_interval: float = 30.0  # seconds between progress lines when not on a terminal
    gif: bool = False
    wandb: bool = False  # also log to Weights & Biases (rl_jax.run.tracking), lead process only
    command: str = ""  # the command line, recorded in config.json
    resume_command: str = ""  # printed when stopped
    # how runs that do not divide over the devices are laid out: "auto", "pad" or "split"
    # (rl_jax.run.plan.program_for)
    layout: str = "auto"
    memory_limit: int | None = None  # bytes the state may use (default: what the OS reports)
    # (env steps/s per seed, number of seeds) measured for the script's default config: the
    # plan's time estimate before anything runs. None: estimated after the first training chunk.
    throughput: tuple[float, int] | None = None

    @property
    def seed_numbers(self) -> range:
        """The seeds of the run: ``base_seed`` and on, the same under every config of a grid."""
        return range(self.base_seed, self.base_seed + self.seeds)

    @property
    def grid_labels(self) -> tuple[str, ...]:
        """The names the grid's fields are shown by: ``grid_names``, else the fields'."""
        return self.grid_names or self.grid_fields

    @property
    def identity(self) -> dict[str, Any]:
        """What makes two runs the same run (learner, env, config, hyperparameters, seeds): a
        resume must match it.
        """
        return identity(
            self.algorithm.name,
            self.env_id,
            self.config,
            list(self.hparams),
            self.seeds,
            self.base_seed,
        )


@dataclasses.dataclass
class RunResult:
    """What a finished (or stopped) run returns: where it is, how far it got, its final state and
    per config results.
    """

    run_dir: Path
    step: int  # env steps per seed reached
    stopped: bool  # True when a signal ended the run before total_steps
    state: TrainState  # the final train state, leaves [configs, seeds, ...]
    results: list[plots.FinalResult]
    wall_clock: float  # seconds over all sessions of the run, compilation included
    gif_error: str | None = None
