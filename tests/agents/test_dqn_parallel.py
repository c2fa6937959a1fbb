"""DQN (with its options) and REINFORCE run through ``rl_jax.training.parallel.Program``: a 2
hyperparameter sets x 2 seeds program gives each run the same result as that run alone."""

import jax
import numpy as np
import pytest

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents.dqn import dqn
from rl_jax.agents.reinforce import reinforce
from rl_jax.training import parallel, params

CASES = {
    "dqn": (
        dqn,
        "rl_jax/ProbeTwoStepDiscrete-v0",
        {
            "num_envs": 2,
            "learning_starts": 16,
            "batch_size": 8,
            "buffer_size": 64,
            "iterations_per_chunk": 20,
            "hidden": (8,),
            "n_step": 2,
            "prioritized": True,
            "double": True,
            "dueling": True,
        },
        "learning_rate",
        (1e-3, 3e-3),
    ),
    "reinforce": (
        reinforce,
        "rl_jax/ProbeTwoStepDiscrete-v0",
        {"num_envs": 4, "iterations_per_chunk": 3, "hidden": (8,), "baseline": "value"},
        "learning_rate",
        (1e-3, 1e-2),
    ),
}


def _leaves_close(got, expected):
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if np.issubdtype(a.dtype, np.floating):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)
        elif a.dtype != object and not jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", list(CASES))
def test_grid_of_seeds_and_hyperparameters_equals_single_runs(name):
    algorithm, env_id, overrides, field, values = CASES[name]
    config = algorithm.default_config(env_id, **overrides)
    hparams = [algorithm.default_hyperparams(**{field: value}) for value in values]
    runner = parallel.Program(algorithm, config, num_hparams=2, num_seeds=2)
    state = runner.init(parallel.seed_keys([0, 1]), params.stack(hparams))
    state, metrics = runner.train_chunk(state, params.stack(hparams))
    # The last run alone (hyperparameter set 1, seed 1).
    single = algorithm.init(jax.random.key(1), config, hparams[1])
    single, single_metrics = jax.jit(algorithm.train_chunk, static_argnums=1)(
        single, config, hparams[1]
    )
    _leaves_close(parallel.select(state, 1, 1).agent, single.agent)
    _leaves_close(jax.tree.map(lambda x: x[1, 1], metrics), single_metrics)
    # Runs really differ (different seeds and rates).
    first, last = (
        jax.tree.leaves(parallel.select(state, 0, 0).agent)[0],
        jax.tree.leaves(single.agent)[0],
    )
    assert not np.allclose(first, last)
