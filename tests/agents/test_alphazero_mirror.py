"""AlphaZero's left-right mirrors (``Config.mirror``): the mirrored actions are pgx's own (a game
played with every move mirrored shows the mirrored board and legal moves at every step, and ends
the same), ``parts.mirrored`` flips exactly the positions it is asked to, and an update on
positions that are their own mirrors is the same with the option as without it."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.agents import alphazero
from rl_jax.agents import alphazero_parts as parts

SMALL = alphazero.Config(
    env_id="pgx/tic_tac_toe", num_envs=4, num_simulations=4, buffer_size=64, batch_size=16,
    updates_per_iteration=1, iterations_per_chunk=1, num_eval_games=2, hidden=(16,),
)  # fmt: skip


@pytest.mark.parametrize("game", sorted(parts.MIRRORED_ACTIONS))
def test_a_game_played_mirrored_shows_the_mirrored_board_at_every_step(game: str) -> None:
    env = alphazero.Config(env_id=f"pgx/{game}").make_game()
    order = np.asarray(parts.MIRRORED_ACTIONS[game])
    assert sorted(order) == list(range(env.num_actions))
    assert np.array_equal(order[order], np.arange(env.num_actions))  # its own inverse
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    for game_index in range(3):
        state = mirror = env.init(jax.random.key(game_index))  # the same player opens both
        while not bool(state.terminated):
            assert np.array_equal(np.asarray(mirror.observation), np.flip(state.observation, -2))
            legal = np.asarray(state.legal_action_mask)
            assert np.array_equal(np.asarray(mirror.legal_action_mask), legal[order])
            action = int(rng.choice(np.flatnonzero(legal)))
            state, mirror = step(state, action), step(mirror, int(order[action]))
        assert bool(mirror.terminated)
        assert np.array_equal(np.asarray(mirror.rewards), np.asarray(state.rewards))


def test_mirrored_flips_the_chosen_positions_only() -> None:
    rng = np.random.default_rng(1)
    obs = rng.integers(0, 2, (5, 6, 7, 2)).astype(bool)
    legal = rng.integers(0, 2, (5, 7)).astype(bool)
    policy = rng.random((5, 7)).astype(np.float32)
    flip = np.array([True, False, True, False, False])
    order = parts.MIRRORED_ACTIONS["connect_four"]
    got = parts.mirrored(jnp.asarray(flip), *map(jnp.asarray, (obs, legal, policy)), order)
    for i in range(5):
        want = (obs[i, :, ::-1], legal[i, ::-1], policy[i, ::-1]) if flip[i] else (
            obs[i], legal[i], policy[i]
        )  # fmt: skip
        for array, expected in zip(got, want, strict=True):
            assert np.array_equal(np.asarray(array[i]), expected)


def test_an_update_on_positions_that_are_their_own_mirrors_is_unchanged() -> None:
    """The empty board, with a policy target and legal moves symmetric about the middle column:
    a mirror changes nothing, so the option must not either (the rows drawn are the same)."""
    state = alphazero.init(jax.random.key(0), SMALL, alphazero.default_hyperparams(SMALL.env_id))
    empty = alphazero.Config(env_id=SMALL.env_id).make_game().init(jax.random.key(0))
    size = SMALL.buffer_size
    policy = jnp.asarray([0.1, 0.05, 0.1, 0.15, 0.2, 0.15, 0.1, 0.05, 0.1])
    replay = state.replay._replace(
        obs=jnp.broadcast_to(empty.observation, state.replay.obs.shape),
        legal=jnp.ones_like(state.replay.legal),
        policy=jnp.broadcast_to(policy, state.replay.policy.shape),
        value=jnp.full((size,), 0.5),
        weight=jnp.ones((size,)),
        value_weight=jnp.ones((size,)),
        size=jnp.int32(size),
    )
    hparams = alphazero.default_hyperparams(SMALL.env_id)
    key = jax.random.key(3)
    plain, _ = alphazero.update(state.agent, replay, key, hparams, SMALL)
    mirrored, _ = alphazero.update(
        state.agent, replay, key, hparams, dataclasses.replace(SMALL, mirror=True)
    )
    leaves = zip(jax.tree.leaves(plain.params), jax.tree.leaves(mirrored.params), strict=True)
    assert all(np.array_equal(a, b) for a, b in leaves)
    # and a position that is not its own mirror does change: the option is not a no-op
    lopsided = replay._replace(policy=jnp.broadcast_to(jnp.eye(9)[0], replay.policy.shape))
    plain, _ = alphazero.update(state.agent, lopsided, key, hparams, SMALL)
    mirrored, _ = alphazero.update(
        state.agent, lopsided, key, hparams, dataclasses.replace(SMALL, mirror=True)
    )
    leaves = zip(jax.tree.leaves(plain.params), jax.tree.leaves(mirrored.params), strict=True)
    assert not all(np.array_equal(a, b) for a, b in leaves)


def test_mirror_needs_a_game_with_the_symmetry() -> None:
    with pytest.raises(ValueError, match="mirror needs a game with a left-right symmetry"):
        alphazero.Config(env_id="pgx/othello", mirror=True)
    assert not alphazero.Config().mirror
