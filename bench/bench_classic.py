"""Classic envs: env steps/s of the JAX envs at 1, 64 and 4,096 envs next to one-at-a-time
numpy baselines, measured side by side in one run.

* JAX: ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of steps, uniform random actions
  drawn inside the scan, ``block_until_ready`` after each block; the same with
  ``envs.core.batched.autoreset_step`` (same semantics; resets, and their PRNG keys, computed only
  for the envs that finished);
  and, for the rocket, without autoreset (the env's own cost).
* JAX via gymnasium: ``gymnasium.make_vec(id, vectorization_mode="vector_entry_point")``, one
  ``step`` call per step from Python (numpy actions in, numpy results out).
* Baselines, one env stepped at a time from a Python loop with pre-drawn random actions and a
  reset whenever an episode ends: for the rocket a plain numpy ``gymnasium.Env`` of the same spec
  (``bench/numpy_rocket.py``); for CartPole and Pendulum gymnasium's own envs from
  ``gymnasium.make`` (with its default wrappers, as users run them).
"""

from __future__ import annotations

import functools
import os
import time

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from bench.machine import describe
from bench.numpy_rocket import NumpyRocketEnv, ScalarGoalNumpyRocketEnv
from rl_jax import envs
from rl_jax.envs.core.batched import autoreset_step

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


def _batch_step(env_id: str, mode: str, num_envs: int):
    """``(key, states, actions) -> (states, timestep)`` for a batch, by autoreset mode."""
    env = envs.make(env_id)
    if mode == "batched":
        return env, functools.partial(autoreset_step, env)
    if mode == "wrapper":
        env = envs.AutoReset(env)
    vmapped = jax.vmap(env.step)
    return env, lambda key, states, actions: vmapped(
        jax.random.split(key, num_envs), states, actions
    )


def jax_rollout(env_id: str, num_envs: int, block: int, mode: str = "wrapper"):
    """A function running ``block`` steps of ``num_envs`` envs in one compiled scan; returns the
    number of env steps it ran. ``mode``: autoreset by the ``AutoReset`` wrapper under vmap
    ("wrapper"), by ``envs.core.batched.autoreset_step`` ("batched"), or none ("none")."""
    env, step = _batch_step(env_id, mode, num_envs)
    space = env.action_space()

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = _random_actions(space, key_action, num_envs)
        state, timestep = step(key_step, state, action)
        return state, timestep.reward.sum()

    @jax.jit
    def run(state, key):
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, block))
        return state, rewards.sum()

    state, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), num_envs))
    key = jax.random.PRNGKey(1)
    jax.block_until_ready(run(state, key))  # compile outside the timing

    def once() -> int:
        jax.block_until_ready(run(state, key))
        return num_envs * block

    return once


def make_vec_rollout(env_id: str, num_envs: int, block: int = 20):
    """``block`` steps through the gymnasium VectorEnv API (one Python call per step)."""
    vec = gymnasium.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    vec.reset(seed=0)
    vec.action_space.seed(0)
    actions = [vec.action_space.sample() for _ in range(block)]
    vec.step(actions[0])  # compile outside the timing

    def once() -> int:
        for action in actions:
            vec.step(action)
        return num_envs * block

    return once


def baseline_rollout(name: str, block: int = 1000):
    """``block`` steps of one numpy env stepped from Python, reset when an episode ends."""
    if name == "rocket":
        env = NumpyRocketEnv()
    elif name == "rocket, scalar goal test":
        env = ScalarGoalNumpyRocketEnv()
    else:
        env = gymnasium.make({"cartpole": "CartPole-v1", "pendulum": "Pendulum-v1"}[name])
    env.reset(seed=0)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(block)]

    def once() -> int:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        return block

    return once


def steps_per_second(rollout, min_time: float) -> float:
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < min_time:
        steps += rollout()
    return steps / (time.perf_counter() - start)


def measure_interleaved(rollouts: dict, rounds: int, min_time: float) -> dict:
    """Median steps/s of each rollout, measured in alternating rounds so that a change in the
    machine's load hits all of them alike."""
    rates: dict = {name: [] for name in rollouts}
    for _ in range(rounds):
        for name, rollout in rollouts.items():
            rates[name].append(steps_per_second(rollout, min_time))
    return {name: float(np.median(values)) for name, values in rates.items()}


def _row(env: str, implementation: str, num_envs: int, rate: float, baseline: float) -> str:
    return f"| {env} | {implementation} | {num_envs:,} | {rate:,.0f} | {rate / baseline:,.1f}x |"


IMPLEMENTATIONS = {
    "wrapper": "JAX jit(scan(vmap(AutoReset(env).step)))",
    "batched": "JAX jit(scan(envs.core.batched.autoreset_step))",
    "make_vec": "JAX via gymnasium.make_vec, numpy per step",
    "none": "JAX jit(scan(vmap(env.step))), no autoreset",
    "scalar goal": "numpy gymnasium.Env, goal test on scalars instead of np.allclose",
}


def _rollouts(name: str, env_id: str, blocks: dict[int, int]) -> dict:
    rollouts = {("baseline", 1): baseline_rollout(name)}
    if name == "rocket":  # a faster numpy baseline, to read the ratios against
        rollouts["scalar goal", 1] = baseline_rollout("rocket, scalar goal test")
    for mode in ("wrapper", "batched"):
        for num_envs in SIZES:
            rollouts[mode, num_envs] = jax_rollout(env_id, num_envs, blocks[num_envs], mode)
    for num_envs in (64, 4096):
        rollouts["make_vec", num_envs] = make_vec_rollout(env_id, num_envs)
    if name == "rocket":  # the env's own cost, without resetting (diagnostic)
        rollouts["none", 4096] = jax_rollout(env_id, 4096, blocks[4096], "none")
    return rollouts


def _rows(name: str, label: str, rates: dict) -> list[str]:
    baseline = rates["baseline", 1]
    rows = [_row(name, label + ", one at a time", 1, baseline, baseline)]
    for (mode, num_envs), rate in rates.items():
        if mode in IMPLEMENTATIONS:
            rows.append(_row(name, IMPLEMENTATIONS[mode], num_envs, rate, baseline))
    return rows


def run(quick: bool = False) -> str:
    min_time, rounds = (0.2, 1) if quick else (0.5, 3)
    blocks = {1: 500, 64: 500, 4096: 100 if quick else 500}
    lines = [
        "## Classic envs: JAX vs one env at a time",
        "",
        describe(),
        "",
        "`PYTHONPATH=$PWD python -m bench classic" + (" --quick`" if quick else "`"),
        "",
        "Env steps/s (agent steps, autoreset included, random actions), median of "
        f"{rounds} interleaved round(s) of >= {min_time} s each; ratio over the one-at-a-time "
        "baseline measured in the same rounds.",
        "",
        "| env | implementation | envs | steps/s | vs baseline |",
        "|---|---|---:|---:|---:|",
    ]
    notes = []
    for name, env_id, label in CASES:
        rates = measure_interleaved(_rollouts(name, env_id, blocks), rounds, min_time)
        lines.extend(_rows(name, label, rates))
        if name == "rocket":
            best, scalar = rates["batched", 4096], rates["scalar goal", 1]
            notes.append(
                f"Rocket at 4,096 envs (batched autoreset) over the scalar-goal numpy baseline: "
                f"{best / scalar:,.0f}x."
            )
    load = f"load avg {[round(x, 2) for x in os.getloadavg()]} at end"
    return "\n".join([*lines, "", *notes, "", load, ""])
