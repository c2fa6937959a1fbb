"""DQN and PPO on MinAtar by recipe: the MinAtar paper's torso (16 3x3 filters, then 128 units)
on observations scaled by their upper bound (MinAtar's grids are 0/1, frames 0-255), and one
small chunk of each with finite results."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.agents import dqn, ppo
from rl_jax.training import conv

BREAKOUT = "rl_jax/Breakout-MinAtar"


def test_the_conv_torso_scales_by_the_given_upper_bound():
    grid = jnp.ones((1, 10, 10, 4))
    torso = conv.ConvTorso((2, 3, 1), high=1.0)
    params = torso.init(jax.random.key(0), grid)
    frames = conv.ConvTorso((2, 3, 1))  # the default: uint8 frames
    np.testing.assert_allclose(
        torso.apply(params, grid), frames.apply(params, 255.0 * grid), rtol=1e-6
    )


@pytest.mark.parametrize("env_id", dqn.IMAGE_ENVS)
def test_recipes_give_the_minatar_torso(env_id):
    config = dqn.default_config(env_id)
    assert isinstance(config, dqn.ImageConfig)
    assert (config.conv_layers, config.hidden, config.batch_size) == ((16, 3, 1), (128,), 32)
    assert (config.buffer_size, config.target_update_period) == (100_000, 1000)
    assert config.updates_per_iteration == config.num_envs  # one update per env step
    assert float(dqn.default_hyperparams(env_id).epsilon_end) == pytest.approx(0.1)
    assert dqn.dqn.recipe(env_id).total_steps == 5_000_000
    policy = ppo.default_config(env_id)
    assert isinstance(policy, ppo.ImageConfig)
    # PPO's is gymnax-blines' network: two MLPs on the flattened grid, at its better agent's rate
    assert (policy.conv_layers, policy.hidden, policy.num_envs) == ((), (256, 256), 64)
    assert float(ppo.default_hyperparams(env_id).gamma) == pytest.approx(0.999)
    rate = 3e-4 if env_id in ppo.MINATAR_SLOWER else 1e-3
    assert float(ppo.default_hyperparams(env_id).learning_rate) == pytest.approx(rate)


def test_ppo_without_conv_layers_has_two_mlps_on_the_flattened_grid():
    """``conv_layers=()``: gymnax-blines' MinAtar network, the actor and the critic each an MLP
    of their own on the flattened 10x10x4 grid, giving what the same layers give on the flat
    vector."""
    config = ppo.default_config(BREAKOUT, conv_layers=(), hidden=(8, 8))
    network = ppo.make_network(config)
    grids = (jax.random.uniform(jax.random.key(0), (3, 10, 10, 4)) > 0.8).astype(jnp.float32)
    params = jax.jit(network.init)(jax.random.key(1), grids)["params"]
    assert params["actor_torso"]["Dense_0"]["kernel"].shape == (400, 8)
    assert params["critic_torso"]["Dense_0"]["kernel"].shape == (400, 8)
    flat = grids.reshape(3, 400)
    out = network.apply({"params": params}, grids)
    expected = network.clone(flatten_image=False).apply({"params": params}, flat)
    np.testing.assert_allclose(out["logits"], expected["logits"], rtol=1e-6)
    np.testing.assert_allclose(out["value"], expected["value"], rtol=1e-6)
    values = network.apply({"params": params}, grids, method="value")
    np.testing.assert_allclose(values, expected["value"], rtol=1e-6)


def test_image_configs_refuse_what_does_not_fit():
    with pytest.raises(ValueError, match="not images"):
        dqn.ImageConfig(env_id="rl_jax/CartPole-v1")
    with pytest.raises(ValueError, match="too small"):
        dqn.default_config(BREAKOUT, conv_layers=(16, 11, 1))
    with pytest.raises(ValueError, match="normalize_obs"):
        ppo.default_config(BREAKOUT, normalize_obs=True)


def test_dqn_chunk_on_minatar():
    config = dqn.default_config(
        BREAKOUT,
        num_envs=2,
        updates_per_iteration=1,
        iterations_per_chunk=40,
        learning_starts=32,
        buffer_size=256,
        batch_size=8,
        num_eval_envs=1,
        hidden=(16,),
        conv_layers=(4, 3, 1),
    )
    assert dqn.make_network(config).obs_high == 1.0
    hparams = dqn.default_hyperparams(BREAKOUT)
    # init jitted: op by op, it dispatches every op of the env's reset and the conv torso's init
    state = jax.jit(dqn.init, static_argnums=1)(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(dqn.train_chunk, static_argnums=1)(state, config, hparams)
    assert state.buffer.data.obs.shape[-3:] == (10, 10, 4)  # whole grids in the replay
    assert np.isfinite(float(metrics.extra["loss"]))
    for leaf in jax.tree.leaves(state.agent.online):
        assert np.all(np.isfinite(leaf))


def test_ppo_chunk_on_minatar():
    config = ppo.default_config(
        BREAKOUT,
        num_envs=4,
        num_steps=8,
        num_minibatches=2,
        num_epochs=1,
        iterations_per_chunk=1,
        num_eval_envs=1,
        hidden=(16,),
        conv_layers=(4, 3, 1),
    )
    assert ppo.make_network(config).obs_high == 1.0
    hparams = ppo.default_hyperparams(BREAKOUT)
    state = jax.jit(ppo.init, static_argnums=1)(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(ppo.train_chunk, static_argnums=1)(state, config, hparams)
    assert np.isfinite(float(metrics.extra["policy_loss"]))
    for leaf in jax.tree.leaves(state.agent.params):
        assert np.all(np.isfinite(leaf))
