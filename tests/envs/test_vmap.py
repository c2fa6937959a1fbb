"""Batching does not change results: vmap over 4,096 envs (and over params) equals stepping each
env alone, and jit equals no-jit.

Tolerance: the batched program is compiled separately from the single-env one, so XLA may fuse
multiply-adds or vectorise sin/cos differently: results may differ by a few ulps of the state's
magnitude (we allow 8 ulps of max(1, |value|)); termination and truncation flags must be equal.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax import envs

NUM_ENVS = 4096
EPS32 = float(np.finfo(np.float32).eps)

# Start vectors spanning each env's interesting region (termination bounds included).
STATE_RANGES = {
    "rl_jax/Rocket-v0": [(-2.1, 2.1), (-2.1, 2.1)],
    "rl_jax/CartPole-v1": [(-2.5, 2.5), (-3, 3), (-0.25, 0.25), (-3.5, 3.5)],
    "rl_jax/Pendulum-v1": [(-10, 10), (-8, 8)],
}
# Per-env params to vary in the params-vmap test.
SWEPT_PARAM = {
    "rl_jax/Rocket-v0": ("dt", 0.005, 0.05),
    "rl_jax/CartPole-v1": ("length", 0.25, 1.0),
    "rl_jax/Pendulum-v1": ("g", 5.0, 15.0),
}


class Compiled:
    """One env and its jitted functions, shared by the tests of this module."""

    def __init__(self, env_id: str):
        self.env = env = envs.make(env_id)
        self.params = env.default_params
        self.batch_step = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
        self.sweep_step = jax.jit(jax.vmap(env.step))
        self.single_step = jax.jit(env.step)
        # Each env stepped alone, one after another (a loop over the unbatched step).
        self.each_alone = jax.jit(
            lambda keys, states, actions, params: jax.lax.map(
                lambda xs: env.step(*xs, params), (keys, states, actions)
            )
        )
        self.batch_reset_to = jax.jit(jax.vmap(env.reset_to, in_axes=(0, None)))


_COMPILED: dict[str, Compiled] = {}


def compiled(env_id: str) -> Compiled:
    if env_id not in _COMPILED:
        _COMPILED[env_id] = Compiled(env_id)
    return _COMPILED[env_id]


def _random_inputs(env_id: str, seed: int, n: int):
    env = compiled(env_id).env
    rng = np.random.default_rng(seed)
    low, high = np.array(STATE_RANGES[env_id]).T
    vectors = rng.uniform(low, high, (n, len(low))).astype(np.float32)
    states, _ = compiled(env_id).batch_reset_to(vectors, compiled(env_id).params)
    # Random step counters so that some envs reach the time limit on this step.
    times = rng.integers(env.max_episode_steps - 3, env.max_episode_steps, n).astype(np.int32)
    times[: n // 2] = 0
    states = states.replace(time=jnp.asarray(times))
    space = env.action_space()
    if isinstance(space, envs.Box):
        # A third of the actions lie beyond the bounds (the env clips them).
        actions = 1.5 * rng.uniform(space.low, space.high, (n, *space.shape))
    else:
        actions = rng.integers(0, space.n, n)
    keys = np.asarray(jax.random.split(jax.random.PRNGKey(seed), n))
    return keys, states, jnp.asarray(actions.astype(space.dtype))


def _assert_same(batched, alone) -> None:
    for leaf_batched, leaf_alone in zip(
        jax.tree.leaves(batched), jax.tree.leaves(alone), strict=True
    ):
        leaf_batched, leaf_alone = np.asarray(leaf_batched), np.asarray(leaf_alone)
        assert leaf_batched.shape == leaf_alone.shape and leaf_batched.dtype == leaf_alone.dtype
        if np.issubdtype(leaf_batched.dtype, np.floating):
            allowed = 8 * EPS32 * np.maximum(1.0, np.abs(leaf_alone))
            np.testing.assert_array_less(np.abs(leaf_batched - leaf_alone), allowed + 1e-30)
        else:
            np.testing.assert_array_equal(leaf_batched, leaf_alone)


def _stack(items):
    return jax.tree.map(lambda *xs: np.stack(xs), *items)


@pytest.mark.parametrize("env_id", sorted(STATE_RANGES))
def test_vmap_over_4096_envs_equals_each_alone(env_id):
    program = compiled(env_id)
    keys, states, actions = _random_inputs(env_id, seed=0, n=NUM_ENVS)
    batched = program.batch_step(keys, states, actions, program.params)
    _assert_same(batched, program.each_alone(keys, states, actions, program.params))
    # And through the public single-env jit, call by call, for a subset.
    host = jax.device_get((keys, states, actions))
    alone = [
        program.single_step(*jax.tree.map(lambda x, i=i: x[i], host), program.params)
        for i in range(128)
    ]
    _assert_same(jax.tree.map(lambda x: x[:128], batched), _stack(jax.device_get(alone)))
    terminated, truncated = np.asarray(batched[1].terminated), np.asarray(batched[1].truncated)
    # The inputs exercise both flags, and both values of each.
    assert 0 < terminated.mean() < 1 or env_id == "rl_jax/Pendulum-v1"
    assert 0 < truncated.mean() < 1


@pytest.mark.parametrize("env_id", sorted(STATE_RANGES))
def test_jit_equals_no_jit(env_id):
    program = compiled(env_id)
    keys, states, actions = _random_inputs(env_id, seed=1, n=NUM_ENVS)
    jitted = program.batch_step(keys, states, actions, program.params)
    eager = jax.vmap(program.env.step, in_axes=(0, 0, 0, None))(
        keys, states, actions, program.params
    )
    _assert_same(jitted, eager)
    # Single env, op by op, on a few of them.
    for i in range(3):
        one = jax.tree.map(lambda x, i=i: x[i], (keys, states, actions))
        _assert_same(jax.tree.map(lambda x, i=i: x[i], jitted), program.env.step(*one))


@pytest.mark.parametrize("env_id", sorted(SWEPT_PARAM))
def test_vmap_over_params_equals_each_alone(env_id):
    """A params field varied per env (a sweep in one program) equals separate runs."""
    program = compiled(env_id)
    n = 64
    keys, states, actions = _random_inputs(env_id, seed=2, n=n)
    name, low, high = SWEPT_PARAM[env_id]
    values = np.linspace(low, high, n, dtype=np.float32)
    defaults = program.params
    params = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (n,)).copy(), defaults)
    params = params.replace(**{name: values})
    batched = program.sweep_step(keys, states, actions, params)
    host = jax.device_get((keys, states, actions, params))
    alone = [program.single_step(*jax.tree.map(lambda x, i=i: x[i], host)) for i in range(n)]
    _assert_same(batched, _stack(jax.device_get(alone)))
    # And the field matters: the batch is not just the default repeated.
    default_run = program.batch_step(keys, states, actions, defaults)
    assert not np.allclose(default_run[1].obs, batched[1].obs)
