"""The ``rl-jax`` command (also ``python -m rl_jax``): the experiment scripts of a checkout as
subcommands of an installed package.

  rl-jax train --algo td3 --env rl_jax/Pendulum-v1 --seeds 5
  rl-jax train --algo td3 --env rl_jax/Hopper-v5 --recipe paper-2018 --seeds 5
  rl-jax sweep --algo td3 --env rl_jax/Pendulum-v1 --grid lr=1e-4,1e-3 --seeds 5
  rl-jax evaluate runs/Pendulum-v1__td3__... --episodes 100
  rl-jax render runs/Pendulum-v1__td3__... --seed 0
  rl-jax match runs/results/alphazero-tictactoe-vs-minimax --opponent minimax --games 20

``rl-jax COMMAND --help`` lists that command's flags (for train and sweep: with --algo and --env,
every config field and hyperparameter of the algorithm with its default there).
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from rl_jax import __version__

TRAIN_DOC = """Train any algorithm on any env: --algo and --env choose them, --resume continues a
run (which knows the rest). Every config field and hyperparameter of the algorithm is a flag too:
--help with --algo and --env lists them with their defaults there.

  rl-jax train --algo td3 --env rl_jax/Pendulum-v1 --seeds 5
  rl-jax train --algo td3 --env rl_jax/Hopper-v5 --recipe paper-2018 --seeds 5
  rl-jax train --algo td3 --env gymnasium:Pendulum-v1 --seeds 5
  rl-jax train --algo td3 --env my_envs:my/Env-v0     # my_envs.py registers my/Env-v0
  rl-jax train --resume runs/Pendulum-v1__td3__...

--env takes a registered id; gymnasium:ID, any env gymnasium.make knows, stepped on the host
through rl_jax.envs.from_gymnasium; or MODULE:ID, which imports MODULE (searched on the Python
path and in the current directory) so that its rl_jax.envs.register(ID, ...) runs first.
Algorithms without a recipe for an env start from their own defaults (the TD3 paper's for td3:
25,000 random steps first), so small budgets need flags such as --learning-starts. --recipe NAME
puts one of the algorithm's whole named recipes on top of the env's. Several processes (SLURM,
Open MPI, or hosts of your own): --distributed, or --coordinator/--num-processes/--process-id
(docs/cluster.md).
"""

SWEEP_DOC = """Sweep a grid of hyperparameters x seeds as one compiled program, sharded over all
devices.

  rl-jax sweep --algo td3 --env rl_jax/Pendulum-v1 \\
      --grid lr=1e-4,3e-4,1e-3 --grid tau=0.005,0.02 --seeds 5

Grid names are hyperparameter or config fields (--help with --algo/--env lists them) or the
short names lr (actor and critic learning rates together), width (both networks' hidden widths,
e.g. width=64x64,256x256), batch (batch_size) and buffer (buffer_size). Hyperparameters are
vmapped: every value x every seed is one compiled program. Config fields change shapes: each
shape compiles once and runs its whole hyperparameter grid in its own program.

OUT (default runs/<env>__<algo>-sweep__<time>/) holds one run directory per shape, plus
curves.png with one curve per config and results.txt ranking all configs by final eval return.
--resume OUT continues every shape from its latest checkpoint. Several processes or hosts:
--distributed under SLURM or Open MPI, else --coordinator HOST:PORT, --num-processes N and
--process-id I on each (jax.distributed; docs/cluster.md).
"""


def _train(argv: list[str]) -> int | None:
    from rl_jax.run import cli  # on use: rl-jax --help starts without JAX

    # The defaults of experiments/train.py: one seed, 100k env steps.
    cli.main(None, None, TRAIN_DOC, seeds=1, total_steps=100_000, argv=argv)
    return None


def _sweep(argv: list[str]) -> int | None:
    from rl_jax.run import sweep  # on use: rl-jax --help starts without JAX

    sweep.main(SWEEP_DOC, argv)
    return None


def _evaluate(argv: list[str]) -> int | None:
    from rl_jax.run import evaluate  # on use: rl-jax --help starts without JAX

    return evaluate.main(argv, prog="rl-jax evaluate")


def _render(argv: list[str]) -> int | None:
    from rl_jax.run import render  # on use: rl-jax --help starts without JAX

    return render.main(argv, prog="rl-jax render")


def _match(argv: list[str]) -> int | None:
    from rl_jax.run import match  # on use: rl-jax --help starts without JAX

    return match.main(argv, prog="rl-jax match")


#: command -> (what it does, for --help; its entry point, called with the remaining arguments).
COMMANDS: dict[str, tuple[str, Callable[[list[str]], int | None]]] = {
    "train": ("train an algorithm on an env, or resume a run", _train),
    "sweep": ("a grid of hyperparameters x seeds as one compiled program", _sweep),
    "evaluate": ("play a run's policies on fresh episodes", _evaluate),
    "render": ("render a run's policy to a GIF", _render),
    "match": ("play a board-game run's search against a reference player", _match),
}


def usage() -> str:
    """The text of ``rl-jax --help``: the commands, examples, and how to get each one's flags."""
    width = max(map(len, COMMANDS))
    commands = "\n".join(f"  {name:<{width}}  {summary}" for name, (summary, _) in COMMANDS.items())
    examples = (__doc__ or "").split("\n\n")[1]
    return (
        "usage: rl-jax COMMAND [flags]\n\n"
        "Train and sweep rl_jax's learners on its envs (or yours), and watch the runs.\n\n"
        f"commands:\n{commands}\n\nexamples:\n{examples}\n\n"
        "rl-jax COMMAND --help lists that command's flags; rl-jax --version prints the version.\n"
    )


def main(argv: list[str] | None = None) -> int | None:
    """Dispatch ``rl-jax COMMAND ...``: help and version here, the rest to the command. A missing
    or unknown command is one line on stderr and exit status 2, as a bad flag is."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(f"error: give a command: {', '.join(COMMANDS)} (see rl-jax --help)", file=sys.stderr)
        return 2
    command, rest = argv[0], argv[1:]
    if command in {"-h", "--help", "help"}:
        print(usage(), end="")
        return 0
    if command == "--version":
        print(f"rl-jax {__version__}")
        return 0
    if command not in COMMANDS:
        print(
            f"error: unknown command {command!r}: choose from {', '.join(COMMANDS)} "
            "(see rl-jax --help)",
            file=sys.stderr,
        )
        return 2
    # argparse names the program after sys.argv[0]: usage lines and errors then read
    # "rl-jax train" rather than the path of the console script.
    sys.argv = [f"rl-jax {command}", *rest]
    return COMMANDS[command][1](rest)


if __name__ == "__main__":
    sys.exit(main())
