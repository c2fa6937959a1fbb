"""envs/games/draw.py: frames of pgx tic-tac-toe and Connect Four positions. The pieces placed by
known moves are found in their cells in their side's colour (and nowhere else), the last move's
cell is shaded, the caption says who moves, who won or that it is a draw, and another game is
one user-error line naming the games that can be drawn."""

import functools

import jax
import numpy as np
import pgx
import pytest

from rl_jax.envs.core.registry import UnsupportedEnvError
from rl_jax.envs.games import draw
from rl_jax.errors import user_errors


@functools.cache
def _env(game: str) -> tuple[pgx.Env, object]:
    env = pgx.make(game)
    return env, jax.jit(env.step)


def _play(game: str, moves: list[int]) -> list[pgx.State]:
    """The positions of ``moves`` played from the start (pgx's opening player id is random:
    colour 0 is whoever opens)."""
    env, step = _env(game)
    states = [env.init(jax.random.key(1))]
    for move in moves:
        states.append(step(states[-1], move))
    return states


def _pixels(frame: np.ndarray, box: tuple[int, int, int, int], colour) -> int:
    left, top, right, bottom = box
    cell = frame[top:bottom, left:right]
    return int(np.all(cell == np.asarray(colour, np.uint8), axis=-1).sum())


def _expected(rows: int, cols: int, placed: dict[tuple[int, int], int]) -> np.ndarray:
    cells = -np.ones((rows, cols), np.int32)
    for (row, col), colour in placed.items():
        cells[row, col] = colour
    return cells


def test_tic_tac_toe_pieces_are_in_their_cells_in_their_colours():
    # X 4, O 0, X 8, O 2, X 1, O 7 (cells numbered row by row)
    moves = [4, 0, 8, 2, 1, 7]
    states = _play("tic_tac_toe", moves)
    frame = draw.draw_state(states[-1], states[-2])
    assert frame.shape == (*draw.frame_size("tic_tac_toe"), 3) and frame.dtype == np.uint8
    placed = {divmod(move, 3): index % 2 for index, move in enumerate(moves)}
    assert np.array_equal(draw.board(states[-1]), _expected(3, 3, placed))
    x_colour, o_colour = draw.LOOKS["tic_tac_toe"].colours
    for row in range(3):
        for col in range(3):
            box = draw.cell_box("tic_tac_toe", row, col)
            x, o = _pixels(frame, box, x_colour), _pixels(frame, box, o_colour)
            piece = placed.get((row, col), -1)
            assert (x > 100, o > 100) == (piece == 0, piece == 1), (row, col, x, o)
            assert min(x, o) == 0
            shaded = _pixels(frame, box, draw.LAST_MOVE) > 0
            assert shaded == ((row, col) == (2, 1)), (row, col)  # the last move, O at 7


def test_connect_four_discs_fall_to_the_lowest_free_row():
    # columns: red 3, yellow 3, red 4, yellow 2, red 5, yellow 6, red 6
    states = _play("connect_four", [3, 3, 4, 2, 5, 6, 6])
    placed = {(5, 3): 0, (4, 3): 1, (5, 4): 0, (5, 2): 1, (5, 5): 0, (5, 6): 1, (4, 6): 0}
    assert np.array_equal(draw.board(states[-1]), _expected(6, 7, placed))
    frame = draw.draw_state(states[-1], states[-2])
    look = draw.LOOKS["connect_four"]
    for row in range(6):
        for col in range(7):
            left, top, right, bottom = draw.cell_box("connect_four", row, col)
            centre = frame[(top + bottom) // 2, (left + right) // 2]
            piece = placed.get((row, col), -1)
            expected = look.hole if piece < 0 else look.colours[piece]
            assert tuple(centre) == expected, (row, col)
            corner = tuple(frame[top + 1, left + 1])
            assert corner == (draw.LAST_MOVE if (row, col) == (4, 6) else look.board), (row, col)


@pytest.mark.parametrize(
    ("game", "moves", "expected"),
    [
        ("tic_tac_toe", [], "X to move"),
        ("tic_tac_toe", [4], "O to move"),
        ("tic_tac_toe", [0, 3, 1, 4, 2], "X wins"),
        ("tic_tac_toe", [3, 0, 4, 1, 8, 2], "O wins"),
        ("tic_tac_toe", [0, 4, 8, 1, 7, 6, 2, 5, 3], "draw"),
        ("connect_four", [2], "Yellow to move"),
        ("connect_four", [0, 1, 0, 1, 0, 1, 0], "Red wins"),
        ("connect_four", [0, 1, 0, 1, 0, 1, 2, 1], "Yellow wins"),
    ],
)
def test_the_caption_says_who_moves_who_won_or_draw(game, moves, expected):
    state = _play(game, moves)[-1]
    assert bool(state.terminated) == (expected.endswith("wins") or expected == "draw")
    assert draw.caption(state) == expected
    named = draw.caption(state, ("alphazero", "minimax"))
    if expected != "draw":
        side = "alphazero" if expected.split()[0] in ("X", "Red") else "minimax"
        first, rest = expected.split(" ", 1)
        assert named == f"{first} ({side}) {rest}"
    frame = draw.draw_state(state)
    board_bottom = draw.cell_box(game, *draw.board(state).shape)[1]  # a row past the last
    strip = frame[board_bottom:].astype(int)
    assert (strip.sum(axis=-1) < 300).sum() > 20  # the caption's dark text under the board


def test_captions_of_different_states_draw_different_strips():
    states = _play("tic_tac_toe", [0, 3, 1, 4, 2])
    bottom = draw.cell_box("tic_tac_toe", 2, 2)[3]
    to_move = draw.draw_state(states[-2])[bottom + 2 :]
    won = draw.draw_state(states[-1])[bottom + 2 :]
    assert not np.array_equal(to_move, won)


def test_another_game_is_one_user_error_line_naming_the_drawable_games():
    state = pgx.make("othello").init(jax.random.key(0))
    with pytest.raises(UnsupportedEnvError, match="'othello'.*tic_tac_toe, connect_four") as error:
        draw.draw_state(state)
    assert "\n" not in str(error.value)
    assert isinstance(error.value, user_errors())
