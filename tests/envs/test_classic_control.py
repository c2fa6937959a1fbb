"""CartPole and Pendulum against gymnasium 1.4.0's own envs: step for step and in distribution.

Every start state is a float32 value given to both (gymnasium keeps it as float64), so the only
differences are float32 vs float64 arithmetic inside one step.

Tolerance (one step): our step is ~15 float32 operations on magnitudes up to ~10 (speeds, the
cart's acceleration ~15); each rounds to half an ulp (eps32 = 1.2e-7 relative) and gymnasium's
float64 result is then rounded to float32 once more. A few ulps at magnitude <= 10 is
``ATOL = 4e-6`` with ``RTOL = 1e-6`` for larger values. Termination is compared exactly except
when gymnasium's new x or theta lies within ``BAND = 1e-6`` (4 ulps of 2.4) of its threshold,
where float32 cannot resolve which side it is on; we assert such cases are rare.
"""

import math

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from rl_jax import envs
from rl_jax.envs.classic.cartpole import CartPole
from rl_jax.envs.classic.pendulum import Pendulum

ATOL, RTOL, BAND = 4e-6, 1e-6, 1e-6
TAU = 0.02
X_LIMIT, THETA_LIMIT = 2.4, 12 * 2 * math.pi / 360


CARTPOLE, PENDULUM = CartPole(), Pendulum()
KEY = jax.random.PRNGKey(0)


class Compiled:
    """Jitted functions of one env, compiled once per module (envs are hashable by identity)."""

    def __init__(self, env):
        self.env = env
        self.step = jax.jit(env.step)
        self.batch_step = jax.jit(jax.vmap(env.step, in_axes=(None, 0, 0, None)))
        self.batch_reset_to = jax.jit(jax.vmap(env.reset_to, in_axes=(0, None)))
        self.batch_reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
        self.reset_to = jax.jit(env.reset_to)

        def synced_step(vector, time, action, params):
            # Start from gymnasium's state but keep our own step counter (for truncation).
            state = env.reset_to(vector, params)[0].replace(time=time)
            return env.step(KEY, state, action, params)

        self.synced_step = jax.jit(synced_step)

    def step_pairs(self, states: np.ndarray, actions: np.ndarray, params=None):
        params = self.env.default_params if params is None else params
        state, _ = self.batch_reset_to(jnp.asarray(states), params)
        _, timestep = self.batch_step(KEY, state, jnp.asarray(actions), params)
        return jax.device_get(timestep)


_COMPILED: dict[int, Compiled] = {}


def compiled(env) -> Compiled:
    if id(env) not in _COMPILED:
        _COMPILED[id(env)] = Compiled(env)
    return _COMPILED[id(env)]


def _reference(gym_env: gymnasium.Env, states: np.ndarray, actions: np.ndarray):
    """Step gymnasium's env once from each (state, action); stack obs, reward, flags."""
    out = []
    for state, action in zip(states, actions, strict=True):
        gym_env.reset(seed=0)
        gym_env.unwrapped.state = state.astype(np.float64)
        obs, reward, terminated, truncated, _ = gym_env.step(action)
        out.append((obs, reward, terminated, truncated, np.array(gym_env.unwrapped.state)))
    obs, reward, terminated, truncated, new_state = (np.array(x) for x in zip(*out, strict=True))
    return obs, reward, terminated, truncated, new_state


# ---- CartPole -----------------------------------------------------------------------------------
def _cartpole_pairs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Typical states, states whose next x or theta lands within 1e-3 of +-threshold, and
    states already past it; actions 0 and 1 (the only two, i.e. both bounds)."""
    typical = np.column_stack(
        [
            rng.uniform(-2.4, 2.4, n),
            rng.uniform(-3, 3, n),
            rng.uniform(-0.2, 0.2, n),
            rng.uniform(-3.5, 3.5, n),
        ]
    )
    near_x = typical[: n // 2].copy()
    target = rng.choice([-X_LIMIT, X_LIMIT], n // 2) + rng.uniform(-1e-3, 1e-3, n // 2)
    near_x[:, 0] = target - TAU * near_x[:, 1]
    near_theta = typical[n // 2 :].copy()
    target = rng.choice([-THETA_LIMIT, THETA_LIMIT], n - n // 2) + rng.uniform(
        -1e-3, 1e-3, n - n // 2
    )
    near_theta[:, 2] = target - TAU * near_theta[:, 3]
    beyond = typical[: n // 10] * np.array([1.1, 1, 1.2, 1])
    states = np.concatenate([typical, near_x, near_theta, beyond]).astype(np.float32)
    return states, rng.integers(0, 2, len(states))


def _assert_termination_agrees(ours: np.ndarray, reference: np.ndarray, new_state: np.ndarray):
    ambiguous = (np.abs(np.abs(new_state[:, 0]) - X_LIMIT) <= BAND) | (
        np.abs(np.abs(new_state[:, 2]) - THETA_LIMIT) <= BAND
    )
    assert ambiguous.mean() < 0.01
    np.testing.assert_array_equal(ours[~ambiguous], reference[~ambiguous])


def test_cartpole_matches_gymnasium_on_random_pairs():
    rng = np.random.default_rng(0)
    states, actions = _cartpole_pairs(rng, 1000)
    gym_env = gymnasium.make("CartPole-v1")
    obs, reward, terminated, truncated, new_state = _reference(gym_env, states, actions)
    ours = compiled(CARTPOLE).step_pairs(states, actions)
    assert len(states) >= 1000
    np.testing.assert_allclose(ours.obs, obs, rtol=RTOL, atol=ATOL)
    np.testing.assert_array_equal(ours.reward, reward)
    _assert_termination_agrees(ours.terminated, terminated, new_state)
    np.testing.assert_array_equal(ours.truncated, truncated)
    # Both branches are exercised: the near-threshold states terminate about half the time.
    assert 0.2 < terminated.mean() < 0.8


@pytest.mark.parametrize(
    ("ours", "configure_reference"),
    [
        (dict(sutton_barto_reward=True), dict(sutton_barto_reward=True)),
        (dict(kinematics_integrator="semi-implicit"), dict()),
    ],
    ids=["sutton_barto_reward", "semi_implicit_euler"],
)
def test_cartpole_variants_match_gymnasium(ours, configure_reference):
    rng = np.random.default_rng(1)
    states, actions = _cartpole_pairs(rng, 100)
    gym_env = gymnasium.make("CartPole-v1", **configure_reference)
    if "kinematics_integrator" in ours:
        gym_env.unwrapped.kinematics_integrator = "semi-implicit"  # any value but "euler"
    obs, reward, terminated, _, new_state = _reference(gym_env, states, actions)
    result = Compiled(CartPole(**ours)).step_pairs(states, actions)
    np.testing.assert_allclose(result.obs, obs, rtol=RTOL, atol=ATOL)
    np.testing.assert_array_equal(result.reward, reward)
    _assert_termination_agrees(result.terminated, terminated, new_state)


def test_cartpole_whole_episodes_free_running():
    """Random actions until gymnasium's episode ends; ours must end on the same step.

    These episodes last <= ~60 steps; over that horizon the pole's instability amplifies the
    per-step rounding differences only a few-fold, so the one-step ATOL still holds.
    """
    env, gym_env, step = CARTPOLE, gymnasium.make("CartPole-v1"), compiled(CARTPOLE).step
    rng = np.random.default_rng(2)
    for episode in range(20):
        gym_env.reset(seed=episode)
        start = np.asarray(gym_env.unwrapped.state, np.float32)
        gym_env.unwrapped.state = start.astype(np.float64)
        state, _ = compiled(env).reset_to(start)
        for _ in range(500):
            action = int(rng.integers(2))
            obs, reward, terminated, truncated, _ = gym_env.step(action)
            state, timestep = step(KEY, state, jnp.int32(action))
            np.testing.assert_allclose(timestep.obs, obs, rtol=RTOL, atol=ATOL)
            assert (float(timestep.reward), bool(timestep.terminated)) == (reward, terminated)
            assert bool(timestep.truncated) == truncated
            if terminated or truncated:
                break
        assert terminated


def test_cartpole_truncates_at_500_like_gymnasium():
    """A balancing controller keeps gymnasium's pole up for the full 500 steps.

    The controller closes the loop on gymnasium's state, so ours sees the same actions open
    loop; the upright pole amplifies rounding differences ~e^(4.6 t), so ours is re-synced to
    gymnasium's state (keeping its own step counter) before every step and compared one step
    at a time along the whole episode.
    """
    gym_env, synced_step = gymnasium.make("CartPole-v1"), compiled(CARTPOLE).synced_step
    obs, _ = gym_env.reset(seed=3)
    time = jnp.int32(0)
    for t in range(1, 501):
        action = int(obs[2] + 0.5 * obs[3] + 0.01 * obs[0] + 0.1 * obs[1] > 0)
        start = np.asarray(gym_env.unwrapped.state, np.float32)
        gym_env.unwrapped.state = start.astype(np.float64)
        obs, reward, terminated, truncated, _ = gym_env.step(action)
        state, timestep = synced_step(start, time, jnp.int32(action), CARTPOLE.default_params)
        time = state.time
        np.testing.assert_allclose(timestep.obs, obs, rtol=RTOL, atol=ATOL)
        assert float(timestep.reward) == reward
        assert not terminated and not bool(timestep.terminated), t
        assert bool(timestep.truncated) == truncated == (t == 500)
    assert int(time) == 500


# ---- Pendulum -----------------------------------------------------------------------------------
def _pendulum_pairs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Unwrapped angles over several turns, speeds up to and at the +-8 clip, torques inside,
    at and far beyond the +-2 bound."""
    theta = rng.uniform(-4 * np.pi, 4 * np.pi, n)
    theta_dot = rng.uniform(-8, 8, n)
    theta_dot[: n // 10] = rng.choice([-8.0, 8.0], n // 10)
    theta_dot[n // 10 : n // 5] = rng.choice([-1, 1], n // 10) * rng.uniform(7.5, 8, n // 10)
    torque = rng.uniform(-2, 2, n)
    torque[: n // 10] = rng.choice([-2.0, 2.0], n // 10)
    torque[n // 10 : n // 4] = rng.choice([-1, 1], n // 4 - n // 10) * rng.uniform(
        2, 50, n // 4 - n // 10
    )
    rng.shuffle(torque)
    states = np.column_stack([theta, theta_dot]).astype(np.float32)
    return states, torque.astype(np.float32)[:, None]


def _assert_pendulum_close(ours, obs, reward, terminated, truncated):
    np.testing.assert_allclose(ours.obs, obs, rtol=RTOL, atol=ATOL)
    # The cost reaches pi^2 + 0.1 * 64 + 0.001 * 4 ~ 16.3, where RTOL allows ~2e-5: a few ulps.
    np.testing.assert_allclose(ours.reward, reward, rtol=RTOL, atol=ATOL)
    np.testing.assert_array_equal(ours.terminated, terminated)
    np.testing.assert_array_equal(ours.truncated, truncated)


def test_pendulum_matches_gymnasium_on_random_pairs():
    rng = np.random.default_rng(4)
    states, torques = _pendulum_pairs(rng, 1500)
    gym_env = gymnasium.make("Pendulum-v1")
    obs, reward, terminated, truncated, _ = _reference(gym_env, states, torques)
    ours = compiled(PENDULUM).step_pairs(states, torques)
    _assert_pendulum_close(ours, obs, reward, terminated, truncated)


def test_pendulum_params_match_gymnasium_constructor_argument():
    """gymnasium's Pendulum takes ``g``; ours has it as a params field."""
    rng = np.random.default_rng(5)
    states, torques = _pendulum_pairs(rng, 200)
    gym_env = gymnasium.make("Pendulum-v1", g=9.81)
    obs, reward, terminated, truncated, _ = _reference(gym_env, states, torques)
    params = PENDULUM.default_params.replace(g=np.float32(9.81))
    ours = compiled(PENDULUM).step_pairs(states, torques, params)
    _assert_pendulum_close(ours, obs, reward, terminated, truncated)


def test_pendulum_whole_episodes():
    """Full 200-step episodes (swing-ups included) compared one step at a time, ours re-synced
    to gymnasium's state before each step: near upright errors grow ~e^(3.9 t), so free-running
    trajectories part after a few seconds whatever the precision. Truncation at step 200."""
    gym_env, synced_step = gymnasium.make("Pendulum-v1"), compiled(PENDULUM).synced_step
    rng = np.random.default_rng(6)
    for episode in range(5):
        gym_env.reset(seed=episode)
        time = jnp.int32(0)
        for t in range(1, 201):
            start = np.asarray(gym_env.unwrapped.state, np.float32)
            gym_env.unwrapped.state = start.astype(np.float64)
            torque = rng.uniform(-3, 3, (1,)).astype(np.float32)
            obs, reward, terminated, truncated, _ = gym_env.step(torque)
            state, timestep = synced_step(start, time, torque, PENDULUM.default_params)
            time = state.time
            np.testing.assert_allclose(timestep.obs, obs, rtol=RTOL, atol=ATOL)
            np.testing.assert_allclose(timestep.reward, reward, rtol=RTOL, atol=ATOL)
            assert not terminated and not bool(timestep.terminated)
            assert bool(timestep.truncated) == truncated == (t == 200)


def test_pendulum_free_running_in_the_stable_regime():
    """Hanging down with weak torques (no swing-up) the dynamics do not amplify errors:
    semi-implicit Euler of an undamped oscillator only accumulates them, so after n steps the
    difference is at most n one-step tolerances."""
    env, gym_env, step = PENDULUM, gymnasium.make("Pendulum-v1"), compiled(PENDULUM).step
    rng = np.random.default_rng(7)
    for episode in range(5):
        gym_env.reset(seed=episode)
        start = np.array([np.pi + rng.uniform(-1, 1), rng.uniform(-1, 1)], np.float32)
        gym_env.unwrapped.state = start.astype(np.float64)
        state, _ = compiled(env).reset_to(start)
        for t in range(1, 201):
            torque = rng.uniform(-0.5, 0.5, (1,)).astype(np.float32)
            obs, reward, _, truncated, _ = gym_env.step(torque)
            state, timestep = step(KEY, state, torque)
            np.testing.assert_allclose(timestep.obs, obs, rtol=t * RTOL, atol=t * ATOL)
            np.testing.assert_allclose(timestep.reward, reward, rtol=t * RTOL, atol=t * ATOL)
            assert bool(timestep.truncated) == truncated == (t == 200)


# ---- reset distributions ------------------------------------------------------------------------
def _our_resets(env, n: int, params=None) -> np.ndarray:
    keys = jax.random.split(jax.random.PRNGKey(123), n)
    params = env.default_params if params is None else params
    state, _ = compiled(env).batch_reset(keys, params)
    return np.asarray(jax.vmap(env.state_to_vector)(state))


def _gym_resets(gym_id: str, n: int, options=None) -> np.ndarray:
    gym_env = gymnasium.make(gym_id)
    out = []
    for seed in range(n):
        gym_env.reset(seed=seed, options=options)
        out.append(np.array(gym_env.unwrapped.state))
    return np.array(out)


def _assert_same_uniform(ours: np.ndarray, reference: np.ndarray, low, high) -> None:
    """Bounds, mean, spread and shape (two-sample Kolmogorov-Smirnov) per state variable.

    jax.random cannot reproduce numpy's stream, so the comparison is statistical; the seeds are
    fixed, so the test is deterministic. Thresholds: 5 standard errors for the moments and a KS
    p-value above 1e-3.
    """
    low, high = np.broadcast_to(low, ours.shape[1:]), np.broadcast_to(high, ours.shape[1:])
    assert np.all(ours >= low.astype(np.float32)) and np.all(ours <= high.astype(np.float32))
    assert np.all(reference >= low) and np.all(reference <= high)
    width = high - low
    std = width / math.sqrt(12)
    np.testing.assert_array_less(
        np.abs(ours.mean(0) - (low + high) / 2), 5 * std / math.sqrt(len(ours))
    )
    np.testing.assert_allclose(ours.std(0), std, rtol=0.02)
    np.testing.assert_allclose(reference.std(0), std, rtol=0.1)
    for column in range(ours.shape[1]):
        assert stats.ks_2samp(ours[:, column], reference[:, column]).pvalue > 1e-3
    # Spread covers the whole range: the extremes are within 1% of the bounds.
    assert np.all(ours.min(0) < low + 0.01 * width) and np.all(ours.max(0) > high - 0.01 * width)


def test_cartpole_reset_distribution_matches_gymnasium():
    ours = _our_resets(CARTPOLE, 10000)
    _assert_same_uniform(ours, _gym_resets("CartPole-v1", 2000), -0.05, 0.05)


def test_cartpole_reset_bounds_option_matches_gymnasium():
    """gymnasium's ``reset(options={"low", "high"})`` is params ``reset_low``/``reset_high``."""
    params = CARTPOLE.default_params.replace(reset_low=np.float32(-0.2), reset_high=np.float32(0.1))
    ours = _our_resets(CARTPOLE, 10000, params)
    reference = _gym_resets("CartPole-v1", 2000, {"low": -0.2, "high": 0.1})
    _assert_same_uniform(ours, reference, -0.2, 0.1)


def test_pendulum_reset_distribution_matches_gymnasium():
    ours = _our_resets(PENDULUM, 10000)
    _assert_same_uniform(ours, _gym_resets("Pendulum-v1", 2000), [-np.pi, -1], [np.pi, 1])


def test_reset_observations_are_consistent_with_the_state():
    for env in (CARTPOLE, PENDULUM):
        state, timestep = env.reset(KEY)
        _, expected = env.reset_to(env.state_to_vector(state))
        np.testing.assert_array_equal(timestep.obs, expected.obs)
        assert timestep.obs.dtype == jnp.float32
        assert bool(env.observation_space().contains(timestep.obs))


def test_spaces_match_gymnasium():
    for ours, gym_id in ((envs.make("CartPole-v1"), "CartPole-v1"), (Pendulum(), "Pendulum-v1")):
        reference = gymnasium.make(gym_id)
        assert ours.observation_space().to_gymnasium() == reference.observation_space
        assert ours.action_space().to_gymnasium() == reference.action_space
        assert ours.max_episode_steps == reference.spec.max_episode_steps
