"""``python -m bench.scaling``: what crosses processes in a multi-process run, in bytes, on paper.

Nothing is compiled or trained: the train state of one run and the metrics of one chunk are
shapes from ``jax.eval_shape`` on the learner's own ``init`` and ``train_chunk``, with the
recipe's settings, as the run's plan sizes them (``rl_jax.run.plan.runs_template``). From them:

- per run: the whole state, its replay buffer, the policy part that ``best/`` keeps, and the
  chunk metrics gathered after every chunk (``Program.gather``, an all-gather);
- how the per-chunk gather and a checkpoint's gather (the whole state of every run, replay
  buffers included, received by every process, written by process 0) grow with hosts;
- what a sweep of 10,000 runs would hold and write.

The times assume ``RATE`` bytes/s (a stated assumption, not a measurement) for process 0's
network link and its disk.
"""

from __future__ import annotations

from typing import NamedTuple

import jax

from rl_jax.run.best import policy_fields
from rl_jax.run.plan import format_bytes, leaf_bytes
from rl_jax.run.recipe_choice import recipe_settings
from rl_jax.training.algorithm import hooks

#: Assumed bytes/s of process 0's network link and disk writes (about 10 Gbit/s).
RATE = 1.25e9
SEEDS_PER_HOST = 8
HOSTS = (1, 8, 64)
SWEEP_RUNS = 10_000


class RunBytes(NamedTuple):
    """Bytes of one run (one seed of one config)."""

    name: str
    state: int
    buffer: int
    policy: int
    metrics: int


def tree_bytes(tree: object) -> int:
    """Bytes of every leaf of a tree of arrays or ``jax.ShapeDtypeStruct`` (keys as key data)."""
    return sum(leaf_bytes(leaf) for leaf in jax.tree.leaves(tree))


def run_bytes(name: str, algorithm_name: str, env_id: str, recipe: str | None = None) -> RunBytes:
    """The sizes of one run of ``algorithm_name`` on ``env_id`` under ``recipe``."""
    from rl_jax.run.learners import resolve as resolve_algorithm

    algorithm = resolve_algorithm(algorithm_name)
    config, hparams = recipe_settings(algorithm, env_id, hooks(algorithm).recipe(env_id, recipe))
    state = jax.eval_shape(lambda key: algorithm.init(key, config, hparams), jax.random.key(0))
    _, metrics = jax.eval_shape(lambda s: algorithm.train_chunk(s, config, hparams), state)
    policy = {field: getattr(state, field) for field in policy_fields(algorithm, state)}
    buffer = getattr(state, "buffer", None)
    return RunBytes(
        name, tree_bytes(state), tree_bytes(buffer), tree_bytes(policy), tree_bytes(metrics)
    )


RUNS = (
    ("TD3 half cheetah (default)", "td3", "rl_jax/HalfCheetah-v5", None),
    ("SAC half cheetah (default)", "sac", "rl_jax/HalfCheetah-v5", None),
    ("PPO half cheetah (cleanrl)", "ppo", "rl_jax/HalfCheetah-v5", "cleanrl"),
    ("DQN CartPole (default)", "dqn", "rl_jax/CartPole-v1", None),
)


def seconds(size: float) -> str:
    """``size`` bytes at ``RATE``, in seconds or hours."""
    time = size / RATE
    if time >= 3600:
        return f"{time / 3600:.1f} h"
    return f"{time / 60:.0f} min" if time >= 60 else f"{time:.2f} s"


def per_run_table(runs: list[RunBytes]) -> str:
    """Bytes per run (one seed)."""
    lines = [
        "| run | state | replay buffer | policy (best/) | metrics per chunk |",
        "|---|---:|---:|---:|---:|",
    ]
    for run in runs:
        sizes = (run.state, run.buffer, run.policy, run.metrics)
        lines.append(f"| {run.name} | " + " | ".join(format_bytes(s) for s in sizes) + " |")
    return "\n".join(lines)


def growth_rows(run: RunBytes) -> list[list[str]]:
    """Rows of ``growth_table`` for one run: hosts x ``SEEDS_PER_HOST`` seeds in one program."""
    rows = []
    for hosts in HOSTS:
        runs = hosts * SEEDS_PER_HOST
        # All-gathers: every process receives every run's share, of the metrics after each
        # chunk, of the policy parts when a best return improves, of the state at a checkpoint.
        checkpoint = runs * run.state
        received = (hosts - 1) * SEEDS_PER_HOST * run.state
        sharded = SEEDS_PER_HOST * run.state  # each host writing its own runs
        sizes = (runs * run.metrics, runs * run.policy, checkpoint, received)
        rows.append(
            [run.name, str(hosts), str(runs), *(format_bytes(s) for s in sizes)]
            + [seconds(received + checkpoint), seconds(sharded)]
        )
    return rows


def growth_table(runs: list[RunBytes]) -> str:
    """Per-chunk gather and checkpoint gather against hosts, ``SEEDS_PER_HOST`` seeds a host."""
    lines = [
        "| run | hosts | runs | metrics gather per chunk | best/ gather | checkpoint "
        "(process 0 writes) | received per process | checkpoint time | sharded writes |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for run in runs:
        lines += ["| " + " | ".join(row) + " |" for row in growth_rows(run)]
    return "\n".join(lines)


def sweep_table(runs: list[RunBytes]) -> str:
    """A sweep of ``SWEEP_RUNS`` runs as one program, per checkpoint and per chunk."""
    lines = [
        f"| run | state of {SWEEP_RUNS:,} runs | checkpoint time, one program | sharded, "
        f"{HOSTS[-1]} hosts | metrics gather per chunk | best/ policies |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for run in runs:
        state = SWEEP_RUNS * run.state
        lines.append(
            f"| {run.name} | {format_bytes(state)} | {seconds(2 * state)} "
            f"| {seconds(state / HOSTS[-1])} | {format_bytes(SWEEP_RUNS * run.metrics)} "
            f"| {format_bytes(SWEEP_RUNS * run.policy)} |"
        )
    return "\n".join(lines)


def main() -> None:
    """Print the three tables."""
    runs = [run_bytes(*entry) for entry in RUNS]
    print(f"Bytes per run (one seed):\n\n{per_run_table(runs)}\n")
    print(
        f"{SEEDS_PER_HOST} seeds per host. Checkpoint time: bytes received plus bytes written by "
        f"process 0 at an assumed {RATE / 1e9:g} GB/s; sharded writes: each host writing its "
        f"own runs at that rate, in parallel:\n\n{growth_table(runs)}\n"
    )
    print(
        f"A sweep of {SWEEP_RUNS:,} runs (checkpoint time as one program: received and written "
        f"by process 0 at {RATE / 1e9:g} GB/s; sharded: each of {HOSTS[-1]} hosts writing its "
        f"own runs):\n\n{sweep_table(runs)}"
    )


if __name__ == "__main__":
    main()
