"""The exact tic-tac-toe solver: known counts and positions, and its map onto pgx's states."""

import collections

import jax
import jax.numpy as jnp
import numpy as np
import pgx
import pytest

from rl_jax.envs.games import tic_tac_toe_minimax as minimax
from rl_jax.envs.games.match import play_match, random_player


def board(x: set[int], o: set[int]) -> minimax.Board:
    """The position with X's stones on the cells ``x`` and O's on ``o``."""
    return tuple(0 if cell in x else 1 if cell in o else -1 for cell in range(9))


def test_every_reachable_position_is_solved_and_counted():
    positions = minimax.reachable_positions()
    assert len(positions) == 5478
    # by stones on the board: the known counts of legal positions, which sum to 5,478
    by_stones = collections.Counter(9 - position.count(-1) for position in positions)
    assert [by_stones[n] for n in range(10)] == [1, 9, 72, 252, 756, 1260, 1520, 1140, 390, 78]


def test_the_empty_board_is_a_draw_and_every_opening_keeps_it():
    assert minimax.value(minimax.EMPTY_BOARD) == 0
    assert minimax.optimal_moves(minimax.EMPTY_BOARD) == tuple(range(9))


@pytest.mark.parametrize(
    ("x", "o", "expected_value", "expected_moves"),
    [
        # X completes the top row at once
        ({0, 1}, {3, 4}, 1, (2,)),
        # O must block the top row; the game is then drawn
        ({0, 1}, {4}, 0, (2,)),
        # X must block O's diagonal 2-4-6 at 6, which makes two lines of X at once (3 and 7)
        ({0, 8}, {2, 4}, 1, (6,)),
        # X forks: at 3 (lines 0-3-6 and 3-4-5) or at 6 (lines 0-3-6 and 2-4-6)
        ({0, 4}, {1, 8}, 1, (3, 6)),
        # opposite corners against the centre: O must take an edge, a corner loses to a fork
        ({0, 8}, {4}, 0, (1, 3, 5, 7)),
        # a corner opening: only the centre holds the draw for O
        ({0}, set(), 0, (4,)),
        # a finished game: X has the diagonal, O to move has lost and has no move
        ({0, 4, 8}, {1, 2}, -1, ()),
    ],
)
def test_known_positions(x, o, expected_value, expected_moves):
    position = board(x, o)
    assert minimax.value(position) == expected_value
    assert minimax.optimal_moves(position) == expected_moves


def test_an_unreachable_board_is_refused():
    with pytest.raises(ValueError, match="cannot be reached"):
        minimax.value(board({0, 1, 2}, set()))


def test_the_move_table_holds_the_optimal_moves():
    table = minimax.optimal_move_table()
    assert table.shape == (3**9, 9)
    position = board({0, 4}, {1, 8})
    assert np.flatnonzero(table[minimax.board_index(position)]).tolist() == [3, 6]
    assert not table[minimax.board_index(board({0, 1, 2}, set()))].any()


def test_boards_read_from_observations_are_pgx_boards():
    env = pgx.make("tic_tac_toe")
    step = jax.jit(env.step)
    read = jax.jit(minimax.board_from_observation)
    key = jax.random.key(0)
    seen = 0
    for _ in range(20):
        key, init_key = jax.random.split(key)
        state = env.init(init_key)
        while not bool(state.terminated):
            np.testing.assert_array_equal(read(state.observation), state._x.board)
            key, action_key = jax.random.split(key)
            state = step(state, random_player(state, action_key))
            seen += 1
    assert seen > 100


def test_the_minimax_player_never_loses():
    env = pgx.make("tic_tac_toe")
    against_random = play_match(env, minimax.minimax_player, random_player, jax.random.key(1), 200)
    assert against_random.losses == 0
    assert against_random.wins > 150  # it wins ~99% opening, ~80% replying
    against_itself = play_match(
        env, minimax.minimax_player, minimax.minimax_player, jax.random.key(2), 50
    )
    assert against_itself.draws == 50
    np.testing.assert_array_equal(against_itself.moves, [9] * 50)


def test_the_minimax_player_breaks_ties_at_random():
    # every opening move keeps the draw, so a perfect player still varies its games
    env = pgx.make("tic_tac_toe")
    state = env.init(jax.random.key(0))
    keys = jax.random.split(jax.random.key(4), 64)
    openings = jax.vmap(minimax.minimax_player, in_axes=(None, 0))(state, keys)
    assert set(np.asarray(openings).tolist()) == set(range(9))


def test_the_minimax_player_plays_an_optimal_move_from_a_position():
    env = pgx.make("tic_tac_toe")
    state = env.init(jax.random.key(0))
    for action in (0, 2, 8, 4):  # X 0 and 8 against O 2 and 4: only 6 holds the win
        state = env.step(state, jnp.int32(action))
    moves = jax.vmap(minimax.minimax_player, in_axes=(None, 0))(
        state, jax.random.split(jax.random.key(3), 16)
    )
    assert set(np.asarray(moves).tolist()) == {6}
