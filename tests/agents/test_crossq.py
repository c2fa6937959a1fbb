"""CrossQ end to end: batch-renormalised critics without target networks, Adam at b1 0.5 and an
actor update every third critic update, in a short run under the seed vmap; its recipes;
checkpoint and resume. Its maths alone is tested in ``test_crossq_losses.py``.

One run serves the training tests (compiling it dominates): 2 seeds in one program on
``rl_jax/Pendulum-v1`` with tiny networks, 2 chunks of 200 env steps (2 envs), updates from step
100, 4 per iteration: 600 updates per seed, the first 50 of plain batch norm.
"""

import dataclasses
import functools

import numpy as np
from test_td3_network_options import (
    ENV_ID,
    assert_resumes_bit_identical,
    assert_trained_and_finite,
    train,
)

from rl_jax.agents import crossq as crossq_module
from rl_jax.agents.crossq import crossq
from rl_jax.agents.td3 import td3
from rl_jax.training import validation

CHEETAH = "rl_jax/HalfCheetah-v5"
SMALL = {"renorm_warmup": 50}


@functools.cache
def crossq_run():
    """``(states before the first chunk and after each of 2, metrics per chunk)``."""
    return train(2, algorithm=crossq, **SMALL)


def test_crossq_trains_without_target_networks_and_keeps_its_statistics():
    states, history = crossq_run()
    agent = states[-1].agent
    first = agent.critic_stats["MLP_0"]["BatchRenorm_0"]
    np.testing.assert_array_equal(first["steps"], 600)  # one training pass per critic update
    assert np.all(first["var"] > 0.0)
    # No target networks: the state has none to keep.
    fields = {field.name for field in dataclasses.fields(crossq_module.Agent)}
    assert fields == {"actor", "critics", "actor_opt", "critic_opt", "critic_stats"}
    assert "batch_stats" not in agent.critics  # the optimizer never sees the statistics
    # One actor update per 3 critic updates; CrossQ's Adam, recorded in the state.
    np.testing.assert_array_equal(agent.critic_opt.count, 600)
    np.testing.assert_array_equal(agent.actor_opt.count, 200)
    for opt in (agent.critic_opt, agent.actor_opt):
        np.testing.assert_array_equal(opt.hyperparams["b1"], 0.5)
    assert_trained_and_finite(states[-1], history)


def test_the_state_checkpoints_and_a_resumed_run_ends_bit_identical(tmp_path):
    """The batch statistics beside the critics go through orbax with the rest."""
    assert_resumes_bit_identical(crossq, tmp_path, **SMALL)


def test_every_config_field_and_hyperparameter_has_help_text():
    from rl_jax.run import field_docs

    assert field_docs.undocumented_fields(crossq.default_config(ENV_ID)) == ["env_id"]
    assert field_docs.undocumented_fields(crossq.default_hyperparams()) == []


def test_the_default_recipe_is_crossqs_published_settings():
    config = crossq.default_config(CHEETAH)
    assert (config.actor_hidden, config.critic_hidden) == ((256, 256), (2048, 2048))
    assert (config.num_critics, config.policy_delay) == (2, 3)
    assert (config.renorm_warmup, config.adam_b1) == (100_000, 0.5)
    loop = ("num_envs", "updates_per_iteration", "batch_size", "learning_starts")
    assert tuple(getattr(config, name) for name in loop) == (1, 1, 256, 25_000)  # TD3 paper's
    hparams = crossq.default_hyperparams(CHEETAH).to_dict()
    assert [hparams["actor_lr"], hparams["critic_lr"]] == [np.float32(1e-3)] * 2
    assert dataclasses.replace(crossq.default_config(ENV_ID), env_id=CHEETAH) == config
    assert validation.out_of_range(config, crossq) is None
    assert validation.out_of_range(crossq.default_hyperparams(CHEETAH), crossq) is None
    refused = validation.out_of_range(crossq.default_config(ENV_ID, renorm_warmup=-1), crossq)
    assert refused == "--renorm-warmup must be >= 0, got -1"


def test_the_cpu_recipe_is_crossq_in_the_cpu_loop_at_128_sizes():
    cpu = crossq.default_config(CHEETAH, "cpu")
    td3_cpu = td3.default_config(CHEETAH)  # TD3's half-cheetah CPU recipe: loop and sizes
    published = crossq.default_config(CHEETAH)
    loop = ("num_envs", "updates_per_iteration", "batch_size", "learning_starts")
    for field in dataclasses.fields(cpu):
        name = field.name
        if name in loop + ("iterations_per_chunk", "actor_hidden", "critic_hidden"):
            assert getattr(cpu, name) == getattr(td3_cpu, name), name
        else:
            assert getattr(cpu, name) == getattr(published, name), name
    assert cpu.actor_hidden == cpu.critic_hidden == (128, 128)
    hparams = crossq.default_hyperparams(CHEETAH, "cpu").to_dict()
    assert hparams == crossq.default_hyperparams(CHEETAH).to_dict()
