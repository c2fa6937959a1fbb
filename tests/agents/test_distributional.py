"""C51 and QR-DQN (``rl_jax.agents.distributional``): their settings and recipes, the bootstrap
action (Double DQN's on the means), a few training chunks on CartPole (n-step, Double, PER) and
on MinAtar with finite losses, acting and bootstrapping over legal actions only on an env whose
illegal actions are fatal, and (in RESULTS.md's rows c51-cartpole and qrdqn-cartpole, whose goals
tests/test_results_slow.py asserts) CartPole solved in most seeds at the recipe's budget."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import distributional, dqn
from rl_jax.agents import distributional_parts as parts
from rl_jax.agents.distributional import c51, qrdqn
from rl_jax.envs.core.probes import FatalIllegalActions
from rl_jax.run import learners
from rl_jax.training.replay import NStepBatch

CARTPOLE = "rl_jax/CartPole-v1"
BOTH = pytest.mark.parametrize("algorithm", [c51, qrdqn], ids=["c51", "qrdqn"])


# ---- settings -----------------------------------------------------------------------------------
def test_recipes_and_config_types():
    cartpole = c51.default_config(CARTPOLE)
    assert type(cartpole) is distributional.Config
    assert (cartpole.head, cartpole.num_atoms, cartpole.v_min, cartpole.v_max) == (
        "categorical",
        101,
        -100.0,
        100.0,
    )
    assert cartpole.n_step == 3 and cartpole.policy_checkpoints  # DQN's CartPole recipe
    quantile = qrdqn.default_config("rl_jax/Breakout-MinAtar")
    assert isinstance(quantile, distributional.ImageConfig)
    assert isinstance(quantile, dqn.ImageConfig)
    assert (quantile.head, quantile.num_atoms, quantile.conv_layers) == (
        "quantile",
        200,
        (16, 3, 1),
    )
    assert float(qrdqn.default_hyperparams("rl_jax/Breakout-MinAtar").adam_eps) == pytest.approx(
        0.01 / 32
    )
    pixels = c51.default_config("rl_jax/CartPolePixels-v1")
    assert isinstance(pixels, distributional.PixelConfig) and pixels.head == "categorical"
    # a head given explicitly wins over the learner's
    assert c51.default_config(CARTPOLE, head="quantile").head == "quantile"


def test_bad_settings_are_one_clear_error():
    with pytest.raises(ValueError, match="head must be"):
        c51.default_config(CARTPOLE, head="gaussian")
    with pytest.raises(ValueError, match="dueling"):
        c51.default_config(CARTPOLE, dueling=True)
    with pytest.raises(ValueError, match="v_min"):
        c51.default_config(CARTPOLE, v_min=5.0, v_max=5.0)
    with pytest.raises(ValueError, match="num_atoms"):
        qrdqn.default_config(CARTPOLE, num_atoms=1)


def test_the_two_learners_are_registered_by_name():
    assert learners.ALGORITHMS["c51"] == "rl_jax.agents.distributional:c51"
    assert learners.ALGORITHMS["qrdqn"] == "rl_jax.agents.distributional:qrdqn"
    assert (c51.name, qrdqn.name) == ("c51", "qrdqn")


# ---- the bootstrap action -----------------------------------------------------------------------
def test_bootstrap_action_is_the_argmax_of_the_means_of_the_selecting_net():
    config = qrdqn.default_config(CARTPOLE, num_atoms=2)
    # target net: action means 1.0, 2.0; online net: 3.0, 0.0
    target_t = jnp.array([[[0.0, 2.0], [1.0, 3.0]]])
    online_t = jnp.array([[[3.0, 3.0], [-1.0, 1.0]]])
    assert int(distributional.bootstrap_actions(target_t, None, None, config)[0]) == 1
    assert int(distributional.bootstrap_actions(target_t, online_t, None, config)[0]) == 0
    # over legal actions only
    legal = jnp.array([[False, True]])
    assert int(distributional.bootstrap_actions(target_t, online_t, legal, config)[0]) == 1
    # C51: the means on the support
    categorical = c51.default_config(CARTPOLE, num_atoms=3, v_min=-1.0, v_max=1.0)
    logits = jnp.log(jnp.array([[[0.8, 0.1, 0.1], [0.1, 0.1, 0.8]]]))
    assert int(distributional.bootstrap_actions(logits, None, None, categorical)[0]) == 1


# ---- the loss on networks: terminal targets and Double DQN's bootstrap -------------------------
def _batch_and_nets(algorithm, terminal, **overrides):
    config = algorithm.default_config(CARTPOLE, hidden=(8,), **overrides)
    hparams = algorithm.default_hyperparams(CARTPOLE)
    net = distributional.make_network(config)
    keys = jax.random.split(jax.random.key(1), 4)
    online, target = (net.init(k, jnp.zeros(4)) for k in keys[:2])
    batch = NStepBatch(
        obs=jax.random.normal(keys[2], (3, 4)),
        action=jnp.array([0, 1, 1]),
        r_t=jnp.array([[1.0, 0.5], [2.0, 0.0], [-1.0, 1.0]]),
        discount_t=jnp.zeros((3, 2)) if terminal else jnp.full((3, 2), 0.9),
        next_obs=jax.random.normal(keys[3], (3, 4)),
    )
    return config, hparams, online, target, batch


@BOTH
def test_a_terminal_target_is_the_reward_alone(algorithm):
    extra = {"num_atoms": 201} if algorithm is c51 else {}  # C51: an atom at every integer
    config, hparams, online, target, batch = _batch_and_nets(algorithm, terminal=True, **extra)
    weights = jnp.ones(3)
    _, (per_sample, _) = distributional.loss_fn(online, target, batch, weights, hparams, config)
    values = distributional.distributions(online, batch.obs, config)
    rewards = batch.r_t[:, 0]  # d = 0 after the first step: later rewards do not count
    if algorithm is qrdqn:
        samples = jnp.broadcast_to(rewards[:, None], (3, config.num_atoms))
        expected = parts.quantile_huber_loss(values, batch.action, samples, weights, 1.0)[1]
    else:
        # all mass on the atom of the reward
        atoms = distributional.support(config)
        target_probs = (jnp.abs(atoms[None, :] - rewards[:, None]) < 1e-3).astype(jnp.float32)
        expected = parts.categorical_loss(values, batch.action, target_probs, weights)[1]
    np.testing.assert_allclose(per_sample, expected, rtol=1e-5, atol=1e-6)


def test_double_bootstraps_the_online_choice_valued_by_the_target_net():
    config, hparams, online, target, batch = _batch_and_nets(
        qrdqn, terminal=False, double=True, num_atoms=4, n_step=2
    )
    weights = jnp.ones(3)
    _, (per_sample, _) = distributional.loss_fn(online, target, batch, weights, hparams, config)
    chosen = jnp.argmax(distributional.q_values(online, batch.next_obs, config), axis=-1)
    target_t = distributional.distributions(target, batch.next_obs, config)
    total = batch.r_t[:, 0] + 0.9 * batch.r_t[:, 1]
    samples = total[:, None] + 0.81 * parts.select_action(target_t, chosen)
    values = distributional.distributions(online, batch.obs, config)
    expected = parts.quantile_huber_loss(values, batch.action, samples, weights, 1.0)[1]
    np.testing.assert_allclose(per_sample, expected, rtol=1e-5)
    # without double the target net chooses: the two differ on these random nets
    plain = dataclasses.replace(config, double=False)
    _, (other, _) = distributional.loss_fn(online, target, batch, weights, hparams, plain)
    assert not np.allclose(other, per_sample)


# ---- a few chunks --------------------------------------------------------------------------------
SMALL = {
    "num_envs": 4,
    "learning_starts": 64,
    "batch_size": 16,
    "buffer_size": 512,
    "iterations_per_chunk": 40,
    "num_eval_envs": 2,
    "target_update_period": 10,
}


def _chunks(algorithm, env_id, count, **overrides):
    config = algorithm.default_config(env_id, **{**SMALL, **overrides})
    hparams = algorithm.default_hyperparams(env_id)
    state = algorithm.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(algorithm.train_chunk, static_argnums=1)
    for _ in range(count):
        state, metrics = chunk(state, config, hparams)
    return state, config, metrics


def _assert_finite(state, metrics):
    for name in ("loss", "q"):
        assert np.isfinite(float(metrics.extra[name])), metrics.extra
    for leaf in jax.tree.leaves(state.agent.online):
        assert np.all(np.isfinite(leaf))


@BOTH
def test_cartpole_chunks_with_double_n_step_and_prioritized_replay(algorithm):
    state, config, metrics = _chunks(
        algorithm, CARTPOLE, 2, double=True, n_step=3, prioritized=True, hidden=(32, 32)
    )
    assert int(metrics.env_steps) == 2 * 4 * 40
    _assert_finite(state, metrics)
    assert float(metrics.extra["loss"]) > 0.0
    # priorities came from the per-sample losses: no longer all the initial value
    leaves = np.asarray(state.buffer.sums)[state.buffer.leaves :]
    assert len(np.unique(leaves[leaves > 0.0])) > 2
    out = distributional.distributions(state.agent.online, jnp.zeros((5, 4)), config)
    assert out.shape == (5, 2, config.num_atoms)
    assert state.agent.opt_state.hyperparams["adam_eps"].shape == ()


@BOTH
def test_minatar_chunk_on_the_conv_torso(algorithm):
    """Both learners build MinAtar's image config, network and state; C51 trains a chunk on it.
    The two differ only in the head and the loss (test_distributional_parts.py checks both),
    which QR-DQN trains on a conv torso in ``test_pixel_chunk_on_the_frame_replay``: a second
    whole-learner compile here would check nothing more."""
    overrides = {**SMALL, "hidden": (16,), "conv_layers": (4, 3, 1)}
    config = algorithm.default_config("rl_jax/Breakout-MinAtar", **overrides)
    assert isinstance(config, distributional.ImageConfig)
    assert distributional.make_network(config).obs_high == 1.0  # MinAtar's grids of 0/1
    if algorithm is qrdqn:
        hparams = algorithm.default_hyperparams("rl_jax/Breakout-MinAtar")
        assert algorithm.init(jax.random.key(0), config, hparams).obs.shape == (4, 10, 10, 4)
        return
    state, config, metrics = _chunks(
        algorithm, "rl_jax/Breakout-MinAtar", 1, hidden=(16,), conv_layers=(4, 3, 1)
    )
    assert state.obs.shape == (4, 10, 10, 4)
    _assert_finite(state, metrics)


@BOTH
def test_pixel_chunk_on_the_frame_replay(algorithm):
    state, config, metrics = _chunks(
        algorithm,
        "rl_jax/CartPolePixels-v1",
        1,
        frame_size=36,
        conv_layers=(8, 8, 4, 8, 3, 1),
        hidden=(16,),
        num_envs=2,
        batch_size=8,
        buffer_size=64,
        double=True,
        n_step=3,
        prioritized=True,
        augment_shift=2,
    )
    assert isinstance(config, distributional.PixelConfig)
    assert state.obs.dtype == jnp.uint8 and state.buffer.frames.dtype == jnp.uint8
    _assert_finite(state, metrics)
    assert algorithm.policy(state, config)(state.obs[0]).shape == ()


# ---- action masks -------------------------------------------------------------------------------
MASKED = "rl_jax/ProbeFatalIllegalActions-v0"
GAMMA = 0.5


@BOTH
def test_masked_env_acting_and_bootstrapping_over_legal_actions_only(algorithm):
    extra = {"v_min": -2.0, "v_max": 4.0} if algorithm is c51 else {"num_atoms": 16}
    config = algorithm.default_config(
        MASKED,
        num_envs=8,
        learning_starts=256,
        batch_size=64,
        buffer_size=8000,
        iterations_per_chunk=250,
        hidden=(32, 32),
        target_update_period=1,
        num_eval_envs=16,
        **extra,
    )
    hparams = algorithm.default_hyperparams(
        gamma=GAMMA,
        tau=0.05,
        learning_rate=1e-3,
        epsilon_end=0.2,
        epsilon_decay_steps=4000,
        adam_eps=1e-8,
    )
    state = algorithm.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(algorithm.train_chunk, static_argnums=1)
    for _ in range(4):
        state, metrics = chunk(state, config, hparams)
    assert state.action_mask is not None
    # every transition of training (all in the buffer) took a legal action: none was fatal
    assert int(jnp.sum(state.buffer.data.terminated)) == 0
    optimum = 10 * FatalIllegalActions().best_reward()
    assert float(metrics.eval_return) > 0.9 * optimum
    subsets = np.array([[(s >> a) & 1 for a in range(4)] for s in range(1, 16)], bool)
    legal = jnp.asarray(subsets)
    actions = distributional.act(state.agent, legal.astype(jnp.float32), config, legal)
    np.testing.assert_array_equal(actions, 3 - np.argmax(subsets[:, ::-1], axis=1))
