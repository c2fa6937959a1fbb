"""Training-loop updates/s of DQN from pixels (``rl_jax/CartPolePixels-v1``) with its seeds
vmapped against its seeds as an unrolled loop in the same compiled program
(``parallel.Program(loop_seeds=True)``, the pixel recipe's default).

Vmapped over seeds, XLA turns each convolution with per-seed weights into one grouped
convolution, which this CPU runs several times slower than the same convs one seed after
another. Each program is the recipe's training chunk (4 envs, 2 updates per iteration, batch 64,
the 2013 DQN torso, frames drawn in JAX), timed on chunks of 100 iterations (200 updates per
seed) once learning has started, for 3 seeds (the pixel goal's) and 1 seed for reference.
"""

from __future__ import annotations

import os
import time

import jax
import numpy as np

from bench.machine import describe
from rl_jax.agents.dqn import dqn
from rl_jax.training import parallel, params

ENV_ID = "rl_jax/CartPolePixels-v1"
ITERATIONS = 100  # per timed chunk: 200 updates per seed


def program(frame_size: int, seeds: int, loop_seeds: bool):
    """A function that trains one chunk of every seed and blocks; returns updates per seed."""
    config = dqn.default_config(
        ENV_ID,
        frame_size=frame_size,
        iterations_per_chunk=ITERATIONS,
        learning_starts=0,
        buffer_size=4_000,
        loop_seeds=loop_seeds,
    )
    hparams = params.stack([dqn.default_hyperparams(ENV_ID)])
    runner = parallel.Program(dqn, config, 1, seeds, pad=False, loop_seeds=loop_seeds)
    state = runner.init(parallel.seed_keys(range(seeds)), hparams)
    box = {"state": state}

    def once() -> int:
        box["state"], metrics = runner.train_chunk(box["state"], hparams)
        jax.block_until_ready(metrics)
        return ITERATIONS * config.updates_per_iteration

    return once


def measure(once, rounds: int, min_time: float) -> float:
    """Median over ``rounds`` of updates per second per seed, each round >= ``min_time``."""
    once()  # compile and warm up
    rates = []
    for _ in range(rounds):
        updates, start = 0, time.perf_counter()
        while time.perf_counter() - start < min_time:
            updates += once()
        rates.append(updates / (time.perf_counter() - start))
    return float(np.median(rates))


def run(quick: bool = False) -> str:
    rounds, min_time = (1, 1.0) if quick else (3, 5.0)
    sizes = (42,) if quick else (42, 84)
    lines = [
        "## Pixel DQN: seeds vmapped vs seeds as a loop in one program",
        "",
        describe(),
        "",
        "`python -m bench pixel_dqn" + (" --quick`" if quick else "`"),
        "",
        f"Updates/s per seed of the pixel recipe's training chunk ({ITERATIONS} iterations of 4 "
        "env steps and 2 updates, batch 64, frames drawn in JAX), learning on; median of "
        f"{rounds} round(s) of >= {min_time} s per program, programs measured one after another.",
        "",
        "| frame | seeds | seeds vmapped | seeds as a loop | loop / vmap |",
        "|---:|---:|---:|---:|---:|",
    ]
    for size in sizes:
        for seeds in (1, 3):
            vmapped = measure(program(size, seeds, False), rounds, min_time)
            looped = measure(program(size, seeds, True), rounds, min_time)
            lines.append(
                f"| {size}x{size} | {seeds} | {vmapped:,.1f} | {looped:,.1f} | "
                f"{looped / vmapped:.2f}x |"
            )
    load = [round(x, 2) for x in os.getloadavg()]
    return "\n".join([*lines, "", f"load avg {load} at end", ""])
