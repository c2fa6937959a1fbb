"""REINFORCE's rollout on MuJoCo C: stepping only the envs still in their episode
(``Environment.step_active``, the FFI op's ``rl_jax_mujoco_step_active``) against stepping every
env and keeping the ended ones' state (the generic path, as before the op could skip).

A REINFORCE batch is ``num_envs`` whole episodes per seed; the loop runs until the longest one
ends, so with exploring policies most envs sit finished for most of the loop. The policies are
the trained ones of the results row ``reinforce-double-pendulum`` (each seed's latest
checkpoint: run ``python -m bench.results reinforce-double-pendulum`` first), rolled out with
their training noise: 5 seeds x 32 episodes in one program, as the script trains.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from bench.machine import describe

ROOT = Path(__file__).resolve().parent.parent
RUN = ROOT / "runs" / "results" / "reinforce-double-pendulum"
SKIP, FULL = "step_active: ended envs skipped", "every env stepped, ended ones' state kept"


def programs(run_dir: Path = RUN) -> tuple[dict, tuple]:
    """``({label: call}, (params, obs_stats))``: ``call(params, obs_stats, keys)`` rolls out one
    batch for every seed of the run (seeds vmapped)."""
    import jax

    from rl_jax.agents import reinforce
    from rl_jax.envs.core.wrappers import Wrapper
    from rl_jax.run.policy import LoadedPolicy
    from rl_jax.training import episodes

    loaded = [LoadedPolicy(run_dir, seed=s, which="latest") for s in range(5)]
    config = loaded[0].config
    stack = lambda trees: jax.tree.map(lambda *x: np.stack(x), *trees)
    params = stack([p.state.agent.params for p in loaded])
    stats = stack([p.state.agent.obs_stats for p in loaded])
    env = episodes.make_eval_env(config)

    def program(which_env):
        one = lambda p, s, k: reinforce.rollout(p, k, config, s, env=which_env)
        return jax.jit(jax.vmap(one))

    return {SKIP: program(env), FULL: program(Wrapper(env))}, (params, stats)


def run(quick: bool = False) -> str:
    import jax

    if not (RUN / "metrics.jsonl").exists():
        first = "python -m bench.results reinforce-double-pendulum"
        return f"## REINFORCE rollout\n\nno run at {RUN}: run `{first}` first\n"
    calls, (params, stats) = programs()
    batches = 1 if quick else 3
    keys = [jax.random.split(jax.random.key(k), 5) for k in range(batches)]
    masks = {}
    for label, call in calls.items():  # compile outside the timing, and keep the episodes
        masks[label] = [np.asarray(call(params, stats, k).mask) for k in keys]
    same = all(np.array_equal(a, b) for a, b in zip(*masks.values(), strict=True))
    rounds = 1 if quick else 3
    seconds: dict[str, list[float]] = {label: [] for label in calls}
    for _ in range(rounds):
        for label, call in calls.items():
            start = time.perf_counter()
            for k in keys:
                jax.block_until_ready(call(params, stats, k))
            seconds[label].append((time.perf_counter() - start) / batches)
    mask = np.stack(masks[SKIP])  # [batches, seeds, horizon, envs]
    lengths = mask.sum(axis=2)
    loop = mask.any(axis=(1, 3)).sum(axis=1)  # loop steps per batch
    share = mask.sum() / (loop.sum() * mask.shape[1] * mask.shape[3])
    best = {label: min(values) for label, values in seconds.items()}
    lines = [
        "## REINFORCE rollout on MuJoCo C: skipping ended envs",
        "",
        describe(),
        "",
        "`python -m bench reinforce" + (" --quick`" if quick else "`"),
        "",
        "The trained policies of `runs/results/reinforce-double-pendulum` (latest checkpoints, 5 "
        f"seeds x 32 episodes with training noise), {batches} batch(es) with the same keys for "
        f"both programs (identical episodes: {same}), best of {rounds} interleaved round(s). "
        f"Episode length mean {lengths.mean():.0f}, max {lengths.max():.0f}; the loop ran "
        f"{loop.mean():.0f} steps per batch, and the envs still running were {share:.0%} of "
        "the loop's steps x envs.",
        "",
        "| program | s per batch (5 seeds x 32 episodes) | speed-up |",
        "|---|---:|---:|",
    ]
    for label, value in best.items():
        lines.append(f"| {label} | {value:.2f} | {best[FULL] / value:.1f}x |")
    load = f"load avg {[round(x, 2) for x in os.getloadavg()]} at end"
    return "\n".join([*lines, "", load, ""])
