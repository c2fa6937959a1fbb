"""MuZero on image observations (MinAtar, ``muzero.ImageConfig``): the config the image envs
get, a conv torso in the representation network only (the dynamics and prediction networks read
the hidden state), a tiny run trained, resumed into a loadable policy, and the settings refused
on such envs."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax.agents import muzero as mz
from rl_jax.training import episodes

BREAKOUT = "rl_jax/Breakout-MinAtar"
TINY = dict(
    num_envs=2,
    num_steps=2,
    iterations_per_chunk=3,
    num_simulations=2,
    unroll_steps=2,
    td_steps=2,
    buffer_size=40,
    batch_size=4,
    updates_per_iteration=1,
    warm_up=0,
    latent_size=4,
    hidden=(8,),
    value_support=3,
    reward_support=2,
    num_eval_envs=2,
    conv_layers=(4, 3, 1),
)


def test_image_envs_get_an_image_config_and_keep_their_images():
    config = mz.default_config(BREAKOUT)
    assert isinstance(config, mz.ImageConfig) and config.conv_layers == (16, 3, 1)
    assert episodes.observation_space(config).shape == (10, 10, 4)
    flat = mz.default_config("rl_jax/CartPole-v1")
    assert type(flat) is mz.Config and not isinstance(flat, mz.ImageConfig)


def test_the_representation_alone_reads_the_image_through_the_conv_torso():
    config = mz.default_config(BREAKOUT, **TINY)
    network = mz.make_network(config)
    obs = jnp.zeros((1, 10, 10, 4), jnp.float32)
    net_params = network.init(jax.random.key(0), obs, jnp.zeros((1,), jnp.int32))
    shapes = jax.tree.map(jnp.shape, net_params)["params"]
    assert shapes["torso"]["Conv_0"]["kernel"] == (3, 3, 4, 4)  # 4 3x3 filters on 4 channels

    # the representation's first layer reads the 8x8x4 feature map; the dynamics' the hidden
    # state and the one-hot action (4 + 3), the prediction's the hidden state (4)
    def kernels(tree: object) -> list[tuple[int, ...]]:
        leaves = jax.tree.leaves(tree, is_leaf=lambda x: type(x) is tuple)
        return [shape for shape in leaves if len(shape) == 2]

    assert kernels(shapes["representation"])[0] == (8 * 8 * 4, 8)
    assert kernels(shapes["dynamics"])[0] == (4 + 3, 8)
    assert kernels(shapes["prediction"])[0] == (4, 8)
    latent, policy_logits, value_logits = network.apply(net_params, obs, method=network.initial)
    assert latent.shape == (1, 4) and policy_logits.shape == (1, 3)
    assert value_logits.shape == (1, 2 * 3 + 1)


def test_a_tiny_run_trains_resumes_and_its_policy_loads(tmp_path):
    out = tmp_path / "run"
    rl_jax.train("muzero", BREAKOUT, seeds=1, total_steps=12, config=TINY, out=out, quiet=True)
    rl_jax.resume(out, total_steps=24, quiet=True)
    rows = [json.loads(line) for line in (out / "metrics.jsonl").open()]
    assert max(row["step"] for row in rows) == 24
    for name in ("policy_loss", "value_loss", "reward_loss"):
        assert all(np.isfinite(row[name]) for row in rows), name
    policy = rl_jax.load_policy(out)
    env = episodes.make_eval_env(mz.default_config(BREAKOUT, **TINY))
    _, ts = env.reset(jax.random.key(3))
    assert np.asarray(ts.obs).shape == (10, 10, 4)
    assert int(policy(np.asarray(ts.obs))) in (0, 1, 2)


def test_settings_an_image_env_cannot_take_are_refused():
    with pytest.raises(ValueError, match="image envs train the learned model"):
        mz.default_config(BREAKOUT, model="simulator")
    with pytest.raises(ValueError, match="not images"):
        mz.ImageConfig(env_id="rl_jax/CartPole-v1")
    with pytest.raises(ValueError, match="too small for the conv layers"):
        mz.default_config(BREAKOUT, conv_layers=(4, 11, 1))
