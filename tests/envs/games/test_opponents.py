"""envs/games/opponents.py: the reference players by name, as AlphaZero's evaluation and the GIF
of a game of a run choose them."""

import jax
import numpy as np
import pgx
import pytest

from rl_jax.envs.games import opponents, tic_tac_toe_minimax
from rl_jax.envs.games.match import random_player


def test_each_name_gives_its_player_and_a_legal_move():
    game = pgx.make("tic_tac_toe")
    assert opponents.opponent_player("random", game) is random_player
    assert opponents.opponent_player("minimax", game) is tic_tac_toe_minimax.minimax_player
    state = game.step(game.init(jax.random.key(0)), 4)
    mcts = opponents.opponent_player("mcts", game, simulations=8)
    move = int(jax.jit(mcts)(state, jax.random.key(1)))
    assert np.asarray(state.legal_action_mask)[move]
    assert [opponents.describe(name, 8) for name in opponents.OPPONENTS] == [
        "random",
        "mcts 8",
        "minimax",
    ]


def test_minimax_is_tic_tac_toe_only_and_an_unknown_name_is_refused():
    with pytest.raises(ValueError, match="tic_tac_toe only, not connect_four"):
        opponents.opponent_player("minimax", pgx.make("connect_four"))
    with pytest.raises(ValueError, match="unknown opponent 'alphabeta'.*random, mcts, minimax"):
        opponents.opponent_player("alphabeta", pgx.make("tic_tac_toe"))
