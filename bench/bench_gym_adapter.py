"""The gymnasium adapter (``envs.from_gymnasium``): env steps/s of gymnasium's own Pendulum-v1
stepped on the host from inside jit, next to our pure-JAX ``rl_jax/Pendulum-v1`` and
``rl_jax/Rocket-v0`` and to gymnasium's Pendulum stepped one at a time from Python.

* Adapter and JAX envs: ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of steps with
  uniform random actions drawn inside the scan (what the learners run), and for the adapter also
  ``envs.core.batched.autoreset_step``, which resets only the envs whose episode ended
  (``AutoReset`` computes a reset for every env on every step: for the adapter, a gymnasium
  ``reset(seed=...)`` on the host per env and step).
* Baseline: one ``gymnasium.make("Pendulum-v1")`` stepped from a Python loop with pre-drawn
  random actions and a reset whenever an episode ends (``bench_classic.baseline_rollout``).

The adapter's cost is the gymnasium env's Python code plus one host callback per step (not per
env), so its steps/s should stay near the baseline's at every batch size, while the JAX envs
scale with the batch.
"""

from __future__ import annotations

from bench.bench_classic import baseline_rollout, jax_rollout, measure_interleaved
from bench.machine import rates_section

SIZES = (1, 16, 256)
ADAPTER_ID = "gymnasium:Pendulum-v1"
CASES = [  # (label, env id, autoreset mode)
    ("gymnasium Pendulum-v1 via envs.from_gymnasium, AutoReset", ADAPTER_ID, "wrapper"),
    ("gymnasium Pendulum-v1 via envs.from_gymnasium, batched autoreset", ADAPTER_ID, "batched"),
    ("rl_jax/Pendulum-v1 (pure JAX), AutoReset", "rl_jax/Pendulum-v1", "wrapper"),
    ("rl_jax/Rocket-v0 (pure JAX), AutoReset", "rl_jax/Rocket-v0", "wrapper"),
]


def _block(env_id: str, num_envs: int, quick: bool) -> int:
    """Steps per compiled call: host-stepped envs get fewer, so one call stays well under 1 s."""
    if env_id == ADAPTER_ID:
        return max(10, (2000 if not quick else 400) // num_envs)
    return 500 if not quick else 100


def rollouts(quick: bool = False, sizes: tuple[int, ...] = SIZES) -> dict:
    """``{(label, num_envs): once}``; ``once()`` runs one block and returns its env steps."""
    runs = {
        ("gymnasium Pendulum-v1, one env at a time from Python", 1): baseline_rollout("pendulum")
    }
    for label, env_id, mode in CASES:
        for num_envs in sizes:
            block = _block(env_id, num_envs, quick)
            runs[label, num_envs] = jax_rollout(env_id, num_envs, block, mode)
    return runs


def run(quick: bool = False) -> str:
    min_time, rounds = (0.2, 1) if quick else (0.5, 3)
    sizes = SIZES[:2] if quick else SIZES
    rates = measure_interleaved(rollouts(quick, sizes), rounds, min_time)
    command = "PYTHONPATH=$PWD python -m bench gym_adapter" + (" --quick" if quick else "")
    explanation = (
        "Env steps/s (agent steps, autoreset included, random actions), median of "
        f"{rounds} interleaved round(s) of >= {min_time} s each; ratio over gymnasium's "
        "Pendulum stepped one at a time in the same rounds."
    )
    title = "gymnasium envs through envs.from_gymnasium vs pure-JAX envs"
    columns = ("steps/s", "vs gymnasium one at a time")
    return rates_section(title, command, explanation, columns, rates)
