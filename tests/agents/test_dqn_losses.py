"""DQN losses alone: hand-computed targets (plain, Double, n-step), Huber, n-step windows cut at
episode ends (terminated vs truncated), gradients, and no gradient into the target network."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import dqn, q_learning
from rl_jax.training import networks, replay
from rl_jax.training.replay import Transition

modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])
GAMMA = 0.9


@modes
def test_plain_target_is_reward_plus_discounted_max(transform):
    q_t = jnp.array([[1.0, 3.0, -1.0], [0.5, -2.0, 0.0], [2.0, 2.5, 4.0]])
    r_t = jnp.array([[1.0], [-1.0], [0.5]])
    discount_t = jnp.array([[GAMMA], [0.0], [GAMMA]])  # the second transition terminated
    got = transform(lambda r, d, q: q_learning.n_step_target(r, d, q_learning.greedy_values(q)))(
        r_t, discount_t, q_t
    )
    np.testing.assert_allclose(got, [1.0 + 0.9 * 3.0, -1.0, 0.5 + 0.9 * 4.0], rtol=1e-6)


@modes
def test_double_target_values_the_online_argmax_with_the_target_net(transform):
    q_t_target = jnp.array([[1.0, 3.0, -1.0], [0.5, -2.0, 0.0]])
    q_t_online = jnp.array([[5.0, 0.0, 1.0], [0.0, 1.0, 0.5]])  # argmax 0 and 1
    got = transform(q_learning.double_q_values)(q_t_target, q_t_online)
    np.testing.assert_allclose(got, [1.0, -2.0])
    r_t, discount_t = jnp.array([[1.0], [2.0]]), jnp.array([[GAMMA], [GAMMA]])
    target = transform(q_learning.n_step_target)(r_t, discount_t, got)
    # Plain DQN would bootstrap from 3 and 0.5 here: the two targets really differ.
    np.testing.assert_allclose(target, [1.0 + 0.9 * 1.0, 2.0 - 0.9 * 2.0], rtol=1e-6)


@modes
def test_n_step_target_sums_discounted_rewards_then_bootstraps(transform):
    # Row 0: three full steps. Row 1: the window ended after 2 steps (r 0, d 1 after).
    # Row 2: terminated on its second step (d 0 there).
    r_t = jnp.array([[1.0, 2.0, 3.0], [1.0, 2.0, 0.0], [1.0, 2.0, 0.0]])
    discount_t = jnp.array([[GAMMA] * 3, [GAMMA, GAMMA, 1.0], [GAMMA, 0.0, 1.0]])
    v_t = jnp.array([10.0, 10.0, 10.0])
    got = transform(q_learning.n_step_target)(r_t, discount_t, v_t)
    expected = [
        1.0 + 0.9 * 2.0 + 0.81 * 3.0 + 0.729 * 10.0,
        1.0 + 0.9 * 2.0 + 0.81 * 10.0,
        1.0 + 0.9 * 2.0,
    ]
    np.testing.assert_allclose(got, expected, rtol=1e-6)


@modes
def test_huber_and_weighted_q_learning_loss_values(transform):
    x = jnp.array([0.5, -2.0, 3.0, 0.0])
    np.testing.assert_allclose(transform(q_learning.huber_loss)(x, 1.0), [0.125, 1.5, 2.5, 0.0])
    q_tm1 = jnp.array([[1.0, 2.0], [0.0, -1.0], [4.0, 0.0]])
    a_tm1 = jnp.array([1, 0, 0])
    target = jnp.array([2.5, 3.0, 4.2])  # td errors 0.5, 3, 0.2
    weights = jnp.array([1.0, 0.5, 0.25])
    loss, td_error = transform(q_learning.q_learning_loss)(q_tm1, a_tm1, target, weights, 1.0)
    np.testing.assert_allclose(td_error, [0.5, 3.0, 0.2], rtol=1e-6)
    np.testing.assert_allclose(loss, (0.125 + 0.5 * 2.5 + 0.25 * 0.02) / 3, rtol=1e-6)


def test_linear_schedule_values():
    got = [float(q_learning.linear_schedule(1.0, 0.1, t, 100.0)) for t in (0, 50, 100, 500)]
    np.testing.assert_allclose(got, [1.0, 0.55, 0.1, 0.1], rtol=1e-6)


def test_learning_rate_decays_linearly_to_zero_and_is_off_at_zero():
    decaying = dqn.default_hyperparams(learning_rate=1e-3, lr_decay_steps=40_000.0)
    rates = [float(dqn.learning_rate_at(s, decaying)) for s in (0, 10_000, 40_000, 90_000)]
    np.testing.assert_allclose(rates, [1e-3, 7.5e-4, 0.0, 0.0], rtol=1e-6, atol=1e-12)
    constant = dqn.default_hyperparams(learning_rate=1e-3, lr_decay_steps=0.0)
    assert float(dqn.learning_rate_at(1_000_000, constant)) == pytest.approx(1e-3)


def test_pure_losses_check_grads():
    q_tm1 = jax.random.normal(jax.random.key(0), (6, 3))
    a_tm1 = jnp.array([0, 1, 2, 0, 1, 2])
    target = jnp.array([0.3, -2.0, 0.1, 1.5, 0.0, 4.0])
    weights = jnp.linspace(0.2, 1.0, 6)
    loss = jax.jit(lambda q: q_learning.q_learning_loss(q, a_tm1, target, weights, 1.0)[0])
    check_grads(loss, (q_tm1,), order=2, eps=1e-3)
    check_grads(jax.jit(lambda x: q_learning.huber_loss(x, 1.0)), (target * 0.9 + 0.05,), order=2)


def test_n_step_target_has_no_gradient():
    grads = jax.grad(lambda r, d, v: jnp.sum(q_learning.n_step_target(r, d, v)), argnums=(0, 1, 2))(
        jnp.ones((2, 3)), jnp.full((2, 3), GAMMA), jnp.ones(2)
    )
    for leaf in grads:
        assert np.all(np.asarray(leaf) == 0.0)


@pytest.mark.parametrize("n", [1, 3])
def test_fold_n_step_gives_the_n_step_target_as_reward_plus_discount_times_value(n):
    """TD3's n-step critic target is ``reward + discount * min q``: the fold must equal the
    nested n-step target for any bootstrap value."""
    keys = jax.random.split(jax.random.key(3), 3)
    r_t = jax.random.normal(keys[0], (4, n))
    discount_t = jax.random.choice(keys[1], jnp.array([0.0, GAMMA, 1.0]), (4, n))
    v_t = jax.random.normal(keys[2], (4,))
    reward, discount = replay.fold_n_step(r_t, discount_t)
    expected = q_learning.n_step_target(r_t, discount_t, v_t)
    np.testing.assert_allclose(reward + discount * v_t, expected, rtol=1e-6, atol=1e-6)


# ---- n-step windows from the buffer, episode ends --------------------------------------------
def _transition(step, terminated=False, truncated=False):
    """One env's step ``step``: obs = step, next_obs = step + 100 (marks the true next obs)."""
    return Transition(
        obs=jnp.array([[float(step)]]),
        action=jnp.array([step % 2], jnp.int32),
        reward=jnp.array([float(step)]),
        next_obs=jnp.array([[step + 100.0]]),
        terminated=jnp.array([terminated]),
        truncated=jnp.array([truncated]),
    )


@pytest.fixture(scope="module")
def window_buffer():
    """One env, 8 slots, 10 steps written (wrapped): steps 2..9 stored; step 4 terminated,
    step 6 truncated."""
    buffer = replay.init(jax.tree.map(lambda x: x[0], _transition(0)), 8, 1)
    for step in range(10):
        buffer = replay.add(buffer, _transition(step, step == 4, step == 6))
    return buffer


def _windows(buffer, first_steps, n):
    rows = jnp.array([s % 8 for s in first_steps], jnp.int32)
    window, stored = replay.gather_windows(buffer, rows, jnp.zeros_like(rows), n)
    return replay.n_step_batch(window, stored, GAMMA)


def test_n_step_window_stops_at_termination_without_bootstrap(window_buffer):
    batch = _windows(window_buffer, [3], 3)  # steps 3, 4 (terminated), 5 is another episode
    np.testing.assert_allclose(batch.r_t, [[3.0, 4.0, 0.0]])
    np.testing.assert_allclose(batch.discount_t, [[GAMMA, 0.0, 1.0]])
    np.testing.assert_allclose(batch.obs, [[3.0]])
    np.testing.assert_allclose(batch.next_obs, [[104.0]])


def test_n_step_window_bootstraps_through_truncation_from_the_final_obs(window_buffer):
    batch = _windows(window_buffer, [5], 3)  # steps 5, 6 (truncated), 7 is another episode
    np.testing.assert_allclose(batch.r_t, [[5.0, 6.0, 0.0]])
    np.testing.assert_allclose(batch.discount_t, [[GAMMA, GAMMA, 1.0]])
    np.testing.assert_allclose(batch.next_obs, [[106.0]])  # the final obs, not the reset obs
    target = q_learning.n_step_target(batch.r_t, batch.discount_t, jnp.array([10.0]))
    np.testing.assert_allclose(target, [5.0 + 0.9 * 6.0 + 0.81 * 10.0], rtol=1e-6)


def test_n_step_window_stops_at_the_newest_stored_step(window_buffer):
    batch = _windows(window_buffer, [7, 8, 9], 3)  # step 9 is the newest; 2 is older data
    np.testing.assert_allclose(batch.r_t, [[7.0, 8.0, 9.0], [8.0, 9.0, 0.0], [9.0, 0.0, 0.0]])
    np.testing.assert_allclose(batch.next_obs, [[109.0], [109.0], [109.0]])
    np.testing.assert_allclose(batch.discount_t[2], [GAMMA, 1.0, 1.0])


def test_one_step_window_is_the_plain_transition(window_buffer):
    batch = _windows(window_buffer, [4, 6], 1)
    np.testing.assert_allclose(batch.discount_t, [[0.0], [GAMMA]])
    np.testing.assert_allclose(batch.next_obs, [[104.0], [106.0]])


# ---- the loss on networks ---------------------------------------------------------------------
ENV_ID = "rl_jax/ProbeActionRewardDiscrete-v0"  # obs (1,), 5 actions
BATCH = 6


@pytest.fixture(scope="module")
def setup():
    keys = jax.random.split(jax.random.key(1), 5)
    config = dqn.default_config(ENV_ID, hidden=(16,), n_step=2)
    net = dqn.make_network(config)
    online = net.init(keys[0], jnp.zeros(1))
    target = net.init(keys[1], jnp.zeros(1))
    batch = replay.NStepBatch(
        obs=jax.random.normal(keys[2], (BATCH, 1)),
        action=jnp.array([0, 1, 2, 3, 4, 0], jnp.int32),
        r_t=jnp.array([[1.0, 0.5]] * 3 + [[-1.0, 0.0]] * 3),
        discount_t=jnp.array([[GAMMA, GAMMA]] * 3 + [[0.0, 1.0]] * 3),
        next_obs=jax.random.normal(keys[3], (BATCH, 1)),
    )
    weights = jax.random.uniform(keys[4], (BATCH,), minval=0.1, maxval=1.0)
    return config, net, online, target, batch, weights


@pytest.mark.parametrize("double", [False, True], ids=["plain", "double"])
def test_loss_fn_matches_hand_assembled_target(setup, double):
    config, net, online, target, batch, weights = setup
    config = dqn.default_config(ENV_ID, hidden=(16,), n_step=2, double=double)
    hparams = dqn.default_hyperparams()
    loss, (td_error, _) = dqn.loss_fn(online, target, batch, weights, hparams, config)
    q_next_target = np.asarray(net.apply(target, batch.next_obs))
    q_next_online = np.asarray(net.apply(online, batch.next_obs))
    rows = np.arange(BATCH)
    if double:
        v_t = q_next_target[rows, q_next_online.argmax(axis=1)]
    else:
        v_t = q_next_target.max(axis=1)
    r, d = np.asarray(batch.r_t), np.asarray(batch.discount_t)
    y = r[:, 0] + d[:, 0] * (r[:, 1] + d[:, 1] * v_t)
    q = np.asarray(net.apply(online, batch.obs))[rows, np.asarray(batch.action)]
    delta = y - q
    huber = np.where(np.abs(delta) <= 1.0, 0.5 * delta**2, np.abs(delta) - 0.5)
    np.testing.assert_allclose(td_error, delta, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(loss, np.mean(np.asarray(weights) * huber), rtol=1e-5)
    assert not np.array_equal(q_next_online.argmax(1), q_next_target.argmax(1))  # a real choice


@pytest.mark.parametrize("double", [False, True], ids=["plain", "double"])
def test_loss_has_exactly_zero_gradient_wrt_the_target_network(setup, double):
    config, _, online, target, batch, weights = setup
    config = dqn.default_config(ENV_ID, hidden=(16,), n_step=2, double=double)
    hparams = dqn.default_hyperparams()
    grad_online, grad_target = jax.grad(
        lambda o, t: dqn.loss_fn(o, t, batch, weights, hparams, config)[0], argnums=(0, 1)
    )(online, target)
    assert all(np.all(np.asarray(leaf) == 0.0) for leaf in jax.tree.leaves(grad_target))
    assert all(np.any(np.asarray(leaf) != 0.0) for leaf in jax.tree.leaves(grad_online))


def test_network_loss_check_grads(setup):
    # Finite differences through ReLU networks need float64 (locally; library stays float32).
    _, _, _, _, batch, weights = setup
    with jax.enable_x64(True):
        to64 = lambda tree: jax.tree.map(lambda x: x.astype(jnp.float64), tree)  # noqa: E731
        for dueling in (False, True):
            net = networks.QNetwork(networks.Layers((8,), dtype=jnp.float64), 5, dueling=dueling)
            online, target = (
                to64(net.init(k, jnp.zeros(1))) for k in jax.random.split(jax.random.key(2))
            )
            batch64 = batch._replace(
                obs=to64(batch.obs), next_obs=to64(batch.next_obs), r_t=to64(batch.r_t)
            )
            batch64 = batch64._replace(discount_t=to64(batch64.discount_t))

            def objective(params, net=net, target=target, batch=batch64):
                q_tm1 = net.apply(params, batch.obs)
                v_t = q_learning.greedy_values(net.apply(target, batch.next_obs))
                y = q_learning.n_step_target(batch.r_t, batch.discount_t, v_t)
                return q_learning.q_learning_loss(q_tm1, batch.action, y, to64(weights), 1.0)[0]

            check_grads(jax.jit(objective), (online,), order=1, modes=("rev",), eps=1e-6)


def test_dueling_head_is_value_plus_centred_advantage():
    net = networks.QNetwork(networks.Layers((8,)), 4, dueling=True)
    params = net.init(jax.random.key(3), jnp.zeros(2))
    obs = jax.random.normal(jax.random.key(4), (5, 2))
    q = net.apply(params, obs)
    features = networks.Torso(networks.Layers((8,))).apply(
        {"params": params["params"]["Torso_0"]}, obs
    )
    value_head, advantage_head = params["params"]["Dense_0"], params["params"]["Dense_1"]
    value = features @ value_head["kernel"] + value_head["bias"][None, :]
    advantage = features @ advantage_head["kernel"] + advantage_head["bias"][None, :]
    expected = value + advantage - advantage.mean(axis=1, keepdims=True)
    np.testing.assert_allclose(q, expected, rtol=1e-5, atol=1e-6)
    # The state value is the mean of q over actions.
    np.testing.assert_allclose(q.mean(axis=1), value[:, 0], rtol=1e-5, atol=1e-6)


def test_layer_norm_q_network_normalises_each_hidden_layer_before_its_relu():
    net = networks.QNetwork(networks.Layers((8, 6), norm="layer"), 3)
    params = net.init(jax.random.key(3), jnp.zeros(2))["params"]
    torso = params["Torso_0"]
    assert set(torso) == {"Dense_0", "LayerNorm_0", "Dense_1", "LayerNorm_1"}
    obs = jax.random.normal(jax.random.key(4), (5, 2))
    x = np.asarray(obs, np.float64)
    for layer in range(2):
        dense, norm = torso[f"Dense_{layer}"], torso[f"LayerNorm_{layer}"]
        x = x @ np.asarray(dense["kernel"], np.float64) + np.asarray(dense["bias"], np.float64)
        x = (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + 1e-6)
        x = np.maximum(x * np.asarray(norm["scale"]) + np.asarray(norm["bias"]), 0.0)
    head = params["Dense_0"]
    expected = x @ np.asarray(head["kernel"], np.float64) + np.asarray(head["bias"], np.float64)
    np.testing.assert_allclose(net.apply({"params": params}, obs), expected, rtol=1e-4, atol=1e-5)
    # Off, the parameters are the ones saved runs have.
    plain = networks.QNetwork(networks.Layers((8, 6)), 3).init(jax.random.key(3), jnp.zeros(2))[
        "params"
    ]
    assert set(plain["Torso_0"]) == {"Dense_0", "Dense_1"}
    with pytest.raises(ValueError, match="norm must be"):
        dqn.default_config("rl_jax/CartPole-v1", norm="batch")


# ---- target network steps, epsilon-greedy -----------------------------------------------------
@pytest.fixture(scope="module")
def updater():
    return jax.jit(dqn.update, static_argnums=3)


def _agent_and_buffer(config, hparams):
    state = dqn.init(jax.random.key(5), config, hparams)
    buffer = state.buffer
    for step in range(8):
        buffer = dqn.add_to_buffer(buffer, _probe_transition(step, config), config, hparams)
    return state.agent, buffer


def _probe_transition(step, config):
    n = config.num_envs
    return Transition(
        obs=jnp.full((n, 1), 0.1 * step),
        action=jnp.full((n,), step % 5, jnp.int32),
        reward=jnp.full((n,), 1.0),
        next_obs=jnp.full((n, 1), 0.1 * step + 0.1),
        terminated=jnp.zeros(n, bool),
        truncated=jnp.zeros(n, bool),
    )


@pytest.mark.parametrize("tau,period", [(1.0, 3), (0.25, 1)], ids=["hard", "polyak"])
def test_target_network_hard_copy_or_polyak(updater, tau, period):
    config = dqn.default_config(
        ENV_ID, hidden=(8,), batch_size=4, buffer_size=16, target_update_period=period
    )
    hparams = dqn.default_hyperparams(tau=tau)
    agent, buffer = _agent_and_buffer(config, hparams)
    for index in range(3):
        previous = agent
        agent, buffer, _ = updater(agent, buffer, jax.random.key(index), config, hparams, index)
        due = (index + 1) % period == 0
        expected = jax.tree.map(
            lambda t, o, due=due: (1 - tau) * t + tau * o if due else t,
            previous.target,
            agent.online,
        )
        jax.tree.map(
            lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7),
            agent.target,
            expected,
        )
    if tau == 1.0:  # after 3 updates with period 3, the target is the online net exactly
        jax.tree.map(np.testing.assert_array_equal, agent.target, agent.online)


def test_epsilon_greedy_frequencies_follow_the_schedule():
    config = dqn.default_config(ENV_ID, hidden=(8,), buffer_size=16)
    hparams = dqn.default_hyperparams(
        epsilon_start=1.0, epsilon_end=0.2, epsilon_decay_steps=1000.0
    )
    agent = dqn.init(jax.random.key(6), config, hparams).agent
    obs = jnp.zeros((4000, 1))
    greedy = dqn.act(agent, obs[:1], config)[0]
    explore = jax.jit(dqn.explore, static_argnums=4)
    for env_steps, epsilon in ((0, 1.0), (500, 0.6), (5000, 0.2)):
        clock = dqn.offpolicy.Clock(jnp.int32(env_steps), jnp.int32(0), jnp.int32(0))
        noise = jnp.zeros(4000)
        actions, noise_out = explore(agent, obs, noise, jax.random.key(7), config, hparams, clock)
        # Greedy with probability 1 - epsilon + epsilon / 5 (a uniform draw can pick it too).
        p_greedy = 1.0 - epsilon + epsilon / 5
        frequency = float(jnp.mean(actions == greedy))
        assert abs(frequency - p_greedy) < 4 * np.sqrt(p_greedy * (1 - p_greedy) / 4000) + 1e-3
        np.testing.assert_array_equal(noise_out, noise)


# ---- policy checkpoints (TD7's, rl_jax.training.policy_checkpoints) ----------------------------
def _always(params, action: int):
    """``params`` changed so that the greedy action is ``action`` whatever the observation."""
    head = params["params"]["Dense_0"]
    head = {"kernel": jnp.zeros_like(head["kernel"]), "bias": jax.nn.one_hot(action, 5)}
    return {"params": {**params["params"], "Dense_0": head}}


def test_policy_checkpoints_evaluate_the_checkpoint_and_explore_with_the_assessed_copy():
    config = dqn.default_config(
        ENV_ID, hidden=(8,), buffer_size=16, policy_checkpoints=True, checkpoint_episodes_from=10
    )
    hparams = dqn.default_hyperparams(epsilon_start=0.0, epsilon_end=0.0).as_arrays()
    state = dqn.init(jax.random.key(6), config, hparams)
    online = state.agent.online
    # At init the checkpoint and the copy are the initial network.
    jax.tree.map(np.testing.assert_array_equal, state.agent.checkpoint.best, online)
    checkpoint = state.agent.checkpoint.replace(
        best=_always(online, 0), assessed=_always(online, 1)
    )
    agent = state.agent.replace(online=_always(online, 2), checkpoint=checkpoint)
    obs = jax.random.normal(jax.random.key(7), (6, 1))
    clock = dqn.offpolicy.Clock(jnp.int32(0), jnp.int32(0), jnp.int32(0))
    explored, _ = dqn.explore(agent, obs, jnp.zeros(6), jax.random.key(8), config, hparams, clock)
    assert dqn.act(agent, obs, config).tolist() == [0] * 6  # evaluation: the checkpoint
    assert explored.tolist() == [1] * 6  # training envs: the copy under assessment
    policy = dqn.dqn.policy(state.replace(agent=agent), config)
    assert policy(obs).tolist() == [0] * 6  # what best/ and load_policy get
    # One episode is an assessment before env step 10: the copy's 7 passes (score -1e8) and it
    # becomes the checkpoint; the next copy is the online network.
    counting = jnp.ones(config.num_envs, bool)
    agent = agent.replace(checkpoint=agent.checkpoint.replace(counting=counting))
    done = jnp.zeros(config.num_envs, bool).at[0].set(True)
    returns = jnp.full(config.num_envs, 7.0)
    agent = dqn.observe(agent, None, returns, done, clock, config, hparams)
    assert dqn.act(agent, obs, config).tolist() == [1] * 6
    assert float(agent.checkpoint.score) == 7.0
    jax.tree.map(np.testing.assert_array_equal, agent.checkpoint.assessed, agent.online)
    # Off: no checkpoint in the state, and observing leaves the agent as it was.
    plain = dqn.default_config(ENV_ID, hidden=(8,), buffer_size=16)
    plain_agent = dqn.init(jax.random.key(6), plain, hparams).agent
    assert plain_agent.checkpoint is None
    assert dqn.observe(plain_agent, None, returns, done, clock, plain, hparams) is plain_agent
