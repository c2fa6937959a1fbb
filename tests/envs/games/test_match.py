"""The match runner: colours, seeds, the table, and random play against its exact odds."""

import functools
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pgx
import pytest

from rl_jax.envs.games import tic_tac_toe_minimax as minimax
from rl_jax.envs.games.match import MatchResult, play_match, random_player


@functools.cache
def random_play_odds(position: minimax.Board = minimax.EMPTY_BOARD) -> tuple[Fraction, ...]:
    """(X wins, draw, O wins): the exact chances of a game played on from ``position`` with
    uniformly random legal moves by both sides."""
    if minimax.is_terminal(position):
        won = minimax.winner(position)
        return (Fraction(won == 0), Fraction(won == -1), Fraction(won == 1))
    moves = minimax.legal_moves(position)
    after = [random_play_odds(minimax.play(position, move)) for move in moves]
    return tuple(sum(chances, Fraction(0)) / len(moves) for chances in zip(*after, strict=True))


def test_random_play_odds_are_the_known_ones():
    # of the 255,168 possible games, weighted by their chance under random play
    assert random_play_odds() == (Fraction(737, 1260), Fraction(160, 1260), Fraction(363, 1260))


def first_mover_player(state: pgx.State, key: jax.Array) -> jax.Array:
    """Plays the lowest empty cell. Against itself from the empty board X takes 0, 2, 4, 6 and
    O 1, 3, 5: X wins on the seventh move with the diagonal 2-4-6."""
    del key
    return jnp.argmax(state.legal_action_mask).astype(jnp.int32)


def test_colours_alternate_and_outcomes_are_the_first_players():
    env = pgx.make("tic_tac_toe")
    result = play_match(env, first_mover_player, first_mover_player, jax.random.key(0), 7)
    # the same deterministic player on both sides: whoever opens wins in 7 moves
    np.testing.assert_array_equal(result.first_moved, [True, False] * 3 + [True])
    np.testing.assert_array_equal(result.outcomes, np.where(result.first_moved, 1, -1))
    np.testing.assert_array_equal(result.moves, [7] * 7)
    assert (result.wins, result.draws, result.losses) == (4, 0, 3)
    assert result.counts(result.first_moved) == (4, 0, 0)
    assert result.counts(~result.first_moved) == (0, 0, 3)


def test_a_move_limit_ends_games_as_draws_so_far():
    env = pgx.make("tic_tac_toe")
    result = play_match(env, first_mover_player, first_mover_player, jax.random.key(0), 4, 3)
    np.testing.assert_array_equal(result.moves, [3] * 4)
    assert result.draws == 4


def test_random_play_matches_its_exact_odds_and_the_seed_repeats_it():
    env = pgx.make("tic_tac_toe")
    games = 2000
    result = play_match(env, random_player, random_player, jax.random.key(5), games)
    x_wins, draws, o_wins = (float(chance) for chance in random_play_odds())
    opening = result.first_moved
    observed = {
        "opener wins": (result.outcomes[opening] == 1).mean(),
        "draws": (result.outcomes == 0).mean(),
        "replier wins": (result.outcomes[~opening] == 1).mean(),
    }
    expected = {"opener wins": x_wins, "draws": draws, "replier wins": o_wins}
    for name, chance in expected.items():
        count = games // 2 if name != "draws" else games
        standard_error = (chance * (1 - chance) / count) ** 0.5
        assert abs(observed[name] - chance) < 4 * standard_error, name
    again = play_match(env, random_player, random_player, jax.random.key(5), games)
    np.testing.assert_array_equal(again.outcomes, result.outcomes)
    other = play_match(env, random_player, random_player, jax.random.key(6), games)
    assert (other.outcomes != result.outcomes).any()


def test_the_table_by_colour_with_its_elo_line():
    outcomes = np.array([1, 1, 1, 0, 1, -1])
    result = MatchResult(outcomes=outcomes, first_moved=np.arange(6) % 2 == 0, moves=np.full(6, 9))
    assert result.table().splitlines() == [
        "first player     wins  draws losses  score",
        "moving first        3      0      0  1.000",
        "moving second       1      1      1  0.500",
        "total               4      1      1  0.750",
        # s = 0.75: d = 400 log10(3) = 190.8; var = (4 * 0.0625 + 0.0625 + 0.5625) / 6 = 0.1458,
        # se = sqrt(0.1458 / 6) = 0.1559, s - 1.96 se = 0.4444: 400 log10(0.4444 / 0.5556) = -38.8;
        # s + 1.96 se > 1: the upper end is infinite
        "Elo difference +191, 95% interval [-39, +inf]",
    ]


def test_no_games_and_one_player_games_are_refused():
    with pytest.raises(ValueError, match="num_games"):
        play_match(pgx.make("tic_tac_toe"), random_player, random_player, jax.random.key(0), 0)
    with pytest.raises(ValueError, match="two-player"):
        play_match(pgx.make("2048"), random_player, random_player, jax.random.key(0), 2)


def test_a_second_match_of_the_same_players_reuses_its_program():
    traces = []

    def counting_player(state: pgx.State, key: jax.Array) -> jax.Array:
        traces.append(None)  # runs when the program is traced, not when it runs
        return random_player(state, key)

    env = pgx.make("tic_tac_toe")
    play_match(env, counting_player, random_player, jax.random.key(0), 4)
    traced = len(traces)
    assert traced > 0
    play_match(env, counting_player, random_player, jax.random.key(1), 4)
    assert len(traces) == traced
