"""The smallest AlphaZero run on ``pgx/tic_tac_toe`` that trains: its settings, and the run
itself, which tests/run/conftest.py trains once per test process for the board-game files
(test_board_game_runs.py, test_match_command.py)."""

from pathlib import Path

import rl_jax
from rl_jax.run.api import Run

GAME = "pgx/tic_tac_toe"
# 8 games x 9 moves = 72 env steps per chunk: the smallest config that trains (one update).
TINY = {
    "num_envs": 8,
    "num_simulations": 4,
    "max_considered_actions": 4,
    "iterations_per_chunk": 1,
    "updates_per_iteration": 1,
    "batch_size": 16,
    "num_eval_games": 4,
    "hidden": (16,),
    "buffer_size": 200,
}
CHUNK = 72
SEEDS = 2  # two, so that a command's choice of one seed is seen


def train(out: Path) -> Run:
    """One chunk of ``TINY`` on ``GAME`` for ``SEEDS`` seeds, written to ``out``."""
    return rl_jax.train(
        "alphazero", GAME, seeds=SEEDS, total_steps=CHUNK, out=out, config=TINY, quiet=True
    )
