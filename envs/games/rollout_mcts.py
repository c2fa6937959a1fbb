"""Pure Monte Carlo tree search for any pgx game: UCT, with random rollouts as the value.

No network and no prior: the yardstick that AlphaZero's own search is measured against. Each
simulation walks down the tree by UCB1 (Kocsis and Szepesvári, 2006),

    Q(s, a) + c * sqrt(ln N(s) / N(s, a)),

an unvisited legal move first, ties broken at random; expands one new node by stepping the pgx
env; and backs up the outcome of one game from there played out with uniformly random legal
moves. The tree, its statistics and the backup are mctx's (``mctx.search``); ours are the
selection rule above, the ``recurrent_fn`` that steps the true game and plays the rollout, and
the move choice: the root's most visited legal move.

Values are signed for the player to move at each node. An edge carries the mover's reward and a
discount of -1 when the turn passes to the other player, +1 when the same player moves again,
0 when the game has ended, so mctx's ``reward + discount * value`` backup gives every ``Q(s, a)``
from the view of the player who chooses ``a``. That covers pgx's two-player zero-sum games and
its one-player games alike. A chance move (pgx's stochastic games) is sampled once, when its
node is expanded, and then held fixed: plain UCT's approximation there.

Everything runs inside the compiled program and batches over games: ``search`` takes a batch of
states, ``rollout_mcts_player`` makes a player for one state (``envs.games.match``'s form), which
the match runner vmaps.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mctx
import pgx

from rl_jax.envs.games.match import Player, random_player

#: UCB1's exploration constant ``c``: ``sqrt(2)``, its textbook value for returns in [0, 1];
#: ours lie in [-1, 1], so this explores half as much relative to the spread of returns. At 200
#: simulations against tic-tac-toe minimax, c = 0.5, 1, sqrt(2) and 2 all lost 13-16 of 50
#: replying games: at that budget the rollouts, not the constant, limit it.
DEFAULT_EXPLORATION = math.sqrt(2.0)
#: The score an unvisited legal move gets, above any UCB1 score of a visited one.
_UNVISITED_SCORE = 1e6


def rollout_return(env: pgx.Env, state: pgx.State, key: jax.Array) -> jax.Array:
    """The return, for the player to move in ``state``, of one game played on from it with
    uniformly random legal moves: the sum of that player's rewards until the game ends (0 when
    it has already ended)."""
    player = state.current_player

    def unfinished(carry: tuple[pgx.State, jax.Array, jax.Array]) -> jax.Array:
        state, _, _ = carry
        return ~(state.terminated | state.truncated)

    def move(carry: tuple[pgx.State, jax.Array, jax.Array]) -> tuple:
        state, total, key = carry
        key, action_key, step_key = jax.random.split(key, 3)
        state = env.step(state, random_player(state, action_key), step_key)
        return state, total + state.rewards[player], key

    _, total, _ = jax.lax.while_loop(unfinished, move, (state, jnp.float32(0.0), key))
    return total


def _recurrent_fn(env: pgx.Env) -> mctx.RecurrentFn:
    """mctx's model for the true game: step the env, then value the new state by a rollout."""

    def recurrent_fn(
        params: None, key: jax.Array, action: jax.Array, state: pgx.State
    ) -> tuple[mctx.RecurrentFnOutput, pgx.State]:
        del params
        batch = action.shape[0]
        step_key, rollout_key = jax.random.split(key)
        step_keys = jax.random.split(step_key, batch)
        rollout_keys = jax.random.split(rollout_key, batch)
        mover = state.current_player
        next_state = jax.vmap(env.step)(state, action, step_keys)
        reward = jnp.take_along_axis(next_state.rewards, mover[:, None], axis=1)[:, 0]
        value = jax.vmap(lambda s, k: rollout_return(env, s, k))(next_state, rollout_keys)
        same_player = next_state.current_player == mover
        discount = jnp.where(same_player, 1.0, -1.0)
        discount = jnp.where(next_state.terminated, 0.0, discount)
        output = mctx.RecurrentFnOutput(
            reward=reward,
            discount=discount,
            prior_logits=jnp.zeros_like(next_state.legal_action_mask, dtype=jnp.float32),
            value=value,
        )
        return output, next_state

    return recurrent_fn


def _uct_selection(exploration: float) -> mctx.InteriorActionSelectionFn:
    """UCB1 over the legal moves of one node of an (unbatched) mctx tree of pgx states."""

    def select(
        key: jax.Array, tree: mctx.Tree, node_index: jax.Array, depth: jax.Array
    ) -> jax.Array:
        del depth
        visits = tree.children_visits[node_index].astype(jnp.float32)
        parent_visits = tree.node_visits[node_index].astype(jnp.float32)
        legal = tree.embeddings.legal_action_mask[node_index]
        bonus = exploration * jnp.sqrt(jnp.log(parent_visits) / jnp.maximum(visits, 1.0))
        score = jnp.where(visits > 0, tree.qvalues(node_index) + bonus, _UNVISITED_SCORE)
        tie_break = 1e-6 * jax.random.uniform(key, score.shape)
        return jnp.argmax(jnp.where(legal, score + tie_break, -jnp.inf)).astype(jnp.int32)

    return select


def search(
    env: pgx.Env,
    states: pgx.State,
    key: jax.Array,
    num_simulations: int,
    exploration: float = DEFAULT_EXPLORATION,
) -> mctx.Tree:
    """UCT with random rollouts from a batch of pgx states ``[B]``: the finished mctx tree
    (``tree.summary().visit_counts`` are the root's visits ``[B, num_actions]``)."""
    root_key, search_key = jax.random.split(key)
    batch = states.legal_action_mask.shape[0]
    root_keys = jax.random.split(root_key, batch)
    root = mctx.RootFnOutput(
        prior_logits=jnp.zeros(states.legal_action_mask.shape, jnp.float32),
        value=jax.vmap(lambda s, k: rollout_return(env, s, k))(states, root_keys),
        embedding=states,
    )
    select = _uct_selection(exploration)
    return mctx.search(
        params=None,
        rng_key=search_key,
        root=root,
        recurrent_fn=_recurrent_fn(env),
        root_action_selection_fn=lambda key, tree, node: select(key, tree, node, jnp.int32(0)),
        interior_action_selection_fn=select,
        num_simulations=num_simulations,
        invalid_actions=~states.legal_action_mask,
    )


def most_visited_action(tree: mctx.Tree, legal: jax.Array, key: jax.Array) -> jax.Array:
    """The root's most visited legal action ``[B]``, ties broken at random."""
    visits = tree.summary().visit_counts
    tie_break = jax.random.uniform(key, visits.shape)
    return jnp.argmax(jnp.where(legal, visits + tie_break, -jnp.inf), axis=-1).astype(jnp.int32)


def rollout_mcts_player(
    env: pgx.Env, num_simulations: int, exploration: float = DEFAULT_EXPLORATION
) -> Player:
    """A player for one pgx state (``envs.games.match.Player``): UCT with random rollouts and
    ``num_simulations`` simulations, playing the root's most visited legal move."""
    if num_simulations < 1:
        raise ValueError(f"num_simulations must be at least 1, got {num_simulations}")

    def player(state: pgx.State, key: jax.Array) -> jax.Array:
        search_key, choice_key = jax.random.split(key)
        states = jax.tree.map(lambda leaf: leaf[None], state)
        tree = search(env, states, search_key, num_simulations, exploration)
        return most_visited_action(tree, states.legal_action_mask, choice_key)[0]

    return player
