"""Atari games through envs.from_atari (envs/adapters/atari.py): step for step against gymnasium's
``AtariPreprocessing`` + ``FrameStackObservation`` reset with the same seed, with ALE v5's sticky
actions and 30 no-op starts on (the no-op count and the sticky draws come from the generators
that ``reset(seed=...)`` seeds, so both sides start and go on alike) and with both off; the
frames' layout; vmapped, jitted and scanned stepping under AutoReset, the resets included; the
no-op count's range; episodic life and reward clipping."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax import envs
from rl_jax.envs.adapters import atari
from rl_jax.envs.core import registry

pytest.importorskip("ale_py", reason="ale-py is not installed (the atari extra)")
pytest.importorskip("cv2", reason="OpenCV is not installed (the atari extra)")


def _reference(game: str, **host) -> gymnasium.Env:
    """gymnasium's own preprocessing and stack, observed channels last as ours."""
    env = atari.host_env(game, frame_and_lives=False, **host)
    return gymnasium.wrappers.FrameStackObservation(env, 4)


def _channels_last(obs) -> np.ndarray:
    return np.moveaxis(np.asarray(obs), 0, -1)


@pytest.mark.parametrize(
    ("game", "host"),
    [
        ("Pong", {}),  # ALE v5's sticky actions (0.25) and 1-30 no-op starts
        ("Breakout", {"noop_max": 0, "repeat_action_probability": 0.0}),
    ],
)
def test_step_for_step_as_gymnasium_atari_preprocessing(game, host):
    env = atari.from_atari(game, **host)
    reference = _reference(game, **host)
    state, ts = env.reset(jax.random.key(3))
    obs, _ = reference.reset(seed=int(state.env_state.seed))
    np.testing.assert_array_equal(np.asarray(ts.obs), _channels_last(obs))
    step = jax.jit(env.step)
    actions = np.random.default_rng(0).integers(env.action_space().n, size=150)
    for t, action in enumerate(actions):
        state, ts = step(jax.random.key(t), state, jnp.int32(action))
        obs, reward, terminated, truncated, _ = reference.step(int(action))
        np.testing.assert_array_equal(np.asarray(ts.obs), _channels_last(obs), err_msg=f"step {t}")
        assert float(ts.reward) == reward
        assert bool(ts.terminated) == terminated and bool(ts.truncated) == truncated
        assert int(ts.info["lives"]) == reference.unwrapped.ale.lives()


def test_frames_are_uint8_channels_last_as_the_pixel_envs():
    env = envs.make("rl_jax/Pong-Atari")
    pixels = envs.make("rl_jax/CartPolePixels-v1")
    space = env.observation_space()
    assert space.shape == pixels.observation_space().shape == (84, 84, 4)
    assert space.dtype == pixels.observation_space().dtype == np.uint8
    assert env.action_space().n == 6  # the minimal action set
    assert env.max_episode_steps == 27_000 == registry.max_episode_steps("rl_jax/Pong-Atari")
    _, ts = env.reset(jax.random.key(0))
    assert ts.obs.shape == (84, 84, 4) and ts.obs.dtype == jnp.uint8
    # after a reset the first frame fills the stack, as FrameStackObservation's "reset" padding
    assert all(np.array_equal(ts.obs[..., 0], ts.obs[..., i]) for i in range(4))


def test_vmapped_scan_under_autoreset_restarts_as_gymnasium():
    """Episodes cut at 12 steps: each env's frames after the cut are those of gymnasium's env
    reset with the new episode's seed, and only ended envs paid for a host start."""
    limit, n_envs, steps = 12, 3, 30
    env = envs.AutoReset(atari.from_atari("Pong", max_episode_steps=limit))
    keys = jax.random.split(jax.random.key(1), n_envs)
    state, _ = jax.vmap(env.reset)(keys)
    actions = jnp.asarray(np.random.default_rng(1).integers(6, size=(steps, n_envs)), jnp.int32)

    def body(state, inputs):
        t, action = inputs
        step_keys = jax.random.split(jax.random.fold_in(jax.random.key(2), t), n_envs)
        state, ts = jax.vmap(env.step)(step_keys, state, action)
        return state, (ts.obs, ts.truncated, state.env_state.seed)

    run = jax.jit(lambda s: jax.lax.scan(body, s, (jnp.arange(steps), actions)))
    _, (obs, truncated, seeds) = run(state)
    truncated, obs, seeds = np.asarray(truncated), np.asarray(obs), np.asarray(seeds)
    assert truncated[limit - 1].all() and truncated.sum() == n_envs * (steps // limit)
    for lane in range(n_envs):
        start, _ = _reference("Pong").reset(seed=int(seeds[limit - 1, lane]))
        np.testing.assert_array_equal(obs[limit - 1, lane], _channels_last(start))
    assert seeds[0].tolist() != seeds[limit - 1].tolist()  # new episodes, new seeds


def test_no_op_starts_are_1_to_noop_max_frames():
    counts = []
    for seed in range(12):
        env = atari.host_env("Pong", noop_max=30)
        env.reset(seed=seed)
        counts.append(env.unwrapped.ale.getEpisodeFrameNumber())
    assert all(1 <= n <= 30 for n in counts) and len(set(counts)) > 4, counts
    env = atari.host_env("Pong", noop_max=0)
    env.reset(seed=0)
    assert env.unwrapped.ale.getEpisodeFrameNumber() == 0


def test_episodic_life_ends_the_episode_and_the_game_goes_on():
    env = envs.AutoReset(atari.from_atari("Breakout", episodic_life=True))
    state, ts = env.reset(jax.random.key(0))
    assert int(ts.info["lives"]) == 5
    step = jax.jit(env.step)
    rng = np.random.default_rng(0)
    for t in range(2000):
        state, ts = step(jax.random.key(t), state, jnp.int32(rng.integers(4)))
        if ts.terminated:
            break
    assert ts.terminated, "no life lost in 2000 steps"
    assert int(ts.info["lives"]) == 4  # the same game, one life fewer, not a new one
    life = state.env_state  # FrameStack's state holds EpisodicLife's
    assert not bool(life.game_over) and int(life.env_state.time) == t + 1  # the host game's steps
    # the next episode starts from the frame where the life was lost, the stack padded with it
    last = np.asarray(ts.info["final_obs"])[..., -1]
    for i in range(4):
        np.testing.assert_array_equal(np.asarray(ts.obs)[..., i], last)


def test_clip_rewards_gives_the_rewards_sign():
    plain = atari.from_atari("SpaceInvaders", repeat_action_probability=0.0)
    clipped = atari.from_atari("SpaceInvaders", repeat_action_probability=0.0, clip_rewards=True)
    key = jax.random.key(5)
    (state, _), (clipped_state, _) = plain.reset(key), clipped.reset(key)
    step, clipped_step = jax.jit(plain.step), jax.jit(clipped.step)
    rewards = []
    for t in range(150):
        action = jnp.int32(1)  # FIRE
        state, ts = step(jax.random.key(t), state, action)
        clipped_state, clipped_ts = clipped_step(jax.random.key(t), clipped_state, action)
        rewards.append((float(ts.reward), float(clipped_ts.reward)))
    assert any(r > 1 for r, _ in rewards), "no invader hit"
    assert all(c == np.sign(r) for r, c in rewards)
