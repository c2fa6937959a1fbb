"""The MuJoCo envs' API: construction, spaces, reset statistics, exact float64 state transport,
non-finite physics, jit/vmap (with extra outer vmaps), wrappers, determinism.

Most checks use the C backend, whose compiled programs are small, and those that concern its
exactness run on both ways of calling it (the FFI op and the pure_callback path); the MJX ones
reuse the compiled 256-env steps of test_mujoco_parity.py (same process, same cache) where they
can.
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats
from test_mujoco_parity import BATCH, C_BACKENDS, engine, mjx_params

from rl_jax import envs
from rl_jax.envs.mujoco import mujoco_backend, mujoco_ffi_build
from rl_jax.envs.mujoco.float64_bits import float32_to_float64_bits, float64_bits_to_float32

ENV_IDS = ["InvertedPendulum-v5", "InvertedDoublePendulum-v5", "HalfCheetah-v5"]
# Checked here on the C backend only (their MJX steps are compiled in test_mujoco_parity.py).
NEW_ENV_IDS = ["Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Reacher-v5", "Ant-v5", "Humanoid-v5"]


@functools.cache
def c_env(env_id: str, backend: str = "mujoco"):
    if backend == "mujoco_ffi" and not mujoco_ffi_build.available():
        pytest.skip("the MuJoCo FFI op cannot be built here")
    return envs.make("rl_jax/" + env_id, backend=backend)


@functools.cache
def c_functions(env_id: str, backend: str = "mujoco"):
    env = c_env(env_id, backend)
    return jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


@functools.cache
def mjx_reset(env_id: str):
    """The batched reset of test_mujoco_parity.py's MJX env, compiled once (for BATCH keys) for
    the tests that sample MJX resets."""
    return jax.jit(jax.vmap(engine(env_id, "mjx")[0].reset))


# ---- construction -----------------------------------------------------------------------------
def test_backend_choice(monkeypatch):
    monkeypatch.delenv(mujoco_backend.BACKEND_ENV_VAR, raising=False)
    expected = "mujoco" if jax.default_backend() == "cpu" else "mjx"
    assert mujoco_backend.default_backend() == expected
    assert envs.make("rl_jax/InvertedPendulum-v5").backend == expected
    monkeypatch.setenv(mujoco_backend.BACKEND_ENV_VAR, "mjx")
    assert envs.make("InvertedPendulum-v5").backend == "mjx"
    assert envs.make("InvertedPendulum-v5", backend="mujoco").backend == "mujoco"
    callback = envs.make("InvertedPendulum-v5", backend="mujoco_callback")
    assert (callback.backend, callback.physics.name) == ("mujoco", "mujoco_callback")
    monkeypatch.setenv(mujoco_backend.BACKEND_ENV_VAR, "mujoco_callback")
    assert envs.make("InvertedPendulum-v5").physics.name == "mujoco_callback"
    if mujoco_ffi_build.available():  # "mujoco" is the FFI op wherever it builds
        assert envs.make("InvertedPendulum-v5", backend="mujoco").physics.name == "mujoco_ffi"
    with pytest.raises(ValueError, match="unknown MuJoCo backend"):
        envs.make("InvertedPendulum-v5", backend="bullet")
    with pytest.raises(ValueError, match="fidelity"):
        envs.make("InvertedPendulum-v5", fidelity="sloppy")


def test_gymnasium_style_arguments_set_default_params():
    env = envs.make("HalfCheetah-v5", backend="mujoco", ctrl_cost_weight=0.2)
    assert float(env.default_params.ctrl_cost_weight) == pytest.approx(0.2)
    with pytest.raises(TypeError, match="no parameter"):
        envs.make("HalfCheetah-v5", backend="mujoco", ctrl_cost=0.2)
    full = envs.make("HalfCheetah-v5", exclude_current_positions_from_observation=False)
    assert full.observation_space().shape == (18,)


def test_gymnasium_range_keywords_set_two_params_fields():
    env = envs.make("Hopper-v5", backend="mujoco", healthy_z_range=(0.5, 2.0))
    assert float(env.default_params.healthy_z_min) == pytest.approx(0.5)
    assert float(env.default_params.healthy_z_max) == pytest.approx(2.0)
    assert float(env.default_params.healthy_angle_max) == pytest.approx(0.2)  # default kept
    with pytest.raises(TypeError, match="healthy_z_range"):
        envs.make("Hopper-v5", backend="mujoco", healthy_z_range=(0.5, 2.0), healthy_z_min=0.6)
    with pytest.raises(TypeError, match="healthy_state_range"):  # the walker has none
        envs.make("Walker2d-v5", backend="mujoco", healthy_state_range=(-1.0, 1.0))


@pytest.mark.parametrize("keyword", ["xml_file", "frame_skip", "default_camera_config"])
@pytest.mark.parametrize("env_id", NEW_ENV_IDS + ["HalfCheetah-v5"])
def test_fixed_gymnasium_keywords_are_refused_by_name(env_id, keyword):
    value = {"xml_file": "other.xml", "frame_skip": 1, "default_camera_config": {}}[keyword]
    with pytest.raises(TypeError, match=f"keyword '{keyword}'") as error:
        envs.make(env_id, backend="mujoco", **{keyword: value})
    assert "\n" not in str(error.value)
    with pytest.raises(TypeError, match=f"keyword '{keyword}'"):  # also through gymnasium.make
        gymnasium.make("rl_jax/" + env_id, **{keyword: value})


@pytest.mark.parametrize("env_id", ENV_IDS + NEW_ENV_IDS)
def test_spaces_and_limits_match_gymnasium(env_id):
    ours, theirs = c_env(env_id), gymnasium.make(env_id)
    assert ours.observation_space().shape == theirs.observation_space.shape
    action_space = ours.action_space()
    np.testing.assert_array_equal(action_space.low, theirs.action_space.low)
    np.testing.assert_array_equal(action_space.high, theirs.action_space.high)
    assert ours.max_episode_steps == theirs.spec.max_episode_steps
    assert ours.max_episode_steps == (50 if env_id == "Reacher-v5" else 1000)
    assert ours.dt == pytest.approx(theirs.unwrapped.dt)
    assert ours.frame_skip == theirs.unwrapped.frame_skip


# ---- exact float64 transport ------------------------------------------------------------------
def _special_float32_values() -> np.ndarray:
    rng = np.random.default_rng(0)
    values = [
        rng.normal(size=2000) * 10.0 ** rng.integers(-30, 30, 2000),
        [0.0, -0.0, np.inf, -np.inf, np.nan, 1.0, -1.0, 3.4e38, -3.4e38, 1.2e-38, 1e-45, -1e-40],
        np.finfo(np.float32).tiny * np.array([1.0, 2.0, 0.5, 0.25, 2.0**-22]),
    ]
    return np.concatenate([np.asarray(v, np.float64) for v in values]).astype(np.float32)


def test_float32_to_float64_bits_is_exact():
    x = _special_float32_values()
    ours = np.asarray(jax.jit(float32_to_float64_bits)(x)).reshape(-1)
    expected = x.astype(np.float64).view(np.uint32)
    assert ours.tobytes() == expected.tobytes()


def test_float64_bits_to_float32_rounds_like_numpy():
    rng = np.random.default_rng(1)
    x = np.concatenate([rng.normal(size=5000) * 10.0 ** rng.integers(-30, 30, 5000), [0.0, -0.0]])
    x = np.concatenate([x, [np.inf, -np.inf, 3.5e38, -1e300, 1 + 2**-24, 1 + 3 * 2**-24]])
    ours = np.asarray(jax.jit(float64_bits_to_float32)(x.view(np.uint32)))
    with np.errstate(over="ignore"):  # numpy's own cast overflows to inf, as ours must
        np.testing.assert_array_equal(ours, x.astype(np.float32))
    assert np.isnan(np.asarray(float64_bits_to_float32(np.array([np.nan]).view(np.uint32))))


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_c_backend_keeps_float64_starts_bit_exact(env_id, backend):
    env = c_env(env_id, backend)
    rng = np.random.default_rng(2)
    nq, nv = env.physics.nq, env.physics.nv
    vector = rng.normal(size=(3, nq + 2 * nv)) * np.pi
    state, ts = env.reset_to(vector)
    qpos, qvel, warm = env.physics.to_numpy(state.physics)
    np.testing.assert_array_equal(np.concatenate([qpos, qvel, warm], -1), vector)
    assert ts.obs.shape == (3, env.obs_size)
    # a traced (float32) start is widened exactly
    state32, _ = jax.jit(env.reset_to)(vector[0, : nq + nv].astype(np.float32))
    qpos, qvel, _ = env.physics.to_numpy(state32.physics)
    np.testing.assert_array_equal(qpos, vector[0, :nq].astype(np.float32).astype(np.float64))


# ---- reset statistics -------------------------------------------------------------------------
def _gym_resets(env_id: str, count: int) -> np.ndarray:
    env = gymnasium.make(env_id).unwrapped
    rows = []
    for seed in range(count):
        env.reset(seed=seed)
        rows.append(np.concatenate([env.data.qpos, env.data.qvel]))
    return np.stack(rows)


@pytest.mark.parametrize("env_id", ENV_IDS + NEW_ENV_IDS)
def test_reset_distribution_matches_gymnasium(env_id):
    """Per qpos/qvel component: means, spreads and whole distributions (KS) agree."""
    n_ours, n_gym = 4096, 2000
    reset, _ = c_functions(env_id)
    state, ts = reset(jax.random.split(jax.random.PRNGKey(3), n_ours))
    qpos, qvel, warm = c_env(env_id).physics.to_numpy(jax.device_get(state.physics))
    ours, theirs = np.concatenate([qpos, qvel], -1), _gym_resets(env_id, n_gym)
    assert not warm.any() and not np.asarray(ts.info["physics_diverged"]).any()
    for column in range(ours.shape[1]):
        a, b = ours[:, column], theirs[:, column]
        standard_error = np.sqrt(a.var() / len(a) + b.var() / len(b))
        assert abs(a.mean() - b.mean()) <= 5 * standard_error, column  # =: constant columns
        assert a.std() == pytest.approx(b.std(), rel=0.1), column
        assert stats.ks_2samp(a, b).pvalue > 1e-4, column


def test_reacher_goal_is_uniform_in_the_open_disc():
    """gymnasium's rejection sampling: uniform in the disc of radius 0.2, so the squared radius
    is uniform on [0, 0.04) and the angle on the circle."""
    reset, _ = c_functions("Reacher-v5")
    state, _ = reset(jax.random.split(jax.random.PRNGKey(4), 4096))
    qpos, qvel, _ = c_env("Reacher-v5").physics.to_numpy(jax.device_get(state.physics))
    goal = qpos[:, 2:]
    radius_squared = np.sum(goal**2, axis=-1)
    assert radius_squared.max() < 0.2**2 and not qvel[:, 2:].any()
    assert stats.kstest(radius_squared / 0.2**2, "uniform").pvalue > 1e-4
    angle = np.arctan2(goal[:, 1], goal[:, 0])
    assert stats.kstest((angle + np.pi) / (2 * np.pi), "uniform").pvalue > 1e-4


# ---- non-finite physics -----------------------------------------------------------------------
def check_divergence_handling(env, ts, next_state, diverged_rows) -> None:
    """Shared by both backends: flag, termination, finite everything, state back at the default."""
    diverged = np.asarray(ts.info["physics_diverged"])
    np.testing.assert_array_equal(diverged, diverged_rows)
    assert np.asarray(ts.terminated)[diverged_rows].all()
    assert np.isfinite(np.asarray(ts.obs)).all() and np.isfinite(np.asarray(ts.reward)).all()
    for value in ts.info.values():
        assert np.isfinite(np.asarray(value, np.float32)).all()
    assert (np.asarray(ts.reward)[diverged_rows] == 0).all()
    qpos, qvel, _ = env.physics.to_numpy(jax.device_get(next_state.physics))
    np.testing.assert_array_equal(
        qpos[diverged_rows], np.broadcast_to(env.model.qpos0, qpos[diverged_rows].shape)
    )
    assert not qvel[diverged_rows].any()


def diverging_starts(env, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows 1-3 are injected non-finite (NaN qpos, inf qvel, qvel beyond 1e10), row 4 gets a NaN
    action; the others are ordinary."""
    nq, nv = env.physics.nq, env.physics.nv
    vectors = np.zeros((count, nq + nv))
    vectors[1, 0], vectors[2, nq], vectors[3, nq] = np.nan, np.inf, 1e12
    actions = np.zeros((count, env.physics.nu), np.float32)
    actions[4] = np.nan
    rows = np.zeros(count, bool)
    rows[1:5] = True
    return vectors, actions, rows


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", ENV_IDS + NEW_ENV_IDS)
def test_c_backend_non_finite_physics_ends_the_episode(env_id, backend):
    env = c_env(env_id, backend)
    vectors, actions, rows = diverging_starts(env, 6)
    state, first = env.reset_to(vectors)
    assert np.isfinite(np.asarray(first.obs)).all()
    np.testing.assert_array_equal(
        np.asarray(first.info["physics_diverged"]), rows & ~(np.arange(6) == 4)
    )
    _, step = c_functions(env_id, backend)
    keys = jax.random.split(jax.random.PRNGKey(4), 6)
    next_state, ts = step(keys, state, jnp.asarray(actions))
    check_divergence_handling(env, ts, next_state, rows)
    # the returned state is usable: the next step is ordinary
    _, ts = step(keys, next_state, jnp.zeros_like(jnp.asarray(actions)))
    assert not np.asarray(ts.info["physics_diverged"]).any()


# The inverted pendulum's MJX step is checked in every run; half cheetah's (~13 s of MJX
# compilation on a cold cache) with the slow tests, with the other slow MJX envs.
@pytest.mark.parametrize(
    "env_id",
    [
        pytest.param(env_id, marks=pytest.mark.slow) if env_id == "HalfCheetah-v5" else env_id
        for env_id in mjx_params(ENV_IDS)
    ],
)
def test_mjx_backend_non_finite_physics_ends_the_episode(env_id):
    env, start, step = engine(env_id, "mjx")
    vectors, actions, rows = diverging_starts(env, BATCH)
    nq = env.physics.nq
    physics = env.physics.from_qpos_qvel(vectors[:, :nq], vectors[:, nq:], None)
    state, first = start(physics)
    assert np.isfinite(np.asarray(first.obs)).all()
    keys = jax.random.split(jax.random.PRNGKey(4), BATCH)
    next_state, ts = step(keys, state, jnp.asarray(actions))
    check_divergence_handling(env, ts, next_state, rows)
    _, ts = step(keys, next_state, jnp.zeros_like(jnp.asarray(actions)))
    assert not np.asarray(ts.info["physics_diverged"]).any()


def test_mjx_half_cheetah_step_calls_no_lapack_cholesky():
    """jaxlib 0.10.2 deadlocked in a batched LAPACK Cholesky under MJX half cheetah over ~1,000+
    envs (test_mujoco_hang.py, slow). Our step factorises its small matrices unrolled, so its
    program (the 256-env one compiled above) must call no LAPACK Cholesky (potrf)."""
    env, start, step = engine("HalfCheetah-v5", "mjx")
    keys = jax.random.split(jax.random.PRNGKey(4), BATCH)
    state, _ = start(
        env.physics.from_qpos_qvel(
            np.zeros((BATCH, env.physics.nq)), np.zeros((BATCH, env.physics.nv))
        )
    )
    program = step.lower(keys, state, jnp.zeros((BATCH, env.physics.nu))).as_text()
    assert "potrf" not in program
    # ... where a plain batched Cholesky would show one: the name searched for is the right one.
    matrices = jnp.broadcast_to(jnp.eye(9), (BATCH, 9, 9))
    assert "potrf" in jax.jit(jax.vmap(jax.scipy.linalg.cho_factor)).lower(matrices).as_text()


def test_autoreset_after_divergence_keeps_nan_out_of_final_obs():
    env = envs.AutoReset(c_env("HalfCheetah-v5"))
    vectors, actions, rows = diverging_starts(c_env("HalfCheetah-v5"), 6)
    state, _ = c_env("HalfCheetah-v5").reset_to(vectors)
    keys = jax.random.split(jax.random.PRNGKey(5), 6)
    _, ts = jax.jit(jax.vmap(env.step))(keys, state, jnp.asarray(actions))
    assert np.isfinite(np.asarray(ts.info["final_obs"])).all()
    assert np.isfinite(np.asarray(ts.obs)).all()
    np.testing.assert_array_equal(np.asarray(ts.terminated), rows)


# ---- jit / vmap / wrappers / determinism -----------------------------------------------------
@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_outer_vmap_over_seeds_and_params_matches_flat_batch(env_id, backend):
    """vmap(seeds) o vmap(envs) with per-seed params gives the per-env results of one flat batch."""
    env = c_env(env_id, backend)
    seeds, per_seed = 3, 4
    params = jax.tree.map(lambda x: jnp.stack([x, 1.5 * x, 0.5 * x]), env.default_params)
    keys = jax.random.split(jax.random.PRNGKey(6), seeds * per_seed).reshape(seeds, per_seed, -1)
    inner_reset = jax.vmap(env.reset, in_axes=(0, None))
    inner_step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    state, _ = jax.jit(jax.vmap(inner_reset))(keys, params)
    actions = jax.random.uniform(
        jax.random.PRNGKey(7), (seeds, per_seed, env.physics.nu), minval=-1
    )
    nested_state, nested = jax.jit(jax.vmap(inner_step))(keys, state, actions, params)
    flat = lambda tree: jax.tree.map(lambda x: x.reshape(seeds * per_seed, *x.shape[2:]), tree)
    flat_params = jax.tree.map(lambda x: jnp.repeat(x, per_seed), params)
    flat_state, flat_ts = jax.jit(jax.vmap(env.step))(
        flat(keys), flat(state), flat(actions), flat_params
    )
    # The C physics is bit-identical; float32 rewards/observations computed in JAX from it may
    # differ by an ulp between two differently fused XLA programs (summation order).
    np.testing.assert_array_equal(flat(nested_state.physics), flat_state.physics)
    for a, b in zip(jax.tree.leaves(nested), jax.tree.leaves(flat_ts), strict=True):
        np.testing.assert_allclose(np.asarray(a).reshape(np.shape(b)), b, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("backend", C_BACKENDS)
def test_c_backend_is_pure_and_batch_independent(backend):
    """One env stepped alone, or as row 5 of a batch, or again from a copied state: same bits."""
    env = c_env("HalfCheetah-v5", backend)
    reset, step = c_functions("HalfCheetah-v5", backend)
    keys = jax.random.split(jax.random.PRNGKey(8), 8)
    state, _ = reset(keys)
    actions = jax.random.uniform(jax.random.PRNGKey(9), (8, 6), minval=-1)
    for _ in range(3):
        state, ts = step(keys, state, actions)
    copied = jax.tree.map(lambda x: jnp.asarray(np.array(x)), state)  # as after save/restore
    batch_state, batch_ts = step(keys, copied, actions)
    single = jax.jit(env.step)
    row = lambda tree: jax.tree.map(lambda x: x[5], tree)
    alone_state, alone_ts = single(keys[5], row(state), actions[5])
    for a, b in zip(
        jax.tree.leaves((alone_state, alone_ts)),
        jax.tree.leaves(row((batch_state, batch_ts))),
        strict=True,
    ):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_scan_with_training_wrappers(env_id):
    """The usual training stack, scanned inside jit: episodes end and restart, stats are sane."""
    env = envs.EpisodeStatistics(envs.AutoReset(envs.RescaleAction(c_env(env_id))))
    n_envs, n_steps = 4, 60

    @jax.jit
    def run(key):
        state, ts = jax.vmap(env.reset)(jax.random.split(key, n_envs))

        def body(carry, key):
            state, _ = carry
            key_action, key_step = jax.random.split(key)
            action = jax.random.uniform(
                key_action, (n_envs, env.action_space().shape[0]), minval=-1
            )
            state, ts = jax.vmap(env.step)(jax.random.split(key_step, n_envs), state, action)
            return (state, ts), ts

        _, trajectory = jax.lax.scan(body, (state, ts), jax.random.split(key, n_steps))
        return trajectory

    trajectory = run(jax.random.PRNGKey(10))
    assert trajectory.obs.shape == (n_steps, n_envs, env.observation_space().shape[0])
    assert np.isfinite(np.asarray(trajectory.obs)).all()
    assert not np.asarray(trajectory.info["physics_diverged"]).any()
    if env_id != "HalfCheetah-v5":  # random actions topple both pendulums quickly
        assert np.asarray(trajectory.info["episode_done"]).any()
        assert not np.asarray(trajectory.truncated).any()


def test_mjx_backend_under_outer_vmap_matches_flat_batch():
    """vmap(seeds) o vmap(envs) of the MJX step equals the flat batch of the same envs."""
    env, _, flat_step = engine("InvertedPendulum-v5", "mjx")
    seeds, per_seed = 2, BATCH // 2
    keys = jax.random.split(jax.random.PRNGKey(11), BATCH)
    state, _ = mjx_reset("InvertedPendulum-v5")(keys)
    actions = jax.random.uniform(jax.random.PRNGKey(12), (BATCH, 1), minval=-3, maxval=3)
    _, flat = flat_step(keys, state, actions)
    split = lambda tree: jax.tree.map(lambda x: x.reshape(seeds, per_seed, *x.shape[1:]), tree)
    nested_step = jax.jit(jax.vmap(jax.vmap(env.step)))
    _, nested = nested_step(split(keys), split(state), split(actions))
    for a, b in zip(jax.tree.leaves(nested), jax.tree.leaves(flat), strict=True):
        np.testing.assert_allclose(np.asarray(a).reshape(np.shape(b)), b, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("env_id", ["InvertedPendulum-v5", "HalfCheetah-v5"])
def test_backends_sample_the_same_resets(env_id):
    """Reset sampling is backend-independent: same keys, same start (float32 values)."""
    keys = jax.random.split(jax.random.PRNGKey(13), BATCH)
    mjx_state, mjx_ts = mjx_reset(env_id)(keys)
    c_state, c_ts = c_functions(env_id)[0](keys)
    # Equal to the last bit on the pinned jax; jax 0.12 compiles the two programs' noise scaling
    # differently and one velocity in 272 moves by 1 ulp. A different draw would differ by ~0.1.
    same = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=0)  # noqa: E731
    same(mjx_ts.obs, c_ts.obs)
    c_qpos, c_qvel, _ = c_env(env_id).physics.to_numpy(c_state.physics)
    same(np.asarray(mjx_state.physics[0], np.float64), c_qpos)
    same(np.asarray(mjx_state.physics[1], np.float64), c_qvel)


@pytest.mark.parametrize("size", [1, 3, 9])
def test_small_cholesky_matches_lapack(size):
    """The unrolled factor/solve MJX is traced with equals jax.scipy's (float32 rounding)."""
    rng = np.random.default_rng(size)
    a = rng.normal(size=(32, size, size)).astype(np.float32)
    spd = a @ np.swapaxes(a, 1, 2) + size * np.eye(size, dtype=np.float32)
    b = rng.normal(size=(32, size)).astype(np.float32)
    b_matrix = rng.normal(size=(32, size, 2)).astype(np.float32)

    def solve(matrix, vector, rhs):
        factor = jax.scipy.linalg.cho_factor(matrix)
        lower_factor = jax.scipy.linalg.cho_factor(matrix, lower=True)
        solutions = (
            jax.scipy.linalg.cho_solve(factor, vector),
            jax.scipy.linalg.cho_solve(lower_factor, rhs),
        )
        return jnp.triu(factor[0]), solutions

    expected = jax.jit(jax.vmap(solve))(spd, b, b_matrix)
    with mujoco_backend.small_cholesky():
        assert jax.scipy.linalg.cho_factor.__module__ == "rl_jax.envs.mujoco.mujoco_backend"
        ours = jax.jit(jax.vmap(solve))(spd, b, b_matrix)
    assert jax.scipy.linalg.cho_factor.__module__ != "rl_jax.envs.mujoco.mujoco_backend"  # restored
    for x, y in zip(jax.tree.leaves(ours), jax.tree.leaves(expected), strict=True):
        np.testing.assert_allclose(x, y, rtol=2e-5, atol=2e-5)


def test_mjx_extras_are_read_without_deprecation_warnings():
    """mjx.Data keeps cfrc_ext, cinert, cacc and cfrc_int in ``_impl`` (reading them from Data
    warns once per access: Ant and Humanoid on MJX then failed check_env on an H100); the extras
    come from there, with the values MuJoCo C computes."""
    import warnings

    import mujoco
    from mujoco import mjx

    model = envs.make("rl_jax/Ant-v5", backend="mujoco").physics.model
    data = mujoco.MjData(model)
    data.qpos[2] += 0.3
    mujoco.mj_step(model, data)
    mjx_data = mjx.put_data(model, data)
    names = ["cfrc_ext", "cinert", "cvel", "qfrc_actuator", "xpos", "cacc", "cfrc_int"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        values = {name: mujoco_backend.extra_field(name, mjx_data, jnp) for name in names}
    for name in names:
        np.testing.assert_allclose(values[name], getattr(data, name), rtol=1e-6, atol=1e-6)
