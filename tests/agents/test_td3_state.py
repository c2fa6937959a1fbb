"""Config / Hyperparams / TrainState: what the run machinery serialises and checkpoints."""

import json

import jax
import numpy as np
import pytest
from probe_runs import probe_config, train

from rl_jax.agents.td3 import Config, Hyperparams, ddpg, explore, td3, update
from rl_jax.training import offpolicy, params

ENV_ID = "rl_jax/ProbeActionReward-v0"


def test_config_round_trips_through_json_and_rejects_bad_values():
    config = td3.default_config("rl_jax/Pendulum-v1", actor_hidden=(64, 32))
    again = Config.from_dict(json.loads(config.to_json()))
    assert again == config and hash(again) == hash(config)
    with pytest.raises(ValueError, match="unknown Config field"):
        Config.from_dict({**config.to_dict(), "learning_rate": 1e-3})
    for bad in (
        {"num_envs": 0},
        {"batch_size": -1},
        {"learning_starts": -5},
        {"num_critics": 0},
        {"network_init": "xavier"},
    ):
        with pytest.raises(ValueError):
            td3.default_config(ENV_ID, **bad)


def test_settings_that_moved_to_td7_and_crossq_load_from_old_runs_only_when_off():
    """A run recorded before TD7 and CrossQ became learners of their own has their settings in
    its config.json: at their "off" values it still loads as TD3 (the path runs load through);
    with one on, the message says where the setting went."""
    from rl_jax.errors import RunError
    from rl_jax.training.params import dataclass_from_dict

    config, hparams = td3.default_config(ENV_ID), td3.default_hyperparams()
    recorded = {
        **config.to_dict(),
        "sale": False,
        "policy_checkpoints": False,
        "target_update_period": 0,
        "embedding_hidden": [256, 256],  # as JSON holds it
        "target_networks": True,
        "adam_b1": 0.9,
    }
    assert dataclass_from_dict(config, recorded) == config
    loaded = dataclass_from_dict(hparams, {**hparams.to_dict(), "lap_alpha": 0.4})
    assert loaded.to_dict() == hparams.to_dict()
    with pytest.raises(RunError, match="sale, which is now the td7 learner's"):
        dataclass_from_dict(config, {**recorded, "sale": True})
    with pytest.raises(RunError, match="target_networks, which is now the crossq learner's"):
        dataclass_from_dict(config, {**recorded, "target_networks": False})
    with pytest.raises(RunError, match="lap_alpha, which is now the td7 learner's"):
        dataclass_from_dict(hparams, {**hparams.to_dict(), "lap_alpha": 0.5})


def test_td3_and_ddpg_defaults_are_the_papers():
    hparams = td3.default_hyperparams()
    assert hparams.to_dict() == pytest.approx(
        {
            "actor_lr": 3e-4,
            "critic_lr": 3e-4,
            "gamma": 0.99,
            "tau": 0.005,
            "exploration_noise": 0.1,
            "exploration_correlation": 0.0,
            "target_noise": 0.2,
            "target_noise_clip": 0.5,
            "lr_decay_steps": 0.0,
        }
    )
    # An env without a recipe gets the paper's settings (half cheetah has faster recipes).
    config = td3.default_config("rl_jax/InvertedPendulum-v5")
    assert (config.num_critics, config.policy_delay, config.batch_size) == (2, 2, 256)
    assert config.actor_hidden == config.critic_hidden == (256, 256)
    cheetah = td3.default_config("rl_jax/HalfCheetah-v5")
    assert cheetah.updates_per_iteration == cheetah.num_envs  # one update per env step, as paper
    assert cheetah.critic_hidden == (128, 128)  # its default: the CPU recipe's networks
    assert td3.default_config("rl_jax/HalfCheetah-v5", "paper-width").critic_hidden == (256, 256)
    ddpg_config = ddpg.default_config("rl_jax/InvertedPendulum-v5")
    assert (ddpg_config.num_critics, ddpg_config.policy_delay) == (1, 1)
    assert float(ddpg.default_hyperparams().target_noise) == 0.0
    # Everything else is shared: DDPG is TD3 with three settings changed.
    same = {k: v for k, v in config.to_dict().items() if k not in ("num_critics", "policy_delay")}
    assert same == {k: v for k, v in ddpg_config.to_dict().items() if k in same}


def test_hyperparams_round_trip_single_and_stacked():
    hparams = td3.default_hyperparams(actor_lr=1e-3)
    again = Hyperparams.from_dict(json.loads(json.dumps(hparams.to_dict())))
    jax.tree.map(np.testing.assert_array_equal, again, hparams)
    assert {leaf.dtype for leaf in jax.tree.leaves(again)} == {np.dtype(np.float32)}
    stacked, combos = params.grid(hparams, tau=[0.01, 0.02], gamma=[0.9, 0.99, 0.999])
    assert stacked.tau.shape == (6,) and combos[1] == {"tau": 0.01, "gamma": 0.99}
    assert Hyperparams.from_dict(stacked.to_dict()).gamma.tolist() == pytest.approx(
        [0.9, 0.99, 0.999] * 2
    )


def test_learning_rates_decay_linearly_with_env_steps_when_asked():
    config = probe_config(ENV_ID)  # 8 envs, learning starts at 256 env steps, 1 update/iteration
    rates = {}
    for decay in (0.0, 1_024.0):
        hparams = td3.default_hyperparams(actor_lr=1e-3, critic_lr=2e-3, lr_decay_steps=decay)
        state = td3.init(jax.random.key(0), config, hparams)
        agent = state.agent
        for index in (0, 1, 63):  # env steps 264, 272, 768 (after this iteration's envs)
            agent, _, _ = jax.jit(update, static_argnums=3)(
                agent, state.buffer, jax.random.key(1), config, hparams, jax.numpy.int32(index)
            )
            actor = float(agent.actor_opt.hyperparams["learning_rate"])
            critic = float(agent.critic_opt.hyperparams["learning_rate"])
            rates[decay, index] = (actor, critic)
    # The actor steps on every second update (policy_delay 2): at 1 and 63, not at 0.
    for index in (1, 63):
        assert rates[0.0, index] == pytest.approx((1e-3, 2e-3))
    fraction = {0: 1 - 264 / 1024, 1: 1 - 272 / 1024, 63: 1 - 768 / 1024}
    assert rates[1_024.0, 0][1] == pytest.approx(2e-3 * fraction[0], rel=1e-5)
    for index in (1, 63):
        expected = (1e-3 * fraction[index], 2e-3 * fraction[index])
        assert rates[1_024.0, index] == pytest.approx(expected, rel=1e-5)


def test_train_state_is_only_nonempty_arrays_and_buffer_estimate_is_exact():
    state, _ = train(ENV_ID)  # shared with test_td3_probes: no extra compile
    leaves = jax.tree.leaves(state)
    assert all(isinstance(leaf, jax.Array) and leaf.size > 0 for leaf in leaves)  # orbax-safe
    config = probe_config(ENV_ID)
    stored = sum(leaf.nbytes for leaf in jax.tree.leaves(state.buffer.data))
    assert offpolicy.buffer_nbytes(config) == stored
    # obs, action, next_obs of 1 float each, reward, two flags; 16,384 transitions.
    assert stored == 16_384 * (4 + 4 + 4 + 4 + 1 + 1)


def test_exploration_noise_is_scaled_gaussian_and_optionally_correlated():
    config = probe_config(ENV_ID)  # actions in [-1, 1]: half-range 1
    state = td3.init(jax.random.key(0), config, td3.default_hyperparams())
    num_envs = 20_000
    obs = jax.numpy.zeros((num_envs, 1))

    @jax.jit
    def noise_path(hparams, key):
        def step(noise, key):
            actions, noise = explore(state.agent, obs, noise, key, config, hparams, state.clock)
            return noise, actions[:, 0]

        return jax.lax.scan(step, jax.numpy.zeros((num_envs, 1)), jax.random.split(key, 60))[1]

    policy = float(td3.policy(state, config)(obs[:1])[0, 0])
    for rho in (0.0, 0.9):
        hparams = td3.default_hyperparams(exploration_correlation=rho)
        deviation = np.asarray(noise_path(hparams, jax.random.key(1))) - policy  # [60, envs]
        # Stationary std 0.1 (exploration_noise x half-range) whatever the correlation...
        assert np.std(deviation[-1]) == pytest.approx(0.1, rel=0.03)
        # ... and lag-1 correlation rho (the AR(1) starts at 0 and is stationary by step 30).
        lag1 = np.corrcoef(deviation[-2], deviation[-1])[0, 1]
        assert lag1 == pytest.approx(rho, abs=0.02)
