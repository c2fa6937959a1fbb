"""DQN learns the known Q-values, and REINFORCE the known best action, of the probe envs, end to
end (vmapped envs -> replay or whole episodes -> scanned train step -> evaluation).

DQN acts uniformly at random throughout (epsilon 1): Q-learning is off-policy, so the greedy
values must come out all the same, and every action's value gets data. The options are spread
over the probes (one compile each): Double + dueling on the two-step chain, n-step + prioritized +
Double on the truncation/termination pair, where bootstrapping through a time limit but not
through a terminal state is what is tested. Tolerance 0.05 on values of order 1; the wrong
answers ruled out (no bootstrap through truncation, bootstrap through termination, wrong action)
are all at least 0.2 away.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import dqn, reinforce
from rl_jax.envs.core.probes import Truncation

GAMMA = 0.5
TOL = 0.05
GRID = np.linspace(-1.0, 1.0, 5)


@functools.cache
def _dqn_chunk():
    return jax.jit(dqn.train_chunk, static_argnums=1)


@functools.cache
def train_dqn(env_id: str, **options):
    config = dqn.default_config(
        env_id,
        num_envs=8,
        learning_starts=256,
        batch_size=64,
        buffer_size=4096,
        iterations_per_chunk=250,
        hidden=(32, 32),
        target_update_period=1,
        **options,
    )
    hparams = dqn.default_hyperparams(
        gamma=GAMMA, tau=0.05, learning_rate=1e-3, epsilon_start=1.0, epsilon_end=1.0
    )
    state = dqn.init(jax.random.key(0), config, hparams)
    for _ in range(6):
        state, metrics = _dqn_chunk()(state, config, hparams)
    return config, state, metrics


def q_values(config, state, positions):
    obs = jnp.asarray(positions, jnp.float32)[:, None]
    return np.asarray(dqn.make_network(config).apply(state.agent.online, obs))


def test_dqn_learns_every_action_value_of_the_action_reward_probe():
    config, state, metrics = train_dqn("rl_jax/ProbeActionRewardDiscrete-v0")
    np.testing.assert_allclose(q_values(config, state, [0.0])[0], 1 - (GRID - 0.5) ** 2, atol=TOL)
    assert float(metrics.eval_return) == pytest.approx(1.0)  # the greedy action is index 3


def test_double_dueling_dqn_learns_the_two_step_chain():
    config, state, _ = train_dqn("rl_jax/ProbeTwoStepDiscrete-v0", double=True, dueling=True)
    q = q_values(config, state, [0.0, 1.0])
    np.testing.assert_allclose(q[0], GAMMA, atol=TOL)  # bootstraps from Q(1) = 1
    np.testing.assert_allclose(q[1], 1.0, atol=TOL)


NSTEP_PER = {"n_step": 2, "prioritized": True, "double": True}


@pytest.mark.parametrize("terminal", [False, True], ids=["truncation", "termination"])
def test_n_step_prioritized_dqn_bootstraps_through_truncation_only(terminal):
    env_id = (
        "rl_jax/ProbeTerminationDiscrete-v0" if terminal else "rl_jax/ProbeTruncationDiscrete-v0"
    )
    config, state, _ = train_dqn(env_id, **NSTEP_PER)
    q = q_values(config, state, [0.0, 1.0])
    for position in (0, 1):
        expected = Truncation.true_q(float(position), GAMMA, terminal)
        np.testing.assert_allclose(q[position], expected, atol=TOL)


# ---- REINFORCE ----------------------------------------------------------------------------------
@functools.cache
def train_reinforce(env_id: str):
    config = reinforce.default_config(
        env_id, num_envs=64, iterations_per_chunk=100, hidden=(16,), baseline="mean"
    )
    hparams = reinforce.default_hyperparams(learning_rate=1e-2, weight_decay=0.0)
    state = reinforce.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(reinforce.train_chunk, static_argnums=1)(state, config, hparams)
    return config, state, metrics


def test_reinforce_gaussian_policy_finds_the_best_action():
    config, state, metrics = train_reinforce("rl_jax/ProbeActionReward-v0")
    policy = reinforce.make_network(config).apply(state.agent.params, jnp.zeros((1, 1)))
    assert abs(float(policy["mean"][0, 0]) - 0.5) < TOL
    assert float(metrics.eval_return) > 1.0 - TOL**2


def test_reinforce_categorical_policy_finds_the_best_action():
    config, state, metrics = train_reinforce("rl_jax/ProbeActionRewardDiscrete-v0")
    logits = reinforce.make_network(config).apply(state.agent.params, jnp.zeros((1, 1)))["logits"]
    probabilities = np.asarray(jax.nn.softmax(logits[0]))
    assert probabilities.argmax() == 3 and probabilities[3] > 0.8, probabilities
    assert float(metrics.eval_return) == pytest.approx(1.0)
