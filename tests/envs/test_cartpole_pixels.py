"""rl_jax/CartPolePixels-v1: CartPole-v1's dynamics step for step, frames drawn in JAX that match
gymnasium's own rendering after the same preprocessing, stacking, jit/vmap, gymnasium checks.

Frame bound. Our frame and gymnasium's ``rgb_array`` frame of the same state, both grayscale
(ITU-R 601 luma) and area-averaged to 84x84, differ by a mean absolute difference (MAD, gray
levels 0-255, over all 84x84 pixels) of 0.110 on average over 200 random states and 0.153 at
worst (measured). The renderers differ by under a screen pixel at every edge: pygame truncates
vertices to whole pixels and antialiases outlines, we supersample 4x4 points per output pixel.
The bounds, ``MEAN_MAD = 0.15`` over the states and ``MAX_MAD = 0.25`` for any one state, fail
when the geometry is off by one screen pixel: the same comparison with the cart drawn one pixel
to the right (x + 1/125 m) measures 0.195 on average, which the test checks too.
"""

import os
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gym_frames import preprocess
from gymnasium.utils.env_checker import check_env

from rl_jax import envs
from rl_jax.envs.classic.cartpole import CartPole, CartPoleParams
from rl_jax.envs.classic.cartpole_pixels import CartPolePixels, draw_frame

ENV_ID = "rl_jax/CartPolePixels-v1"
MEAN_MAD, MAX_MAD = 0.15, 0.25
ONE_PIXEL = 2 * 2.4 / 600  # metres per screen pixel at gymnasium's scale
PIXELS, PHYSICS = CartPolePixels(), CartPole()


@pytest.fixture(scope="module")
def gymnasium_frames():
    """(x, theta, preprocessed gymnasium frames) of 200 random states."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no display: pygame draws off screen
    pytest.importorskip("pygame", reason="gymnasium renders CartPole with pygame (pyproject)")
    rng = np.random.default_rng(0)
    xs = rng.uniform(-2.4, 2.4, 200).astype(np.float32)
    thetas = rng.uniform(-0.8, 0.8, 200).astype(np.float32)
    env = gymnasium.make("CartPole-v1", render_mode="rgb_array").unwrapped
    env.reset(seed=0)
    frames = []
    for x, theta in zip(xs, thetas, strict=True):
        env.state = np.array([x, 0.0, theta, 0.0], np.float64)
        frames.append(preprocess(env.render(), 84))
    env.close()
    return xs, thetas, np.stack(frames)


def _mads(xs, thetas, reference) -> np.ndarray:
    draw = jax.jit(jax.vmap(lambda x, theta: draw_frame(x, theta, CartPoleParams())))
    ours = np.asarray(draw(jnp.asarray(xs), jnp.asarray(thetas)), np.float64)
    return np.abs(ours - reference).mean(axis=(1, 2))


def test_frames_match_gymnasiums_rendering_after_the_same_preprocessing(gymnasium_frames):
    xs, thetas, reference = gymnasium_frames
    mads = _mads(xs, thetas, reference)
    assert mads.mean() < MEAN_MAD and mads.max() < MAX_MAD, (mads.mean(), mads.max())


def test_the_frame_bound_catches_a_one_pixel_error(gymnasium_frames):
    xs, thetas, reference = gymnasium_frames
    assert _mads(xs + np.float32(ONE_PIXEL), thetas, reference).mean() > MEAN_MAD


def test_gymnasiums_frames_are_white_outside_the_drawn_rows():
    """``drawn_rows`` bounds what gymnasium draws, on states up to 90 degrees from upright and
    across the track (its own renderer, not ours), and is not loose: the cart's bottom edge and the
    upright pole's tip lie in its first and last rows."""
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    pytest.importorskip("pygame", reason="gymnasium renders CartPole with pygame (pyproject)")
    env = gymnasium.make("CartPole-v1", render_mode="rgb_array").unwrapped
    env.reset(seed=0)
    size, first_seen, last_seen = 84, 84, -1
    first, stop = PIXELS.drawn_rows()
    for x in (-2.4, -1.0, 0.0, 1.7, 2.4):
        for theta in np.linspace(-np.pi / 2, np.pi / 2, 13):
            env.state = np.array([x, 0.0, theta, 0.0], np.float64)
            frame = preprocess(env.render(), size)
            drawn = np.flatnonzero((frame < 255.0 - 1e-9).any(axis=1))
            first_seen, last_seen = min(first_seen, drawn[0]), max(last_seen, drawn[-1])
    env.close()
    assert first <= first_seen and last_seen < stop, (first, stop, first_seen, last_seen)
    assert first_seen - first <= 1 and stop - 1 - last_seen <= 1, (first, stop)
    assert CartPolePixels(frame_size=42).drawn_rows() == (18, 34)


def test_drawing_only_the_rows_a_state_can_reach_changes_no_pixel():
    """With the params known while tracing (the env's defaults) only the rows any state can reach
    are computed; with traced params every row is. The frames are equal at every angle, the
    pole hanging below the track included."""
    x, theta = (
        v.ravel() for v in jnp.meshgrid(jnp.linspace(-2.4, 2.4, 7), jnp.linspace(-3.2, 3.2, 11))
    )
    params = CartPoleParams()
    known = jax.jit(jax.vmap(lambda x, theta: draw_frame(x, theta, params)))(x, theta)
    traced = jax.jit(jax.vmap(draw_frame, in_axes=(0, 0, None)))(x, theta, params)
    np.testing.assert_array_equal(np.asarray(known), np.asarray(traced))
    assert np.asarray(known)[:, 83].min() < 255  # a hanging pole reaches the bottom row


# ---- dynamics, shapes, stacking --------------------------------------------------------------
def _rollout(env, steps: int = 120, num_envs: int = 8):
    """Random actions from the same keys: (physics vectors, rewards, terminated, truncated)."""
    keys = jax.random.split(jax.random.key(3), num_envs)
    state, _ = jax.vmap(env.reset)(keys)
    actions = jax.random.randint(jax.random.key(4), (steps, num_envs), 0, 2)

    def step(state, action):
        state, ts = jax.vmap(env.step)(keys, state, action)
        physics = state.physics if hasattr(state, "physics") else state
        vector = jax.vmap(PHYSICS.state_to_vector)(physics)
        return state, (vector, ts.reward, ts.terminated, ts.truncated)

    return jax.jit(lambda s: jax.lax.scan(step, s, actions)[1])(state)


def test_dynamics_are_cartpoles_step_for_step():
    for ours, reference in zip(_rollout(PIXELS), _rollout(PHYSICS), strict=True):
        np.testing.assert_array_equal(np.asarray(ours), np.asarray(reference))


def test_obs_is_a_uint8_stack_that_shifts_by_one_frame_per_step():
    env = CartPolePixels(frame_size=32, frame_stack=3)
    state, ts = env.reset(jax.random.key(0))
    assert ts.obs.shape == (32, 32, 3) and ts.obs.dtype == jnp.uint8
    assert bool(env.observation_space().contains(ts.obs))
    assert np.all(np.asarray(ts.obs) == np.asarray(ts.obs[..., :1]))  # a reset repeats its frame
    previous = ts.obs
    for action in (1, 1, 0):
        state, ts = env.step(jax.random.key(1), state, jnp.int32(action))
        np.testing.assert_array_equal(ts.obs[..., :-1], previous[..., 1:])
        np.testing.assert_array_equal(ts.obs[..., -1], env.draw(state.physics, env.default_params))
        previous = ts.obs
    assert not np.array_equal(ts.obs[..., -1], ts.obs[..., 0])  # the cart moved


def test_frame_shows_the_cart_where_the_state_puts_it():
    left = np.asarray(draw_frame(jnp.float32(-1.5), jnp.float32(0.0), CartPoleParams()))
    right = np.asarray(draw_frame(jnp.float32(1.5), jnp.float32(0.0), CartPoleParams()))
    cart_row = left[61]  # screen rows 290.5-295.2: the cart, below the axle
    assert cart_row[: 84 // 2].min() == 0 and cart_row[84 // 2 :].min() == 255
    assert right[61][84 // 2 :].min() == 0 and right[61][: 84 // 2].min() == 255


def test_jit_equals_no_jit_and_vmap_equals_one_by_one():
    keys = jax.random.split(jax.random.key(5), 4)
    actions = jnp.array([0, 1, 1, 0], jnp.int32)
    state, _ = jax.vmap(PIXELS.reset)(keys)
    _, batched = jax.jit(jax.vmap(PIXELS.step))(keys, state, actions)
    step = jax.jit(PIXELS.step)
    for i in range(4):
        one_state, _ = jax.jit(PIXELS.reset)(keys[i])
        _, jitted = step(keys[i], one_state, actions[i])
        np.testing.assert_array_equal(np.asarray(batched.obs[i]), np.asarray(jitted.obs))
        if i == 0:  # eager dispatch is slow: one env shows it
            _, eager = PIXELS.step(keys[i], PIXELS.reset(keys[i])[0], actions[i])
            np.testing.assert_array_equal(np.asarray(eager.obs), np.asarray(jitted.obs))


# ---- gymnasium -------------------------------------------------------------------------------
def test_registered_and_passes_check_env_without_warnings():
    assert ENV_ID in envs.registered_ids()
    assert gymnasium.spec(ENV_ID).max_episode_steps == CartPolePixels.max_episode_steps == 500
    env = gymnasium.make(ENV_ID, render_mode="rgb_array")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert not caught, [str(w.message) for w in caught]  # not even CartPole-v1's infinite bounds
    obs, _ = env.reset(seed=0, options={"state": [0.5, 0.0, 0.1, 0.0]})
    assert obs.shape == (84, 84, 4) and obs.dtype == np.uint8
    assert env.render().shape == (400, 600, 3)
    small = gymnasium.make(ENV_ID, frame_size=48, frame_stack=2)
    assert small.reset(seed=1)[0].shape == (48, 48, 2)
    vector = gymnasium.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    vector.reset(seed=0)
    obs, reward, *_ = vector.step(np.array([0, 1, 1]))
    assert obs.shape == (3, 84, 84, 4) and obs.dtype == np.uint8 and reward.tolist() == [1.0] * 3
