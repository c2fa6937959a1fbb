"""Batch renormalisation: training and evaluation mode by hand (r/d clipping, warm-up), the
running statistics, no gradient through r and d, and the layer's placement in an MLP."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.training import batch_renorm, networks

modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])
X = jnp.array([[0.0, 0.0], [2.0, 4.0]])  # batch mean (1, 2), batch variance (1, 4)


@modes
def test_evaluation_mode_uses_the_running_statistics(transform):
    got = transform(batch_renorm.renorm_eval)(
        jnp.array([[1.0, 2.0], [3.0, 6.0]]), jnp.array([1.0, 2.0]), jnp.array([4.0, 16.0]), 0.0
    )
    np.testing.assert_allclose(got, [[0.0, 0.0], [1.0, 1.0]], rtol=1e-7)


@modes
def test_training_mode_is_plain_batch_norm_during_the_warm_up(transform):
    running = jnp.zeros(2), jnp.array([0.01, 100.0])
    x_hat, mean, var = transform(batch_renorm.renorm_train)(X, *running, 99, 100, 3.0, 5.0, 0.0)
    np.testing.assert_allclose(x_hat, [[-1.0, -1.0], [1.0, 1.0]], rtol=1e-7)
    np.testing.assert_allclose(mean, [1.0, 2.0], rtol=1e-7)
    np.testing.assert_allclose(var, [1.0, 4.0], rtol=1e-7)


@modes
def test_training_mode_after_the_warm_up_clips_r_and_d(transform):
    running = jnp.zeros(2), jnp.array([0.01, 100.0])  # running std (0.1, 10)
    x_hat, _, _ = transform(batch_renorm.renorm_train)(X, *running, 100, 100, 3.0, 5.0, 0.0)
    # r = clip(batch std / std) = clip((10, 0.2), 1/3, 3) = (3, 1/3);
    # d = clip((batch mean - mean) / std) = clip((10, 0.2), -5, 5) = (5, 0.2).
    expected = np.array([[-1.0, -1.0], [1.0, 1.0]]) * [3.0, 1 / 3] + [5.0, 0.2]
    np.testing.assert_allclose(x_hat, expected, rtol=1e-6)


@modes
def test_running_statistics_step_towards_the_batch(transform):
    mean, var = transform(batch_renorm.running_update)(
        jnp.array([0.0, 1.0]), jnp.array([1.0, 1.0]), jnp.array([1.0, 2.0]), jnp.array([4.0, 0.0])
    )
    np.testing.assert_allclose(mean, [0.01, 1.01], rtol=1e-6)
    np.testing.assert_allclose(var, [1.03, 0.99], rtol=1e-6)


def test_no_gradient_through_r_d_or_the_running_statistics():
    weights = jnp.array([[0.3, -1.0], [2.0, 0.5]])

    def objective(x, mean, var):
        return jnp.sum(batch_renorm.renorm_train(x, mean, var, 100, 0)[0] * weights)

    x = jnp.array([[0.5, -1.0], [2.0, 4.0]])
    grads = jax.grad(objective, argnums=(0, 1, 2))(x, jnp.array([0.2, 0.1]), jnp.array([2.0, 3.0]))
    assert np.any(np.asarray(grads[0]) != 0.0)  # through the batch statistics, as batch norm
    assert np.all(np.asarray(grads[1]) == 0.0) and np.all(np.asarray(grads[2]) == 0.0)
    step = jax.grad(lambda m: jnp.sum(batch_renorm.running_update(m, 1.0, x[0], x[1])[0]))
    assert np.all(np.asarray(step(jnp.zeros(2))) == 0.99)  # only the decay: no batch gradient


def test_the_layer_updates_its_statistics_only_in_training_mode():
    layer = batch_renorm.BatchRenorm(warmup=0)
    variables = layer.init(jax.random.key(0), X)
    stats = variables["batch_stats"]
    assert int(stats["steps"]) == 0 and np.all(stats["mean"] == 0.0)  # init changes nothing
    out, updated = layer.apply(variables, X, True, mutable=["batch_stats"])
    new = updated["batch_stats"]
    assert int(new["steps"]) == 1
    np.testing.assert_allclose(new["mean"], [0.01, 0.02], rtol=1e-6)
    np.testing.assert_allclose(new["var"], [0.99 + 0.01, 0.99 + 0.04], rtol=1e-6)
    evaluated = layer.apply({**variables, "batch_stats": new}, X)
    expected = (np.asarray(X) - np.asarray(new["mean"])) / np.sqrt(np.asarray(new["var"]) + 1e-3)
    np.testing.assert_allclose(evaluated, expected, rtol=1e-5)


def test_batch_renorm_sits_on_the_input_and_after_each_nonlinearity():
    mlp = networks.MLP(networks.Layers((8, 6), norm="batch_renorm"), 1)
    x = jax.random.normal(jax.random.key(1), (5, 3))
    variables = mlp.init(jax.random.key(2), x)
    names = sorted(variables["params"])
    assert names == [
        "BatchRenorm_0",
        "BatchRenorm_1",
        "BatchRenorm_2",
        "Dense_0",
        "Dense_1",
        "Dense_2",
    ]
    params, stats = variables["params"], variables["batch_stats"]
    assert params["BatchRenorm_0"]["scale"].shape == (3,)  # the input's features
    assert stats["BatchRenorm_2"]["mean"].shape == (6,)  # after the last hidden layer

    def eval_norm(h):  # fresh statistics (mean 0, var 1) and scale 1, bias 0
        return h / np.sqrt(1.0 + 1e-3)

    h = eval_norm(np.asarray(x, np.float64))
    for index in range(2):
        layer = params[f"Dense_{index}"]
        h = np.maximum(h @ np.asarray(layer["kernel"]) + np.asarray(layer["bias"]), 0.0)
        h = eval_norm(h)
    out = h @ np.asarray(params["Dense_2"]["kernel"]) + np.asarray(params["Dense_2"]["bias"])
    np.testing.assert_allclose(mlp.apply(variables, x), out, rtol=1e-5, atol=1e-6)


def test_the_joint_pass_is_one_training_pass_over_both_halves():
    """CrossQ's pass over ``[(s, a); (s', a')]``: its values and statistics are those of one
    training-mode pass of each stacked critic over the 2B rows together, split back in two."""
    critic = networks.Critic(networks.Layers((8,), norm="batch_renorm", renorm_warmup=0))
    keys = jax.random.split(jax.random.key(3), 5)
    obs, next_obs = jax.random.normal(keys[0], (2, 5, 3))
    action, next_action = jax.random.uniform(keys[1], (2, 5, 2))
    critics = dict(networks.init_stacked(critic, keys[2], 2, obs, action))
    stats = critics.pop("batch_stats")
    q_tm1, q_t, new_stats = jax.jit(batch_renorm.joint_pass, static_argnums=0)(
        critic, critics, stats, obs, action, next_obs, next_action
    )
    assert q_tm1.shape == q_t.shape == (2, 5)
    for index in range(2):
        variables = jax.tree.map(lambda x, i=index: x[i], {**critics, "batch_stats": stats})
        both, updated = critic.apply(
            variables,
            jnp.concatenate([obs, next_obs]),
            jnp.concatenate([action, next_action]),
            train=True,
            mutable=["batch_stats"],
        )
        np.testing.assert_allclose(q_tm1[index], both[:5], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(q_t[index], both[5:], rtol=1e-6, atol=1e-7)
        mine = jax.tree.map(lambda x, i=index: x[i], new_stats)
        same = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)  # noqa: E731
        jax.tree.map(same, mine, updated["batch_stats"])
    assert np.all(np.asarray(new_stats["MLP_0"]["BatchRenorm_0"]["steps"]) == 1)
