"""rl_jax.training.frame_replay: stacks rebuilt from single frames equal the env's own observations,
across episode starts (termination and truncation) and after the ring wraps, in n-step windows,
under uniform and prioritized rows; and the memory it takes is what the run's plan counts."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax import envs
from rl_jax.agents.dqn import dqn
from rl_jax.envs.classic.cartpole_pixels import CartPolePixels
from rl_jax.run.plan import memory_breakdown
from rl_jax.training import frame_replay, prioritized, replay
from rl_jax.training.replay import Transition

WIDTH, STEPS, CAPACITY_ROWS, LIMIT = 3, 70, 25, 9


def _env():
    env = CartPolePixels(frame_size=12, frame_stack=4)
    env.max_episode_steps = LIMIT  # short episodes: truncations as well as terminations
    return envs.AutoReset(env)


# A pole that falls past 4 degrees ends the episode: terminations come often too.
PARAMS = CartPolePixels().default_params.replace(theta_threshold_radians=np.float32(0.07))


@pytest.fixture(scope="module")
def played():
    """``STEPS`` steps of ``WIDTH`` envs with random actions, as the off-policy loop stores them
    (obs, action, reward, true next obs, flags), leaves ``[STEPS, WIDTH, ...]``."""
    env = _env()
    keys = jax.random.split(jax.random.key(0), WIDTH)
    state, ts = jax.vmap(env.reset, (0, None))(keys, PARAMS)

    def step(carry, key):
        state, obs = carry
        action_key, step_key = jax.random.split(key)
        actions = jax.random.randint(action_key, (WIDTH,), 0, 2)
        step_keys = jax.random.split(step_key, WIDTH)
        state, ts = jax.vmap(env.step, (0, 0, 0, None))(step_keys, state, actions, PARAMS)
        transition = Transition(
            obs, actions, ts.reward, ts.info["final_obs"], ts.terminated, ts.truncated
        )
        return (state, ts.obs), transition

    keys = jax.random.split(jax.random.key(1), STEPS)
    return jax.jit(lambda c: jax.lax.scan(step, c, keys)[1])((state, ts.obs))


def _fill(played, prioritize: bool):
    example = jax.tree.map(lambda leaf: leaf[0, 0], played)
    capacity = CAPACITY_ROWS * WIDTH
    if prioritize:
        init_rows = lambda row: prioritized.init(row, capacity, WIDTH)  # noqa: E731
        add_rows = lambda rows, batch: prioritized.add(rows, batch, 0.6)  # noqa: E731
    else:
        init_rows = lambda row: replay.init(row, capacity, WIDTH)  # noqa: E731
        add_rows = replay.add
    buffer = frame_replay.init(example, init_rows)

    def add(buffer, batch):
        return frame_replay.add(buffer, batch, add_rows), None

    return jax.jit(lambda b: jax.lax.scan(add, b, played)[0])(buffer)


def test_the_played_steps_cross_every_kind_of_episode_boundary(played):
    assert played.obs.dtype == jnp.uint8 and played.obs.shape == (STEPS, WIDTH, 12, 12, 4)
    kept = slice(STEPS - CAPACITY_ROWS, STEPS)  # what the buffer holds at the end
    assert int(played.terminated[kept].sum()) >= 3 and int(played.truncated[kept].sum()) >= 3
    assert STEPS > CAPACITY_ROWS + 4  # the ring wrapped: the oldest rows' history was evicted


@pytest.mark.parametrize("prioritize", [False, True])
def test_rebuilt_windows_equal_the_stored_transitions(played, prioritize):
    buffer = _fill(played, prioritize)
    rows = jnp.repeat(jnp.arange(CAPACITY_ROWS, dtype=jnp.int32), WIDTH)
    columns = jnp.tile(jnp.arange(WIDTH, dtype=jnp.int32), CAPACITY_ROWS)
    window, stored = replay.gather_windows(buffer.storage, rows, columns, 3)
    rebuilt = frame_replay.transitions(buffer, window, rows, columns)
    steps = np.asarray(frame_replay.global_steps(buffer, rows))
    assert sorted(set(steps.tolist())) == list(range(STEPS - CAPACITY_ROWS, STEPS))
    checked = 0
    for i, (step, column) in enumerate(zip(steps, np.asarray(columns), strict=True)):
        for k in range(3):
            if not stored[i, k]:
                continue
            truth = jax.tree.map(lambda leaf, s=step + k, c=column: np.asarray(leaf[s, c]), played)
            ours = jax.tree.map(lambda leaf, i=i, k=k: np.asarray(leaf[i, k]), rebuilt)
            for name in Transition._fields:
                np.testing.assert_array_equal(getattr(ours, name), getattr(truth, name), name)
            checked += 1
    assert checked == WIDTH * (3 * CAPACITY_ROWS - 3)  # the last two rows' windows run out


def test_a_reset_obs_rebuilds_as_its_first_frame_repeated(played):
    buffer = _fill(played, prioritize=False)
    ended = np.asarray(played.terminated | played.truncated)
    step, column = [(s + 1, c) for s, c in zip(*np.nonzero(ended), strict=True) if s > 50][0]
    obs = frame_replay.stacks(buffer, jnp.int32(step), jnp.int32(column))
    first = np.asarray(played.obs[step, column, ..., -1])
    assert np.all(np.asarray(obs) == first[..., None])
    # The previous step's obs belongs to the other episode: nothing of it leaks in.
    assert not np.array_equal(np.asarray(played.obs[step - 1, column, ..., -1]), first)


def test_memory_is_two_frames_per_transition_and_the_plan_counts_it():
    config = dqn.default_config(
        "rl_jax/CartPolePixels-v1", buffer_size=1000, num_envs=4, frame_size=84
    )
    state = jax.eval_shape(
        lambda key: dqn.init(key, config, dqn.default_hyperparams()), jax.random.key(0)
    )
    frame, rows = 84 * 84, 250
    # obs frames (+3 slots of history) with their ended flag; next frame, action, reward, flags.
    expected = (rows + 3) * 4 * (frame + 1) + rows * 4 * (frame + 4 + 4 + 1 + 1) + 3 * 4
    assert dict(memory_breakdown(state))["buffer"] == expected
    two_uint8_stacks = 1000 * 2 * 4 * frame
    assert expected < 0.26 * two_uint8_stacks
