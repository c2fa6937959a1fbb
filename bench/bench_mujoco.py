"""MuJoCo env throughput: our two backends next to gymnasium and raw batched MuJoCo C.

Env steps/s counts agent steps (``frame_skip`` physics substeps each), all measured in one run on
the same cores:

* gymnasium ``*-v5``: one env stepped in a Python loop, and ``AsyncVectorEnv`` with one env per
  process over as many processes as cores;
* raw ``mujoco.rollout`` (threaded batched C, one thread per core): ``frame_skip`` substeps per
  call with fresh controls, the ceiling for stepping MuJoCo C from Python;
* ours, ``backend="mujoco"`` and ``backend="mjx"``: ``jax.jit`` of a ``lax.scan`` over steps of
  ``vmap(env.step)`` with random actions drawn inside the program — what a learner's compiled step
  runs.

Ratios: ``mujoco/raw`` and ``mjx/raw`` against raw rollout at the same batch size, and
``mjx/best C`` against the best batched-C rate of the env at any batch size.
"""

from __future__ import annotations

import functools
import os
import time
from typing import Any

import jax
import numpy as np

from bench.machine import describe

ENV_IDS = ["InvertedPendulum-v5", "InvertedDoublePendulum-v5", "HalfCheetah-v5"]
BATCH_SIZES = (1, 64, 1024, 4096)
QUICK_BATCH_SIZES = (64,)
BACKENDS = ("mujoco", "mjx")
ROUNDS = 3  # raw C and both backends are timed in turn, ROUNDS times; the best of each is kept


def _scan_steps(n_envs: int) -> int:
    """Agent steps per compiled call: enough to hide dispatch, few enough to time big batches."""
    return 16 if n_envs < 1024 else 4


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def gymnasium_single_call(env_id: str, unwrapped: bool = False):
    """One gymnasium env stepped in a Python loop; a call runs 200 steps. ``unwrapped``: the env
    without ``gymnasium.make``'s wrappers (time limit, order and passive checks), which cost a
    few microseconds a step: the MuJoCo env itself. Its episodes are cut at the same limit."""
    import gymnasium

    env = gymnasium.make(env_id)
    limit = env.spec.max_episode_steps or np.inf
    if unwrapped:
        env = env.unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(
        env.action_space.low, env.action_space.high, (200, *env.action_space.shape)
    )
    actions = actions.astype(np.float32)
    episode_steps = [0]

    def call() -> int:
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            episode_steps[0] += 1
            if terminated or truncated or episode_steps[0] >= limit:
                env.reset()
                episode_steps[0] = 0
        return len(actions)

    return call


def gymnasium_async_call(env_id: str):
    """gymnasium's AsyncVectorEnv, one env per process, one process per core; a call runs 50
    vector steps (autoreset inside)."""
    import gymnasium

    processes = _cores()
    # spawn, not fork: this process already runs JAX's threads
    make = functools.partial(gymnasium.make, env_id)
    vector = gymnasium.vector.AsyncVectorEnv([make] * processes, context="spawn")
    vector.reset(seed=0)
    actions = vector.action_space.sample()
    _KEEP_ALIVE.append(vector)

    def call() -> int:
        for _ in range(50):
            vector.step(actions)
        return 50 * processes

    return call


def raw_rollout_call(env_id: str, n_envs: int):
    """Batched C stepping with nothing around it (the reference for the C backend): a call runs
    one agent step (``frame_skip`` substeps, fresh controls) of every env and returns n_envs."""
    import mujoco
    from mujoco import rollout

    env = _our_env(env_id, "mujoco")
    model, frame_skip = env.model, env.frame_skip
    threads = _cores()
    runner = rollout.Rollout(nthread=threads)
    datas = [mujoco.MjData(model) for _ in range(threads)]
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    data = mujoco.MjData(model)
    state = np.zeros((n_envs, size))
    mujoco.mj_getState(model, data, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state[:] = state[0]
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    controls = rng.uniform(low, high, (8, n_envs, frame_skip, model.nu))
    out = np.empty((n_envs, frame_skip, size))
    sensors = np.empty((n_envs, frame_skip, model.nsensordata))
    counter = [0]

    def call() -> int:
        control = controls[counter[0] % len(controls)]
        counter[0] += 1
        runner.rollout(model, datas, state, control, state=out, sensordata=sensors)
        state[:] = out[:, -1]
        return n_envs

    _KEEP_ALIVE.append(runner)
    return call


_KEEP_ALIVE: list = []  # rollout thread pools live until the benchmark ends


def release() -> None:
    """Close the rollout thread pools and gymnasium's worker processes made so far."""
    for runner in _KEEP_ALIVE:
        runner.close()
    _KEEP_ALIVE.clear()


_ENVS: dict = {}


def _our_env(env_id: str, backend: str):
    from rl_jax import envs

    key = (env_id, backend)
    if key not in _ENVS:
        _ENVS[key] = envs.make("rl_jax/" + env_id, backend=backend)
    return _ENVS[key]


def ours(env_id: str, backend: str, n_envs: int) -> tuple[Any, float]:
    """(a call that runs ``_scan_steps`` vmapped steps and returns env steps, compile seconds)."""
    env = _our_env(env_id, backend)
    n_actions, steps = env.action_space().shape[0], _scan_steps(n_envs)
    low, high = env.action_space().low, env.action_space().high

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = jax.random.uniform(key_action, (n_envs, n_actions), minval=low, maxval=high)
        state, ts = jax.vmap(env.step)(jax.random.split(key_step, n_envs), state, action)
        return state, ts.reward.sum()

    def run(state, key):
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state, rewards.sum()

    state, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n_envs))
    start = time.perf_counter()
    compiled = jax.jit(run).lower(state, jax.random.PRNGKey(1)).compile()
    compile_seconds = time.perf_counter() - start
    holder = {"state": state, "key": jax.random.PRNGKey(2)}

    def call() -> int:
        holder["key"], key = jax.random.split(holder["key"])
        holder["state"], total = compiled(holder["state"], key)
        total.block_until_ready()
        return steps * n_envs

    return call, compile_seconds


def _rate(call, min_time: float) -> float:
    """Env steps/s of ``call`` (which returns the env steps it ran), over at least ``min_time``."""
    call()  # warm up
    steps, start = 0, time.perf_counter()
    while True:
        steps += call()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            return steps / elapsed


def measure_batch(
    env_id: str, n_envs: int, min_time: float, rounds: int, backends: tuple = BACKENDS
) -> dict:
    """Raw C rollout and ``backends`` at one batch size, timed in turn; best of ``rounds``."""
    calls = {"raw": raw_rollout_call(env_id, n_envs)}
    compile_seconds = {}
    for backend in backends:
        calls[backend], compile_seconds[backend] = ours(env_id, backend, n_envs)
    best = dict.fromkeys(calls, 0.0)
    for _ in range(rounds):
        for name, call in calls.items():
            best[name] = max(best[name], _rate(call, min_time))
    return {"rates": best, "compile": compile_seconds}


def _format(rate: float) -> str:
    return f"{rate:,.0f}"


def run(quick: bool = False) -> str:
    min_time = 0.3 if quick else 1.0
    rounds = 1 if quick else ROUNDS
    sizes = QUICK_BATCH_SIZES if quick else BATCH_SIZES
    load_start = os.getloadavg()[0]
    lines = [
        "## MuJoCo envs: env steps/s (agent steps, frame skip included)",
        "",
        describe(),
        "",
        f"Command: `python -m bench mujoco{' --quick' if quick else ''}`; "
        f"{_cores()} cores; every batched C path uses {_cores()} threads. Raw C and both backends "
        f"are timed in turn, best of {rounds} rounds of >= {min_time} s.",
        "",
    ]
    for env_id in ENV_IDS:
        single = _rate(gymnasium_single_call(env_id), min_time)
        vector = _rate(gymnasium_async_call(env_id), min_time)
        rows = [(n, measure_batch(env_id, n, min_time, rounds)) for n in sizes]
        best_c = max(max(r["rates"]["raw"], r["rates"]["mujoco"]) for _, r in rows)
        lines += [
            f"### {env_id}",
            "",
            f"gymnasium, 1 env in a loop: {_format(single)}; "
            f"gymnasium AsyncVectorEnv ({_cores()} processes): {_format(vector)}; "
            f"best batched C: {_format(best_c)}",
            "",
            "| envs | raw C rollout | ours mujoco | ours mjx | mujoco/raw | mjx/raw | "
            "mjx/best C | mujoco/gym 1 env | mjx compile s |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for n_envs, result in rows:
            raw, c_rate, mjx_rate = (result["rates"][k] for k in ("raw", "mujoco", "mjx"))
            lines.append(
                f"| {n_envs} | {_format(raw)} | {_format(c_rate)} | {_format(mjx_rate)} | "
                f"{c_rate / raw:.2f} | {mjx_rate / raw:.2f} | {mjx_rate / best_c:.2f} | "
                f"{c_rate / single:.1f} | {result['compile']['mjx']:.0f} |"
            )
        lines.append("")
    release()
    lines.append(
        f"Load average (1 min): {load_start:.2f} at start, {os.getloadavg()[0]:.2f} at end."
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    from rl_jax.training.jax_setup import configure

    configure()
    print(run(quick=True))
