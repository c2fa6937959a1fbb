"""Frames per second of ``rl_jax/CartPolePixels-v1`` (frames drawn in JAX inside the compiled
step) against what our users' pixel-DQN tutorial runs: gymnasium's own ``CartPole-v1`` with
``render_mode="rgb_array"`` (pygame draws a 600x400 RGB frame), then the same preprocessing in
numpy (ITU-R 601 grayscale, exact area-average down to 84x84, the last 4 frames stacked).

* Ours: ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of steps with uniform random
  actions drawn inside the scan: every step draws each env's new frame, grayscale and
  downsampled, and shifts it into the 4-frame stack (what the DQN learner runs).
* Baseline: one gymnasium env stepped from a Python loop with pre-drawn random actions, a reset
  when an episode ends, and every observation rendered and preprocessed as above.

A "frame" is one agent step's new observation (one newly drawn 84x84 frame pushed onto the
stack), the unit both sides produce.
"""

from __future__ import annotations

import os

import numpy as np

from bench.bench_classic import jax_rollout, measure_interleaved
from bench.machine import rates_section

SIZES = (1, 64, 1024)
FRAME_SIZE, STACK = 84, 4


def area_weights(n_out: int, n_in: int) -> np.ndarray:
    """``[n_out, n_in]``: each input pixel's share of each output pixel (exact area average)."""
    edges = np.arange(n_out + 1) * (n_in / n_out)
    pixels = np.arange(n_in)[None, :]
    overlap = np.minimum(edges[1:, None], pixels + 1) - np.maximum(edges[:-1, None], pixels)
    return (np.clip(overlap, 0.0, None) / (n_in / n_out)).astype(np.float32)


def gymnasium_rollout(block: int = 200, size: int = FRAME_SIZE):
    """gymnasium CartPole-v1 rendered to rgb_array and preprocessed in numpy, one env."""
    import gymnasium

    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no display: pygame draws off screen
    env = gymnasium.make("CartPole-v1", render_mode="rgb_array")
    env.reset(seed=0)
    rows = area_weights(size, 400)
    cols = area_weights(size, 600).T.copy()
    luma = np.array([0.299, 0.587, 0.114], np.float32)
    actions = np.random.default_rng(0).integers(0, 2, block)
    stack = np.zeros((size, size, STACK), np.uint8)

    def frame() -> np.ndarray:
        gray = env.render().astype(np.float32) @ luma
        return np.clip(np.rint(rows @ gray @ cols), 0, 255).astype(np.uint8)

    def once() -> int:
        nonlocal stack
        for action in actions:
            _, _, terminated, truncated, _ = env.step(int(action))
            if terminated or truncated:
                env.reset()
            stack = np.concatenate([stack[..., 1:], frame()[..., None]], axis=-1)
        return block

    once()  # warm up pygame's surfaces outside the timing
    return once


def rollouts(quick: bool, sizes: tuple[int, ...]) -> dict:
    runs = {
        ("gymnasium CartPole-v1 rgb_array + numpy preprocessing, one env", 1): (
            gymnasium_rollout(50 if quick else 200)
        )
    }
    for num_envs in sizes:
        block = max(4, (2048 if not quick else 256) // num_envs)
        label = "rl_jax/CartPolePixels-v1, jit(scan(vmap(AutoReset(env).step)))"
        runs[label, num_envs] = jax_rollout("rl_jax/CartPolePixels-v1", num_envs, block)
    return runs


def run(quick: bool = False) -> str:
    min_time, rounds = (0.2, 1) if quick else (1.0, 3)
    sizes = SIZES[:2] if quick else SIZES
    rates = measure_interleaved(rollouts(quick, sizes), rounds, min_time)
    command = "python -m bench pixels" + (" --quick" if quick else "")
    explanation = (
        f"Frames/s = agent steps/s, each producing one new {FRAME_SIZE}x{FRAME_SIZE} grayscale "
        f"frame pushed onto a {STACK}-frame uint8 stack (random actions, autoreset included); "
        f"median of {rounds} interleaved round(s) of >= {min_time} s each; ratio over gymnasium "
        "in the same rounds."
    )
    title = "Pixel CartPole: frames drawn in JAX vs gymnasium's rgb_array + numpy"
    return rates_section(title, command, explanation, ("frames/s", "vs gymnasium"), rates, 1)
