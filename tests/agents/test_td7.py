"""TD7 end to end: SALE's encoders, LAP's prioritized replay, hard target copies, value clipping
and policy checkpoints in one short run under the seed vmap; its recipes; checkpoint and resume.
Their maths alone is tested in ``test_td7_losses.py``.

One run serves every training test (compiling it dominates): 2 seeds in one program on
``rl_jax/Pendulum-v1`` with tiny networks and embeddings, 4 chunks of 200 env steps (2 envs),
updates from step 100, 4 per iteration: 600 updates per seed after 2 chunks, 1,400 after 4, and a
hard target copy every 60th (the 600th is one, the 1,400th is 20 updates after one).
"""

import dataclasses
import functools

import jax
import numpy as np
import pytest
from test_td3_network_options import (
    ENV_ID,
    TINY,
    assert_resumes_bit_identical,
    assert_trained_and_finite,
    train,
)

from rl_jax.agents import td7 as td7_module
from rl_jax.agents.td3 import td3
from rl_jax.agents.td7 import td7
from rl_jax.training import validation

CHEETAH = "rl_jax/HalfCheetah-v5"
SMALL = {"embedding_dim": 8, "embedding_hidden": (16,), "target_update_period": 60}


@functools.cache
def td7_run():
    """``(states before the first chunk and after each of 4, metrics per chunk)``."""
    return train(4, algorithm=td7, **SMALL)


def leaf(tree) -> np.ndarray:
    """The first parameter leaf of ``tree``: moved parameters move it too."""
    return np.asarray(jax.tree.leaves(tree)[0])


def test_lap_keeps_every_stored_priority_at_or_above_one():
    states, history = td7_run()
    tree = states[-1].buffer
    leaves = np.asarray(tree.sums)[..., tree.sums.shape[-1] // 2 :]
    # Every stored transition has priority max(|td|, 1)^alpha >= 1 (800 of 1,000 slots filled).
    assert np.all(np.sum(leaves >= 1.0 - 1e-6, axis=-1) == 800)
    assert np.all(np.asarray(tree.max_priority) > 1.0)
    assert_trained_and_finite(states[-1], history)


def test_hard_copies_renew_targets_fixed_encoders_and_the_value_range():
    states, history = td7_run()
    # After 600 updates the last update was a copy: targets and the fixed encoder equal the
    # online networks, and the clipping range is the extremes of the targets seen so far.
    agent = states[2].agent
    jax.tree.map(np.testing.assert_array_equal, agent.target_critics, agent.critics)
    jax.tree.map(np.testing.assert_array_equal, agent.target_actor, agent.actor)
    jax.tree.map(np.testing.assert_array_equal, agent.encoders.fixed, agent.encoders.online)
    assert not np.allclose(leaf(agent.encoders.fixed_target), leaf(agent.encoders.fixed))
    np.testing.assert_array_equal(agent.value_range.low, agent.value_range.seen_min)
    np.testing.assert_array_equal(agent.value_range.high, agent.value_range.seen_max)
    # 20 updates after a copy: the online networks and encoder have moved on from their copies.
    agent = states[-1].agent
    encoders = agent.encoders
    assert np.all(np.isfinite(history[-1].extra["encoder_loss"]))
    parts = (encoders.online, encoders.fixed, encoders.fixed_target)
    online, fixed, target = (leaf(part) for part in parts)
    assert not np.allclose(online, fixed) and not np.allclose(fixed, target)
    assert not np.allclose(leaf(agent.target_critics), leaf(agent.critics))
    assert np.all(agent.value_range.low < agent.value_range.high)  # renewed from [0, 0]
    assert_trained_and_finite(states[-1], history)


def test_policy_checkpoints_evaluate_the_checkpoint_not_the_online_actor():
    states, history = td7_run()
    state = states[-1]
    checkpoint = state.agent.checkpoint
    # Pendulum's 200-step episodes end together in both envs at env steps 400 and 800 (2 envs);
    # updates start at 100, so the first counted episodes are those from 400 to 800: they pass
    # (nothing to beat yet) and the copy taken at 400, after 600 updates, is the checkpoint.
    np.testing.assert_array_equal(checkpoint.episodes, 0)
    assert np.all(checkpoint.score > -1e8) and np.all(checkpoint.score < 0.0)
    initial = leaf(states[0].agent.actor)
    assert not np.allclose(leaf(checkpoint.best.actor), initial)
    assert not np.allclose(leaf(checkpoint.best.actor), leaf(state.agent.actor))
    # A new copy was taken at 800, before that iteration's update moved the online actor.
    assert not np.allclose(leaf(checkpoint.assessed.actor), leaf(checkpoint.best.actor))
    config = td7.default_config(ENV_ID, **TINY, **SMALL)
    one = jax.tree.map(lambda x: x[0, 0], state.agent)
    obs = np.zeros((1, 3), np.float32)
    best = one.checkpoint.best
    expected = td7_module.policy_action(
        td7_module.make_networks(config), best.actor, best.encoder, obs
    )
    np.testing.assert_array_equal(td7.policy(state.replace(agent=one), config)(obs), expected)
    assert_trained_and_finite(state, history)


def test_the_state_checkpoints_and_a_resumed_run_ends_bit_identical(tmp_path):
    """SALE's encoders, the prioritized replay, the value range and the policy checkpoint all go
    through orbax."""
    assert_resumes_bit_identical(td7, tmp_path, **SMALL)


def test_every_config_field_and_hyperparameter_has_help_text():
    from rl_jax.run import field_docs

    assert field_docs.undocumented_fields(td7.default_config(ENV_ID)) == ["env_id"]
    assert field_docs.undocumented_fields(td7.default_hyperparams()) == []


def test_the_default_recipe_is_td7s_published_settings():
    config = td7.default_config(CHEETAH)
    assert (config.target_update_period, config.embedding_dim, config.embedding_hidden) == (
        250,
        256,
        (256, 256),
    )
    # the TD3 paper's loop: one env, one update per env step, batch 256, 25,000 random steps,
    # an evaluation every 5,000 steps, a replay of a million transitions
    loop = ("num_envs", "updates_per_iteration", "batch_size", "learning_starts")
    assert tuple(getattr(config, name) for name in loop) == (1, 1, 256, 25_000)
    assert (config.iterations_per_chunk, config.buffer_size) == (5000, 1_000_000)
    assert (config.actor_hidden, config.critic_hidden) == ((256, 256), (256, 256))
    assert (config.actor_activation, config.critic_activation) == ("relu", "elu")
    assert (config.num_critics, config.policy_delay) == (2, 2)  # TD3's
    assert (config.checkpoint_episodes, config.checkpoint_episodes_from) == (20, 750_000)
    hparams = td7.default_hyperparams(CHEETAH).to_dict()
    rates = [hparams[name] for name in ("actor_lr", "critic_lr", "encoder_lr")]
    assert rates == pytest.approx([3e-4] * 3)
    assert hparams["lap_alpha"] == pytest.approx(0.4)
    assert hparams["checkpoint_reset_weight"] == pytest.approx(0.9)
    noise = [hparams[name] for name in ("exploration_noise", "target_noise", "target_noise_clip")]
    assert noise == pytest.approx([0.1, 0.2, 0.5])  # TD3's
    assert td7.default_config(CHEETAH, "default") == config
    # one recipe for every env
    assert dataclasses.replace(td7.default_config(ENV_ID), env_id=CHEETAH) == config
    assert validation.out_of_range(config, td7) is None
    assert validation.out_of_range(td7.default_hyperparams(CHEETAH), td7) is None


def test_lap_alpha_outside_the_unit_interval_is_refused():
    refused = validation.out_of_range(td7.default_hyperparams(lap_alpha=1.5), td7)
    assert refused == "--lap-alpha must be in [0, 1], got 1.5"
    negative = validation.out_of_range(td7.default_hyperparams(checkpoint_reset_weight=-1.0), td7)
    assert negative == "--checkpoint-reset-weight must be >= 0, got -1"


def test_the_cpu_recipe_is_td7_in_the_cpu_loop_at_its_sizes():
    cpu = td7.default_config(CHEETAH, "cpu")
    td3_cpu = td3.default_config(CHEETAH)  # TD3's half-cheetah CPU recipe: loop and sizes
    published = td7.default_config(CHEETAH)
    loop = ("num_envs", "updates_per_iteration", "batch_size", "learning_starts")
    sizes = ("actor_hidden", "critic_hidden")
    for field in dataclasses.fields(cpu):
        name = field.name
        if name in loop + sizes + ("iterations_per_chunk",):
            assert getattr(cpu, name) == getattr(td3_cpu, name), name
        elif name in ("embedding_dim", "embedding_hidden"):
            assert getattr(cpu, name) in (128, (128, 128)), name
        else:
            assert getattr(cpu, name) == getattr(published, name), name
    assert cpu.actor_hidden == cpu.critic_hidden == (128, 128)
    hparams = td7.default_hyperparams(CHEETAH, "cpu").to_dict()
    assert hparams == td7.default_hyperparams(CHEETAH).to_dict()
