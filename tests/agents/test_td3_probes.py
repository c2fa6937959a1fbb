"""TD3 (and DDPG) learn the known values and actions of the probe environments, end to end:
vmapped envs -> replay buffer -> scanned train step -> evaluation.

Tolerance: 0.05 on values of order 1 and on the action (range [-1, 1]) for one seed after 1,500
iterations; the wrong answers the tests rule out are all at least 0.15 away.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from probe_runs import PROBE_HPARAMS, policy_actions, probe_config, probe_hparams, q_values, train

from rl_jax import envs
from rl_jax.envs.core.probes import ActionReward, Truncation

GAMMA = PROBE_HPARAMS["gamma"]
TOL = 0.05


# ---- the probe envs themselves -----------------------------------------------------------------
def _run(env, actions, seed=0, start=None):
    key = jax.random.key(seed)
    state, ts = env.reset(key) if start is None else env.reset_to(jnp.array([start]))
    steps = [ts]
    for i, action in enumerate(actions):
        state, ts = env.step(jax.random.fold_in(key, i), state, jnp.asarray(action))
        steps.append(ts)
    return steps


@pytest.mark.parametrize("num_actions", [None, 5])
def test_probe_dynamics(num_actions):
    # Discrete index i of 5 stands for linspace(-1, 1, 5)[i]: index 3 is 0.5, index 0 is -1.
    best, worst = (jnp.array([0.5]), jnp.array([-1.0])) if num_actions is None else (3, 0)
    make = lambda env_id: envs.make(env_id, num_actions=num_actions)  # noqa: E731
    constant = _run(make("rl_jax/ProbeConstantReward-v0"), [worst])[1]
    assert (float(constant.reward), bool(constant.terminated)) == (1.0, True)
    action_probe = make("rl_jax/ProbeActionReward-v0")
    assert float(_run(action_probe, [best])[1].reward) == 1.0
    assert float(_run(action_probe, [worst])[1].reward) == pytest.approx(1 - 1.5**2)
    two = _run(make("rl_jax/ProbeTwoStep-v0"), [best, best])
    assert [float(t.obs[0]) for t in two] == [0.0, 1.0, 1.0]
    assert [float(t.reward) for t in two[1:]] == [0.0, 1.0]
    assert [bool(t.terminated) for t in two[1:]] == [False, True]
    for env_id, terminal in [
        ("rl_jax/ProbeTruncation-v0", False),
        ("rl_jax/ProbeTermination-v0", True),
    ]:
        for start in (0.0, 1.0):
            step = _run(make(env_id), [best], start=start)[1]
            assert float(step.obs[0]) == 1.0 - start and float(step.reward) == start
            assert bool(step.truncated) and bool(step.terminated) == terminal
    space = action_probe.action_space()
    assert (space.n == 5) if num_actions else (space.shape == (1,))


def test_truncation_probe_values_solve_the_bellman_equations():
    for gamma in (0.5, 0.9):
        q0, q1 = Truncation.true_q(0.0, gamma), Truncation.true_q(1.0, gamma)
        assert q0 == pytest.approx(0.0 + gamma * q1) and q1 == pytest.approx(1.0 + gamma * q0)
    assert Truncation.true_q(0.0, 0.5, terminal=True) == 0.0


# ---- learning ---------------------------------------------------------------------------------
def test_td3_learns_constant_value():
    env_id = "rl_jax/ProbeConstantReward-v0"
    state, history = train(env_id)
    q = q_values(state, probe_config(env_id), [0.0] * 5, np.linspace(-1, 1, 5))
    np.testing.assert_allclose(q, 1.0, atol=TOL)
    assert float(history[-1].eval_return) == 1.0


def test_td3_learns_action_dependent_reward_and_best_action():
    env_id = "rl_jax/ProbeActionReward-v0"
    config = probe_config(env_id)
    state, history = train(env_id)
    assert float(policy_actions(state, config, [0.0])[0]) == pytest.approx(0.5, abs=TOL)
    actions = np.array([-0.5, 0.0, 0.5, 1.0])
    q = q_values(state, config, [0.0] * 4, actions)
    np.testing.assert_allclose(q, np.broadcast_to(1 - (actions - 0.5) ** 2, q.shape), atol=TOL)
    assert float(history[-1].eval_return) == pytest.approx(1.0, abs=TOL**2)


def test_td3_warms_up_with_random_actions_then_follows_the_policy():
    env_id = "rl_jax/ProbeActionReward-v0"
    state, _ = train(env_id)
    config = probe_config(env_id)
    warm_rows = config.learning_starts // config.num_envs
    actions = np.asarray(state.buffer.data.action[..., 0])
    # Uniform on [-1, 1] has std 1/sqrt(3); exploration noise around the policy has std 0.1.
    assert np.std(actions[:warm_rows]) == pytest.approx(1 / np.sqrt(3), rel=0.15)
    last_rows = actions[int(state.buffer.rows_filled) - 50 : int(state.buffer.rows_filled)]
    assert np.std(last_rows) == pytest.approx(0.1, rel=0.2)
    assert np.mean(last_rows) == pytest.approx(ActionReward.best_action, abs=TOL)


def test_td3_updates_actor_and_targets_every_second_critic_update():
    env_id = "rl_jax/ProbeActionReward-v0"
    state, history = train(env_id)
    config = probe_config(env_id)
    iterations = len(history) * config.iterations_per_chunk
    critic_updates = iterations - config.learning_starts // config.num_envs
    assert int(state.clock.updates) == int(history[-1].updates) == critic_updates
    assert int(state.agent.critic_opt.count) == critic_updates
    assert int(state.agent.actor_opt.count) == critic_updates // 2
    # The learning rates in use sit in the optimizer states (and so in every checkpoint).
    assert float(state.agent.actor_opt.hyperparams["learning_rate"]) == pytest.approx(1e-3)
    assert state.agent.critics["params"]["MLP_0"]["Dense_0"]["kernel"].shape[0] == 2


def test_td3_learns_discounted_two_step_values():
    env_id = "rl_jax/ProbeTwoStep-v0"
    state, _ = train(env_id)
    config = probe_config(env_id)
    q = q_values(state, config, [0.0, 1.0], policy_actions(state, config, [0.0, 1.0]))
    np.testing.assert_allclose(q[:, 0], GAMMA, atol=TOL)
    np.testing.assert_allclose(q[:, 1], 1.0, atol=TOL)


@pytest.mark.parametrize("env_id", ["rl_jax/ProbeTruncation-v0", "rl_jax/ProbeTermination-v0"])
def test_bootstraps_through_truncation_not_termination(env_id):
    """Every episode ends after one step, cut by the time limit (Truncation) or terminal
    (Termination). Only bootstrapping from the true final obs at truncation, and not at
    termination, gives the values asserted here."""
    state, _ = train(env_id)
    config = probe_config(env_id)
    terminal = env_id.endswith("Termination-v0")

    # What the train step stored: the true final obs (not the autoreset's new start) and the
    # two flags apart.
    data, rows = state.buffer.data, int(state.buffer.rows_filled)
    obs, next_obs = np.asarray(data.obs[:rows, :, 0]), np.asarray(data.next_obs[:rows, :, 0])
    np.testing.assert_array_equal(next_obs, 1.0 - obs)
    np.testing.assert_array_equal(np.asarray(data.reward[:rows]), obs)
    assert np.all(np.asarray(data.truncated[:rows]))
    assert np.all(np.asarray(data.terminated[:rows]) == terminal)
    # The next row starts from fresh coin flips, which differ from the final obs half the time.
    assert 0.4 < np.mean(np.asarray(data.obs[1:rows, :, 0]) != next_obs[:-1]) < 0.6

    # What the critics learned.
    q = q_values(state, config, [0.0, 1.0], policy_actions(state, config, [0.0, 1.0]))
    expected = [Truncation.true_q(p, GAMMA, terminal) for p in (0.0, 1.0)]
    np.testing.assert_allclose(q, np.broadcast_to(expected, q.shape), atol=TOL)
    # The wrong answers are far: terminal-vs-not swapped, or bootstrapping from the new start.
    wrong = [[Truncation.true_q(p, GAMMA, not terminal) for p in (0.0, 1.0)]]
    wrong.append([GAMMA / (2 * (1 - GAMMA)), 1 + GAMMA / (2 * (1 - GAMMA))])
    for values in wrong:
        assert np.max(np.abs(np.asarray(values) - np.asarray(expected))) > 3 * TOL


@pytest.mark.parametrize(
    "env_id", ["rl_jax/ProbeTwoStep-v0", "rl_jax/ProbeTruncation-v0", "rl_jax/ProbeTermination-v0"]
)
def test_n_step_returns_learn_the_same_values(env_id):
    """3-step windows reach past each episode's end here: the window must stop there, bootstrap
    from the true final obs at truncation and not at termination, or the values come out wrong
    (the one-step tests above rule those answers out)."""
    overrides = (("n_step", 3),)
    state, _ = train(env_id, config_overrides=overrides)
    config = probe_config(env_id, **dict(overrides))
    q = q_values(state, config, [0.0, 1.0], policy_actions(state, config, [0.0, 1.0]))
    if env_id == "rl_jax/ProbeTwoStep-v0":
        expected = np.array([[GAMMA, 1.0]])
    else:
        terminal = env_id.endswith("Termination-v0")
        expected = np.array([[Truncation.true_q(p, GAMMA, terminal) for p in (0.0, 1.0)]])
    np.testing.assert_allclose(q, np.broadcast_to(expected, q.shape), atol=TOL)


def test_ddpg_learns_action_dependent_reward_with_one_critic_and_no_delay():
    env_id = "rl_jax/ProbeActionReward-v0"
    config = probe_config(env_id, "ddpg")
    assert (config.num_critics, config.policy_delay) == (1, 1)
    assert float(probe_hparams("ddpg").target_noise) == 0.0
    state, history = train(env_id, "ddpg")
    assert float(policy_actions(state, config, [0.0])[0]) == pytest.approx(0.5, abs=TOL)
    q = q_values(state, config, [0.0, 0.0], [0.0, 0.5])
    assert q.shape == (1, 2)
    np.testing.assert_allclose(q[0], [0.75, 1.0], atol=TOL)
    assert int(state.agent.actor_opt.count) == int(state.agent.critic_opt.count)
    assert float(history[-1].eval_return) == pytest.approx(1.0, abs=TOL**2)
