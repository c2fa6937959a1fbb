"""Pixel DQN (``rl_jax/CartPolePixels-v1``): where its update time goes on this CPU.

1. The conv torso's gradient step inside a ``lax.scan`` (where the training chunk runs it):
   ``flax.linen.Conv`` against ``rl_jax.training.conv.MatmulConv`` (space-to-depth + one
   matmul, the same parameters and results). XLA's CPU backend runs a convolution's gradient
   inside a loop body far slower than outside one (jax-ml/jax#12868).
2. MinAtar's torso (the MinAtar paper's 16 3x3 stride-1 filters, then 128 units: PPO's recipe
   for ``rl_jax/*-MinAtar``) the same way, on a batch of 1,024 (PPO's minibatch there) of 10x10
   grids of 0/1 with 4 channels (Breakout) and 7 (Freeway): ``nn.Conv`` against ``MatmulConv``
   forced to sum per-tap products and forced to multiply patches (``MatmulConv.layout``; its
   ``auto`` picks patches for these layers, where the input is shallower than the output).
3. The recipe's whole training chunk (``dqn.RECIPES``: 4 envs, one batch-32 update per
   iteration, Double DQN with 3-step returns, frames drawn in JAX) with the torso over the whole
   84x84 frame and over the rows CartPole draws on (``crop_drawn_rows``, the recipe's), and
   with its 3 seeds vmapped against an unrolled loop in the same program
   (``parallel.Program(loop_seeds=True)``, the recipe's). Timed on chunks of 100 iterations
   once learning has started.
"""

from __future__ import annotations

import os
import time

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from bench.machine import describe
from rl_jax.agents.dqn import dqn
from rl_jax.training import conv, parallel, params

ENV_ID = "rl_jax/CartPolePixels-v1"
ITERATIONS = 100  # per timed chunk: 200 updates per seed


def program(frame_size: int, seeds: int, loop_seeds: bool, crop: bool = True):
    """A function that trains one chunk of every seed and blocks; returns updates per seed."""
    config = dqn.default_config(
        ENV_ID,
        frame_size=frame_size,
        iterations_per_chunk=ITERATIONS,
        learning_starts=0,
        buffer_size=4_000,
        loop_seeds=loop_seeds,
        crop_drawn_rows=crop,
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


class _FlaxTorso(nn.Module):
    """The 2013 DQN torso and head with ``nn.Conv`` (what ``conv.ConvTorso`` was)."""

    matmul: bool

    @nn.compact
    def __call__(self, pixels):
        x = pixels / 255.0
        for index, (features, kernel, stride) in enumerate(((16, 8, 4), (32, 4, 2))):
            if self.matmul:
                layer = conv.MatmulConv(features, kernel, stride, name=f"Conv_{index}")
            else:
                layer = nn.Conv(features, (kernel, kernel), (stride, stride), "VALID")
            x = nn.relu(layer(x))
        return nn.Dense(2)(nn.relu(nn.Dense(256)(x.reshape(x.shape[:-3] + (-1,)))))


def torso_steps(frame_size: int, matmul: bool, steps: int = 10):
    """A function running ``steps`` SGD steps of the torso on a batch of 64 in one scan."""
    frames = jax.random.uniform(jax.random.key(0), (64, frame_size, frame_size, 4)) * 255.0
    return _scanned_sgd(_FlaxTorso(matmul), frames, steps)


def _scanned_sgd(net: nn.Module, inputs: jax.Array, steps: int):
    """A function running ``steps`` SGD steps of ``net`` on ``inputs`` in one jitted scan and
    blocking; it returns ``steps``."""
    params = net.init(jax.random.key(1), inputs)

    def loss(params):
        return jnp.sum(net.apply(params, inputs) ** 2)

    def step(params, _):
        grads = jax.grad(loss)(params)
        return jax.tree.map(lambda p, g: p - 1e-6 * g, params, grads), None

    scanned = jax.jit(lambda params: jax.lax.scan(step, params, None, length=steps)[0])

    def once() -> int:
        jax.block_until_ready(scanned(params))
        return steps

    return once


MINATAR_BATCH = 1_024  # PPO's MinAtar minibatch: 64 envs x 128 steps / 8 minibatches
MINATAR_ACTIONS = 3  # Breakout's and Freeway's minimal action sets


class _MinAtarTorso(nn.Module):
    """MinAtar's network as ``ConvTorso`` + dense layers build it (16 3x3 filters of stride 1,
    128 units, one output per action), its conv ``nn.Conv`` (``layout=None``) or
    ``MatmulConv`` with ``layout``."""

    layout: str | None

    @nn.compact
    def __call__(self, grids):
        if self.layout is None:
            layer = nn.Conv(16, (3, 3), (1, 1), "VALID")
        else:
            layer = conv.MatmulConv(16, 3, 1, layout=self.layout, name="Conv_0")
        x = nn.relu(layer(grids))
        x = nn.relu(nn.Dense(128)(x.reshape(x.shape[:-3] + (-1,))))
        return nn.Dense(MINATAR_ACTIONS)(x)


def minatar_steps(channels: int, layout: str | None, steps: int = 10):
    """A function running ``steps`` SGD steps of MinAtar's torso on a batch of 1,024 10x10 grids
    of 0/1 with ``channels`` channels in one scan."""
    shape = (MINATAR_BATCH, 10, 10, channels)
    grids = jax.random.bernoulli(jax.random.key(0), 0.1, shape).astype(jnp.float32)
    return _scanned_sgd(_MinAtarTorso(layout), grids, steps)


def run(quick: bool = False) -> str:
    rounds, min_time = (1, 1.0) if quick else (3, 5.0)
    sizes = (42,) if quick else (42, 84)
    lines = [
        "## Pixel DQN: the conv torso in the training loop, seeds vmapped or looped",
        "",
        describe(),
        "",
        "`python -m bench pixel_dqn" + (" --quick`" if quick else "`"),
        "",
        "Gradient steps/s of the torso (2 conv layers, 256 units, batch 64) inside a "
        f"`lax.scan` of 10 steps; median of {rounds} round(s) of >= {min_time} s.",
        "",
        "| frame | nn.Conv | MatmulConv | MatmulConv / nn.Conv |",
        "|---:|---:|---:|---:|",
    ]
    for size in sizes:
        flax_rate = measure(torso_steps(size, False), rounds, min_time)
        matmul_rate = measure(torso_steps(size, True), rounds, min_time)
        lines.append(
            f"| {size}x{size} | {flax_rate:,.1f} | {matmul_rate:,.1f} | "
            f"{matmul_rate / flax_rate:.2f}x |"
        )
    # nn.Conv's gradient takes ~0.5 s a step here: a shorter scan keeps --quick quick
    minatar_scan = 3 if quick else 10
    lines += [
        "",
        "Gradient steps/s of MinAtar's torso (16 3x3 stride-1 filters, 128 units, "
        f"{MINATAR_ACTIONS} actions; batch {MINATAR_BATCH:,} of 10x10 grids of 0/1) inside a "
        f"`lax.scan` of {minatar_scan} steps; median of {rounds} round(s) of >= {min_time} s. "
        "MatmulConv forced to sum per-tap products or to multiply patches (`layout`; `auto` "
        "picks patches here).",
        "",
        "| channels | nn.Conv | products | patches | patches / products |",
        "|---:|---:|---:|---:|---:|",
    ]
    for channels in (4, 7):
        flax_rate, products, patches = (
            measure(minatar_steps(channels, layout, minatar_scan), rounds, min_time)
            for layout in (None, "products", "patches")
        )
        lines.append(
            f"| {channels} | {flax_rate:,.1f} | {products:,.1f} | {patches:,.1f} | "
            f"{patches / products:.2f}x |"
        )
    lines += [
        "",
        f"Updates/s per seed of the pixel recipe's training chunk ({ITERATIONS} iterations of 4 "
        "env steps and one batch-32 update, frames drawn in JAX, evaluation included), learning "
        f"on; median of {rounds} round(s) of >= {min_time} s per program, one after another. "
        "Torso over the whole frame, or over the rows CartPole draws on (`crop_drawn_rows`).",
        "",
        "| frame | seeds | torso sees | seeds vmapped | seeds as a loop | loop / vmap |",
        "|---:|---:|---|---:|---:|---:|",
    ]
    cases = [(42, 3, True)] if quick else [(84, 1, False), (84, 1, True), (84, 3, False)]
    cases += [] if quick else [(84, 3, True)]
    for size, seeds, crop in cases:
        vmapped = measure(program(size, seeds, False, crop), rounds, min_time)
        looped = measure(program(size, seeds, True, crop), rounds, min_time)
        seen = "drawn rows" if crop else "whole frame"
        lines.append(
            f"| {size}x{size} | {seeds} | {seen} | {vmapped:,.1f} | {looped:,.1f} | "
            f"{looped / vmapped:.2f}x |"
        )
    load = [round(x, 2) for x in os.getloadavg()]
    return "\n".join([*lines, "", f"load avg {load} at end", ""])
