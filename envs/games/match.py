"""Matches between two players of a pgx game: both colours, seeded, in one compiled program.

A player is a function ``(state, key) -> action`` of one pgx state (the player to move is
``state.current_player``): ``random_player``, ``rollout_mcts.rollout_mcts_player(...)``,
``tic_tac_toe_minimax.minimax_player``, or a learner's policy. ``play_match`` plays
``num_games`` games vmapped side by side, the first player making the opening move in the even
games and the second player in the odd ones, and returns every game's outcome from the first
player's view: a win/draw/loss table by colour and the Elo difference with its confidence
interval (``envs.games.elo``).

All games of a match step together until the last one ends, and every step asks both players
for a move in every game (the one not to move is discarded): a vmapped program computes both
branches of a choice anyway. A game that has ended idles, its state unchanged, so a player may
be called on a finished state and must return some action there.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pgx

from rl_jax.envs.games.elo import EloEstimate, elo_estimate

#: A player: one pgx state and a key to the action it plays.
Player = Callable[[pgx.State, jax.Array], jax.Array]


def random_player(state: pgx.State, key: jax.Array) -> jax.Array:
    """A uniformly random legal action of one pgx state."""
    logits = jnp.where(state.legal_action_mask, 0.0, -jnp.inf)
    return jax.random.categorical(key, logits).astype(jnp.int32)


@dataclasses.dataclass(frozen=True)
class MatchResult:
    """The games of a match, from the first player's view, one entry per game."""

    outcomes: np.ndarray  # [games] int: 1 the first player won, 0 a draw, -1 it lost
    first_moved: np.ndarray  # [games] bool: the first player made the opening move
    moves: np.ndarray  # [games] int: moves played

    def counts(self, games: np.ndarray | None = None) -> tuple[int, int, int]:
        """``(wins, draws, losses)`` of the first player over ``games`` (a mask; all games
        when None)."""
        outcomes = self.outcomes if games is None else self.outcomes[games]
        return int((outcomes > 0).sum()), int((outcomes == 0).sum()), int((outcomes < 0).sum())

    @property
    def wins(self) -> int:
        """Games the first player won."""
        return self.counts()[0]

    @property
    def draws(self) -> int:
        """Games drawn."""
        return self.counts()[1]

    @property
    def losses(self) -> int:
        """Games the first player lost."""
        return self.counts()[2]

    def elo(self, confidence: float = 0.95) -> EloEstimate:
        """The first player's Elo difference over the second, with its interval."""
        return elo_estimate(*self.counts(), confidence=confidence)

    def table(self, confidence: float = 0.95) -> str:
        """The win/draw/loss table by colour and the Elo line, as plain text."""
        rows = [
            ("moving first", self.counts(self.first_moved)),
            ("moving second", self.counts(~self.first_moved)),
            ("total", self.counts()),
        ]
        lines = [f"{'first player':<14} {'wins':>6} {'draws':>6} {'losses':>6} {'score':>6}"]
        for name, (wins, draws, losses) in rows:
            games = wins + draws + losses
            score = f"{(wins + 0.5 * draws) / games:6.3f}" if games else f"{'-':>6}"
            lines.append(f"{name:<14} {wins:>6} {draws:>6} {losses:>6} {score}")
        elo = self.elo(confidence)
        lines.append(
            f"Elo difference {elo.difference:+.0f}, {confidence:.0%} interval "
            f"[{elo.low:+.0f}, {elo.high:+.0f}]"
        )
        return "\n".join(lines)


@functools.lru_cache(maxsize=16)
def _compiled_match(env: pgx.Env, first: Player, second: Player, max_moves: int) -> Callable:
    """The jitted, vmapped games of ``first`` against ``second``: kept, so that another match
    of the same players (the same function objects) does not compile again."""
    return jax.jit(jax.vmap(_game(env, first, second, max_moves)))


def _game(env: pgx.Env, first: Player, second: Player, max_moves: int) -> Callable:
    """One game, from a key and whether the first player opens, to the first player's return
    and the number of moves played."""

    def play(key: jax.Array, first_opens: jax.Array) -> tuple[jax.Array, jax.Array]:
        init_key, key = jax.random.split(key)
        state = env.init(init_key)
        # pgx draws which player id opens; the first player takes that id in its opening games
        first_id = jnp.where(first_opens, state.current_player, 1 - state.current_player)

        def unfinished(carry: tuple) -> jax.Array:
            state, _, moves, _ = carry
            return ~(state.terminated | state.truncated) & (moves < max_moves)

        def move(carry: tuple) -> tuple:
            state, total, moves, key = carry
            key, first_key, second_key, step_key = jax.random.split(key, 4)
            action = jnp.where(
                state.current_player == first_id,
                first(state, first_key),
                second(state, second_key),
            )
            state = env.step(state, action, step_key)
            return state, total + state.rewards[first_id], moves + 1, key

        carry = (state, jnp.float32(0.0), jnp.int32(0), key)
        _, total, moves, _ = jax.lax.while_loop(unfinished, move, carry)
        return total, moves

    return play


def play_match(
    env: pgx.Env,
    first: Player,
    second: Player,
    key: jax.Array,
    num_games: int,
    max_moves: int | None = None,
) -> MatchResult:
    """``num_games`` games of ``first`` against ``second`` on ``env``, seeded by ``key``: the
    first player opens the even games, the second the odd ones. A game still running after
    ``max_moves`` moves (no limit when None) ends there and is scored by the rewards so far."""
    if num_games < 1:
        raise ValueError(f"num_games must be at least 1, got {num_games}")
    if env.num_players != 2:
        raise ValueError(f"a match needs a two-player game; {env.id} has {env.num_players}")
    limit = int(jnp.iinfo(jnp.int32).max) if max_moves is None else max_moves
    first_opens = jnp.arange(num_games) % 2 == 0
    keys = jax.random.split(key, num_games)
    totals, moves = _compiled_match(env, first, second, limit)(keys, first_opens)
    return MatchResult(
        outcomes=np.sign(np.asarray(totals)).astype(np.int32),
        first_moved=np.asarray(first_opens),
        moves=np.asarray(moves),
    )
