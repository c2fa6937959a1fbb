"""Atari through the ALE (``envs.from_atari``): agent steps/s of Pong with DQN's preprocessing,
the library on its own next to our adapter inside a compiled scan, at 1, 8 and 32 envs.

* gymnasium, from Python: ``num_envs`` of the adapter's host envs (``ALE/Pong-v5`` in gymnasium's
  ``AtariPreprocessing``, in ``FrameStackObservation``) stepped one after another from a Python
  loop with random actions, each reset when its episode ends. This is what the adapter runs on
  the host, without JAX: the difference to the next rows is the callback's cost.
* ale-py's ``AtariVectorEnv``: the same preprocessing in ale-py's C++ threads (as many as the
  machine has cores), one ``step`` call for the batch; the alternative the adapter does not use
  (its module docstring says why).
* ours: ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of steps with random actions
  drawn inside the scan, what the learners run: one host callback per step for the whole batch,
  the frame stack in JAX, and a host reset only for the envs whose episode ended.

Sticky actions (0.25) and no-op starts (up to 30) are on everywhere, as ALE v5's defaults.
"""

from __future__ import annotations

import gymnasium
import jax
import numpy as np

from bench.bench_classic import measure_interleaved
from bench.machine import rates_section
from rl_jax import envs
from rl_jax.envs.adapters import atari

SIZES = (1, 8, 32)
GAME = "Pong"


def python_rollout(num_envs: int, block: int):
    """``block`` steps of ``num_envs`` host envs stepped one at a time from Python."""
    host = [
        gymnasium.wrappers.FrameStackObservation(atari.host_env(GAME, frame_and_lives=False), 4)
        for _ in range(num_envs)
    ]
    for seed, env in enumerate(host):
        env.reset(seed=seed)
    actions = np.random.default_rng(0).integers(6, size=(block, num_envs))

    def once() -> int:
        for row in actions:
            for env, action in zip(host, row, strict=True):
                _, _, terminated, truncated, _ = env.step(int(action))
                if terminated or truncated:
                    env.reset()
        return num_envs * block

    return once


def vector_rollout(num_envs: int, block: int):
    """``block`` steps of ale-py's ``AtariVectorEnv`` (preprocessing in C++ threads)."""
    from ale_py.vector_env import AtariVectorEnv

    env = AtariVectorEnv(
        GAME.lower(), num_envs, repeat_action_probability=0.25, reward_clipping=False
    )
    env.reset(seed=0)
    actions = np.random.default_rng(0).integers(6, size=(block, num_envs))

    def once() -> int:
        for row in actions:
            env.step(row)  # it resets ended envs itself
        return num_envs * block

    return once


def adapter_rollout(num_envs: int, block: int):
    """``block`` steps of ``num_envs`` envs in one compiled scan under ``AutoReset``."""
    env = envs.AutoReset(envs.from_atari(GAME))

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = jax.random.randint(key_action, (num_envs,), 0, 6)
        state, ts = jax.vmap(env.step)(jax.random.split(key_step, num_envs), state, action)
        return state, ts.reward.sum()

    @jax.jit
    def run(state, key):
        return jax.lax.scan(body, state, jax.random.split(key, block))

    state, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), num_envs))
    carry = {"state": state, "key": jax.random.key(1)}
    state, _ = jax.block_until_ready(run(state, carry["key"]))  # compile outside the timing

    def once() -> int:
        # the host games move on, so the state must too: an old state's episodes are cut
        carry["key"], key = jax.random.split(carry["key"])
        carry["state"], _ = jax.block_until_ready(run(carry["state"], key))
        return num_envs * block

    carry["state"] = state
    return once


def run(quick: bool = False) -> str:
    min_time, rounds = (0.5, 1) if quick else (2.0, 3)
    rollouts = {}
    for num_envs in SIZES:
        block = max(4, (96 if quick else 256) // num_envs)
        rollouts["gymnasium AtariPreprocessing, from Python", num_envs] = python_rollout(
            num_envs, block
        )
        rollouts["ale-py AtariVectorEnv (C++ threads)", num_envs] = vector_rollout(num_envs, block)
        rollouts["envs.from_atari, jit(scan(vmap(AutoReset(env).step)))", num_envs] = (
            adapter_rollout(num_envs, block)
        )
    rates = measure_interleaved(rollouts, rounds, min_time)
    command = "PYTHONPATH=$PWD python -m bench atari" + (" --quick" if quick else "")
    explanation = (
        f"Agent steps/s of {GAME} (4 frames each, sticky actions 0.25, random actions, resets "
        f"included), median of {rounds} interleaved round(s) of >= {min_time} s each; ratio over "
        "one gymnasium env stepped from Python in the same rounds."
    )
    title = "Atari through the ALE: the library alone vs envs.from_atari in a compiled scan"
    return rates_section(title, command, explanation, ("steps/s", "vs one gymnasium env"), rates)
