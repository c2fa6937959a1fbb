"""Tic-tac-toe solved exactly: negamax over every position reachable in play, memoised.

A board is nine cells read row by row (``0 1 2 / 3 4 5 / 6 7 8``, pgx's action numbering), each
``-1`` (empty), ``0`` (X, who moves first) or ``1`` (O): the same encoding as the board inside a
pgx ``tic_tac_toe`` state. The side to move follows from the counts (X when they are equal), so a
board alone is a position. ``board_from_observation`` recovers it from pgx's public observation
(the mover's stones, then the opponent's), which maps one to one onto pgx's own board.

``value(board)`` is the game-theoretic value for the side to move (+1 win, 0 draw, -1 loss
under perfect play by both) and ``optimal_moves(board)`` the moves that keep it. Every position
reachable from the empty board, stopping at wins and full boards, is solved once (5,478 of
them) in plain Python in well under a second. ``minimax_player`` plays those moves inside a
compiled program: a table of optimal moves indexed by the board read as a base-3 number, with
ties broken at random, so that a perfect opponent still varies its games.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pgx

#: A tic-tac-toe position: nine cells of -1 (empty), 0 (X) or 1 (O).
Board = tuple[int, ...]

EMPTY_BOARD: Board = (-1,) * 9
#: The eight lines of three: rows, columns, diagonals.
LINES = ((0, 1, 2), (3, 4, 5), (6, 7, 8), (0, 3, 6), (1, 4, 7), (2, 5, 8), (0, 4, 8), (2, 4, 6))
#: Number of boards with cells in {-1, 0, 1}: the size of the base-3 index of ``board_index``.
NUM_BOARDS = 3**9


def to_move(board: Board) -> int:
    """The colour to move: 0 (X) when both have as many stones, else 1 (O)."""
    return 0 if board.count(0) == board.count(1) else 1


def winner(board: Board) -> int:
    """The colour with three in a line, or -1 when neither has one."""
    for a, b, c in LINES:
        if board[a] != -1 and board[a] == board[b] == board[c]:
            return board[a]
    return -1


def is_terminal(board: Board) -> bool:
    """Whether the game is over: a line of three, or a full board."""
    return winner(board) != -1 or -1 not in board


def legal_moves(board: Board) -> tuple[int, ...]:
    """The empty cells of a position that is not over; none once it is."""
    if is_terminal(board):
        return ()
    return tuple(cell for cell in range(9) if board[cell] == -1)


def play(board: Board, move: int) -> Board:
    """The position after the side to move takes the empty cell ``move``."""
    if board[move] != -1:
        raise ValueError(f"cell {move} of {board} is not empty")
    return board[:move] + (to_move(board),) + board[move + 1 :]


@functools.cache
def solve() -> dict[Board, int]:
    """Every position reachable from the empty board, with its value for the side to move.

    Negamax: a finished game is worth -1 to the side to move when the other side has just made
    a line, 0 when the board is full; any other position is worth the best over its moves of
    minus the value of the position that move leads to.
    """
    values: dict[Board, int] = {}

    def negamax(board: Board) -> int:
        if board in values:
            return values[board]
        if is_terminal(board):
            value = -1 if winner(board) != -1 else 0
        else:
            value = max(-negamax(play(board, move)) for move in legal_moves(board))
        values[board] = value
        return value

    negamax(EMPTY_BOARD)
    return values


def _solved(board: Board) -> int:
    board = tuple(int(cell) for cell in board)
    values = solve()
    if board not in values:
        raise ValueError(f"{board} cannot be reached from the empty board in play")
    return values[board]


def value(board: Board) -> int:
    """The game-theoretic value of a reachable position for the side to move: 1, 0 or -1."""
    return _solved(board)


def optimal_moves(board: Board) -> tuple[int, ...]:
    """The moves of a reachable position that keep its value (empty once the game is over)."""
    target = _solved(board)
    return tuple(move for move in legal_moves(board) if -_solved(play(board, move)) == target)


def reachable_positions() -> frozenset[Board]:
    """Every position that play from the empty board can reach, finished games included."""
    return frozenset(solve())


def board_index(board: Board) -> int:
    """The board read as a base-3 number, cell 0 the lowest digit: an index into the tables."""
    return sum((cell + 1) * 3**position for position, cell in enumerate(board))


@functools.cache
def optimal_move_table() -> np.ndarray:
    """``[NUM_BOARDS, 9]`` booleans, row ``board_index(board)``: the optimal moves of every
    reachable position that is not over; rows of other boards are all False."""
    table = np.zeros((NUM_BOARDS, 9), dtype=bool)
    for board in solve():
        table[board_index(board), list(optimal_moves(board))] = True
    return table


def board_from_observation(observation: jax.Array) -> jax.Array:
    """pgx's ``tic_tac_toe`` observation ``[3, 3, 2]`` (the mover's stones, then the
    opponent's) as a board ``[9]`` of -1, 0 and 1, the same as pgx's own internal board."""
    own = observation[..., 0].reshape(-1)
    opponent = observation[..., 1].reshape(-1)
    mover = jnp.where(own.sum() == opponent.sum(), 0, 1)
    return jnp.where(own, mover, jnp.where(opponent, 1 - mover, -1)).astype(jnp.int32)


def minimax_player(state: pgx.State, key: jax.Array) -> jax.Array:
    """A perfect tic-tac-toe player for one pgx state: an optimal move, chosen uniformly among
    the optimal moves with ``key``. Where no optimal move is known (the game is over) it picks
    any legal action, so that it can be called on finished games of a batch too."""
    board = board_from_observation(state.observation)
    index = jnp.sum((board + 1) * 3 ** jnp.arange(9, dtype=jnp.int32))
    optimal = jnp.asarray(optimal_move_table())[index]
    choices = jnp.where(optimal.any(), optimal, state.legal_action_mask)
    return jax.random.categorical(key, jnp.where(choices, 0.0, -jnp.inf)).astype(jnp.int32)
