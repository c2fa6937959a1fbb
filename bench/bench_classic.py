"""Classic envs: env steps/s of the JAX envs at 1, 64 and 4,096 envs next to one-at-a-time
numpy baselines, measured side by side in one run.

* JAX: ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of steps, uniform random actions
  drawn inside the scan, ``block_until_ready`` after each block.
* JAX via gymnasium: ``gymnasium.make_vec(id, vectorization_mode="vector_entry_point")``, one
  ``step`` call per step from Python (numpy actions in, numpy results out).
* Baselines, one env stepped at a time from a Python loop with pre-drawn random actions and a
  reset whenever an episode ends: for the rocket a plain numpy ``gymnasium.Env`` of the same spec
  (``bench/numpy_rocket.py``); for CartPole and Pendulum gymnasium's own envs from
  ``gymnasium.make`` (with its default wrappers, as users run them).
"""

from __future__ import annotations

import os
import time

import gymnasium
import jax
import jax.numpy as jnp

import envs
from bench.machine import describe, timeit
from bench.numpy_rocket import NumpyRocketEnv

SIZES = (1, 64, 4096)
CASES = [
    ("rocket", "rl_jax/Rocket-v0", "numpy gymnasium.Env (bench/numpy_rocket.py)"),
    ("cartpole", "rl_jax/CartPole-v1", "gymnasium CartPole-v1"),
    ("pendulum", "rl_jax/Pendulum-v1", "gymnasium Pendulum-v1"),
]


def _random_actions(space: envs.Space, key: jax.Array, num_envs: int) -> jax.Array:
    if isinstance(space, envs.Discrete):
        return jax.random.randint(key, (num_envs,), 0, space.n, space.dtype)
    low, high = jnp.asarray(space.low), jnp.asarray(space.high)
    return jax.random.uniform(key, (num_envs, *space.shape), space.dtype, low, high)


def jax_steps_per_second(env_id: str, num_envs: int, block: int, min_time: float) -> float:
    """Env steps/s of ``block`` autoreset steps of ``num_envs`` envs in one compiled scan."""
    env = envs.AutoReset(envs.make(env_id))
    space = env.action_space()
    step = jax.vmap(env.step)

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = _random_actions(space, key_action, num_envs)
        state, timestep = step(jax.random.split(key_step, num_envs), state, action)
        return state, timestep.reward.sum()

    @jax.jit
    def run(state, key):
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, block))
        return state, rewards.sum()

    state, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
    key = jax.random.PRNGKey(1)
    seconds = timeit(lambda: jax.block_until_ready(run(state, key)), min_time=min_time)
    return num_envs * block / seconds


def make_vec_steps_per_second(env_id: str, num_envs: int, min_time: float) -> float:
    """Env steps/s through the gymnasium VectorEnv API (one Python call per step)."""
    vec = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    vec.reset(seed=0)
    vec.action_space.seed(0)
    actions = [vec.action_space.sample() for _ in range(64)]
    calls = 0

    def one_step():
        nonlocal calls
        vec.step(actions[calls % len(actions)])
        calls += 1

    return num_envs / timeit(one_step, min_time=min_time, warmup=3)


def baseline_steps_per_second(name: str, min_time: float) -> float:
    """Env steps/s of one numpy env stepped from Python, reset when an episode ends."""
    if name == "rocket":
        env = NumpyRocketEnv()
    else:
        env = gymnasium.make({"cartpole": "CartPole-v1", "pendulum": "Pendulum-v1"}[name])
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(1000)]
    steps, start = 0, time.perf_counter()
    while True:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        steps += len(actions)
        if time.perf_counter() - start >= min_time:
            return steps / (time.perf_counter() - start)


def _row(env: str, implementation: str, num_envs: int, rate: float, baseline: float) -> str:
    return f"| {env} | {implementation} | {num_envs:,} | {rate:,.0f} | {rate / baseline:,.1f}x |"


def run(quick: bool = False) -> str:
    min_time = 0.3 if quick else 1.0
    blocks = {1: 500, 64: 500, 4096: 100 if quick else 500}
    lines = [
        "## Classic envs: JAX vs one env at a time",
        "",
        describe(),
        "",
        "`PYTHONPATH=$PWD python -m bench classic" + (" --quick`" if quick else "`"),
        "",
        "Env steps/s (agent steps; autoreset included). Ratio: over the one-at-a-time baseline "
        "measured in this run.",
        "",
        "| env | implementation | envs | steps/s | vs baseline |",
        "|---|---|---:|---:|---:|",
    ]
    for name, env_id, baseline_label in CASES:
        baseline = baseline_steps_per_second(name, min_time)
        lines.append(_row(name, baseline_label + ", one at a time", 1, baseline, baseline))
        for num_envs in SIZES:
            rate = jax_steps_per_second(env_id, num_envs, blocks[num_envs], min_time)
            lines.append(_row(name, "JAX jit(scan(vmap(step)))", num_envs, rate, baseline))
        for num_envs in (64, 4096):
            rate = make_vec_steps_per_second(env_id, num_envs, min_time)
            lines.append(_row(name, "JAX via gymnasium.make_vec", num_envs, rate, baseline))
    load = f"load avg {[round(x, 2) for x in os.getloadavg()]} at end"
    return "\n".join([*lines, "", load, ""])
