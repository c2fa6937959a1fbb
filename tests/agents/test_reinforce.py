"""REINFORCE's pieces against things we did not write: a Python loop for the reward-to-go, the
closed-form densities, the analytic policy gradient of a Gaussian bandit; and rollout masks."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy import stats

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import common, policy_gradient, reinforce, reinforce_parts
from rl_jax.agents.reinforce import Trajectory
from rl_jax.training import networks

GAMMA = 0.9


#: a policy's hidden layers as REINFORCE's defaults make them: tanh
TANH_16_32 = networks.Layers((16, 32), activation="tanh")


def test_reward_to_go_with_masks_equals_a_python_loop():
    rng = np.random.default_rng(0)
    horizon, count = 7, 5
    lengths = np.array([7, 3, 1, 5, 6])
    mask = (np.arange(horizon)[:, None] < lengths[None, :]).astype(np.float32)
    rewards = rng.normal(size=(horizon, count)).astype(np.float32) * mask
    expected = np.zeros((horizon, count))
    for i in range(count):
        for t in range(lengths[i]):
            expected[t, i] = sum(GAMMA ** (k - t) * rewards[k, i] for k in range(t, lengths[i]))
    got = jax.jit(policy_gradient.reward_to_go)(jnp.asarray(rewards), jnp.asarray(mask), GAMMA)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    # Garbage after an episode's end (a masked step) must not leak into earlier returns.
    noisy = jnp.asarray(rewards + (1.0 - mask) * 100.0)
    got = policy_gradient.reward_to_go(noisy, jnp.asarray(mask), GAMMA)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)


def test_normalize_over_valid_entries():
    x = jnp.array([[1.0, 2.0], [3.0, 50.0]])
    mask = jnp.array([[1.0, 1.0], [1.0, 0.0]])
    got = np.asarray(policy_gradient.normalize(x, mask))
    valid = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(got[[0, 0, 1], [0, 1, 0]], (valid - 2.0) / valid.std(), rtol=1e-5)
    assert got[1, 1] == 0.0


def test_gaussian_and_categorical_log_probs_equal_closed_forms():
    key_a, key_m, key_s, key_l = jax.random.split(jax.random.key(0), 4)
    action = jax.random.normal(key_a, (6, 3))
    mean = jax.random.normal(key_m, (6, 3))
    std = jax.random.uniform(key_s, (6, 3), minval=0.1, maxval=2.0)
    expected = stats.norm.logpdf(action, mean, std).sum(axis=-1)
    np.testing.assert_allclose(
        policy_gradient.gaussian_log_prob(action, mean, std), expected, rtol=1e-5
    )
    logits = jax.random.normal(key_l, (6, 4))
    index = jnp.array([0, 1, 2, 3, 1, 0])
    probabilities = np.exp(logits) / np.exp(logits).sum(axis=-1, keepdims=True)
    expected = np.log(probabilities[np.arange(6), np.asarray(index)])
    np.testing.assert_allclose(
        policy_gradient.categorical_log_prob(logits, index), expected, rtol=1e-5
    )
    check_grads(
        lambda m, s: policy_gradient.gaussian_log_prob(action, m, s), (mean, std), order=1, eps=1e-3
    )


def test_std_floor_bounds_the_std_and_leaves_the_mean_alone():
    obs = jax.random.normal(jax.random.key(1), (8, 3))
    low = networks.StochasticPolicy(TANH_16_32, action_dim=2, std_floor=1e-6)
    high = networks.StochasticPolicy(TANH_16_32, action_dim=2, std_floor=0.5)
    params = low.init(jax.random.key(2), obs)
    # Push the std head's raw output far negative: the std is then the floor.
    params = jax.tree_util.tree_map_with_path(
        lambda path, x: x - 1e3 if "Dense_1" in jax.tree_util.keystr(path) and x.ndim == 1 else x,
        params,
    )
    out_low, out_high = low.apply(params, obs), high.apply(params, obs)
    np.testing.assert_allclose(out_low["std"], 1e-6, rtol=1e-3)
    np.testing.assert_allclose(out_high["std"], 0.5, rtol=1e-6)
    np.testing.assert_array_equal(out_low["mean"], out_high["mean"])
    assert np.all(np.isfinite(policy_gradient.gaussian_log_prob(out_low["mean"], **_ms(out_low))))


def _ms(out):
    return {"mean": out["mean"], "std": out["std"]}


# ---- the gradient estimate against the analytic policy gradient --------------------------------
TARGET = 0.7  # bandit reward r(a) = -(a - TARGET)^2


def test_batch_gradient_matches_the_analytic_gaussian_bandit_gradient():
    """One-step episodes, reward ``-(a - c)^2``: ``J = -((mu - c)^2 + sigma^2)`` exactly, so
    ``grad J = d J / d(mu, sigma) . d(mu, sigma) / d theta``. The estimate from N episodes must
    agree within 4 standard errors of its own per-episode spread, in every coordinate."""
    config = reinforce.default_config("rl_jax/ProbeActionReward-v0", hidden=(4,))
    network = reinforce.make_network(config)
    obs = jnp.full((1, 1, 1), 0.3)
    params = network.init(jax.random.key(3), obs[0, 0])
    hparams = reinforce.default_hyperparams(gamma=GAMMA)
    flat = lambda tree: jnp.concatenate([x.ravel() for x in jax.tree.leaves(tree)])  # noqa: E731

    def objective(p):
        out = network.apply(p, obs[0, 0])
        return -((out["mean"][0] - TARGET) ** 2 + out["std"][0] ** 2)

    # each part compiled: op by op, every op of the network and the loss compiles on its own
    analytic = flat(jax.jit(jax.grad(objective))(params))

    def one_episode_gradient(key):
        action = reinforce_parts.sample_action(network.apply(params, obs), key)
        trajectory = Trajectory(obs, action, -((action[..., 0] - TARGET) ** 2), jnp.ones((1, 1)))
        gradient = jax.grad(lambda p: -reinforce.loss_fn(p, trajectory, hparams, config)[0])
        return flat(gradient(params))

    count = 5000
    keys = jax.random.split(jax.random.key(4), count)
    per_episode = jax.jit(jax.vmap(one_episode_gradient))(keys)
    estimate = per_episode.mean(axis=0)
    standard_error = per_episode.std(axis=0) / np.sqrt(count)
    assert np.all(np.abs(estimate - analytic) < 4 * standard_error + 1e-6), (estimate, analytic)
    # The batch loss over all N episodes at once is the same estimate (the mean over episodes).
    actions = jax.jit(
        jax.vmap(lambda k: reinforce_parts.sample_action(network.apply(params, obs), k))
    )(keys)
    batch = Trajectory(
        jnp.broadcast_to(obs[0], (1, count, 1)),
        actions[:, 0, 0][None],
        -((actions[:, 0, 0, 0] - TARGET) ** 2)[None],
        jnp.ones((1, count)),
    )
    batch_gradient = flat(
        jax.jit(jax.grad(lambda q: -reinforce.loss_fn(q, batch, hparams, config)[0]))(params)
    )
    np.testing.assert_allclose(batch_gradient, estimate, rtol=1e-3, atol=1e-5)
    assert np.max(np.abs(analytic)) > 10 * np.max(standard_error)  # the test can tell apart


# ---- baselines and rollouts --------------------------------------------------------------------
@pytest.fixture(scope="module")
def cartpole_rollout():
    config = reinforce.default_config("rl_jax/CartPole-v1", num_envs=6, baseline="value")
    params = reinforce.make_network(config).init(jax.random.key(5), jnp.zeros(4))
    trajectory = jax.jit(reinforce.rollout, static_argnums=2)(params, jax.random.key(6), config)
    return config, params, trajectory


def test_rollout_masks_each_episode_after_its_end(cartpole_rollout):
    _, _, trajectory = cartpole_rollout
    mask, reward = np.asarray(trajectory.mask), np.asarray(trajectory.reward)
    lengths = mask.sum(axis=0).astype(int)
    assert np.all(lengths >= 8) and len(set(lengths.tolist())) > 1  # random policy, varied ends
    for i, length in enumerate(lengths):
        assert np.all(mask[:length, i] == 1.0) and np.all(mask[length:, i] == 0.0)
        assert np.all(reward[:length, i] == 1.0) and np.all(reward[length:, i] == 0.0)
    # The last valid observation of each episode is a failing cart-pole state (or the time limit).
    obs = np.asarray(trajectory.obs)
    last = obs[lengths - 1, np.arange(len(lengths))]
    near_edge = (np.abs(last[:, 0]) > 2.0) | (np.abs(last[:, 2]) > 0.15)
    assert np.all(near_edge | (lengths == 500))


def test_rollout_on_mujoco_c_skipping_ended_envs_equals_stepping_them_all():
    """The rollout steps only the envs still in their episode (``Environment.step_active``, which
    the MuJoCo C backend implements by skipping the others' physics); wrapped in a bare
    ``Wrapper``, the same env takes the generic path that steps every env and keeps the ended
    ones' state. The trajectories are identical."""
    from rl_jax.envs.core.wrappers import Wrapper
    from rl_jax.training import episodes

    env_id = "rl_jax/InvertedDoublePendulum-v5"
    config = reinforce.default_config(env_id, num_envs=8, normalize_obs=False)
    params = reinforce.make_network(config).init(jax.random.key(5), jnp.zeros(9))
    skipping = jax.jit(lambda p, k: reinforce.rollout(p, k, config))(params, jax.random.key(6))
    wrapped = Wrapper(episodes.make_eval_env(config))
    stepping = jax.jit(lambda p, k: reinforce.rollout(p, k, config, env=wrapped))
    stepping = stepping(params, jax.random.key(6))
    lengths = np.asarray(skipping.mask).sum(axis=0)
    assert len(set(lengths.tolist())) > 1  # episodes end at different steps
    for got, want in zip(skipping, stepping, strict=True):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_value_baseline_trains_the_value_head_without_leaking_into_the_policy_loss(
    cartpole_rollout,
):
    config, params, trajectory = cartpole_rollout
    hparams = reinforce.default_hyperparams(value_coef=0.0)
    policy_only = jax.grad(lambda p: reinforce.loss_fn(p, trajectory, hparams, config)[0])(params)
    value_head = "Dense_1"  # after the logits head
    assert all(
        np.all(np.asarray(x) == 0.0) for x in jax.tree.leaves(policy_only["params"][value_head])
    )
    hparams = reinforce.default_hyperparams(value_coef=0.5)
    both = jax.grad(lambda p: reinforce.loss_fn(p, trajectory, hparams, config)[0])(params)
    assert all(np.any(np.asarray(x) != 0.0) for x in jax.tree.leaves(both["params"][value_head]))


def test_mean_baseline_equals_centred_returns(cartpole_rollout):
    config, params, trajectory = cartpole_rollout
    config_mean = reinforce.default_config(
        "rl_jax/CartPole-v1", num_envs=6, baseline="mean", normalize_returns=False
    )
    network = reinforce.make_network(config_mean)
    params = network.init(jax.random.key(7), jnp.zeros(4))
    hparams = reinforce.default_hyperparams(gamma=GAMMA)
    loss, _ = reinforce.loss_fn(params, trajectory, hparams, config_mean)
    returns = np.asarray(policy_gradient.reward_to_go(trajectory.reward, trajectory.mask, GAMMA))
    mask = np.asarray(trajectory.mask)
    advantage = returns - (returns * mask).sum() / mask.sum()
    logits = network.apply(params, trajectory.obs)["logits"]
    log_prob = np.asarray(policy_gradient.categorical_log_prob(logits, trajectory.action))
    terms = -(mask * log_prob * advantage) / 6
    # The centred terms cancel (|terms| adds to ~30, the loss is ~0.4), so another summation
    # order (a GPU's reduction: 6.7e-6 off on an H100) differs by a few float32 ulps of the
    # absolute sum, not of the loss.
    ulps = 4 * np.finfo(np.float32).eps * np.abs(terms).sum()
    np.testing.assert_allclose(loss, terms.sum(), rtol=1e-5, atol=ulps)


def test_gaussian_and_categorical_entropy_match_closed_forms():
    std = jnp.array([[0.5, 2.0]])
    gaussian = policy_gradient.entropy({"mean": jnp.zeros_like(std), "std": std})
    expected = np.sum(0.5 * np.log(2 * np.pi * np.e * np.asarray(std) ** 2), axis=-1)
    np.testing.assert_allclose(gaussian, expected, rtol=1e-5)
    probs = np.array([0.2, 0.3, 0.5])
    categorical = policy_gradient.entropy({"logits": jnp.log(jnp.asarray(probs))})
    np.testing.assert_allclose(categorical, -np.sum(probs * np.log(probs)), rtol=1e-5)


def test_gradient_clipping_scales_to_the_bound_and_zero_turns_it_off():
    grads = {"a": jnp.array([3.0, 0.0]), "b": jnp.array([[4.0]])}  # global norm 5
    clipped, norm = common.clip_by_global_norm(grads, jnp.float32(1.0))
    np.testing.assert_allclose(norm, 5.0, rtol=1e-6)
    np.testing.assert_allclose(clipped["a"], [0.6, 0.0], rtol=1e-6)
    np.testing.assert_allclose(clipped["b"], [[0.8]], rtol=1e-6)
    same, _ = common.clip_by_global_norm(grads, jnp.float32(0.0))
    np.testing.assert_allclose(same["b"], [[4.0]])


def test_learning_rate_decays_linearly_to_zero_or_stays_constant():
    decaying = reinforce.default_hyperparams(learning_rate=1e-3, lr_decay_updates=100.0)
    rates = [float(reinforce.learning_rate(decaying, jnp.float32(u))) for u in (0, 25, 100, 500)]
    np.testing.assert_allclose(rates, [1e-3, 7.5e-4, 0.0, 0.0], rtol=1e-6, atol=1e-12)
    constant = reinforce.default_hyperparams(learning_rate=1e-3)
    assert float(reinforce.learning_rate(constant, jnp.float32(10**6))) == np.float32(1e-3)


def test_state_independent_std_starts_at_initial_std_for_every_obs():
    network = networks.StochasticPolicy(
        networks.Layers((8,), activation="tanh"), action_dim=3, std_mode="param", initial_std=0.5
    )
    obs = jax.random.normal(jax.random.key(0), (4, 2))
    out = network.apply(network.init(jax.random.key(1), obs), obs)
    np.testing.assert_allclose(out["std"], np.full((4, 3), 0.5 + 1e-3), rtol=1e-6)


def test_normalized_observations_reach_the_policy_and_the_stats_learn_the_batch():
    config = reinforce.default_config(
        "rl_jax/CartPole-v1", num_envs=4, normalize_obs=True, value_hidden=(8,), baseline="value"
    )
    hparams = reinforce.default_hyperparams()
    state = reinforce.init(jax.random.key(0), config, hparams)
    stats = state.agent.obs_stats
    # Jitted: op by op, the rollout's scan and the update took ~2x as long to dispatch.
    rollout = jax.jit(reinforce.rollout, static_argnums=2)
    trajectory = rollout(state.agent.params, jax.random.key(1), config, stats)
    agent, metrics = jax.jit(reinforce.update, static_argnums=3)(
        state.agent, trajectory, hparams, config
    )
    mask = np.asarray(trajectory.mask, bool)
    np.testing.assert_allclose(agent.obs_stats.mean, np.asarray(trajectory.obs)[mask].mean(0),
                               rtol=1e-3, atol=1e-4)  # fmt: skip
    assert np.isfinite(float(metrics["loss"])) and np.isfinite(float(metrics["value_loss"]))


def test_squashed_mean_stays_inside_the_action_bounds_and_equals_tanh_of_the_head():
    config = reinforce.Config(env_id="rl_jax/InvertedDoublePendulum-v5", hidden=(8,))
    squashed = dataclasses.replace(config, squash_mean=True)
    params = reinforce.make_network(config).init(jax.random.PRNGKey(0), jnp.zeros(9))
    # Scale the mean head up so the raw mean lies far outside [-1, 1] for many observations.
    head = params["params"]["Dense_0"]
    params = {"params": {**params["params"], "Dense_0": jax.tree.map(lambda w: 1e3 * w, head)}}
    obs = jax.random.normal(jax.random.PRNGKey(1), (256, 9))
    raw = reinforce.policy_outputs(params, None, obs, config)["mean"]
    mean = reinforce.policy_outputs(params, None, obs, squashed)["mean"]
    assert np.abs(np.asarray(raw)).max() > 10.0
    np.testing.assert_allclose(mean, np.tanh(np.asarray(raw)), rtol=1e-5, atol=1e-6)
    assert np.all(np.abs(np.asarray(mean)) <= 1.0)  # tanh rounds to 1 in float32 past ~9
