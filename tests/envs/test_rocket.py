"""The 1-D rocket against its spec: a numpy implementation written here, the analytic solution,
and hand-computed rewards for every reward, termination and truncation case."""

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from rl_jax.envs.classic.rocket import Rocket, RocketSettle, draw_rocket, plot_episode

ENV = Rocket()
PARAMS = ENV.default_params
KEY = jax.random.PRNGKey(0)
EPS32 = float(np.finfo(np.float32).eps)
step = jax.jit(ENV.step)
batch_step = jax.jit(jax.vmap(ENV.step, in_axes=(None, 0, 0, None)))
batch_reset_to = jax.jit(jax.vmap(ENV.reset_to, in_axes=(0, None)))


def spec_step(x, v, u, dt=0.01, tolerance=1e-8):
    """The issue's rocket, literally, in numpy float32: returns (x, v, reward, terminated)."""
    f32 = np.float32
    dt, u = f32(dt), np.clip(f32(u), f32(-1), f32(1))
    y = np.array([x, v], f32)
    derivative = lambda y: np.array([y[1], u], f32)  # noqa: E731
    k1 = derivative(y)
    k2 = derivative(y + dt / 2 * k1)
    k3 = derivative(y + dt / 2 * k2)
    k4 = derivative(y + dt * k3)
    x, v = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    reward = 1 / (x**2 + 1)
    if x * v > 0:
        reward -= 10 * abs(v)
    else:
        reward += 1 / (v**2 + 1)
    terminated = False
    if abs(x) > 2 or abs(v) > 2:
        terminated, reward = True, reward - 500
    if np.allclose([x, v], 0, atol=tolerance):
        terminated, reward = True, reward + 500
    return x, v, reward, terminated


def one_step(x: float, v: float, u: float, params=PARAMS, time: int = 0):
    state, _ = ENV.reset_to(jnp.array([x, v]), params)
    state, timestep = step(KEY, state.replace(time=jnp.int32(time)), jnp.array([u]), params)
    return state, jax.device_get(timestep)


def test_matches_numpy_spec_on_random_pairs():
    """Tolerance: XLA's CPU backend fuses ``a + dt * b`` into one FMA (one rounding instead of
    two), so results may differ from numpy by an ulp per update: we allow 4 ulps of the state's
    magnitude. Flags must agree exactly (no state here sits within an ulp of +-2)."""
    rng = np.random.default_rng(0)
    states = rng.uniform(-2.2, 2.2, (1500, 2))
    states[:200] *= 1e-8 * rng.uniform(0, 3, (200, 1))  # around the goal tolerance
    states[200:400, 0] = rng.choice([-2, 2], 200) - rng.uniform(-0.02, 0.02, 200)  # x bound
    states[400:600, 1] = rng.choice([-2, 2], 200) - rng.uniform(-0.02, 0.02, 200)  # v bound
    states = states.astype(np.float32)
    actions = rng.uniform(-3, 3, (1500, 1)).astype(np.float32)
    actions[:200] = 0.0
    actions[600:700] = rng.choice([-1.0, 1.0], (100, 1))
    state, _ = batch_reset_to(jnp.asarray(states), PARAMS)
    _, ours = batch_step(KEY, state, jnp.asarray(actions), PARAMS)
    reference = [spec_step(s[0], s[1], a[0]) for s, a in zip(states, actions, strict=True)]
    x, v, reward, terminated = (np.array(c) for c in zip(*reference, strict=True))
    scale = 4 * EPS32 * np.maximum(1.0, np.abs(states).max(axis=1))
    np.testing.assert_array_less(np.abs(np.asarray(ours.obs[:, 0]) - x), scale + 1e-30)
    np.testing.assert_array_less(np.abs(np.asarray(ours.obs[:, 1]) - v), scale + 1e-30)
    # Reward: the state's few ulps times the reward's slope (10 |v| -> 10), plus its own rounding.
    np.testing.assert_allclose(ours.reward, reward, rtol=4 * EPS32, atol=4 * EPS32 * 20)
    np.testing.assert_array_equal(ours.terminated, terminated)
    assert not np.any(ours.truncated)
    # All cases occur: crashes, goals (the zero-thrust states near the origin) and neither.
    assert terminated[200:600].mean() > 0.3 and terminated[:200].any() and not terminated.all()


@pytest.mark.parametrize(
    ("x0", "v0", "u"), [(0.5, -0.3, 1.0), (-1.0, 0.7, -0.4), (0.9, 0.9, 0.0), (0.2, 1.0, -0.75)]
)
def test_rk4_is_exact_under_constant_thrust(x0, v0, u):
    """x(t) = x0 + v0 t + u t^2 / 2 solves x'' = u, and RK4 integrates quadratics exactly, so the
    only error is float32 rounding: at most ~4 ulps after one step, and at most one ulp of the
    state's magnitude per step (rounding adds up, there is no truncation error) over 500 steps.
    Euler's truncation error alone would be u dt^2 / 2 = 5e-5 per step."""

    def body(state, _):
        state, timestep = ENV.step(KEY, state, jnp.array([u]), PARAMS)
        return state, timestep.obs

    start, _ = ENV.reset_to(jnp.array([x0, v0]))
    _, obs = jax.jit(lambda s: jax.lax.scan(body, s, None, length=500))(start)
    obs = np.asarray(obs, np.float64)
    t = np.arange(1, 501) * np.float64(np.float32(0.01))
    x0, v0 = np.float64(np.float32(x0)), np.float64(np.float32(v0))
    exact = np.column_stack([x0 + v0 * t + u * t**2 / 2, v0 + u * t])
    magnitude = np.maximum(1.0, np.abs(exact).max())
    assert np.abs(obs[0] - exact[0]).max() <= 4 * EPS32 * magnitude
    allowed = np.repeat(np.arange(1, 501)[:, None], 2, axis=1) * EPS32 * magnitude
    np.testing.assert_array_less(np.abs(obs - exact), allowed)


# ---- reward, termination and truncation cases ---------------------------------------------------
def test_reward_moving_away_from_the_origin():
    # x = 0.5 + 0.5 * 0.01 = 0.505, v = 0.5: r = 1 / (0.505^2 + 1) - 10 * 0.5
    _, timestep = one_step(0.5, 0.5, 0.0)
    np.testing.assert_allclose(timestep.reward, -4.203203123443756, rtol=1e-6)
    assert not timestep.terminated and not timestep.truncated


def test_reward_approaching_the_origin():
    # x = 0.495, v = -0.5: r = 1 / (0.495^2 + 1) + 1 / (0.25 + 1)
    _, timestep = one_step(0.5, -0.5, 0.0)
    np.testing.assert_allclose(timestep.reward, 1.6031967229573705, rtol=1e-6)
    assert not timestep.terminated


def test_reward_at_rest_counts_as_approaching():
    # x v = 0 is not "moving away": r = 1 / (1.5^2 + 1) + 1 / (0 + 1)
    _, timestep = one_step(1.5, 0.0, 0.0)
    np.testing.assert_allclose(timestep.reward, 1 / 3.25 + 1, rtol=1e-6)


@pytest.mark.parametrize(
    ("x0", "v0", "u", "crashed_on"),
    [
        (1.999, 0.5, 0.0, "x"),
        (-1.999, -0.5, 0.0, "x"),
        (0.0, 1.999, 1.0, "v"),
        (0.0, -1.999, -1.0, "v"),
    ],
)
def test_leaving_the_box_terminates_with_penalty(x0, v0, u, crashed_on):
    state, timestep = one_step(x0, v0, u)
    x, v = float(state.x), float(state.v)
    assert abs(x if crashed_on == "x" else v) > 2
    assert bool(timestep.terminated) and not bool(timestep.truncated)
    away = 1 / (x**2 + 1) - 10 * abs(v) if x * v > 0 else 1 / (x**2 + 1) + 1 / (v**2 + 1)
    np.testing.assert_allclose(timestep.reward, away - 500, rtol=1e-6)


def test_just_inside_the_box_does_not_terminate():
    state, timestep = one_step(1.99, 0.5, -1.0)
    assert float(state.x) < 2 and not bool(timestep.terminated)


def test_goal_with_the_default_tolerance():
    # At rest within 1e-8 of the origin: r = 1 / (x^2 + 1) + 1 / (0 + 1) + 500 ~ 502.
    _, timestep = one_step(5e-9, 0.0, 0.0)
    assert bool(timestep.terminated)
    np.testing.assert_allclose(timestep.reward, 502.0, rtol=1e-7)
    _, timestep = one_step(0.0, 0.0, 0.0)
    assert bool(timestep.terminated)
    # Just outside numpy allclose's atol=1e-8: no goal.
    _, timestep = one_step(2e-8, 0.0, 0.0)
    assert not bool(timestep.terminated)
    np.testing.assert_allclose(timestep.reward, 2.0, rtol=1e-7)


def test_goal_with_a_looser_params_tolerance():
    loose = PARAMS.replace(goal_tolerance=np.float32(1e-2))
    # New state (0.00495, -0.005): inside 1e-2 but not inside the default 1e-8.
    state, timestep = one_step(0.005, -0.005, 0.0, params=loose)
    assert bool(timestep.terminated)
    x, v = float(state.x), float(state.v)
    np.testing.assert_allclose(timestep.reward, 1 / (x**2 + 1) + 1 / (v**2 + 1) + 500, rtol=1e-6)
    _, timestep = one_step(0.005, -0.005, 0.0)
    assert not bool(timestep.terminated)


def test_truncated_after_500_steps():
    # At rest at x = 0.5 with no thrust nothing ever terminates.
    state, _ = ENV.reset_to(jnp.array([0.5, 0.0]))
    flags = []
    for _ in range(501):
        state, timestep = step(KEY, state, jnp.zeros((1,)))
        flags.append((bool(timestep.terminated), bool(timestep.truncated)))
    assert flags[:499] == [(False, False)] * 499
    assert flags[499] == (False, True)
    assert int(state.time) == 501  # stepping past the limit is the caller's choice


def test_termination_on_the_last_step_sets_both_flags():
    _, timestep = one_step(1.999, 0.5, 0.0, time=499)
    assert bool(timestep.terminated) and bool(timestep.truncated)


def test_action_is_clipped_to_unit_interval():
    for over, bound in ((5.0, 1.0), (-7.0, -1.0), (np.inf, 1.0)):
        clipped, _ = one_step(0.3, 0.2, over)
        reference, _ = one_step(0.3, 0.2, bound)
        assert (float(clipped.x), float(clipped.v)) == (float(reference.x), float(reference.v))
    inside, _ = one_step(0.3, 0.2, 0.3)
    np.testing.assert_allclose(float(inside.v), 0.2 + 0.3 * 0.01, rtol=1e-6)


def test_dt_is_a_params_field():
    state, _ = one_step(0.3, 0.2, 1.0, params=PARAMS.replace(dt=np.float32(0.1)))
    np.testing.assert_allclose([float(state.x), float(state.v)], [0.325, 0.3], rtol=1e-6)


# ---- reset, spaces, exact starts ----------------------------------------------------------------
def test_reset_distribution():
    keys = jax.random.split(jax.random.PRNGKey(1), 20000)
    _, timestep = jax.jit(jax.vmap(ENV.reset))(keys)
    obs = np.asarray(timestep.obs)
    magnitude, positive = np.abs(obs), obs > 0
    assert magnitude.min() >= 0.5 and magnitude.max() <= 1.0
    for column in range(2):
        assert stats.kstest(magnitude[:, column], stats.uniform(0.5, 0.5).cdf).pvalue > 1e-3
    # Signs: fair and independent of each other (4 quadrants, ~5000 each, SE ~ 61).
    quadrants = np.bincount(positive[:, 0] * 2 + positive[:, 1], minlength=4)
    np.testing.assert_allclose(quadrants, 5000, atol=5 * 61)
    assert np.all(timestep.reward == 0) and not np.any(timestep.terminated)


def test_spaces_and_exact_start():
    assert ENV.observation_space().shape == (2,)
    np.testing.assert_array_equal(ENV.observation_space().high, [3, 3])
    np.testing.assert_array_equal(ENV.observation_space().low, [-3, -3])
    assert ENV.action_space().shape == (1,)
    np.testing.assert_array_equal(ENV.action_space().high, [1])
    state, timestep = ENV.reset_to(jnp.array([0.75, -0.25]))
    assert (float(state.x), float(state.v), int(state.time)) == (0.75, -0.25, 0)
    np.testing.assert_array_equal(timestep.obs, [0.75, -0.25])
    np.testing.assert_array_equal(ENV.state_to_vector(state), [0.75, -0.25])


# ---- rendering ----------------------------------------------------------------------------------
def _red_columns(frame: np.ndarray) -> np.ndarray:
    red = (frame[..., 0] > 150) & (frame[..., 1] < 80) & (frame[..., 2] < 80)
    return np.nonzero(red.any(axis=0))[0]


def test_render_frame_moves_with_the_rocket():
    left, _ = ENV.reset_to(jnp.array([-1.0, 0.0]))
    right, _ = ENV.reset_to(jnp.array([1.0, 0.0]))
    frames = [ENV.render(left), ENV.render(right)]
    for frame in frames:
        assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    width = frames[0].shape[1]
    left_center, right_center = (_red_columns(f).mean() for f in frames)
    assert left_center < width / 2 < right_center
    # The track -2..2 spans the frame minus two 50 px margins: 125 px per unit.
    np.testing.assert_allclose(right_center - left_center, 2 * (width - 100) / 4, atol=1)
    # Off the track (a crash) the rocket is still drawn, at the frame's edge.
    assert _red_columns(draw_rocket(2.5, 0.0)).max() >= width - 30


def test_plot_episode_returns_image_and_writes_png(tmp_path):
    t = np.arange(101) * 0.01
    path = tmp_path / "episode.png"
    image = plot_episode(1 - t, -np.ones_like(t), dt=0.01, path=path, title="test")
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    assert image.std() > 10  # not blank
    saved = iio.imread(path)
    assert saved.shape[:2] == image.shape[:2]


# ---- rl_jax/RocketSettle-v0: the documented variant for coming to rest and staying there -------
SETTLE = RocketSettle()
SETTLE_PARAMS = SETTLE.default_params


def settle_step_once(x: float, v: float, u: float):
    state, _ = SETTLE.reset_to(jnp.array([x, v]), SETTLE_PARAMS)
    _, timestep = step_settle(KEY, state, jnp.array([u]), SETTLE_PARAMS)
    return jax.device_get(timestep)


step_settle = jax.jit(SETTLE.step)


def settle_reward(x: float, v: float) -> float:
    """The variant's reward at the new state (x, v), written from its docstring."""
    reward = 1 / (x**2 + 1) + (-10 * abs(v) if x * v > 0 else 0.0)
    reward += 0.5 * np.exp(-(abs(x) + abs(v)) / 0.05)
    if abs(x) <= 0.01 and abs(v) <= 0.01:
        reward += 2.0
    return reward


@pytest.mark.parametrize(
    "x, v, u",
    [(1.0, 0.0, -1.0), (0.05, -0.02, 0.3), (0.004, 0.0, 0.0), (-0.003, 0.002, 0.1), (0.5, 0.9, 1)],
)
def test_settle_variant_reward_and_no_goal_termination(x, v, u):
    ours = settle_step_once(x, v, u)
    new_x, new_v = spec_step(x, v, u)[:2]
    zoomed = np.tanh(np.array([new_x, new_v]) / 0.03)
    np.testing.assert_allclose(ours.obs, [new_x, new_v, *zoomed], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours.reward, settle_reward(new_x, new_v), rtol=1e-5, atol=1e-6)
    assert not ours.terminated  # inside the box or not, the episode goes on


def test_settle_variant_keeps_the_dynamics_and_crash_rule():
    ours = settle_step_once(1.999, 0.5, 1.0)
    assert ours.terminated and ours.reward < -400
    # Same dynamics and spaces as the faithful rocket.
    assert SETTLE.action_space() == ENV.action_space()
    assert SETTLE.max_episode_steps == ENV.max_episode_steps


def test_settle_variant_resets_half_near_the_goal_half_anywhere():
    _, timestep = jax.vmap(SETTLE.reset, in_axes=(0, None))(
        jax.random.split(KEY, 8000), SETTLE_PARAMS
    )
    obs = np.asarray(timestep.obs)
    np.testing.assert_allclose(obs[:, 2:], np.tanh(obs[:, :2] / 0.03), rtol=1e-5, atol=1e-6)
    xv = obs[:, :2]
    assert np.all(np.abs(xv) <= 1.0)
    near = np.all(np.abs(xv) <= 0.05, axis=1)
    # Far starts land in the small box with probability 0.05^2 only: near ~ 50% + 0.1%.
    assert abs(near.mean() - 0.5) < 0.03
    for starts, bound in ((xv[near], 0.05), (xv[~near], 1.0)):
        for column in starts.T:  # uniform on [-bound, bound] (far: outside the box as well)
            if bound == 0.05:
                assert stats.kstest(column, "uniform", args=(-0.05, 0.1)).pvalue > 1e-3
            else:
                assert np.abs(column).max() > 0.95 and abs(np.mean(column)) < 0.05
