"""Guard against the large-batch MJX deadlock (DESIGN.md, "jax pin"): with jaxlib 0.10.2, MJX half
cheetah vmapped over ~1,000+ envs blocked forever in a batched LAPACK Cholesky. 2,048 envs must
complete a few steps. It runs in a subprocess with a timeout, so a deadlock fails this test
instead of hanging the suite.

Slow (nearly all of it tracing MJX for 2,048 envs in a fresh process): run `make test-slow`
when the jax pin changes. The default suite keeps MJX half cheetah stepping (256 envs,
test_mujoco_parity.py) and checks that its program holds no LAPACK Cholesky, the call that
deadlocked (test_mujoco_env.py::test_mjx_half_cheetah_step_calls_no_lapack_cholesky)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from child_env import python_path

ROOT = Path(__file__).resolve().parents[2]
N_ENVS = 2048
# Room for compiling MJX half cheetah on a shared, loaded machine; the steps themselves are quick.
TIMEOUT_SECONDS = 400

SCRIPT = textwrap.dedent(
    f"""
    from rl_jax.training.jax_setup import configure
    configure()
    import jax, jax.numpy as jnp
    from rl_jax import envs

    env = envs.make("rl_jax/HalfCheetah-v5", backend="mjx")
    keys = jax.random.split(jax.random.PRNGKey(0), {N_ENVS})
    state, ts = jax.jit(jax.vmap(env.reset))(keys)
    step = jax.jit(jax.vmap(env.step))
    action = jnp.zeros(({N_ENVS}, 6))
    for _ in range(3):
        state, ts = step(keys, state, action)
    jax.block_until_ready(ts)
    assert bool(jnp.isfinite(ts.obs).all())
    print("completed", ts.obs.shape)
    """
)


@pytest.mark.slow
def test_mjx_half_cheetah_2048_envs_does_not_hang():
    env = {**os.environ, "PYTHONPATH": python_path(ROOT)}
    try:
        result = subprocess.run(
            [sys.executable, "-c", SCRIPT],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_SECONDS,
        )
    except subprocess.TimeoutExpired as error:
        raise AssertionError(
            f"{N_ENVS} MJX half cheetah envs did not finish 3 steps in {TIMEOUT_SECONDS} s "
            "(deadlock?)"
        ) from error
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"completed ({N_ENVS}, 17)" in result.stdout
