"""The entry point of experiment scripts: ``main`` reads the command line once
(``rl_jax.run.command``: flags built from the algorithm's ``Config``/``Hyperparams`` dataclasses,
whose field docstrings or comments become ``--help``), runs, and turns every user error into one
line on stderr.

An experiment script is a few lines::

    from rl_jax.run import cli
    from rl_jax.agents.td3 import td3

    if __name__ == "__main__":
        cli.main(td3, "rl_jax/Pendulum-v1", __doc__, seeds=5, total_steps=20_000)

Its settings are the learner's recipe for the env (``--recipe NAME``, else the env's default),
then the flags.

With ``algorithm=None`` / ``env_id=None`` the script takes ``--algo`` / ``--env`` flags instead.
"""

from __future__ import annotations

import sys
from typing import NoReturn

from rl_jax.errors import UsageError, exit_now
from rl_jax.run import command, distributed, processes, runner
from rl_jax.run.command import Defaults, program
from rl_jax.run.learners import resolve as resolve_algorithm
from rl_jax.training.algorithm import Algorithm

__all__ = ["Defaults", "UsageError", "main", "program", "resolve_algorithm", "run_experiment"]


def run_experiment(
    algorithm: Algorithm | None = None,
    env_id: str | None = None,
    description: str | None = None,
    argv: list[str] | None = None,
    defaults: Defaults | None = None,
) -> int:
    """Read the command line once, run, print the outcome. Returns the exit status."""
    line = command.read(sys.argv[1:] if argv is None else argv)
    distributed.begin(line.distribution, line.typed)  # JAX's settings, the processes joined
    defaults = defaults or Defaults()
    description = (description or "").strip()
    choice = command.choose(line, algorithm, env_id)
    if choice is None:
        print(command.generic_help(description, defaults), end="")
        return 0
    if line.help:
        parser = command.help_parser(choice, description, defaults)[0]
        parser.print_help()
        parser.exit()
    result = runner.run(command.run_spec(line, choice, defaults))
    if not processes.is_lead():
        return 0
    print(f"run directory: {result.run_dir}")
    if result.gif_error:
        print(f"error: {result.gif_error}", file=sys.stderr)
        return 1
    return 0


def main(
    algorithm: Algorithm | None = None,
    env_id: str | None = None,
    description: str | None = None,
    *,
    seeds: int = 1,
    total_steps: int = 100_000,
    argv: list[str] | None = None,
) -> NoReturn:
    """Entry point of an experiment script: parse, run, exit with the right status. The
    settings are the learner's recipe for the env (``--recipe NAME``, else its default)."""
    defaults = Defaults(seeds, total_steps)
    run = lambda: run_experiment(algorithm, env_id, description, argv, defaults)  # noqa: E731
    exit_now(distributed.guarded(run))
