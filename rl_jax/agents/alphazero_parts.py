"""AlphaZero's maths, apart from the search and the game: the targets a finished self-play game
gives its positions, the losses on them, and the discount of a search edge between two players.

Time-major throughout: ``[T, B]`` is move ``t`` of game ``b``. A game's move ``t`` is made by
``player_t`` (pgx's ``current_player`` before the move), and ``rewards_t[p]`` is what player
``p`` received from that move (pgx's ``rewards`` after it: nonzero only on the move that ends a
two-player game). ``alive_t`` is 1 for the moves made before the game ended and 0 for the idle
steps after it. In continuous self-play, column ``b`` is a game slot instead, whose games follow
one another (``to_game_end`` and the ``game_*`` helpers at the end).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def value_targets(rewards_t: jax.Array, player_t: jax.Array, alive_t: jax.Array) -> jax.Array:
    """``[T, B]`` value targets: the sum of the rewards that ``player_t``, the player to move at
    ``t``, receives from move ``t`` to the game's end (undiscounted; 0 on idle steps).

    In a two-player zero-sum game with a reward only at the end this is the final outcome from
    the mover's view, so its sign flips from one move to the next (``rewards_t``: ``[T, B, P]``,
    ``player_t``: ``[T, B]`` int, ``alive_t``: ``[T, B]`` 0/1)."""
    received = rewards_t * alive_t[..., None]
    to_go = jnp.flip(jnp.cumsum(jnp.flip(received, axis=0), axis=0), axis=0)  # [T, B, P]
    mover_to_go = jnp.take_along_axis(to_go, player_t[..., None].astype(jnp.int32), axis=-1)
    return jax.lax.stop_gradient(mover_to_go[..., 0] * alive_t)


def mixed_value_targets(
    outcome_t: jax.Array, search_value_t: jax.Array, weight: float, alive_t: jax.Array
) -> jax.Array:
    """``[T, B]`` value targets ``(1 - weight) * outcome + weight * search value`` on the moves
    made (``alive_t`` 1), 0 elsewhere: the game's outcome for the player to move mixed with the
    search's value of the position for that player (its root value). The outcome says how one
    game ended, the search what the position is worth under the current network; AlphaZero
    trains on the outcome alone (``weight`` 0)."""
    mixed = (1.0 - weight) * outcome_t + weight * jax.lax.stop_gradient(search_value_t)
    return mixed * alive_t


def played_on(explored_t: jax.Array, alive_t: jax.Array) -> jax.Array:
    """``[T, B]`` 1 where the rest of the game, from move ``t`` on, was the learner's own play:
    a position before an exploring (random) move, or the position where one was made, gets 0,
    and so do idle steps. Only these positions' outcomes say what the learner's play is worth;
    the outcome of a game a random move turned says what the random move was worth. A random
    "move" drawn on an idle step after the game's end does not count."""
    explored = explored_t * alive_t
    explored_later = jnp.flip(jnp.cumsum(jnp.flip(explored, axis=0), axis=0), axis=0)
    return jnp.where(explored_later > 0, 0.0, alive_t).astype(jnp.float32)


def edge_discount(mover: jax.Array, next_player: jax.Array, terminated: jax.Array) -> jax.Array:
    """The discount of a search edge: -1 where the turn passes to the other player (the next
    node's value is the opponent's), +1 where the same player moves again, 0 where the game
    ended. mctx's backup ``reward + discount * value`` then values every edge for the player
    who chose it."""
    sign = jnp.where(next_player == mover, 1.0, -1.0)
    return jnp.where(terminated, 0.0, sign).astype(jnp.float32)


def masked_logits(logits: jax.Array, legal: jax.Array) -> jax.Array:
    """Logits with the illegal actions at the dtype's lowest value (and the legal ones shifted
    so that their largest is 0): a softmax over them puts no mass on illegal actions."""
    shifted = logits - jnp.max(logits, axis=-1, keepdims=True)
    return jnp.where(legal, shifted, jnp.finfo(logits.dtype).min)


def policy_loss(
    logits: jax.Array, target_probs: jax.Array, legal: jax.Array, weight: jax.Array
) -> jax.Array:
    """The weighted mean over positions of the cross-entropy ``-sum_a pi(a) log p(a)`` between the
    search's improved policy ``target_probs`` ``[N, A]`` and the network's policy over the legal
    actions (``logits``, ``legal`` ``[N, A]``, ``weight`` ``[N]``)."""
    log_probs = jax.nn.log_softmax(masked_logits(logits, legal), axis=-1)
    per_position = -jnp.sum(jnp.where(legal, target_probs * log_probs, 0.0), axis=-1)
    return jnp.sum(weight * per_position) / jnp.maximum(jnp.sum(weight), 1.0)


def value_loss(value: jax.Array, target: jax.Array, weight: jax.Array) -> jax.Array:
    """The weighted mean squared error between the value head ``[N]`` and the outcomes ``[N]``."""
    return jnp.sum(weight * (value - target) ** 2) / jnp.maximum(jnp.sum(weight), 1.0)


# ---- left-right mirrors (``Config.mirror``) ---------------------------------------------------
#: Each game with a left-right symmetry: the action that mirrors each action. A board's mirror
#: reverses its columns (pgx's observations are ``[rows, columns, planes]``); Connect Four's
#: actions are its columns, tic-tac-toe's its cells row by row.
MIRRORED_ACTIONS = {
    "connect_four": (6, 5, 4, 3, 2, 1, 0),
    "tic_tac_toe": (2, 1, 0, 5, 4, 3, 8, 7, 6),
}


def mirrored(
    flip: jax.Array, obs: jax.Array, legal: jax.Array, policy: jax.Array, actions: tuple[int, ...]
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """``(obs, legal, policy)`` of ``N`` positions, each one's left-right mirror where ``flip``
    ``[N]`` is true: the board's columns reversed (``obs`` ``[N, rows, columns, planes]``) and the
    actions permuted by ``actions`` (``legal``, ``policy`` ``[N, A]``). A game's outcome is the
    same from a mirrored position, so its value target is unchanged."""
    order = jnp.asarray(actions)
    board = flip.reshape((-1,) + (1,) * (obs.ndim - 1))
    pick = flip[:, None]
    return (
        jnp.where(board, jnp.flip(obs, axis=-2), obs),
        jnp.where(pick, legal[:, order], legal),
        jnp.where(pick, policy[:, order], policy),
    )


# ---- continuous self-play (``Config.self_play_steps`` > 0) ------------------------------------
# A slot's trajectory ``[T, B]`` holds several games back to back: ``ended_t`` is 1 where move
# ``t`` ended its game (the next row, if any, opens a fresh one). Rows with ``alive_t`` 0 hold no
# move (the unused rows before a slot's carried unfinished game); only the last game of a slot
# can be unfinished, so a move's game ended iff some move at or after it ended a game.
def to_game_end(x_t: jax.Array, ended_t: jax.Array, alive_t: jax.Array) -> jax.Array:
    """``[T, B, ...]`` the sum of ``x`` over the moves from ``t`` to the last move of ``t``'s
    own game (through the window's end for an unfinished game); rows without a move add 0."""
    alive = alive_t.reshape(alive_t.shape + (1,) * (x_t.ndim - alive_t.ndim))
    carry_on = (1.0 - ended_t * alive_t).reshape(alive.shape)

    def back(later: jax.Array, row: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        x, keep = row
        total = x + keep * later
        return total, total

    rows = (x_t * alive, jnp.broadcast_to(carry_on, x_t.shape))
    _, totals = jax.lax.scan(back, jnp.zeros_like(x_t[0]), rows, reverse=True)
    return totals


def game_finished(ended_t: jax.Array, alive_t: jax.Array) -> jax.Array:
    """``[T, B]`` 1 for a move whose game ended within the trajectory, 0 for the moves of a
    slot's unfinished last game and for rows without a move."""
    ends_later = jnp.flip(jnp.cumsum(jnp.flip(ended_t * alive_t, axis=0), axis=0), axis=0)
    return jnp.where(ends_later > 0, alive_t, 0.0).astype(jnp.float32)


def game_value_targets(
    rewards_t: jax.Array, player_t: jax.Array, alive_t: jax.Array, ended_t: jax.Array
) -> jax.Array:
    """``value_targets`` with games back to back: the rewards ``player_t`` receives from move
    ``t`` to the end of its own game (0 for a move of an unfinished game or a row without one)."""
    to_go = to_game_end(rewards_t, ended_t, alive_t)  # [T, B, P]
    mover_to_go = jnp.take_along_axis(to_go, player_t[..., None].astype(jnp.int32), axis=-1)
    return jax.lax.stop_gradient(mover_to_go[..., 0] * game_finished(ended_t, alive_t))


def game_played_on(explored_t: jax.Array, alive_t: jax.Array, ended_t: jax.Array) -> jax.Array:
    """``played_on`` with games back to back: 1 for a move of a finished game where no random
    move was made from it to its game's end; a random move in a later game does not count."""
    explored_later = to_game_end(explored_t, ended_t, alive_t)
    return jnp.where(explored_later > 0, 0.0, game_finished(ended_t, alive_t))


def compacted_rows(keep: jax.Array, position: jax.Array, capacity: int) -> jax.Array:
    """Ring rows for the entries ``keep`` (``[N]`` 0/1) selects: the kept ones, in order, take
    consecutive rows from ``position`` on (modulo ``capacity``); a dropped one gets
    ``capacity``, out of range, which a scatter with ``mode="drop"`` skips. Dropped entries thus
    take no row (``keep`` must select at most ``capacity`` entries)."""
    index = jnp.cumsum(keep.astype(jnp.int32)) - 1
    return jnp.where(keep > 0, (position + index) % capacity, capacity).astype(jnp.int32)
