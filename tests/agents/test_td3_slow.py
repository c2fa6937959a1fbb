"""Long TD3 learning runs (``pytest -m slow -s tests/agents/test_td3_slow.py``): 3 seeds each,
vmapped in one compiled program, with each env's documented recipe (``td3.default_config(env_id)``
and ``td3.default_hyperparams(env_id)``). They print env steps, wall-clock and the per-seed results.
"""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax import envs
from rl_jax.agents.td3 import make_networks, td3
from rl_jax.training import parallel, params

SEEDS = (0, 1, 2)
ROCKET_STEPS = 40_000  # per seed: 8 chunks of the rocket recipe


def _train(env_id: str, env_steps: int):
    """``env_steps`` per seed (all envs of a run), a whole number of the recipe's chunks."""
    config, hparams = td3.default_config(env_id), td3.default_hyperparams(env_id)
    chunks, rest = divmod(env_steps, config.env_steps_per_chunk)
    assert rest == 0 and chunks > 0, (env_steps, config.env_steps_per_chunk)
    runner = parallel.Program(td3, config, num_hparams=1, num_seeds=len(SEEDS))
    stacked = params.stack([hparams])
    start = time.perf_counter()
    state = runner.init(parallel.seed_keys(SEEDS), stacked)
    history = []
    for _ in range(chunks):
        state, metrics = runner.train_chunk(state, stacked)
        history.append(jax.device_get(metrics))
        print(
            f"{env_id} env steps {int(metrics.env_steps[0, 0])}: eval returns "
            f"{np.round(history[-1].eval_return[0], 1)} ({time.perf_counter() - start:.0f} s)"
        )
    seconds = time.perf_counter() - start
    steps = int(history[-1].env_steps[0, 0])
    print(
        f"{env_id}: {steps} env steps and {int(history[-1].updates[0, 0])} updates per seed, "
        f"{len(SEEDS)} seeds, {seconds:.0f} s wall-clock including compilation"
    )
    return config, state, history


@pytest.mark.slow
def test_td3_pendulum_reaches_minus_200():
    _, _, history = _train("rl_jax/Pendulum-v1", env_steps=20_000)
    final = history[-1].eval_return[0]
    print(f"final eval return per seed {np.round(final, 1)}, mean {np.mean(final):.1f}")
    assert np.mean(final) >= -200.0


def _rollout_from(env, actor, actor_params, start, steps: int):
    """The deterministic policy from an exact start: states ``[steps, 2]`` and done flags."""
    state, timestep = env.reset_to(jnp.asarray(start, jnp.float32))

    def step(carry, _):
        state, obs = carry
        state, timestep = env.step(jax.random.key(0), state, actor.apply(actor_params, obs))
        return (state, timestep.obs), (timestep.obs, timestep.terminated)

    _, (states, terminated) = jax.lax.scan(step, (state, timestep.obs), None, length=steps)
    return states, terminated


@pytest.mark.slow
@pytest.mark.xfail(
    strict=True,
    reason="known shortfall: no recipe found yet (40k steps: all 3 seeds still creeping in; "
    "see the comments of td3.HPARAM_RECIPES['rl_jax/Rocket-v0']); strict, so a pass shows up",
)
def test_td3_rocket_settles_at_origin_from_one_zero():
    env_id = "rl_jax/Rocket-v0"
    config, state, _ = _train(env_id, env_steps=ROCKET_STEPS)
    env, actor = envs.make(env_id), make_networks(config).actor
    steps = env.max_episode_steps
    rollout = jax.jit(lambda params: _rollout_from(env, actor, params, [1.0, 0.0], steps))
    crashed, settled = [], []
    for index, seed in enumerate(SEEDS):
        params = parallel.select(state, 0, index).agent.actor
        states, terminated = jax.device_get(rollout(params))
        inside = np.all(np.abs(states) < 0.05, axis=-1)
        outside = np.flatnonzero(~inside)
        settled_at = 0 if outside.size == 0 else int(outside[-1]) + 1
        print(
            f"seed {seed}: inside |x|, |v| < 0.05 from step {settled_at} of {steps}; "
            f"final (x, v) = {np.round(states[-1], 4)}"
        )
        crashed.append(bool(terminated.any()))
        settled.append(settled_at)
    # Every seed first, so a failure shows all of them.
    assert not any(crashed)  # no crash (and the 1e-8 goal is never hit exactly)
    # It arrives, then stays: inside for (at least) the last second of the episode.
    assert max(settled) <= steps - 100, settled


@pytest.mark.slow
def test_td3_settle_variant_comes_to_rest_from_one_zero_in_every_seed(tmp_path):
    """The RESULTS.md row of rl_jax/RocketSettle-v0: the script's defaults (5 seeds, 200k env
    steps), then the latest policy of every seed rolled from (1, 0) by ``rocket_report``: each
    enters |x|, |v| <= 0.01 and stays inside to step 500."""
    import subprocess
    import sys
    from pathlib import Path

    from settle import assert_every_latest_policy_settles

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "rocket_settle"
    script = root / "experiments" / "td3_rocket_settle.py"
    subprocess.run([sys.executable, str(script), "--out", str(out)], check=True, cwd=root)
    assert_every_latest_policy_settles(out, seeds=5)
