"""The reference players a learned player is measured against, by name: ``"random"`` (a
uniformly random legal move, ``match.random_player``), ``"mcts"`` (pure MCTS with random
rollouts, ``rollout_mcts``) and ``"minimax"`` (exact tic-tac-toe, ``tic_tac_toe_minimax``).
AlphaZero's evaluation plays the one its config names (``eval_opponent``), and so does the GIF
of a game of a run (``rl_jax.run.render_game``)."""

from __future__ import annotations

import pgx

from rl_jax.envs.games import rollout_mcts, tic_tac_toe_minimax
from rl_jax.envs.games.match import Player, random_player

#: The opponents by name.
OPPONENTS = ("random", "mcts", "minimax")


def opponent_player(name: str, game: pgx.Env, simulations: int = 100) -> Player:
    """The opponent ``name`` for one state of ``game``: ``simulations`` simulations per move
    for ``"mcts"``; ``ValueError`` for an unknown name, or for minimax on another game than
    tic-tac-toe."""
    if name == "mcts":
        return rollout_mcts.rollout_mcts_player(game, simulations)
    if name == "minimax":
        if game.id != "tic_tac_toe":
            raise ValueError(f"the minimax opponent plays tic_tac_toe only, not {game.id}")
        return tic_tac_toe_minimax.minimax_player
    if name == "random":
        return random_player
    raise ValueError(f"unknown opponent {name!r}: one of {', '.join(OPPONENTS)}")


def describe(name: str, simulations: int = 100) -> str:
    """The opponent as a caption names it: ``"minimax"``, ``"mcts 100"``."""
    return f"mcts {simulations}" if name == "mcts" else name
