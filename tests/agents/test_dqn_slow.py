"""Slow learning tests (``pytest -m slow tests/agents/test_dqn_slow.py -s``): the documented recipes
solve their envs in every seed, all seeds as one compiled program
(``rl_jax.training.parallel.Program``).

* DQN, ``rl_jax/CartPole-v1``: the greedy policy's eval return (10 episodes) reaches 500.
* REINFORCE, ``rl_jax/InvertedPendulum-v5``: the deterministic policy's eval return reaches 1,000
  (each seed as its own program, see below).

Each prints, per seed, the env steps at which the target was first reached, and the wall-clock
(compilation included). The step budgets are ~3x what the recipes needed when measured.
"""

import time

import numpy as np
import pytest

from rl_jax.agents.dqn import dqn
from rl_jax.agents.reinforce import reinforce
from rl_jax.training import parallel, params

SEEDS = 3


def first_reach(algorithm, env_id, target, budget, seeds, steps_of=None):
    """Run ``seeds`` (one compiled program) until each has had an eval return >= ``target`` once,
    or every unfinished seed has spent ``budget`` env steps; ``steps_of(metrics)`` gives the
    per-seed env steps. Returns the env steps of each seed's first success (``None``: never)."""
    config = algorithm.default_config(env_id)
    hparams = params.stack([algorithm.default_hyperparams(env_id)])
    runner = parallel.Program(algorithm, config, 1, len(seeds))
    started = time.perf_counter()
    state = runner.init(parallel.seed_keys(list(seeds)), hparams)
    reached = [None] * len(seeds)
    steps = np.zeros(len(seeds))
    while any(r is None and s < budget for r, s in zip(reached, steps, strict=True)):
        state, metrics = runner.train_chunk(state, hparams)
        steps = np.asarray(steps_of(metrics) if steps_of else metrics.env_steps)[0]
        returns = np.asarray(metrics.eval_return)[0]
        for index in range(len(seeds)):
            if reached[index] is None and returns[index] >= target:
                reached[index] = int(steps[index])
        print(f"{env_id} seeds {list(seeds)} steps {steps.tolist()} eval {returns.tolist()}")
    seconds = time.perf_counter() - started
    print(f"{algorithm.name} {env_id} seeds {list(seeds)}: first reached {target} at env steps")
    print(f"{reached}, wall-clock {seconds:.0f} s (compilation included)", flush=True)
    return reached


@pytest.mark.slow
def test_dqn_balances_cartpole_for_500_steps_in_every_seed():
    reached = first_reach(dqn, "rl_jax/CartPole-v1", 500.0, 150_000, range(SEEDS))
    assert None not in reached, reached


# Each seed its own program: a batch of whole episodes lasts as long as its longest episode, so
# seeds vmapped together would all wait for the seed whose pendulum already stays up 1,000 steps.
@pytest.mark.slow
@pytest.mark.parametrize("seed", range(SEEDS))
def test_reinforce_balances_the_inverted_pendulum_for_1000_steps_in_every_seed(seed):
    reached = first_reach(
        reinforce,
        "rl_jax/InvertedPendulum-v5",
        1000.0,
        1_000_000,
        [seed],
        steps_of=lambda metrics: metrics.extra["env_steps_taken"],  # real env steps
    )
    assert None not in reached, reached


@pytest.mark.slow
def test_dqn_settles_the_rocket_from_one_zero_in_every_seed(tmp_path):
    """RESULTS.md's DQN row of rl_jax/RocketSettle-v0: the recipe (thrust in {-1, -0.5, 0, 0.5,
    1}, LayerNorm in the Q-network) for 200k env steps, 5 seeds in one program; the
    latest policy of every seed, rolled from (1, 0) by ``rocket_report``, enters |x|, |v| <= 0.01
    and stays inside to step 500."""
    import subprocess
    import sys
    from pathlib import Path

    from settle import assert_every_latest_policy_settles

    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "rocket_settle_dqn"
    argv = ["--algo", "dqn", "--env", "rl_jax/RocketSettle-v0", "--seeds", "5"]
    argv += ["--total-steps", "200000", "--out", str(out)]
    subprocess.run([sys.executable, str(root / "experiments" / "train.py"), *argv], check=True)
    assert_every_latest_policy_settles(out, seeds=5)
