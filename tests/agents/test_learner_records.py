"""Short runs of every learner's recipes give exactly the metrics recorded for them.

Each run is a recipe's settings (learner, env, config and hyperparameters) with a short loop: 2
seeds vmapped in one program, 3 chunks, learning after 100 random env steps. Its record is every
chunk's metrics per seed (evaluation and training return, and the learner's own scalars: losses,
Q-values, epsilon). They were first recorded before the learners were split into modules of their
own (one learner, one file), so an equal record shows that a move of code changed no result.

XLA compiles for the CPU it runs on, and other flags or another jax round the same program
differently, so records are kept per ``jax_setup.cpu_tag()``, jax version and XLA flags in
``tests/data/learner_records.json``; where there is none the test skips at once, naming the command
that prints the values to add (``python tests/agents/test_learner_records.py NAME ...``, as JSON).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from rl_jax.run.learners import resolve as resolve_algorithm
from rl_jax.training import jax_setup, parallel, params

RECORDS = Path(__file__).resolve().parents[1] / "data" / "learner_records.json"
PENDULUM = "rl_jax/Pendulum-v1"
# The off-policy actor-critics' loop, whatever their recipe's: short, and updating from step 100.
LOOP = {
    "num_envs": 2,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 100,
    "batch_size": 64,
    "learning_starts": 100,
    "buffer_size": 2000,
}
DQN_LOOP = {"iterations_per_chunk": 100, "learning_starts": 100, "buffer_size": 2000}
# name -> (learner, recipe or None for the env's own, env, config overrides, hparam overrides)
RUNS: dict[str, tuple[str, str | None, str, dict, dict]] = {
    "td7-cpu": ("td7", "cpu", PENDULUM, LOOP, {}),
    "td7": ("td7", None, PENDULUM, LOOP, {}),
    "crossq-cpu": ("crossq", "cpu", PENDULUM, {**LOOP, "renorm_warmup": 150}, {}),
    "td3-simba": (
        "td3",
        None,
        PENDULUM,
        {**LOOP, "network": "simba", "actor_hidden": (32, 32), "critic_hidden": (32, 32)},
        {},
    ),
    "td3-layer-norm-obs": (
        "td3",
        None,
        PENDULUM,
        {**LOOP, "critic_norm": "layer", "actor_norm": "layer", "normalize_obs": True},
        {},
    ),
    "dqn-cartpole": ("dqn", None, "rl_jax/CartPole-v1", DQN_LOOP, {}),
    "dqn-cartpole-pixels": (
        "dqn",
        None,
        "rl_jax/CartPolePixels-v1",
        {**DQN_LOOP, "iterations_per_chunk": 50, "hidden": (32,)},
        {},
    ),
    "dqn-inverted-pendulum": ("dqn", None, "rl_jax/InvertedPendulum-v5", DQN_LOOP, {}),
    "dqn-rocket": ("dqn", None, "rl_jax/Rocket-v0", DQN_LOOP, {}),
    "dqn-rocket-settle": ("dqn", None, "rl_jax/RocketSettle-v0", DQN_LOOP, {}),
    "reinforce-inverted-pendulum": (
        "reinforce",
        None,
        "rl_jax/InvertedPendulum-v5",
        {"iterations_per_chunk": 2},
        {},
    ),
    "reinforce-double-pendulum": (
        "reinforce",
        None,
        "rl_jax/InvertedDoublePendulum-v5",
        {"iterations_per_chunk": 2},
        {},
    ),
    "reinforce-cartpole": (
        "reinforce",
        None,
        "rl_jax/CartPole-v1",
        {"iterations_per_chunk": 2},
        {},
    ),
}


# Flags that split the host into devices: the runs use one device, and how many the host shows
# changes no program's code. The suite's processes show two, a script or a plain process one.
NOT_KEYS = ("--xla_force_host_platform_device_count",)


def flags() -> str:
    """This process's XLA flags that change compiled code, as a record key ("default": none)."""
    given = os.environ.get("XLA_FLAGS", "").split()
    return " ".join(sorted(f for f in given if not f.startswith(NOT_KEYS))) or "default"


def record_key() -> tuple[str, str, str]:
    """Where this process's records are kept: CPU tag, jax version, XLA flags."""
    return jax_setup.cpu_tag(), jax.__version__, flags()


def recorded(name: str) -> list | None:
    where = record_key()
    for record in json.loads(RECORDS.read_text()) if RECORDS.exists() else []:
        if (record["cpu_tag"], record["jax"], record["flags"]) == where:
            return record["runs"].get(name)
    return None


def settings(name: str):
    """``(algorithm, config, hparams)`` of run ``name``: its recipe, then its overrides."""
    learner, recipe, env_id, config, hparams = RUNS[name]
    algorithm = resolve_algorithm(learner)
    config = algorithm.default_config(env_id, recipe, **config)
    hparams = algorithm.default_hyperparams(env_id, recipe, **hparams)
    return algorithm, config, hparams


def _number(value: float) -> float | str:
    return "nan" if math.isnan(value) else value


def run(name: str) -> list:
    """Per chunk: ``{metric: [value per seed]}``."""
    algorithm, config, hparams = settings(name)
    stacked = params.stack([hparams])
    program = parallel.Program(algorithm, config, 1, 2, devices=jax.devices()[:1])
    state = program.init(parallel.seed_keys([0, 1]), stacked)
    chunks = []
    for _ in range(3):
        state, metrics = program.train_chunk(state, stacked)
        metrics = program.gather(metrics)
        values = {
            "eval_return": metrics.eval_return,
            "train_return": metrics.train_return,
            **metrics.extra,
        }
        chunks.append(
            {
                key: [_number(float(v)) for v in np.asarray(value)[0]]
                for key, value in values.items()
            }
        )
    return chunks


# The default suite runs one short run per learner (and TD3's network options); the rest, longer
# each, run with the slow tests.
DEFAULT = ("td7-cpu", "crossq-cpu", "td3-simba", "dqn-cartpole", "reinforce-cartpole")


@pytest.mark.parametrize(
    "name",
    [name if name in DEFAULT else pytest.param(name, marks=pytest.mark.slow) for name in RUNS],
)
def test_short_run_equals_its_record(name):
    record = recorded(name)
    if record is None:  # skipped before training: another CPU's run would compare with nothing
        pytest.skip(
            f"no record for {record_key()}; `python tests/agents/test_learner_records.py {name}` "
            "prints this host's"
        )
    assert run(name) == record


if __name__ == "__main__":  # the named runs' records as JSON, at the suite's XLA flags
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import compile_level

    compile_level.apply()  # before the backend starts; TEST_XLA_OPT=default keeps XLA's defaults
    jax_setup.configure()
    print(f"key: {record_key()}", file=sys.stderr)
    print(json.dumps({name: run(name) for name in sys.argv[1:] or RUNS}))
