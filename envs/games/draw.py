"""Frames of pgx board games, drawn as rasters with PIL: one ``(H, W, 3)`` uint8 image per
position, for GIFs of a game (``rl_jax.run.render``).

``draw_state(state)`` draws a pgx ``State`` of tic-tac-toe or Connect Four: the grid, the pieces
of the side that opened (X, red discs) and of the other side (O, yellow discs) in two clearly
different colours, the cell of the last move shaded when the position before it is given, and a
caption under the board: who is to move, who won, or "draw". Any other game is an
``UnsupportedEnvError`` naming the games that can be drawn.

The board is read from the state's public fields only: the observation holds the mover's pieces
and then the opponent's (``[rows, cols, 2]``), and the side to move follows from the counts (the
opening side when both have as many pieces), as in ``tic_tac_toe_minimax``. Colour 0 is the
side that opened, whichever player id pgx gave it; a finished game was won by the side that
made the last move when its rewards are not all zero.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import numpy as np
import pgx
from PIL import Image, ImageDraw, ImageFont

from rl_jax.envs.core.registry import UnsupportedEnvError

RGB = tuple[int, int, int]

BACKGROUND: RGB = (250, 250, 247)
INK: RGB = (40, 40, 40)  # grid lines and the caption
LAST_MOVE: RGB = (255, 236, 160)  # the shade of the last move's cell
CAPTION_HEIGHT = 26
MARGIN = 10


@dataclasses.dataclass(frozen=True)
class Look:
    """How one game is drawn: its grid, cell size, the pieces' names and colours, and the
    colours of the board and its empty cells."""

    rows: int
    cols: int
    cell: int  # pixels per cell side
    names: tuple[str, str]  # the opening side's pieces, then the other side's
    colours: tuple[RGB, RGB]
    discs: bool  # discs in holes (Connect Four), else X and O marks on a grid
    board: RGB = BACKGROUND
    hole: RGB = BACKGROUND


LOOKS = {
    "tic_tac_toe": Look(3, 3, 64, ("X", "O"), ((200, 30, 45), (25, 90, 200)), discs=False),
    "connect_four": Look(
        6,
        7,
        40,
        ("Red", "Yellow"),
        ((215, 35, 35), (245, 200, 0)),
        discs=True,
        board=(30, 80, 190),
        hole=(235, 240, 250),
    ),
}
#: The pgx games ``draw_state`` draws.
GAMES = tuple(LOOKS)


def look(game: str) -> Look:
    """How ``game`` (pgx's name, ``"tic_tac_toe"``) is drawn; ``UnsupportedEnvError`` for a
    game that cannot be drawn, naming those that can."""
    if game not in LOOKS:
        raise UnsupportedEnvError(
            f"no drawing of the pgx game {game!r}: the games that can be drawn are "
            f"{', '.join(GAMES)}"
        )
    return LOOKS[game]


def _game(state: pgx.State) -> str:
    return str(getattr(state, "env_id", type(state).__name__))


def board(state: pgx.State) -> np.ndarray:
    """The position as ``[rows, cols]`` int: -1 empty, 0 the opening side's piece, 1 the other
    side's (pgx's own encoding, read from the public observation)."""
    shape = look(_game(state))
    observation = np.asarray(state.observation, dtype=bool)
    own, opponent = observation[..., 0], observation[..., 1]
    mover = 0 if own.sum() == opponent.sum() else 1
    cells = np.where(own, mover, np.where(opponent, 1 - mover, -1))
    return cells.reshape(shape.rows, shape.cols).astype(np.int32)


def to_move(state: pgx.State) -> int:
    """The colour to move (0: the side that opened), from the counts of pieces."""
    cells = board(state)
    return 0 if (cells == 0).sum() == (cells == 1).sum() else 1


def winner(state: pgx.State) -> int | None:
    """The colour that won a finished game, -1 for a draw, None while it goes on."""
    if not bool(np.asarray(state.terminated)):
        return None
    if not np.any(np.asarray(state.rewards)):
        return -1
    return 1 - to_move(state)  # the side that made the last move


def caption(state: pgx.State, players: Sequence[str] | None = None) -> str:
    """The line under the board: ``"X to move"``, ``"O wins"`` or ``"draw"``; with
    ``players`` (the opening side's name, then the other's) ``"X (alphazero) to move"``."""
    names = look(_game(state)).names

    def side(colour: int) -> str:
        return names[colour] if players is None else f"{names[colour]} ({players[colour]})"

    won = winner(state)
    if won is None:
        return f"{side(to_move(state))} to move"
    return "draw" if won < 0 else f"{side(won)} wins"


def cell_box(game: str, row: int, col: int) -> tuple[int, int, int, int]:
    """The pixels ``(left, top, right, bottom)`` of a cell in a frame of ``game`` (exclusive
    right and bottom); row 0 is the top row, as in pgx's board."""
    size = look(game).cell
    left, top = MARGIN + col * size, MARGIN + row * size
    return left, top, left + size, top + size


def frame_size(game: str) -> tuple[int, int]:
    """``(height, width)`` of a frame of ``game``."""
    shape = look(game)
    width = 2 * MARGIN + shape.cols * shape.cell
    return 2 * MARGIN + shape.rows * shape.cell + CAPTION_HEIGHT, width


def last_move(state: pgx.State, previous: pgx.State) -> tuple[int, int] | None:
    """``(row, col)`` of the piece ``state`` has and ``previous`` lacks, if one."""
    added = np.argwhere((board(state) >= 0) & (board(previous) < 0))
    return (int(added[0][0]), int(added[0][1])) if len(added) else None


def draw_state(
    state: pgx.State, previous: pgx.State | None = None, players: Sequence[str] | None = None
) -> np.ndarray:
    """One frame ``(H, W, 3)`` uint8 of a tic-tac-toe or Connect Four position: the board, the
    last move's cell shaded where ``previous`` (the position before it) is given, and the
    caption (``caption(state, players)``)."""
    game = _game(state)
    shape = look(game)
    height, width = frame_size(game)
    image = Image.new("RGB", (width, height), BACKGROUND)
    pen = ImageDraw.Draw(image)
    cells = board(state)
    moved = None if previous is None else last_move(state, previous)
    left, top, _, _ = cell_box(game, 0, 0)
    _, _, right, bottom = cell_box(game, shape.rows - 1, shape.cols - 1)
    pen.rectangle((left, top, right - 1, bottom - 1), fill=shape.board)
    for row in range(shape.rows):
        for col in range(shape.cols):
            box = cell_box(game, row, col)
            if (row, col) == moved:
                pen.rectangle((box[0], box[1], box[2] - 1, box[3] - 1), fill=LAST_MOVE)
            _draw_cell(pen, shape, box, int(cells[row, col]))
    if not shape.discs:
        _draw_grid(pen, shape, (left, top, right, bottom))
    text = caption(state, players)
    font = _font()
    text_width = pen.textlength(text, font=font)
    pen.text(((width - text_width) / 2, bottom + 6), text, fill=INK, font=font)
    return np.asarray(image, dtype=np.uint8)


def _draw_cell(
    pen: ImageDraw.ImageDraw, shape: Look, box: tuple[int, int, int, int], piece: int
) -> None:
    """A piece (or, on a disc board, an empty hole) in the cell ``box``."""
    inset = shape.cell // 6 if shape.discs else shape.cell // 5
    inner = (box[0] + inset, box[1] + inset, box[2] - 1 - inset, box[3] - 1 - inset)
    if shape.discs:
        pen.ellipse(inner, fill=shape.hole if piece < 0 else shape.colours[piece])
        return
    if piece < 0:
        return
    colour, thickness = shape.colours[piece], max(3, shape.cell // 10)
    if piece == 0:
        pen.line((inner[0], inner[1], inner[2], inner[3]), fill=colour, width=thickness)
        pen.line((inner[0], inner[3], inner[2], inner[1]), fill=colour, width=thickness)
    else:
        pen.ellipse(inner, outline=colour, width=thickness)


def _draw_grid(pen: ImageDraw.ImageDraw, shape: Look, bounds: tuple[int, int, int, int]) -> None:
    """The inner lines of a tic-tac-toe grid."""
    left, top, right, bottom = bounds
    pen.rectangle((left, top, right - 1, bottom - 1), outline=INK, width=1)
    for col in range(1, shape.cols):
        x = left + col * shape.cell
        pen.line((x, top, x, bottom - 1), fill=INK, width=2)
    for row in range(1, shape.rows):
        y = top + row * shape.cell
        pen.line((left, y, right - 1, y), fill=INK, width=2)


@functools.cache
def _font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """PIL's default font, at 14 px where PIL has FreeType (its bitmap font otherwise)."""
    try:
        return ImageFont.load_default(size=14)
    except (TypeError, ImportError, OSError):
        return ImageFont.load_default()
