"""AlphaZero's continuous self-play (``Config.self_play_steps`` > 0): the reset-aware targets and
value weights against a plain-Python reference on slots holding several games back to back, the
packed replay writes (wrapping the ring's end), and short train chunks on tic-tac-toe (only
played positions of finished games stored, every search a live move, deterministic, resumed bit
for bit from a checkpoint). No update runs while the replay is empty; a game cut at
max_game_length restarts and is stored as a draw; each game's moves are numbered from its own
opening. The default (whole games) is checked to keep its state's layout."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, cast

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.agents import alphazero
from rl_jax.agents import alphazero_parts as parts
from rl_jax.run.checkpoint import Checkpointer

GAME = "pgx/tic_tac_toe"
# tiny and quick; 4 moves per slot and iteration, so most games span two or three iterations
CONTINUOUS = alphazero.Config(
    env_id=GAME, num_envs=8, num_simulations=4, buffer_size=500, batch_size=32,
    updates_per_iteration=2, iterations_per_chunk=3, num_eval_games=4, hidden=(16,),
    self_play_steps=4,
)  # fmt: skip
HPARAMS = cast(alphazero.Hyperparams, alphazero.default_hyperparams(GAME))


@functools.cache
def _train_chunk() -> Callable[..., Any]:
    return jax.jit(alphazero.train_chunk, static_argnums=1)


# ---- the reset-aware targets against a plain-Python reference ---------------------------------
# A game: (movers, winner (a player id; None: a draw), explored moves, finished). A slot: its
# rows without a move first (``empty``), then its games back to back.
Game = tuple[list[int], int | None, set[int], bool]
Slot = tuple[int, list[Game]]


def _trajectory(slots: list[Slot]) -> tuple[np.ndarray, ...]:
    """``(rewards [T, B, 2], player, alive, ended, explored)`` of the slots and the reference
    ``(targets, value weights)`` ``[T, B]``, worked out game by game."""
    length = max(empty + sum(len(g[0]) for g in games) for empty, games in slots)
    shape = (length, len(slots))
    rewards = np.zeros((*shape, 2), np.float32)
    player, alive, ended, explored = (np.zeros(shape, np.float32) for _ in range(4))
    targets, weights = np.zeros(shape, np.float32), np.zeros(shape, np.float32)
    for b, (empty, games) in enumerate(slots):
        t = empty
        for movers, winner, random_moves, finished in games:
            last = t + len(movers) - 1
            for i, mover in enumerate(movers):
                player[t + i, b], alive[t + i, b] = mover, 1.0
                explored[t + i, b] = float(i in random_moves)
                if finished:
                    outcome = 0.0 if winner is None else (1.0 if mover == winner else -1.0)
                    targets[t + i, b] = outcome
                    weights[t + i, b] = float(not any(j >= i for j in random_moves))
            if finished:
                ended[last, b] = 1.0
                if winner is not None:
                    rewards[last, b, winner], rewards[last, b, 1 - winner] = 1.0, -1.0
            t = last + 1
    return rewards, player.astype(np.int32), alive, ended, explored, targets, weights


def _alternating(first: int, moves: int) -> list[int]:
    return [(first + i) % 2 for i in range(moves)]


HAND_MADE: list[Slot] = [
    # player 0 wins in 5, player 1 (opening) wins in 6, then a game unfinished after 3 moves
    (0, [(_alternating(0, 5), 0, set(), True), (_alternating(1, 6), 1, set(), True),
         (_alternating(0, 3), None, set(), False)]),
    # 2 rows without a move (a carried game shorter than the carry), then a draw in 9 with a
    # random 4th move, a win of the replier in 4 with a random last move, and a 1-move game
    (2, [(_alternating(1, 9), None, {3}, True), (_alternating(0, 4), 1, {3}, True),
         (_alternating(1, 1), 1, set(), True)]),
    # one unfinished game that fills the slot
    (0, [(_alternating(0, 16), None, {2}, False)]),
    # the window ends exactly at a game's end; a random move in the next game does not reach it
    (3, [(_alternating(0, 7), 0, set(), True), (_alternating(1, 6), 0, {0, 5}, True)]),
]  # fmt: skip


def _random_slots(rng: np.random.Generator, count: int) -> list[Slot]:
    slots = []
    for _ in range(count):
        games: list[Game] = []
        for _ in range(int(rng.integers(1, 5))):
            moves = int(rng.integers(1, 10))
            winner = [None, 0, 1][int(rng.integers(3))]
            random_moves = {i for i in range(moves) if rng.random() < 0.15}
            games.append((_alternating(int(rng.integers(2)), moves), winner, random_moves, True))
        if rng.random() < 0.6:  # the slot's last game runs past the window's end
            movers, winner, random_moves, _ = games[-1]
            games[-1] = (movers, None, random_moves, False)
        slots.append((int(rng.integers(0, 4)), games))
    return slots


def _finished(slots: list[Slot], shape: tuple[int, ...]) -> np.ndarray:
    """``[T, B]`` 1 for the moves of the slots' finished games."""
    reference = np.zeros(shape, np.float32)
    for b, (empty, games) in enumerate(slots):
        t = empty
        for movers, _, _, done in games:
            reference[t : t + len(movers), b] = float(done)
            t += len(movers)
    return reference


@pytest.mark.parametrize("case", ["hand-made", "random"])
def test_reset_aware_targets_and_value_weights_match_a_game_by_game_reference(case: str) -> None:
    slots = HAND_MADE if case == "hand-made" else _random_slots(np.random.default_rng(0), 12)
    rewards, player, alive, ended, explored, targets, weights = _trajectory(slots)
    got_targets = jax.jit(parts.game_value_targets)(rewards, player, alive, ended)
    got_weights = jax.jit(parts.game_played_on)(explored, alive, ended)
    np.testing.assert_array_equal(got_targets, targets)
    np.testing.assert_array_equal(got_weights, weights)
    finished = parts.game_finished(jnp.asarray(ended), jnp.asarray(alive))
    np.testing.assert_array_equal(finished, _finished(slots, alive.shape))
    if case == "hand-made":  # the first slot, spelt out
        np.testing.assert_array_equal(
            targets[:14, 0], [1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, 0, 0, 0]
        )
        np.testing.assert_array_equal(weights[:, 1], [0] * 6 + [1] * 5 + [0] * 4 + [1])


def test_compacted_rows_pack_the_kept_entries_and_wrap() -> None:
    keep = jnp.array([1, 0, 1, 1, 0, 1, 0])
    rows = parts.compacted_rows(keep, jnp.int32(8), 10)
    np.testing.assert_array_equal(rows, [8, 10, 9, 0, 10, 1, 10])  # 10: dropped (out of range)
    target = jnp.zeros(10).at[rows].set(jnp.arange(1.0, 8.0), mode="drop")
    np.testing.assert_array_equal(target, [4, 6, 0, 0, 0, 0, 0, 0, 1, 3])


@pytest.mark.parametrize("search_value_weight", [0.0, 0.25])
def test_replay_add_games_packs_the_finished_games_across_the_ring_end(
    search_value_weight: float,
) -> None:
    rewards, player, alive, ended, explored, targets, weights = _trajectory(HAND_MADE)
    config = dataclasses.replace(CONTINUOUS, search_value_weight=search_value_weight)
    steps, slots = alive.shape
    ids = np.arange(1, steps * slots + 1, dtype=np.int32).reshape(steps, slots)  # a move's id
    actions = 2
    positions = alphazero.Positions(
        obs=jnp.asarray(ids[..., None]),
        legal=jnp.asarray(np.stack([ids % 2 == 0, ids % 3 == 0], axis=-1)),
        policy=jnp.asarray(np.stack([ids, -ids], axis=-1).astype(np.float32)),
        player=jnp.asarray(player), rewards=jnp.asarray(rewards), alive=jnp.asarray(alive),
        explored=jnp.asarray(explored), ended=jnp.asarray(ended),
        # the search's value of each move's position, where the option mixes it in
        search_value=jnp.asarray(ids / 100.0, jnp.float32) if search_value_weight else None,
    )  # fmt: skip
    if search_value_weight:  # the outcome and the search's value, mixed on the moves made
        targets = (1 - search_value_weight) * targets + search_value_weight * ids / 100.0 * alive
    capacity, start, carried_rows = 64, 50, 8
    old = -7.0  # what the rows the write must leave alone hold
    replay = alphazero.Replay(
        obs=jnp.full((capacity, 1), -7, jnp.int32),
        legal=jnp.zeros((capacity, actions), jnp.bool_),
        policy=jnp.full((capacity, actions), old),
        value=jnp.full((capacity,), old),
        weight=jnp.full((capacity,), old),
        value_weight=jnp.full((capacity,), old),
        position=jnp.int32(start),
        size=jnp.int32(start),
    )
    add = jax.jit(alphazero.replay_add_games, static_argnums=(2, 3))
    replay, unfinished, count = add(replay, positions, carried_rows, config)
    # the finished games' moves, time-major as the write flattens them: 11 + 14 + 0 + 13
    finished = _finished(HAND_MADE, alive.shape)
    kept = finished.reshape(-1) > 0
    assert int(count) == kept.sum() == 38
    rows = (start + np.arange(38)) % capacity  # 50..63, then 0..23
    replay = jax.tree.map(np.asarray, replay)
    np.testing.assert_array_equal(replay.obs[rows, 0], ids.reshape(-1)[kept])
    np.testing.assert_array_equal(replay.policy[rows, 0], ids.reshape(-1)[kept])
    np.testing.assert_array_equal(replay.legal[rows, 1], ids.reshape(-1)[kept] % 3 == 0)
    np.testing.assert_allclose(replay.value[rows], targets.reshape(-1)[kept], rtol=1e-6)
    np.testing.assert_array_equal(replay.value_weight[rows], weights.reshape(-1)[kept])
    np.testing.assert_array_equal(replay.weight[rows], 1.0)
    untouched = np.setdiff1d(np.arange(capacity), rows)  # 24..49
    np.testing.assert_array_equal(untouched, np.arange(24, 50))
    np.testing.assert_array_equal(replay.value[untouched], old)
    np.testing.assert_array_equal(replay.obs[untouched], -7)
    assert int(replay.position) == (start + 38) % capacity == 24
    assert int(replay.size) == capacity
    # carried on: the last 8 rows, alive only on the moves of the unfinished games (slot 0's
    # 3-move game at rows 11..13, slot 2's 16-move game throughout)
    np.testing.assert_array_equal(unfinished.obs[..., 0], ids[-carried_rows:])
    if search_value_weight:  # an unfinished game keeps its search values until it ends
        np.testing.assert_allclose(unfinished.search_value, ids[-carried_rows:] / 100.0)
    else:
        assert unfinished.search_value is None
    expected = np.zeros((carried_rows, slots), np.float32)
    expected[3:6, 0], expected[:, 2] = 1.0, 1.0
    np.testing.assert_array_equal(unfinished.alive, expected)
    np.testing.assert_array_equal(unfinished.alive, (alive * (1 - finished))[-carried_rows:])


# ---- the option -------------------------------------------------------------------------------
def test_settings_are_validated_and_the_default_keeps_whole_games() -> None:
    with pytest.raises(ValueError, match="self_play_steps must be >= 0"):
        alphazero.Config(self_play_steps=-1)
    # 64 slots x (10 moves + 8 carried) = 1,152 rows may end in one iteration
    with pytest.raises(ValueError, match=r"\(self_play_steps \+ max_game_length - 1\) = 1152"):
        alphazero.Config(self_play_steps=10, buffer_size=1_000)
    default = alphazero.default_config(GAME)
    assert default.self_play_steps == 0 and default.slot_moves() == default.max_game_length
    assert alphazero.alphazero.env_steps_per_chunk(default) == 64 * 9 * 4
    # the default state has no games in progress: its leaves (and so its checkpoints) are those
    # of agent, replay, key, clock and moves_played alone
    state = jax.eval_shape(lambda: alphazero.init(jax.random.key(0), default, HPARAMS))
    assert state.games is None
    fields = (state.agent, state.replay, state.key, state.clock, state.moves_played)
    assert len(jax.tree.leaves(state)) == len(jax.tree.leaves(fields))
    assert alphazero.alphazero.env_steps_per_chunk(CONTINUOUS) == 8 * 4 * 3


def test_continuous_self_play_restarts_finished_games_at_once() -> None:
    config = dataclasses.replace(CONTINUOUS, self_play_steps=12)
    state = alphazero.init(jax.random.key(0), config, HPARAMS)
    assert state.games is not None
    play = jax.jit(alphazero.continuous_self_play, static_argnums=3)
    states, positions = play(
        state.agent.params, state.games.states, jax.random.key(1), config, HPARAMS
    )
    # every move is a live one, and a move that ends a game is followed by an empty board
    np.testing.assert_array_equal(positions.alive, 1.0)
    ended = np.asarray(positions.ended) > 0
    assert ended[:-1].any()
    np.testing.assert_array_equal(np.asarray(positions.legal)[1:][ended[:-1]], True)
    np.testing.assert_array_equal(np.asarray(positions.obs)[1:][ended[:-1]], False)
    # each slot's game has played the moves since its last end
    since = [11 - int(np.nonzero(column)[0].max()) for column in ended.T]  # all ended by move 9
    np.testing.assert_array_equal(states._step_count, since)


def _assert_equal(one: object, other: object) -> None:
    """Two states equal bit for bit, leaf by leaf (PRNG keys by their data)."""
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(other), strict=True):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(a, b)


def _check_replay(state: alphazero.TrainState) -> None:
    size = int(state.replay.size)
    assert 0 < size < CONTINUOUS.buffer_size  # not wrapped: every row below size was written
    replay = jax.tree.map(np.asarray, state.replay)
    np.testing.assert_array_equal(replay.weight[:size], 1.0)  # no idle row
    assert replay.legal[:size].any(axis=1).all()
    np.testing.assert_allclose(replay.policy[:size].sum(axis=1), 1.0, rtol=1e-5)
    assert set(np.unique(replay.value[:size])) <= {-1.0, 0.0, 1.0}
    assert set(np.unique(replay.value_weight[:size])) <= {0.0, 1.0}
    np.testing.assert_array_equal(replay.weight[size:], 0.0)
    # the carried positions of each slot are its unfinished game's moves, as the last rows
    assert state.games is not None
    alive = np.asarray(state.games.unfinished.alive)
    np.testing.assert_array_equal(np.diff(alive, axis=0) >= 0, True)
    np.testing.assert_array_equal(alive.sum(axis=0), state.games.states._step_count)


def test_a_continuous_chunk_stores_only_finished_games_and_is_deterministic() -> None:
    config = CONTINUOUS
    state = alphazero.init(jax.random.key(0), config, HPARAMS)
    first, metrics = _train_chunk()(state, config, HPARAMS)
    again, _ = _train_chunk()(state, config, HPARAMS)
    _assert_equal(first, again)
    steps = config.num_envs * config.self_play_steps * config.iterations_per_chunk
    assert int(metrics.env_steps) == steps == int(first.moves_played)  # every slot live
    assert int(metrics.env_steps) == alphazero.alphazero.env_steps_per_chunk(config)
    stored = float(metrics.extra["positions_stored"]) * config.iterations_per_chunk
    assert int(first.replay.size) == round(stored) == int(first.replay.position)
    # every move played so far is stored or carried in an unfinished game
    assert first.games is not None
    carried = int(np.sum(first.games.unfinished.alive))
    assert int(first.replay.size) + carried == steps
    for name in ("policy_loss", "value_loss", "grad_norm"):
        assert np.isfinite(float(metrics.extra[name])), name
    _check_replay(first)


def test_a_chunk_mixing_in_the_search_value_plays_the_same_games() -> None:
    # one iteration: both runs play from the same network, so they store the same positions,
    # and the mixed run's value targets are half the outcome plus half a search value in [-1, 1]
    plain = dataclasses.replace(CONTINUOUS, iterations_per_chunk=1, self_play_steps=9)
    mixed = dataclasses.replace(plain, search_value_weight=0.5)
    ours, metrics = _train_chunk()(
        alphazero.init(jax.random.key(0), mixed, HPARAMS), mixed, HPARAMS
    )
    theirs, _ = _train_chunk()(alphazero.init(jax.random.key(0), plain, HPARAMS), plain, HPARAMS)
    size = int(theirs.replay.size)
    assert size > 0 and int(ours.replay.size) == size
    replay, reference = (
        jax.tree.map(np.asarray, ours.replay),
        jax.tree.map(np.asarray, theirs.replay),
    )
    np.testing.assert_array_equal(replay.obs[:size], reference.obs[:size])
    np.testing.assert_array_equal(replay.policy[:size], reference.policy[:size])
    search_value = 2.0 * (replay.value[:size] - 0.5 * reference.value[:size])
    assert np.all(np.abs(search_value) <= 1.0 + 1e-6)
    assert not set(np.unique(replay.value[:size])) <= {-1.0, 0.0, 1.0}
    assert ours.games is not None and ours.games.unfinished.search_value is not None
    for name in ("policy_loss", "value_loss", "grad_norm"):
        assert np.isfinite(float(metrics.extra[name])), name


def test_a_continuous_run_resumes_bit_for_bit_from_a_checkpoint(tmp_path) -> None:
    config = CONTINUOUS
    state = alphazero.init(jax.random.key(1), config, HPARAMS)
    state, _ = _train_chunk()(state, config, HPARAMS)
    straight, _ = _train_chunk()(state, config, HPARAMS)
    checkpointer = Checkpointer(tmp_path / "checkpoints")
    checkpointer.save(1, state)
    template = jax.eval_shape(lambda: alphazero.init(jax.random.key(1), config, HPARAMS))
    restored, _ = checkpointer.restore(template)
    resumed, _ = _train_chunk()(restored, config, HPARAMS)
    _assert_equal(straight, resumed)
    _check_replay(resumed)


def test_chunk_means_average_the_update_metrics_over_iterations_that_updated() -> None:
    # iterations 0 and 2 skipped their updates (empty replay): their zeros do not count
    metrics = {
        "policy_loss": jnp.array([0.0, 2.0, 0.0, 4.0]),
        "positions_stored": jnp.array([0.0, 6.0, 0.0, 2.0]),
        "updated": jnp.array([0.0, 1.0, 0.0, 1.0]),
    }
    means = {name: float(value) for name, value in alphazero.chunk_means(metrics).items()}
    assert means == {"policy_loss": 3.0, "positions_stored": 2.0, "updated": 0.5}
    none = {name: value * 0 for name, value in metrics.items()}
    assert float(alphazero.chunk_means(none)["policy_loss"]) == 0.0
    # whole-game self-play has no flag: plain means, as before
    plain = {"policy_loss": metrics["policy_loss"]}
    assert float(alphazero.chunk_means(plain)["policy_loss"]) == 1.5


# 2 moves per slot and iteration, games cut after 4 moves (no tic-tac-toe game ends by itself
# that early): no game ends in the first iteration, every slot's ends in the second
CUT = dataclasses.replace(CONTINUOUS, max_game_length=4, self_play_steps=2)


@functools.cache
def _train_iteration() -> Callable[..., Any]:
    return jax.jit(alphazero.train_iteration, static_argnums=1)


def test_updates_wait_for_the_first_finished_game() -> None:
    state = alphazero.init(jax.random.key(2), CUT, HPARAMS)
    after, metrics = _train_iteration()(state, CUT, HPARAMS)
    assert int(after.replay.size) == 0 and int(metrics["positions_stored"]) == 0
    _assert_equal(after.agent.params, state.agent.params)
    _assert_equal(after.agent.opt_state, state.agent.opt_state)
    for name in ("policy_loss", "value_loss", "grad_norm"):
        assert float(metrics[name]) == 0.0, name
    assert int(after.moves_played) == CUT.num_envs * CUT.self_play_steps
    # once games have ended the updates run
    after, _ = _train_iteration()(after, CUT, HPARAMS)
    assert int(after.replay.size) > 0
    moved = jax.tree.map(lambda a, b: bool(jnp.any(a != b)), after.agent.params, state.agent.params)
    assert all(jax.tree.leaves(moved))


def test_games_cut_at_max_game_length_restart_and_store_outcome_zero() -> None:
    # every game is cut after its 4th move, as a draw (value target 0), with no random move
    # (value weight 1)
    no_random = np.zeros_like(HPARAMS.random_move_prob)  # the same type: no recompiling
    hparams = dataclasses.replace(HPARAMS, random_move_prob=no_random)
    state = alphazero.init(jax.random.key(3), CUT, hparams)
    slots, sizes, counts = CUT.num_envs, [], []
    for _ in range(4):
        state, _ = _train_iteration()(state, CUT, hparams)
        assert state.games is not None
        assert not np.asarray(state.games.states.terminated).any()
        sizes.append(int(state.replay.size))
        counts.append(np.asarray(state.games.states._step_count))
    # each slot restarts after 4 moves: its game's move count runs 2, 0 (fresh), 2, 0
    np.testing.assert_array_equal(np.stack(counts), np.repeat([[2], [0], [2], [0]], slots, axis=1))
    assert sizes == [0, 4 * slots, 4 * slots, 8 * slots]
    stored = 8 * slots
    replay = jax.tree.map(np.asarray, state.replay)
    np.testing.assert_array_equal(replay.value[:stored], 0.0)
    np.testing.assert_array_equal(replay.weight[:stored], 1.0)
    np.testing.assert_array_equal(replay.value_weight[:stored], 1.0)
    # stored move by move (all slots each): the 5th stored move of a slot opens a fresh game
    marks = replay.obs[:stored].reshape(8, slots, -1).sum(axis=-1)
    np.testing.assert_array_equal(marks, np.repeat([[0], [1], [2], [3]] * 2, slots, axis=1))


def test_sampled_moves_count_from_each_games_own_opening(monkeypatch) -> None:
    # the move number each searched move is given (it decides whether the move is sampled from
    # the improved policy), recorded in place of the explored flag
    play_move = alphazero._play_move

    def recording(*args: Any) -> tuple[Any, alphazero.Positions]:
        states, played = play_move(*args)
        return states, played._replace(explored=args[3].astype(jnp.float32))

    monkeypatch.setattr(alphazero, "_play_move", recording)
    config = dataclasses.replace(CONTINUOUS, self_play_steps=7)
    state = alphazero.init(jax.random.key(5), config, HPARAMS)
    assert state.games is not None

    def window(states: Any, key: jax.Array) -> tuple[Any, alphazero.Positions]:
        return alphazero.continuous_self_play(state.agent.params, states, key, config, HPARAMS)

    play = jax.jit(window)
    states, first = play(state.games.states, jax.random.key(6))
    _, second = play(states, jax.random.key(7))
    numbers = np.concatenate([first.explored, second.explored]).astype(int)
    ended = np.concatenate([first.ended, second.ended]) > 0
    # each game's moves are numbered 0, 1, 2, ... from its own opening, across the windows
    expected = np.zeros_like(numbers)
    for t in range(1, len(numbers)):
        expected[t] = np.where(ended[t - 1], 0, expected[t - 1] + 1)
    np.testing.assert_array_equal(numbers, expected)
    # games end at different moves in different slots: the window's step index is not it
    assert (numbers != np.arange(len(numbers))[:, None]).any(axis=0).all()
    assert (numbers[config.self_play_steps :] != np.arange(config.self_play_steps)[:, None]).any()
