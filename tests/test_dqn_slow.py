"""Slow learning tests (``pytest -m slow tests/test_dqn_slow.py -s``): the documented recipes
solve their envs in every seed, all seeds as one compiled program (``rl_jax.parallel.Runner``).

* DQN, ``rl_jax/CartPole-v1``: the greedy policy's eval return (10 episodes) reaches 500.
* REINFORCE, ``rl_jax/InvertedPendulum-v5``: the deterministic policy's eval return reaches 1,000.

Each prints, per seed, the env steps at which the target was first reached, and the wall-clock
(compilation included). The step budgets are ~3x what the recipes needed when measured.
"""

import time

import numpy as np
import pytest

from rl_jax import parallel
from rl_jax.dqn import dqn
from rl_jax.reinforce import reinforce

SEEDS = 3


def first_reach(algorithm, env_id, target, budget, steps_of=None):
    """Run ``SEEDS`` seeds until each has had an eval return >= ``target`` once (or the budget
    of env steps is spent); ``steps_of(metrics)`` gives the per-seed env steps."""
    config = algorithm.default_config(env_id)
    hparams = parallel.stack([algorithm.default_hyperparams(env_id)])
    runner = parallel.Runner(algorithm, config, 1, SEEDS)
    started = time.perf_counter()
    state = runner.init(parallel.seed_keys(list(range(SEEDS))), hparams)
    reached = [None] * SEEDS
    steps = np.zeros(SEEDS)
    while None in reached and steps.max() < budget:
        state, metrics = runner.train_chunk(state, hparams)
        steps = np.asarray(steps_of(metrics) if steps_of else metrics.env_steps)[0]
        returns = np.asarray(metrics.eval_return)[0]
        for seed in range(SEEDS):
            if reached[seed] is None and returns[seed] >= target:
                reached[seed] = int(steps[seed])
        print(f"{env_id} steps {steps.tolist()} eval {np.round(returns, 1).tolist()}", flush=True)
    seconds = time.perf_counter() - started
    print(
        f"{algorithm.name} {env_id}: first reached {target} at env steps {reached}, {seconds:.0f} s"
    )
    return reached


@pytest.mark.slow
def test_dqn_balances_cartpole_for_500_steps_in_every_seed():
    reached = first_reach(dqn, "rl_jax/CartPole-v1", 500.0, budget=150_000)
    assert None not in reached, reached


@pytest.mark.slow
def test_reinforce_balances_the_inverted_pendulum_for_1000_steps_in_every_seed():
    reached = first_reach(
        reinforce,
        "rl_jax/InvertedPendulum-v5",
        1000.0,
        budget=1_000_000,
        steps_of=lambda metrics: metrics.extra["env_steps_taken"],  # real env steps
    )
    assert None not in reached, reached
