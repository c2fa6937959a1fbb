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

import os
import time

import jax
import numpy as np

from bench.machine import describe, timeit

ENV_IDS = ["InvertedPendulum-v5", "InvertedDoublePendulum-v5", "HalfCheetah-v5"]
BATCH_SIZES = (1, 64, 1024, 4096)
QUICK_BATCH_SIZES = (1, 64)
SCAN_STEPS = 16  # agent steps per compiled call
BACKENDS = ("mujoco", "mjx")


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


def gymnasium_single(env_id: str, min_time: float) -> float:
    import gymnasium

    env = gymnasium.make(env_id)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (1000, *env.action_space.shape))
    actions = actions.astype(np.float32)

    def run():
        for action in actions[:200]:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()

    seconds = timeit(run, min_time=min_time)
    return 200 / seconds


def gymnasium_async(env_id: str, min_time: float) -> float:
    import gymnasium

    processes = _cores()
    vector = gymnasium.vector.AsyncVectorEnv([lambda: gymnasium.make(env_id)] * processes)
    try:
        vector.reset(seed=0)
        actions = vector.action_space.sample()

        def run():
            for _ in range(50):
                vector.step(actions)

        seconds = timeit(run, min_time=min_time)
    finally:
        vector.close()
    return 50 * processes / seconds


def raw_rollout(env_id: str, n_envs: int, min_time: float) -> float:
    """Batched C stepping with nothing around it: the reference for the C backend."""
    import mujoco
    from mujoco import rollout

    env = _our_env(env_id, "mujoco")
    model, frame_skip = env.model, env.frame_skip
    threads = _cores()
    runner = rollout.Rollout(nthread=threads)
    datas = [mujoco.MjData(model) for _ in range(threads)]
    size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state = np.zeros((n_envs, size))
    data = mujoco.MjData(model)
    mujoco.mj_getState(model, data, state[0], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    state[:] = state[0]
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    controls = rng.uniform(low, high, (8, n_envs, frame_skip, model.nu))
    out = np.empty((n_envs, frame_skip, size))
    sensors = np.empty((n_envs, frame_skip, model.nsensordata))

    def run():
        nonlocal state
        for control in controls:
            runner.rollout(model, datas, state, control, state=out, sensordata=sensors)
            state = out[:, -1].copy()

    try:
        seconds = timeit(run, min_time=min_time)
    finally:
        runner.close()
    return 8 * n_envs / seconds


_ENVS: dict = {}


def _our_env(env_id: str, backend: str):
    import envs

    key = (env_id, backend)
    if key not in _ENVS:
        _ENVS[key] = envs.make("rl_jax/" + env_id, backend=backend)
    return _ENVS[key]


def ours(env_id: str, backend: str, n_envs: int, min_time: float) -> tuple[float, float]:
    """(env steps/s, compile seconds) of a jitted scan of vmapped steps."""
    env = _our_env(env_id, backend)
    n_actions = env.action_space().shape[0]
    low, high = env.action_space().low, env.action_space().high

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = jax.random.uniform(key_action, (n_envs, n_actions), minval=low, maxval=high)
        state, ts = jax.vmap(env.step)(jax.random.split(key_step, n_envs), state, action)
        return state, ts.reward.sum()

    @jax.jit
    def run(state, key):
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, SCAN_STEPS))
        return state, rewards.sum()

    state, _ = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), n_envs))
    start = time.perf_counter()
    compiled = run.lower(state, jax.random.PRNGKey(1)).compile()
    compile_seconds = time.perf_counter() - start
    holder = {"state": state, "key": jax.random.PRNGKey(2)}

    def call():
        holder["key"], key = jax.random.split(holder["key"])
        holder["state"], total = compiled(holder["state"], key)
        total.block_until_ready()

    return SCAN_STEPS * n_envs / timeit(call, min_time=min_time), compile_seconds


def _format(rate: float) -> str:
    return f"{rate:,.0f}"


def run(quick: bool = False) -> str:
    min_time = 0.5 if quick else 2.0
    sizes = QUICK_BATCH_SIZES if quick else BATCH_SIZES
    load_start = os.getloadavg()[0]
    lines = [
        "## MuJoCo envs: env steps/s (agent steps, frame skip included)",
        "",
        describe(),
        "",
        f"Command: `python -m bench mujoco{' --quick' if quick else ''}`; "
        f"{_cores()} cores/threads for every batched C path.",
        "",
    ]
    for env_id in ENV_IDS:
        single = gymnasium_single(env_id, min_time)
        vector = gymnasium_async(env_id, min_time)
        rows = []
        for n_envs in sizes:
            raw = raw_rollout(env_id, n_envs, min_time)
            measured = {b: ours(env_id, b, n_envs, min_time) for b in BACKENDS}
            rows.append((n_envs, raw, measured))
        best_c = max(max(raw, measured["mujoco"][0]) for _, raw, measured in rows)
        lines += [
            f"### {env_id}",
            "",
            f"gymnasium, 1 env in a loop: {_format(single)}; "
            f"gymnasium AsyncVectorEnv ({_cores()} processes): {_format(vector)}",
            "",
            "| envs | raw C rollout | ours mujoco | ours mjx | mujoco/raw | mjx/raw | "
            "mjx/best C | mujoco/gym 1 env | mjx compile s |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for n_envs, raw, measured in rows:
            c_rate, mjx_rate = measured["mujoco"][0], measured["mjx"][0]
            lines.append(
                f"| {n_envs} | {_format(raw)} | {_format(c_rate)} | {_format(mjx_rate)} | "
                f"{c_rate / raw:.2f} | {mjx_rate / raw:.2f} | {mjx_rate / best_c:.2f} | "
                f"{c_rate / single:.1f} | {measured['mjx'][1]:.0f} |"
            )
        lines.append("")
    lines.append(
        f"Load average (1 min): {load_start:.2f} at start, {os.getloadavg()[0]:.2f} at end."
    )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    from rl_jax.jax_setup import configure

    configure()
    print(run(quick=True))
