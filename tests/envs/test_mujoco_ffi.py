"""The MuJoCo FFI op's own machinery: build cache, version check, fallback, model keys, threads,
errors, and the point of it all: a program that steps MuJoCo C comes from the persistent cache.

Its physics is checked against gymnasium and the pure_callback path in test_mujoco_parity.py and
test_mujoco_env.py (parametrised over both ways of calling MuJoCo C).
"""

from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import compile_level
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from child_env import python_path

from rl_jax import envs
from rl_jax.envs.mujoco import mujoco_backend, mujoco_ffi_build
from rl_jax.envs.mujoco.mujoco_ffi import register_model

REPO = Path(__file__).resolve().parents[2]

needs_ffi = pytest.mark.skipif(
    not mujoco_ffi_build.available(), reason="the MuJoCo FFI op cannot be built here"
)


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process-state as before the first load, so a failure is not remembered afterwards; on
    the CPU, whose custom call the op is (a GPU refuses it before building: tested below)."""
    monkeypatch.setattr(mujoco_ffi_build, "_state", {})
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")


@needs_ffi
def test_library_is_cached_under_a_hash_of_its_inputs(tmp_path, monkeypatch):
    path = mujoco_ffi_build.library_path()
    assert path.exists() and path.parent == mujoco_ffi_build.cache_dir()
    modified = path.stat().st_mtime_ns
    assert mujoco_ffi_build.build() == path and path.stat().st_mtime_ns == modified  # not rebuilt
    edited = tmp_path / "mujoco_ffi.cc"
    edited.write_text(mujoco_ffi_build.SOURCE.read_text() + "\n// edited\n")
    monkeypatch.setattr(mujoco_ffi_build, "SOURCE", edited)
    assert mujoco_ffi_build.library_path() != path


@needs_ffi
def test_library_runs_with_the_mujoco_of_its_headers():
    library = mujoco_ffi_build.load()
    header = library.rl_jax_mujoco_header_version()
    assert header == library.rl_jax_mujoco_library_version() == mujoco.mj_version()


@needs_ffi
def test_version_mismatch_is_refused(fresh_build_state, monkeypatch):
    monkeypatch.setattr(mujoco, "mj_version", lambda: 1)
    with pytest.raises(mujoco_ffi_build.FfiUnavailable, match="MuJoCo version mismatch"):
        mujoco_ffi_build.load()


def test_without_a_compiler_mujoco_falls_back_with_one_line(
    fresh_build_state, monkeypatch, tmp_path, capsys
):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # no library built before
    monkeypatch.setenv("CXX", str(tmp_path / "no-compiler"))
    assert mujoco_backend.resolve_backend("mujoco") == "mujoco_callback"
    assert envs.make("InvertedPendulum-v5").physics.name == "mujoco_callback"
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "no C++ compiler found" in lines[0], lines
    with pytest.raises(mujoco_ffi_build.FfiUnavailable, match="no C\\+\\+ compiler"):
        envs.make("InvertedPendulum-v5", backend="mujoco_ffi")


def test_a_failed_build_falls_back_with_its_first_error(
    fresh_build_state, monkeypatch, tmp_path, capsys
):
    compiler = tmp_path / "broken-g++"
    compiler.write_text("#!/bin/sh\necho 'step.cc:1:1: error: no headers' >&2\nexit 1\n")
    compiler.chmod(0o755)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("CXX", str(compiler))
    assert not mujoco_ffi_build.available()
    building, line = capsys.readouterr().err.splitlines()  # the build announces itself once
    assert building.startswith("rl_jax: building the MuJoCo FFI op (once)")
    assert "compiling mujoco_ffi.cc failed: step.cc:1:1: error: no headers" in line
    assert not list((tmp_path / "rl_jax" / "mujoco_ffi").glob("*.so"))


def test_on_an_accelerator_mujoco_takes_the_callback_and_mujoco_ffi_is_refused(
    fresh_build_state, monkeypatch, capsys
):
    """On a GPU (seen on an H100) the FFI op has no handler ("No FFI handler registered for
    rl_jax_mujoco_step on a platform CUDA"): "mujoco" goes through the host callback there, with
    one line saying why, and an explicit "mujoco_ffi" is refused before anything is compiled."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert mujoco_backend.resolve_backend("mujoco") == "mujoco_callback"
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "CPU custom call" in lines[0] and "JAX_PLATFORMS=cpu" in lines[0]
    with pytest.raises(mujoco_ffi_build.FfiUnavailable, match="default device here is gpu"):
        envs.make("InvertedPendulum-v5", backend="mujoco_ffi")


@needs_ffi
def test_model_key_is_content_addressed():
    """Two loads of one model share a key (so do two processes); any change makes a new one."""
    load = lambda: mujoco_backend.load_model("half_cheetah.xml", 100, 50)
    key = register_model(load(), 5, ("site_xpos",), 2)
    np.testing.assert_array_equal(register_model(load(), 5, ("site_xpos",), 2), key)
    different = [
        register_model(load(), 4, ("site_xpos",), 2),
        register_model(load(), 5, (), 2),
        register_model(load(), 5, ("site_xpos",), 1),
        register_model(mujoco_backend.load_model("half_cheetah.xml", 4, 4), 5, ("site_xpos",), 2),
    ]
    assert len({tuple(k) for k in [key, *different]}) == 5
    with pytest.raises(ValueError, match="cannot run this model: not a floating-point"):
        register_model(load(), 5, ("no_such_field",), 2)


@needs_ffi
def test_thread_count_does_not_change_results():
    keys = jax.random.split(jax.random.PRNGKey(0), 64)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (64, 6), minval=-1)
    results = []
    for nthread in (1, 2):
        env = envs.make("HalfCheetah-v5", backend="mujoco_ffi", nthread=nthread)
        state, _ = jax.jit(jax.vmap(env.reset))(keys)
        step = jax.jit(jax.vmap(env.step))
        for _ in range(5):
            state, _ = step(keys, state, actions)
        results.append(np.asarray(state.physics))
    np.testing.assert_array_equal(*results)


@needs_ffi
def test_unregistered_model_key_fails_the_call_cleanly():
    physics = envs.make("InvertedPendulum-v5", backend="mujoco_ffi").physics
    call = jax.ffi.ffi_call(
        mujoco_ffi_build.STEP_TARGET, physics._result_shapes(True), vmap_method="broadcast_all"
    )
    state = physics.from_qpos_qvel(np.zeros(2), np.zeros(2))
    bogus = jnp.asarray(physics.key ^ np.uint32(1))
    with pytest.raises(Exception, match="not registered in this process"):
        jax.block_until_ready(call(bogus, state, jnp.zeros(1, jnp.float32)))


# ---- the persistent compilation cache ----------------------------------------------------------
CHILD = textwrap.dedent(
    """
    import json, logging, sys
    from rl_jax.training.jax_setup import configure

    configure()
    import jax

    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    hits = []

    class Hits(logging.Handler):
        def emit(self, record):
            if "Persistent compilation cache hit" in record.getMessage():
                hits.append(record.args[0])

    logger = logging.getLogger("jax._src.compiler")
    logger.setLevel(logging.DEBUG)
    logger.addHandler(Hits())
    from rl_jax import envs

    sums = {}
    for backend in sys.argv[1:]:
        env = envs.make("rl_jax/HalfCheetah-v5", backend=backend)

        def steps(keys, env=env):
            state, ts = jax.vmap(env.reset)(keys)
            action = jax.numpy.full((keys.shape[0], 6), 0.5)
            step = lambda s, _: (jax.vmap(env.step)(keys, s, action)[0], None)
            state, _ = jax.lax.scan(step, state, None, length=3)
            return state.physics

        steps.__name__ = "steps_" + backend
        physics = jax.jit(steps)(jax.random.split(jax.random.PRNGKey(0), 4))
        sums[backend] = [float(leaf.sum()) for leaf in jax.tree.leaves(physics)]
    print(json.dumps([hits, sums]))
    """
)


def _python(code: str, *args: str, cache: str = "") -> str:
    """The last stdout line of ``code`` run in a fresh process with this compilation cache dir."""
    environment = {
        **os.environ,
        "JAX_COMPILATION_CACHE_DIR": cache,
        "PYTHONPATH": python_path(REPO),
    }
    result = subprocess.run(
        [sys.executable, "-c", code, *args],
        capture_output=True,
        text=True,
        env=environment,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout.strip().splitlines()[-1]


def _cache_hits(cache: Path, *backends: str) -> tuple[list[str], dict[str, list[float]]]:
    """``(names of the programs loaded from the cache, {backend: sums of the physics leaves})``."""
    hits, sums = json.loads(_python(CHILD, *backends, cache=str(cache)))
    return hits, sums


@needs_ffi
def test_programs_with_the_ffi_op_come_from_the_persistent_cache(tmp_path):
    """Two fresh processes, one cache dir: the second loads the FFI program and steps the same
    physics with it. The host-callback program is compiled again on the pinned jax (0.9 stores no
    program with a host callback) and loaded from the cache on jax 0.12; either way it must step
    the same physics."""
    first, first_sums = _cache_hits(tmp_path, "mujoco_ffi", "mujoco_callback")
    assert "jit_steps_mujoco_ffi" not in first
    second, second_sums = _cache_hits(tmp_path, "mujoco_ffi", "mujoco_callback")
    assert "jit_steps_mujoco_ffi" in second
    assert second_sums == first_sums
    assert first_sums["mujoco_ffi"] == first_sums["mujoco_callback"]


SHARDED_CHILD = textwrap.dedent(
    """
    from rl_jax.training.jax_setup import configure

    configure(cpu_devices=2)
    import jax, numpy as np
    from jax.sharding import Mesh, PartitionSpec as P
    from rl_jax import envs

    mesh = Mesh(np.array(jax.devices()), ("seeds",))
    keys = jax.random.split(jax.random.PRNGKey(0), 8).reshape(4, 2, -1)
    results = []
    for backend in ("mujoco_ffi", "mujoco_callback"):
        env = envs.make("rl_jax/HalfCheetah-v5", backend=backend)
        nested = lambda f: jax.vmap(jax.vmap(f))

        def run(keys):
            state, _ = nested(env.reset)(keys)
            action = jax.numpy.full(keys.shape[:2] + (6,), 0.3)
            for _ in range(3):
                state, ts = nested(env.step)(keys, state, action)
            return state.physics, ts.reward

        sharded = jax.shard_map(run, mesh=mesh, in_specs=P("seeds"), out_specs=P("seeds"))
        results.append(jax.device_get(jax.jit(sharded)(keys)))
    for a, b in zip(*map(jax.tree.leaves, results), strict=True):
        np.testing.assert_array_equal(a, b)
    print("identical")
    """
)


@needs_ffi
def test_ffi_op_under_shard_map_over_two_devices_matches_the_callback():
    """Runs sharded over CPU devices (as the experiment scripts do) call the op per device."""
    assert _python(SHARDED_CHILD) == "identical"


@needs_ffi
def test_an_empty_batch_steps_to_empty_results():
    env = envs.make("InvertedPendulum-v5", backend="mujoco_ffi")
    keys = jax.random.split(jax.random.PRNGKey(0), 0)
    state, first = jax.jit(jax.vmap(env.reset))(keys)
    state, step = jax.jit(jax.vmap(env.step))(keys, state, jnp.zeros((0, 1)))
    assert first.obs.shape == (0, 4) and step.obs.shape == (0, 4) and step.reward.shape == (0,)


# ---- stepping only the active envs -------------------------------------------------------------
@pytest.mark.parametrize(
    "backend, env_id",
    [
        ("mujoco_ffi", "rl_jax/HalfCheetah-v5"),
        ("mujoco_callback", "rl_jax/HalfCheetah-v5"),
        # ~40 s of MJX compilation on a CPU with a cold cache: with the slow tests
        pytest.param("mjx", "rl_jax/InvertedPendulum-v5", marks=pytest.mark.slow),
    ],
)
def test_step_active_steps_the_active_envs_exactly_and_keeps_the_others(backend, env_id):
    """``step_active`` = ``step`` where active (bit for bit: the FFI op steps only those envs in
    the same batch call) and the state unchanged elsewhere, on every backend. The C backends run
    half cheetah, whose contacts the op computes per env; MJX steps every env and keeps the
    active ones' results, whatever the model, so it runs the pendulum, cheaper to trace and
    compile at the default emitters below. MJX on a GPU compiles
    ``step`` and ``step_active`` into differently fused kernels, which round the last bit
    differently (an H100: 3 of 36 numbers 1 ulp apart), so there the stepped envs are compared to
    a few ulp; the envs left alone are compared exactly everywhere. XLA's older CPU emitters, which
    the suite compiles with (``compile_level.py``), fuse the two differently too (98 numbers of the
    stepped state apart, by up to 1.5e-6 relative): these programs use XLA's default emitters."""
    if backend == "mujoco_ffi" and not mujoco_ffi_build.available():
        pytest.skip("the MuJoCo FFI op cannot be built here")
    env = envs.make(env_id, backend=backend)
    keys = jax.random.split(jax.random.PRNGKey(0), 8)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (8, *env.action_space().shape), minval=-1)
    active = jnp.array([True, False, True, True, False, False, True, False])
    jit = functools.partial(jax.jit, compiler_options=compile_level.default_emitters() or None)
    step = jit(jax.vmap(env.step))  # one object, so the second call reuses its trace
    state, _ = jit(jax.vmap(env.reset))(keys)
    state, _ = step(keys, state, actions)  # a state off the reset pose
    full_state, full = step(keys, state, actions)
    some_state, some = jit(jax.vmap(env.step_active))(keys, state, actions, active)
    mask = np.asarray(active)
    if backend == "mjx" and jax.default_backend() != "cpu":

        def same_step(got, want):
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-7)

    else:
        same_step = np.testing.assert_array_equal
    for new, stepped, old in zip(
        jax.tree.leaves(some_state),
        jax.tree.leaves(full_state),
        jax.tree.leaves(state),
        strict=True,
    ):
        same_step(np.asarray(new)[mask], np.asarray(stepped)[mask])
        np.testing.assert_array_equal(np.asarray(new)[~mask], np.asarray(old)[~mask])
    for got, want in ((some.obs, full.obs), (some.reward, full.reward)):
        same_step(np.asarray(got)[mask], np.asarray(want)[mask])
    assert not np.asarray(some.terminated)[mask].any()


@needs_ffi
def test_the_ffi_op_skips_the_physics_of_inactive_envs():
    """The inactive envs' physics is not computed: a state MuJoCo would reject (NaN qvel) passes
    through an inactive env untouched, while the same state in an active env diverges."""
    env = envs.make("InvertedPendulum-v5", backend="mujoco_ffi")
    physics = env.physics
    bad = physics.from_qpos_qvel(np.zeros(2), np.array([np.nan, 0.0]))
    good = physics.from_qpos_qvel(np.zeros(2), np.zeros(2))
    states = jnp.stack([bad, good])
    ctrl = jnp.zeros((2, 1), jnp.float32)
    step = jax.jit(jax.vmap(physics.step))
    after, measured = step(states, ctrl, jnp.array([False, True]))
    np.testing.assert_array_equal(np.asarray(after[0]), np.asarray(bad))
    assert not bool(measured.diverged[1])
    _, measured = step(states, ctrl, jnp.array([True, True]))
    assert bool(measured.diverged[0])


def test_an_unknown_backend_in_the_environment_is_one_user_error(monkeypatch):
    from rl_jax.envs.core.registry import BackendError
    from rl_jax.errors import user_errors

    monkeypatch.setenv(mujoco_backend.BACKEND_ENV_VAR, "cuda")
    with pytest.raises(BackendError, match=r"unknown MuJoCo backend 'cuda'.*RL_JAX_MUJOCO_BACKEND"):
        envs.make("InvertedPendulum-v5")
    assert BackendError in user_errors()


@pytest.mark.parametrize("backend", ["mujoco_ffi", "mujoco_callback"])
def test_post_constraint_fields_are_gymnasiums_after_a_step_and_zero_after_a_forward(backend):
    """cfrc_ext (Ant's and Humanoid's contact forces) is stale after mj_step; gymnasium calls
    mj_rnePostConstraint after every step for it, and after a reset it is zero. Both ways of
    calling MuJoCo C must give exactly that, on humanoid states in floor contact (also the
    other fields read with it, and the model's own 50 PGS iterations, not MuJoCo's default)."""
    if backend == "mujoco_ffi" and not mujoco_ffi_build.available():
        pytest.skip("the MuJoCo FFI op cannot be built here")
    import gymnasium

    from rl_jax.envs.mujoco.mujoco_env import make_physics

    reference = gymnasium.make("Humanoid-v5").unwrapped
    reference.reset(seed=3)
    model, rng = reference.model, np.random.default_rng(3)
    assert model.opt.iterations == 50  # the XML's, which load_model keeps
    extras = ("cfrc_ext", "cinert", "qfrc_actuator")
    physics = make_physics(backend, mujoco_backend.load_model("humanoid.xml"), 5, extras)
    starts, actions, expected = [], [], []
    for _ in range(40):  # the humanoid falls to the floor within these steps
        starts.append(np.concatenate([reference.data.qpos, reference.data.qvel]))
        starts[-1] = np.concatenate([starts[-1], reference.data.qacc_warmstart])
        actions.append(rng.uniform(-0.4, 0.4, model.nu).astype(np.float32))
        reference.step(actions[-1])
        expected.append({name: getattr(reference.data, name).copy() for name in extras})
    nq, nv = model.nq, model.nv
    start = np.stack(starts)
    state = physics.from_qpos_qvel(start[:, :nq], start[:, nq : nq + nv], start[:, nq + nv :])
    _, measured = jax.jit(jax.vmap(physics.step))(state, jnp.asarray(np.stack(actions)))
    for name in extras:
        want = np.stack([e[name] for e in expected]).astype(np.float32)
        np.testing.assert_array_equal(np.asarray(measured.extras[name]), want, err_msg=name)
    assert np.abs(np.stack([e["cfrc_ext"] for e in expected])).max() > 10  # contacts happened
    forward = jax.jit(jax.vmap(physics.forward))(state)
    assert not np.any(np.asarray(forward.extras["cfrc_ext"]))
    assert np.any(np.asarray(forward.extras["cinert"]))
