"""GIFs of board games: the frames ``rl_jax.run.render`` saves for a run whose learner moves
from the env's own positions (``position_policy``, a ``GamePolicy``: AlphaZero on a pgx game).

Each episode is one game of the run's trained search (``GamePolicy.move``) against the run's
evaluation opponent (the config's ``eval_opponent``: ``"random"``, ``"mcts"`` with
``eval_opponent_simulations``, or ``"minimax"``; ``rl_jax.envs.games.opponents``), our side
opening the odd episodes (1, 3, ...) and moving second in the even ones. A frame per position,
drawn by ``rl_jax.envs.games.draw`` (the board, the last move shaded, a caption naming who plays
which side), and the final position held for ``HOLD_SECONDS``.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pgx

from rl_jax.envs.games import draw, opponents
from rl_jax.envs.games.match import Player
from rl_jax.errors import RenderError
from rl_jax.run.policy import GamePolicy, LoadedPolicy
from rl_jax.training.algorithm import hooks

#: Frames per second of a game's GIF: one move every half second.
MOVES_PER_SECOND = 2.0
#: How long the final position of each game stays on screen.
HOLD_SECONDS = 1.0
#: Extra copies of each game's final frame (a GIF player shows them as one longer frame).
HELD_FRAMES = round(HOLD_SECONDS * MOVES_PER_SECOND)


@dataclasses.dataclass(frozen=True)
class PlayedGame:
    """One game: its positions (pgx states, first to last), the moves between them, and our
    side (``opened``: ours was the first move) and outcome (1 win, 0 draw, -1 loss)."""

    states: list[pgx.State]
    moves: list[int]
    opened: bool
    outcome: int


def plays_positions(loaded: LoadedPolicy) -> bool:
    """Whether the loaded learner moves from env positions (its ``position_policy`` gives a
    player): then a GIF is games against its opponent, not episodes of ``env()``."""
    return hooks(loaded.algorithm).position_policy(loaded.state, loaded.config) is not None


def opponent(loaded: LoadedPolicy, game: pgx.Env) -> tuple[str, Player]:
    """The run's evaluation opponent (its config's ``eval_opponent``, random when the config
    has none) with the name a caption gives it."""
    name = str(getattr(loaded.config, "eval_opponent", "random"))
    simulations = int(getattr(loaded.config, "eval_opponent_simulations", 100))
    try:
        player = opponents.opponent_player(name, game, simulations)
    except ValueError as error:
        raise RenderError(f"cannot play the run's opponent: {error}") from None
    return opponents.describe(name, simulations), player


def play_game(
    policy: GamePolicy, other: Player, game: pgx.Env, key: jax.Array, opened: bool
) -> PlayedGame:
    """One game of ``policy.move`` against ``other``, ours the opening move when ``opened``."""
    init_key, key = jax.random.split(key)
    state = game.init(init_key)
    ours = int(state.current_player) if opened else 1 - int(state.current_player)
    step, theirs = jax.jit(game.step), jax.jit(other)
    states, moves = [state], []
    while not (bool(state.terminated) or bool(state.truncated)):
        key, move_key, step_key = jax.random.split(key, 3)
        if int(state.current_player) == ours:
            move = policy.move(state)
        else:
            move = int(theirs(state, move_key))
        state = step(state, move, step_key)
        states.append(state)
        moves.append(move)
    outcome = int(np.sign(float(state.rewards[ours])))
    return PlayedGame(states, moves, opened, outcome)


def game_frames(played: PlayedGame, names: tuple[str, str]) -> list[np.ndarray]:
    """A frame per position of ``played`` and ``HELD_FRAMES`` copies of the last; ``names``:
    our side's name, then the opponent's."""
    players = names if played.opened else names[::-1]
    frames = [draw.draw_state(played.states[0], players=players)]
    for previous, state in zip(played.states, played.states[1:], strict=False):
        frames.append(draw.draw_state(state, previous, players))
    return frames + [frames[-1]] * HELD_FRAMES


def play_and_draw(
    loaded: LoadedPolicy, episodes: int
) -> tuple[list[np.ndarray], list[PlayedGame], str]:
    """``episodes`` games of the loaded run against its opponent: their frames, the games, and
    the opponent's name. ``RenderError`` for a game that cannot be drawn."""
    policy = GamePolicy(loaded)
    if policy.game not in draw.GAMES:
        raise RenderError(
            f"no drawing of {policy.env_id}: GIFs of a game are drawn for "
            f"{', '.join('pgx/' + name for name in draw.GAMES)}"
        )
    game = pgx.make(policy.game)
    opponent_name, other = opponent(loaded, game)
    key = jax.random.key(loaded.seed)
    frames: list[np.ndarray] = []
    games = []
    for episode in range(1, episodes + 1):
        key, game_key = jax.random.split(key)
        played = play_game(policy, other, game, game_key, opened=episode % 2 == 1)
        frames += game_frames(played, (loaded.algorithm.name, opponent_name))
        games.append(played)
    return frames, games, opponent_name


def summary(games: list[PlayedGame], opponent_name: str) -> str:
    """The games in one phrase: ``against minimax: game 1 (first) draw, game 2 (second) won``."""
    words = {1: "won", 0: "draw", -1: "lost"}
    each = ", ".join(
        f"game {number} ({'first' if played.opened else 'second'}) {words[played.outcome]}"
        for number, played in enumerate(games, start=1)
    )
    return f"against {opponent_name}: {each}"
