"""Actor/critic networks: bounds, initialisation schemes, stacked critics."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.training import networks


def _kernels_and_biases(mlp_params):
    layers = mlp_params["params"]
    return [(layers[name]["kernel"], layers[name]["bias"]) for name in sorted(layers)]


def test_actor_is_tanh_stretched_onto_asymmetric_bounds():
    actor = networks.Actor(networks.Layers((8,)), action_low=(0.0, -3.0), action_high=(1.0, 1.0))
    obs = 50.0 * jax.random.normal(jax.random.key(0), (64, 4))
    params = actor.init(jax.random.key(1), obs)
    action = np.asarray(actor.apply(params, obs))
    mlp_params = {"params": params["params"]["MLP_0"]}
    raw = networks.MLP(networks.Layers((8,)), 2, output_gain=0.01).apply(mlp_params, obs)
    expected = np.array([0.0, -3.0]) + (np.tanh(np.asarray(raw)) + 1) / 2 * np.array([1.0, 4.0])
    np.testing.assert_allclose(action, expected, rtol=1e-6, atol=1e-6)
    assert np.all(action >= [0.0, -3.0]) and np.all(action <= [1.0, 1.0])
    assert actor.apply(params, obs[0]).shape == (2,)  # works unbatched too


def test_fan_in_uniform_init_matches_torch_linear_default():
    mlp = networks.MLP(networks.Layers((256, 64)), 3)
    params = jax.jit(mlp.init)(jax.random.key(0), jnp.zeros((1, 17)))
    for kernel, bias in _kernels_and_biases(params):
        bound = 1.0 / np.sqrt(kernel.shape[0])
        assert np.abs(kernel).max() <= bound and np.abs(bias).max() <= bound
        # U(-b, b) has std b / sqrt(3); 17 x 256 and 256 x 64 samples pin it within ~2%.
        if kernel.size > 1000:
            assert np.std(kernel) == pytest.approx(bound / np.sqrt(3), rel=0.05)


def test_orthogonal_init_has_orthogonal_columns_gain_and_zero_bias():
    mlp = networks.MLP(networks.Layers((32,), initializer="orthogonal"), 4, output_gain=0.5)
    params = mlp.init(jax.random.key(0), jnp.zeros((1, 16)))
    (hidden, hidden_bias), (out, out_bias) = _kernels_and_biases(params)
    # 16 x 32: the rows are orthonormal x gain (wide matrix); 32 x 4: columns are.
    np.testing.assert_allclose(hidden @ hidden.T, 2.0 * np.eye(16), atol=1e-5)
    np.testing.assert_allclose(out.T @ out, 0.25 * np.eye(4), atol=1e-5)
    assert np.all(hidden_bias == 0) and np.all(out_bias == 0)


def test_unknown_initializer_is_rejected():
    with pytest.raises(ValueError, match="unknown initializer"):
        networks.Layers((4,), initializer="xavier")  # type: ignore[arg-type]


def test_stacked_critics_are_independent_and_match_one_by_one_apply():
    critic = networks.Critic(networks.Layers((16, 16)))
    obs, action = jnp.ones((5, 3)), jnp.linspace(-1, 1, 10).reshape(5, 2)
    params = networks.init_stacked(critic, jax.random.key(0), 2, obs[0], action[0])
    assert all(leaf.shape[0] == 2 for leaf in jax.tree.leaves(params))
    first, second = (jax.tree.map(lambda x, i=i: x[i], params) for i in range(2))
    assert not np.allclose(jax.tree.leaves(first)[0], jax.tree.leaves(second)[0])
    q = networks.apply_stacked(critic, params, obs, action)
    assert q.shape == (2, 5)
    np.testing.assert_allclose(q[0], critic.apply(first, obs, action), rtol=1e-6)
    np.testing.assert_allclose(q[1], critic.apply(second, obs, action), rtol=1e-6)


def test_bfloat16_compute_keeps_float32_params_and_outputs():
    obs, action = jax.random.normal(jax.random.key(2), (8, 3)), jnp.zeros((8, 1))
    full = networks.Critic(networks.Layers((32, 32)))
    half = networks.Critic(networks.Layers((32, 32), dtype=jnp.bfloat16))
    params = full.init(jax.random.key(0), obs, action)
    assert {leaf.dtype for leaf in jax.tree.leaves(half.init(jax.random.key(0), obs, action))} == {
        jnp.dtype(jnp.float32)
    }
    q_full, q_half = full.apply(params, obs, action), half.apply(params, obs, action)
    assert q_half.dtype == jnp.float32
    # bfloat16 keeps 8 mantissa bits: agreement to a few parts in a hundred.
    np.testing.assert_allclose(q_half, q_full, rtol=0.05, atol=0.02)
    assert isinstance(nn.Dense(1), nn.Module)


def _layer_norm(x, eps=1e-6):
    x = np.asarray(x, np.float64)
    return (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + eps)


@pytest.mark.parametrize("activation", ["relu", "elu"])
def test_layer_norm_sits_between_each_hidden_dense_and_its_nonlinearity(activation):
    mlp = networks.MLP(networks.Layers((8, 6), activation=activation, norm="layer"), 2)
    x = jax.random.normal(jax.random.key(0), (5, 3))
    params = mlp.init(jax.random.key(1), x)
    layers = params["params"]
    assert sorted(layers) == ["Dense_0", "Dense_1", "Dense_2", "LayerNorm_0", "LayerNorm_1"]
    # Non-trivial LayerNorm scale and bias, so that their place in the chain shows.
    layers = jax.tree.map(lambda v: v + 0.1 * jnp.arange(v.size).reshape(v.shape), layers)
    nonlinearity = {
        "relu": lambda h: np.maximum(h, 0),
        "elu": lambda h: np.where(h > 0, h, np.expm1(h)),
    }
    h = np.asarray(x, np.float64)
    for index in range(2):
        dense_params, norm = layers[f"Dense_{index}"], layers[f"LayerNorm_{index}"]
        h = h @ np.asarray(dense_params["kernel"]) + np.asarray(dense_params["bias"])
        h = _layer_norm(h) * np.asarray(norm["scale"]) + np.asarray(norm["bias"])
        h = nonlinearity[activation](h)
    out = h @ np.asarray(layers["Dense_2"]["kernel"]) + np.asarray(layers["Dense_2"]["bias"])
    # float32 LayerNorm: flax computes the variance as E[x^2] - E[x]^2, whose rounding XLA may
    # order differently (jax 0.12 / flax 0.12.12 was 1.2e-4 off on outputs ~4); a misplaced norm
    # would be off by O(1)
    np.testing.assert_allclose(mlp.apply({"params": layers}, x), out, rtol=1e-4, atol=1e-4)


def test_layer_norm_critic_and_actor_keep_the_plain_dense_parameters():
    # The Dense layers keep their names and initial values: a LayerNorm adds parameters only.
    obs, action = jnp.ones((4, 3)), jnp.zeros((4, 1))
    plain = networks.Critic(networks.Layers((16, 16))).init(jax.random.key(0), obs, action)
    normed = networks.Critic(networks.Layers((16, 16), norm="layer")).init(
        jax.random.key(0), obs, action
    )
    for name, layer in plain["params"]["MLP_0"].items():
        jax.tree.map(np.testing.assert_array_equal, layer, normed["params"]["MLP_0"][name])
    actor = networks.Actor(networks.Layers((16,), norm="layer"), (-1.0,), (1.0,))
    assert "LayerNorm_0" in actor.init(jax.random.key(0), obs)["params"]["MLP_0"]
    with pytest.raises(ValueError, match="unknown norm"):
        networks.Layers((4,), norm="group")  # type: ignore[arg-type]


def _relu_block(x, block):
    """SimBa's block by hand (float64): x + W2 relu(W1 LN(x) + b1) + b2."""
    norm, first, second = block["LayerNorm_0"], block["Dense_0"], block["Dense_1"]
    x = np.asarray(x, np.float64)
    h = _layer_norm(x) * np.asarray(norm["scale"]) + np.asarray(norm["bias"])
    h = np.maximum(h @ np.asarray(first["kernel"]) + np.asarray(first["bias"]), 0.0)
    return x + h @ np.asarray(second["kernel"]) + np.asarray(second["bias"])


def test_simba_block_shapes_and_its_skip_path():
    block = networks.SimbaBlock(6)
    x = jax.random.normal(jax.random.key(0), (5, 6))
    params = block.init(jax.random.key(1), x)["params"]
    assert params["Dense_0"]["kernel"].shape == (6, 24)
    assert params["Dense_1"]["kernel"].shape == (24, 6)
    np.testing.assert_allclose(block.apply({"params": params}, x), _relu_block(x, params), 1e-5)
    # With the block's last layer at zero the block is the identity: the skip carries x as is.
    silent = jax.tree.map(jnp.zeros_like, params["Dense_1"])
    out = block.apply({"params": {**params, "Dense_1": silent}}, x)
    np.testing.assert_array_equal(out, x)


def test_simba_is_linear_then_blocks_then_layer_norm_then_head():
    net = networks.Simba(networks.Layers((8, 8)), 3)
    x = jax.random.normal(jax.random.key(2), (4, 5))
    params = net.init(jax.random.key(3), x)["params"]
    assert sorted(params) == ["Dense_0", "Dense_1", "LayerNorm_0", "SimbaBlock_0", "SimbaBlock_1"]
    assert params["Dense_0"]["kernel"].shape == (5, 8)  # input -> the blocks' width
    assert params["Dense_1"]["kernel"].shape == (8, 3)  # the head
    h = np.asarray(x, np.float64) @ np.asarray(params["Dense_0"]["kernel"])
    h = h + np.asarray(params["Dense_0"]["bias"])
    for index in range(2):
        h = _relu_block(h, params[f"SimbaBlock_{index}"])
    norm = params["LayerNorm_0"]
    h = _layer_norm(h) * np.asarray(norm["scale"]) + np.asarray(norm["bias"])
    out = h @ np.asarray(params["Dense_1"]["kernel"]) + np.asarray(params["Dense_1"]["bias"])
    np.testing.assert_allclose(net.apply({"params": params}, x), out, rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match="one width"):
        networks.Simba(networks.Layers((8, 4)), 1).init(jax.random.key(0), x)


def test_actor_and_critic_take_simba_in_place_of_the_mlp():
    obs, action = jnp.ones((4, 3)), jnp.zeros((4, 1))
    critic = networks.Critic(networks.Layers((8, 8), architecture="simba")).init(
        jax.random.key(0), obs, action
    )
    assert list(critic["params"]) == ["Simba_0"]
    actor = networks.Actor(networks.Layers((8,), architecture="simba"), (-1.0,), (1.0,))
    params = actor.init(jax.random.key(0), obs)
    assert list(params["params"]) == ["Simba_0"]
    assert np.all(np.abs(actor.apply(params, obs)) <= 1.0)


def test_layers_spec_is_hashable_and_refuses_unknown_options_where_it_is_made():
    spec = networks.Layers((8, 8), activation="elu", norm="layer")
    assert spec == networks.Layers((8, 8), activation="elu", norm="layer")
    assert hash(spec) == hash(networks.Layers((8, 8), activation="elu", norm="layer"))
    assert networks.Critic(spec) == networks.Critic(spec)  # modules holding it compare equal
    for bad, message in [
        ({"activation": "gelu"}, "unknown activation"),
        ({"norm": "group"}, "unknown norm"),
        ({"architecture": "resnet"}, "unknown architecture"),
        ({"initializer": "xavier"}, "unknown initializer"),
    ]:
        with pytest.raises(ValueError, match=message):
            networks.Layers((8,), **bad)
    # SimBa's blocks share one width and bring their own LayerNorms
    with pytest.raises(ValueError, match="one width"):
        networks.Layers((8, 4), architecture="simba")
    with pytest.raises(ValueError, match="own LayerNorms"):
        networks.Layers((8, 8), architecture="simba", norm="layer")


def test_torso_refuses_what_plain_hidden_layers_cannot_be():
    x = jnp.zeros((2, 3))
    with pytest.raises(ValueError, match="norm is 'none' or 'layer'"):
        networks.Torso(networks.Layers((4,), norm="batch_renorm")).init(jax.random.key(0), x)
    with pytest.raises(ValueError, match="architecture is 'mlp'"):
        networks.Torso(networks.Layers((4,), architecture="simba")).init(jax.random.key(0), x)
