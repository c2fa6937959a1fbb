"""Train TD3 on half cheetah with S seeds in one program and log eval return vs steps and seconds.

The evidence behind td3's half-cheetah recipe: a recipe (config overrides as
JSON) runs with ``rl_jax.training.parallel.Program`` on the MuJoCo C backend, one chunk at a time,
and every chunk appends one JSON line (env steps per seed, wall-clock seconds since start with and
without the first call's compilation, each seed's eval return, their mean, the load average)::

    nice -n 5 python -m bench.cheetah_recipe --seeds 5 --recipe '{"batch_size": 128}' \\
        --max-minutes 50 --stop-at 5000 --out bench/results/cheetah_recipe.jsonl

``--measure N`` instead times N chunks after the first (no learning-starts wait: updates from
the first step) and prints env steps/s and updates/s per seed: how candidates are compared.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

ENV_ID = "rl_jax/HalfCheetah-v5"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--recipe",
        default="{}",
        help='JSON of Config overrides; "learner": "td7" (or another name) for a learner other '
        "than td3",
    )
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--devices", type=int, default=1, help="CPU devices to shard seeds over")
    p.add_argument("--total-steps", type=int, default=1_000_000, help="env steps per seed")
    p.add_argument("--max-minutes", type=float, default=50.0, help="stop after this wall-clock")
    p.add_argument("--stop-at", type=float, default=None, help="stop once the seed mean >= this")
    p.add_argument("--measure", type=int, default=0, help="only time this many chunks")
    p.add_argument("--out", type=Path, default=None, help="JSON-lines log (default: stdout)")
    return p.parse_args(argv)


def make_runner(recipe: dict[str, Any], seeds: int, hparam_sets: int = 1) -> tuple:
    """``(runner, state, hparams, config)`` for ``seeds`` x ``hparam_sets`` runs of a recipe
    (hyperparameter sets identical: the grid benchmark measures cost, not learning); the
    recipe's ``"learner"`` (default ``"td3"``) names its learner."""
    from rl_jax.run.learners import resolve as resolve_algorithm
    from rl_jax.training import episodes, parallel, params

    # JSON gives lists; the static config must be hashable (it keys the compiled program)
    recipe = {k: tuple(v) if isinstance(v, list) else v for k, v in recipe.items()}
    learner = resolve_algorithm(recipe.pop("learner", "td3"))
    config = learner.default_config(ENV_ID, **recipe)
    # Build (and cache) the envs outside any trace: the MuJoCo env's constructor computes its
    # initial observation with jnp, which fails when first called under Program's eval_shape.
    episodes.make_train_env(config)
    one = learner.default_hyperparams(ENV_ID)
    hparams = params.stack([one] * hparam_sets)
    runner = parallel.Program(learner, config, num_hparams=hparam_sets, num_seeds=seeds)
    state = runner.init(parallel.seed_keys(list(range(seeds))), hparams)
    return runner, state, hparams, config


def measure(recipe: dict[str, Any], seeds: int, chunks: int, hparam_sets: int = 1) -> dict:
    """Seconds of the first chunk call (compile + run) and the mean of ``chunks`` more, and per
    seed env steps/s and updates/s; updates from the first step (``learning_starts=0``)."""
    import jax

    recipe = {"learning_starts": 0, **recipe}
    start = time.perf_counter()
    runner, state, hparams, config = make_runner(recipe, seeds, hparam_sets)
    state, metrics = runner.train_chunk(state, hparams)
    jax.block_until_ready(metrics)
    first = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(chunks):
        state, metrics = runner.train_chunk(state, hparams)
        jax.block_until_ready(metrics)
    seconds = (time.perf_counter() - start) / chunks
    steps = config.env_steps_per_chunk
    iterations = config.iterations_per_chunk
    return {
        "recipe": recipe,
        "runs": seeds * hparam_sets,
        "devices": int(runner.mesh.devices.size),
        "first_call_s": round(first, 2),
        "chunk_s": round(seconds, 3),
        "env_steps_per_s_per_run": round(steps / seconds, 1),
        "updates_per_s_per_run": round(iterations * config.updates_per_iteration / seconds, 1),
        "load": round(os.getloadavg()[0], 2),
    }


def train(args: argparse.Namespace) -> None:
    import jax
    import numpy as np

    recipe = json.loads(args.recipe)
    started = time.perf_counter()
    runner, state, hparams, config = make_runner(recipe, args.seeds)
    out = open(args.out, "a") if args.out else None  # noqa: SIM115 - closed below
    header = {"recipe": recipe, "seeds": args.seeds, "devices": len(jax.devices())}
    print(json.dumps(header), file=out, flush=True)
    compile_seconds = None
    steps = 0
    while steps < args.total_steps:
        chunk_start = time.perf_counter()
        state, metrics = runner.train_chunk(state, hparams)
        returns = np.asarray(metrics.eval_return)[0]
        now = time.perf_counter()
        if compile_seconds is None:  # the first call compiles; estimate it as its excess
            compile_seconds = now - chunk_start
        steps = int(np.asarray(metrics.env_steps).reshape(-1)[0])
        row = {
            "step": steps,
            "seconds": round(now - started, 1),
            "eval_return": [round(float(r), 1) for r in returns],
            "mean": round(float(np.mean(returns)), 1),
            "chunk_s": round(now - chunk_start, 1),
            "load": round(os.getloadavg()[0], 2),
        }
        print(json.dumps(row), file=out, flush=True)
        done = args.stop_at is not None and row["mean"] >= args.stop_at
        if done or now - started > 60 * args.max_minutes:
            break
    if out:
        out.close()


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    from rl_jax.training.jax_setup import configure

    configure(cpu_devices=args.devices)
    if args.measure:
        print(json.dumps(measure(json.loads(args.recipe), args.seeds, args.measure)), flush=True)
    else:
        train(args)


if __name__ == "__main__":
    main()
