"""MuZero (``rl_jax.agents.muzero`` and ``muzero_parts``): the categorical value transform on
hand-worked numbers, n-step targets against a plain loop, the unroll's masks and its halved
gradients on a toy model, a deterministic ``train_chunk``, the search policy's actions and
``load_policy`` on a tiny run. The CartPole goal is its row's (tests/test_results_slow.py)."""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax.agents import muzero as mz
from rl_jax.agents import muzero_parts as parts
from rl_jax.agents import muzero_simulator as sim
from rl_jax.training import episodes, parallel, params

CARTPOLE = "rl_jax/CartPole-v1"
TINY = dict(
    num_envs=2,
    num_steps=2,
    iterations_per_chunk=6,
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
)


def h(x: float, eps: float = 1e-3) -> float:
    return math.copysign(math.sqrt(abs(x) + 1.0) - 1.0, x) + eps * x


# ---- the categorical transform ----------------------------------------------------------------
def test_two_hot_of_hand_worked_values():
    # support -2 .. 2; h(3) = 1.003 (0.997 on 1, 0.003 on 2), h(-3) = -1.003, h(0) = 0 and
    # h(8) = 2.008 clipped to the support's end
    got = parts.scalar_to_support(jnp.array([3.0, -3.0, 0.0, 8.0]), 2)
    expected = [
        [0.0, 0.0, 0.0, 0.997, 0.003],
        [0.003, 0.997, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 1.0],
    ]
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_two_hot_mean_is_the_rescaled_value_and_the_inverse_gives_it_back():
    values = [-50.0, -3.7, -0.2, 0.0, 0.5, 12.0, 80.0]
    probs = parts.scalar_to_support(jnp.array(values), 10)
    assert probs.shape == (7, 21)
    np.testing.assert_allclose(jnp.sum(probs, axis=-1), 1.0, atol=1e-6)
    np.testing.assert_allclose(probs @ jnp.arange(-10.0, 11.0), [h(v) for v in values], rtol=1e-5)
    np.testing.assert_allclose(parts.support_to_scalar(probs, 10), values, rtol=1e-4, atol=1e-5)


def test_scale_latent_maps_each_row_to_the_unit_interval():
    got = parts.scale_latent(jnp.array([[2.0, 4.0, 3.0], [-1.0, -1.0, 1.0]]))
    np.testing.assert_allclose(got, [[0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])


# ---- n-step targets ---------------------------------------------------------------------------
def loop_targets(r, terminated, truncated, v_next, gamma, n):
    """The n-step targets, written as the definition reads, one step at a time."""
    steps, batch = r.shape
    out = np.zeros((steps, batch))
    for b in range(batch):
        for t in range(steps):
            total, scale = 0.0, 1.0
            for j in range(t, min(t + n, steps)):
                total += scale * r[j, b]
                if terminated[j, b]:
                    break
                if truncated[j, b] or j == t + n - 1 or j == steps - 1:
                    total += scale * gamma * v_next[j, b]
                    break
                scale *= gamma
            out[t, b] = total
    return out


@pytest.mark.parametrize("n", [1, 3, 10])
def test_n_step_targets_match_a_plain_loop(n):
    rng = np.random.default_rng(n)
    shape = (9, 4)
    r = rng.normal(size=shape).astype(np.float32)
    v_next = rng.normal(size=shape).astype(np.float32)
    ends = rng.random(shape)
    terminated, truncated = ends < 0.15, (ends > 0.15) & (ends < 0.3)
    expected = loop_targets(r, terminated, truncated, v_next, 0.9, n)
    for fn in (parts.value_targets, jax.jit(parts.value_targets, static_argnums=5)):
        got = fn(jnp.array(r), terminated, truncated, jnp.array(v_next), 0.9, n)
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)


# ---- the unroll -------------------------------------------------------------------------------
def test_unroll_masks_of_hand_worked_episodes():
    # K = 4; env 0: no end; env 1: terminated at step 1; env 2: truncated at 0, terminated at 2
    terminated = jnp.array([[0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]], bool)
    truncated = jnp.array([[0, 0, 1], [0, 0, 0], [0, 0, 0], [0, 0, 0]], bool)
    alive, absorbing = parts.unroll_masks(terminated, truncated)
    np.testing.assert_array_equal(alive.T, [[1] * 5, [1, 1, 0, 0, 0], [1, 0, 0, 0, 0]])
    np.testing.assert_array_equal(absorbing.T, [[0] * 5, [0, 0, 1, 1, 1], [0] * 5])


def toy_model(w):
    """A one-number model: latent w * obs, each step latent' = 1.5 latent + action; logits are
    multiples of the latent (policy [l, -l], values and rewards [l, 0, -l] on -1, 0, 1)."""

    def predict(latent):
        return latent * jnp.array([[1.0, -1.0]]), latent * jnp.array([[1.0, 0.0, -1.0]])

    def initial(obs):
        latent = w * obs
        return (latent, *predict(latent))

    def recurrent(latent, action):
        latent = 1.5 * latent + action[:, None]
        return (latent, latent * jnp.array([[1.0, 0.0, -1.0]]), *predict(latent))

    return initial, recurrent


def log_softmax(logits):
    return logits - jnp.log(jnp.sum(jnp.exp(logits), axis=-1, keepdims=True))


def test_unroll_loss_masks_terms_past_a_termination():
    """One unroll, K = 2, terminated at its first step: the value after it is learnt as 0 (the
    absorbing state) and so is the second reward; the policies after it are not learnt."""
    obs, actions, w = jnp.array([[0.7]]), jnp.array([[1], [0]]), 0.8
    pi = jnp.array([[[0.25, 0.75]], [[0.5, 0.5]], [[0.9, 0.1]]])
    # h(3) = 1.003 is past the support's end (S = 1): one-hot on 1; 0 is one-hot on 0
    z, u = jnp.array([[3.0], [5.0], [5.0]]), jnp.array([[3.0], [7.0]])
    masks = parts.unroll_masks(jnp.array([[True], [False]]), jnp.array([[False], [False]]))
    initial, recurrent = toy_model(w)
    # compiled: op by op, each of the unroll's many small ops compiles on its own
    loss, metrics = jax.jit(
        lambda: parts.unroll_loss(
            initial, recurrent, obs, actions, pi, z, u, masks, (1, 1), value_coef=0.5
        )
    )()
    l0 = w * 0.7
    l1 = 1.5 * l0 + 1.0
    l2 = 1.5 * l1 + 0.0
    policy = -jnp.sum(pi[0, 0] * log_softmax(l0 * jnp.array([1.0, -1.0])))
    top, middle = 2, 1  # indices of 1 and 0 on the support -1, 0, 1
    bins = lambda latent: log_softmax(latent * jnp.array([1.0, 0.0, -1.0]))  # noqa: E731
    value = -bins(l0)[top] + 0.5 * (-bins(l1)[middle]) + 0.5 * (-bins(l2)[middle])
    reward = 0.5 * (-bins(l1)[top]) + 0.5 * (-bins(l2)[middle])
    np.testing.assert_allclose(metrics["policy_loss"], policy, rtol=1e-6)
    np.testing.assert_allclose(metrics["value_loss"], value, rtol=1e-6)
    np.testing.assert_allclose(metrics["reward_loss"], reward, rtol=1e-6)
    np.testing.assert_allclose(loss, policy + 0.5 * value + reward, rtol=1e-6)


def test_unroll_loss_halves_the_gradient_at_every_dynamics_step():
    """d loss / d w is the sum over steps k of 0.5^k times the gradient of step k's terms
    alone (each computed without any scaling), weighted 1 at k = 0 and 1 / K after."""
    k_steps = 3
    obs, actions = jnp.array([[0.7], [-0.4]]), jnp.array([[1, 0], [0, 1], [1, 1]])
    pi = jax.nn.softmax(jnp.arange(16.0).reshape(4, 2, 2) / 7.0, axis=-1)
    z, u = jnp.array([[0.2, 0.1], [0.3, 0.0], [0.6, 0.1], [0.05, 0.4]]), jnp.full((3, 2), 0.3)
    masks = (jnp.ones((4, 2)), jnp.zeros((4, 2)))

    def loss(w):
        initial, recurrent = toy_model(w)
        return parts.unroll_loss(initial, recurrent, obs, actions, pi, z, u, masks, (1, 1))[0]

    def step_terms(w, k):
        """Step k's policy, value and reward cross-entropies, unscaled, batch mean."""
        latent = w * obs
        for j in range(k):
            latent = 1.5 * latent + actions[j][:, None]
        policy = -jnp.sum(pi[k] * log_softmax(latent * jnp.array([[1.0, -1.0]])), axis=-1)
        bins = log_softmax(latent * jnp.array([[1.0, 0.0, -1.0]]))
        two_hot = lambda x: jnp.stack([jnp.zeros_like(x), 1.0 - x, x], axis=-1)  # noqa: E731
        value = -jnp.sum(two_hot(jnp.array([h(float(v)) for v in z[k]])) * bins, axis=-1)
        total = policy + value
        if k > 0:
            total += -jnp.sum(two_hot(jnp.full((2,), h(0.3))) * bins, axis=-1)
        return jnp.mean(total)

    w = 0.8
    grads = [
        (1.0 if k == 0 else 1.0 / k_steps) * jax.grad(step_terms)(w, k) for k in range(k_steps + 1)
    ]
    expected = sum(0.5**k * grad for k, grad in enumerate(grads))
    unscaled = sum(grads)
    # the values: every target sits between 0 and 1 on the support, as two_hot assumes
    assert all(0.0 <= h(float(v)) <= 1.0 for v in z.ravel())
    # compiled: op by op, each of the unroll's many small ops compiles on its own
    np.testing.assert_allclose(jax.jit(jax.grad(loss))(w), expected, rtol=1e-5)
    assert abs(float(expected) - float(unscaled)) > 1e-3  # the halving matters here


# ---- the learner ------------------------------------------------------------------------------
@functools.cache
def tiny():
    config = mz.default_config(CARTPOLE, **TINY)
    hparams = mz.default_hyperparams(CARTPOLE)
    return config, hparams


def one_seed_chunks(config, hparams, chunks: int) -> tuple:
    """``(state, metrics of the last chunk)`` of one run of seed 3, on the host, trained by the
    program that ``rl_jax.train`` builds for one seed of ``config`` (one device): the tiny run
    tests below reuse its trace."""
    stacked = params.stack([hparams])
    program = parallel.Program(mz.muzero, config, 1, 1, devices=jax.devices()[:1])
    state = program.init(parallel.seed_keys([3]), stacked)
    for _ in range(chunks):
        state, metrics = program.train_chunk(state, stacked)
    one = program.select(program.unpad(state, stacked), 0, 0)
    return one, jax.tree.map(lambda leaf: leaf[0, 0], program.gather(metrics))


def test_train_chunk_runs_and_is_deterministic_for_a_seed():
    config, hparams = tiny()
    runs = [one_seed_chunks(config, hparams, 2) for _ in range(2)]
    (first, first_metrics), (second, second_metrics) = runs
    chunk = config.num_envs * config.num_steps * config.iterations_per_chunk
    assert int(first_metrics.env_steps) == 2 * chunk == mz.muzero.env_steps_per_chunk(config) * 2
    assert int(first_metrics.updates) > 0
    for name in ("policy_loss", "value_loss", "reward_loss"):
        assert np.isfinite(float(first_metrics.extra[name])), name
    for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1]), strict=True):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(a, b)
    assert int(first.replay.written) == 2 * config.num_steps * config.iterations_per_chunk
    assert first_metrics.eval_return == second_metrics.eval_return


def test_policy_returns_legal_actions_and_a_search_without_noise_is_deterministic():
    config, hparams = tiny()
    state = mz.init(jax.random.key(1), config, hparams)
    policy = jax.jit(mz.muzero.policy(state, config))
    for obs in ([0.0, 0.0, 0.0, 0.0], [0.1, -0.5, 0.2, 1.0], [-2.0, 1.0, -0.2, -1.0]):
        action = policy(jnp.array(obs, jnp.float32))
        assert action.shape == () and int(action) in (0, 1)
    batch = jnp.array([[0.1, -0.5, 0.2, 1.0]] * 2, jnp.float32)
    search = jax.jit(lambda key: mz.search(state.agent, batch, key, config, gumbel_scale=0.0))
    outputs = [search(key) for key in jax.random.split(jax.random.key(0), 2)]
    np.testing.assert_array_equal(outputs[0].action, outputs[1].action)
    np.testing.assert_allclose(jnp.sum(outputs[0].action_weights, axis=-1), 1.0, rtol=1e-6)


# compiled: op by op, each of the draw's many small ops compiles on its own
sample_windows = jax.jit(mz.sample_windows, static_argnums=2)


def filled_replay(config, steps):
    """A replay of ``steps`` steps of 2 envs written 5 at a time: step s of env e has reward
    100 e + s."""
    replay = mz.replay_init(config, jnp.zeros(4), 2)
    for first in range(0, steps, 5):
        count = min(5, steps - first)
        rows = [jnp.zeros((count, *x.shape[1:]), x.dtype) for x in replay[:-1]]
        reward = jnp.arange(first, first + count, dtype=jnp.float32)[:, None]
        reward = reward + 100.0 * jnp.arange(2)[None]
        replay = mz.replay_add(replay, mz.Replay._make([*rows, 0])._replace(reward=reward))
    return replay


def test_windows_are_consecutive_steps_of_one_env():
    config, hparams = tiny()
    rows, steps = config.replay_rows, int(config.replay_rows * 1.5)
    windows, drawn = sample_windows(
        filled_replay(config, steps), jax.random.key(0), config, hparams
    )
    reward = np.asarray(windows.reward)
    assert reward.shape == (config.window, config.batch_size)
    np.testing.assert_array_equal(np.diff(reward, axis=0), 1.0)
    first = reward[0] % 100
    assert np.all(first >= steps - rows) and np.all(first <= steps - config.window)
    np.testing.assert_array_equal(reward[0] // 100, drawn.env)
    np.testing.assert_array_equal(drawn.weight, 1.0)  # uniform draws: no correction


def test_ring_times_and_prioritised_draws_of_hand_worked_numbers():
    np.testing.assert_array_equal(parts.ring_times(jnp.int32(7), 5), [5, 6, 2, 3, 4])
    np.testing.assert_array_equal(parts.ring_times(jnp.int32(3), 5), [0, 1, 2, -2, -1])
    priority = jnp.array([1.0, 2.0, 3.0, 9.0])
    valid = jnp.array([True, True, True, False])
    probability, count = parts.start_probabilities(priority, valid, 1.0)
    np.testing.assert_allclose(probability, [1 / 6, 2 / 6, 3 / 6, 0.0], rtol=1e-6)
    assert int(count) == 3
    # (3 P)^-1 = 2, 1, 2/3, divided by the largest
    weight = parts.importance_weights(probability[:3], count, 1.0)
    np.testing.assert_allclose(weight, [1.0, 0.5, 1 / 3], rtol=1e-6)
    uniform, _ = parts.start_probabilities(priority, valid, 0.0)
    np.testing.assert_allclose(uniform, [1 / 3, 1 / 3, 1 / 3, 0.0], rtol=1e-6)


def test_windows_are_drawn_by_priority():
    config = mz.default_config(CARTPOLE, **TINY, prioritized=True)
    hparams = mz.default_hyperparams(CARTPOLE)
    replay = filled_replay(config, 30)  # 30 steps in a ring of 20 rows: steps 10 .. 29
    # only the window from step 14 of env 1 (row 14) has a priority; step 28 could not start one
    priority = jnp.zeros_like(replay.priority).at[14, 1].set(5.0).at[8, 0].set(7.0)
    replay = replay._replace(priority=priority)
    windows, drawn = sample_windows(replay, jax.random.key(1), config, hparams)
    np.testing.assert_array_equal(windows.reward[0], 114.0)
    np.testing.assert_array_equal(drawn.row, 14)
    np.testing.assert_array_equal(drawn.weight, 1.0)


def test_a_prioritized_chunk_sets_the_drawn_windows_priorities_to_their_value_errors():
    config = mz.default_config(CARTPOLE, **TINY, prioritized=True)
    hparams = mz.default_hyperparams(CARTPOLE)
    state = mz.init(jax.random.key(0), config, hparams)
    state, metrics = jax.jit(mz.train_chunk, static_argnums=1)(state, config, hparams)
    assert int(metrics.updates) > 0 and np.isfinite(float(metrics.extra["value_loss"]))
    written = int(state.replay.written)  # 12 of the ring's 20 rows
    priority = np.asarray(state.replay.priority)
    # new steps enter at the largest priority (at least 1); drawn ones hold an error + 1e-3
    assert np.all(priority[:written] > 0.0) and np.all(priority[written:] == 0.0)
    assert len(np.unique(priority[:written])) > 1


def test_a_tiny_run_trains_and_its_policy_loads(tmp_path):
    run = rl_jax.train(
        "muzero", CARTPOLE, seeds=1, total_steps=24, config=TINY, out=tmp_path / "run", quiet=True
    )
    assert run.run_dir.exists()
    policy = rl_jax.load_policy(tmp_path / "run")
    for obs in ([0.0, 0.0, 0.0, 0.0], [0.05, 0.3, -0.1, -0.4]):
        assert int(policy(np.array(obs, np.float32))) in (0, 1)


# ---- the simulator as the model ---------------------------------------------------------------
SIMULATOR = dict(TINY, model="simulator")
BALANCED, FALLING = [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.2, 2.0]  # the pole tips over next step


def cartpole_states(vectors):
    """The eval env's states ``[B, ...]`` and observations from CartPole's state vectors."""
    config = mz.default_config(CARTPOLE, **SIMULATOR)
    env = episodes.make_eval_env(config)
    state, ts = jax.vmap(env.reset_to)(jnp.array(vectors, jnp.float32))
    return config, env, state, ts.obs


def test_model_is_validated_and_the_simulator_trains_at_the_first_step_only():
    with pytest.raises(ValueError, match="model"):
        mz.default_config(CARTPOLE, **dict(TINY, model="learnt"))
    learned, simulated = (
        mz.default_config(CARTPOLE, **TINY),
        mz.default_config(CARTPOLE, **SIMULATOR),
    )
    assert learned.model == "learned" and learned.window == 2 + 2 + 1
    assert simulated.unrolled == 0 and simulated.window == 2 + 1
    alive, absorbing = parts.unroll_masks(jnp.zeros((0, 3), bool), jnp.zeros((0, 3), bool))
    np.testing.assert_array_equal(alive, [[1.0, 1.0, 1.0]])
    np.testing.assert_array_equal(absorbing, [[0.0, 0.0, 0.0]])


def test_simulator_steps_equal_the_env_and_a_terminal_absorbs():
    config, env, state, obs = cartpole_states([BALANCED, FALLING, BALANCED, FALLING])
    actions = jnp.array([0, 1, 1, 0])
    key, gamma = jax.random.key(5), jnp.float32(0.9)
    predict = lambda obs: (jnp.zeros((obs.shape[0], 2)), jnp.zeros((obs.shape[0], 7)))  # noqa: E731
    recurrent_fn = sim.make_recurrent_fn(env, predict, gamma, config.value_support)
    node = sim.Node(state, obs, jnp.zeros(4, bool))
    output, child = recurrent_fn((), key, actions, node)
    expected_state, ts = jax.vmap(env.step)(jax.random.split(key, 4), state, actions)
    np.testing.assert_array_equal(ts.terminated, [False, True, False, True])
    np.testing.assert_array_equal(output.reward, ts.reward)
    np.testing.assert_allclose(output.discount, 0.9 * (1.0 - ts.terminated))
    np.testing.assert_array_equal(child.obs, ts.obs)
    np.testing.assert_array_equal(child.done, ts.terminated)
    for got, want in zip(
        jax.tree.leaves(child.state), jax.tree.leaves(expected_state), strict=True
    ):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(output.value[jnp.array([1, 3])], 0.0)  # a terminal is worth 0
    # past a terminal: nothing is paid, nothing discounted in, the state stays where it ended
    after, grandchild = recurrent_fn((), key, actions, child)
    np.testing.assert_array_equal(after.reward[jnp.array([1, 3])], 0.0)
    np.testing.assert_array_equal(after.discount[jnp.array([1, 3])], 0.0)
    np.testing.assert_array_equal(grandchild.obs[jnp.array([1, 3])], child.obs[jnp.array([1, 3])])
    np.testing.assert_array_equal(after.reward[jnp.array([0, 2])], 1.0)
    assert np.all(np.isfinite(after.value)) and np.all(np.isfinite(after.prior_logits))


def test_simulator_search_sees_a_failure_one_step_ahead():
    """From a state whose every action ends the episode the root's q-values are the true
    terminal reward, 1 (discount 0), whatever the network says; with a network that values every
    state at v > 1 the falling state's root value ends below the balanced one's."""
    config, env, state, obs = cartpole_states([BALANCED, FALLING])
    hparams = mz.default_hyperparams(CARTPOLE)
    agent = mz.init(jax.random.key(0), config, hparams).agent
    out = jax.jit(lambda k: mz.simulator_search(agent, state, obs, k, config, 0.0))(
        jax.random.key(0)
    )
    tree = out.search_tree
    root = jnp.full(2, tree.ROOT_INDEX)
    visited = np.asarray(tree.children_visits[:, 0] > 0)
    assert visited[1].any()
    np.testing.assert_allclose(np.asarray(tree.qvalues(root))[1][visited[1]], 1.0)

    value_logits = jnp.full((7,), -30.0).at[6].set(30.0)  # h(v) = 3 on the support -3 .. 3
    v = float(parts.logits_to_scalar(value_logits, 3))
    assert v > 1.0
    predict = lambda obs: (jnp.zeros((obs.shape[0], 2)), jnp.tile(value_logits, (obs.shape[0], 1)))  # noqa: E731
    # compiled: op by op, the search compiles each of its many ops and its loop on their own
    out = jax.jit(lambda k: sim.search(predict, env, state, obs, k, 0.99, (8, 2, 3), 0.0))(
        jax.random.key(1)
    )
    balanced, falling = np.asarray(out.search_tree.summary().value)
    assert falling < balanced
    assert falling < (v + 8 * 1.0) / 9 + 1e-4  # the prior and 8 terminal rewards of 1
    assert balanced > v  # 1 + 0.99 v > v below the root


def test_simulator_train_chunk_runs_and_is_deterministic_for_a_seed():
    config = mz.default_config(CARTPOLE, **SIMULATOR)
    hparams = mz.default_hyperparams(CARTPOLE)
    runs = [one_seed_chunks(config, hparams, 1) for _ in range(2)]
    (first, metrics), _ = runs
    assert int(metrics.updates) > 0
    for name in ("policy_loss", "value_loss", "root_value"):
        assert np.isfinite(float(metrics.extra[name])), name
    assert float(metrics.extra["reward_loss"]) == 0.0  # no model to learn
    assert np.isfinite(float(metrics.eval_return)) and float(metrics.eval_return) >= 1.0
    for a, b in zip(jax.tree.leaves(runs[0]), jax.tree.leaves(runs[1]), strict=True):
        if jnp.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(a, b)
    # the policy of an observation alone is the prediction network's greedy action
    policy = jax.jit(mz.muzero.policy(first, config))
    logits = mz.make_network(config).apply(first.agent.params, jnp.zeros((1, 4)), method="predict")[
        0
    ]
    assert int(policy(jnp.zeros(4))) == int(jnp.argmax(logits[0]))


def test_a_tiny_simulator_run_trains_and_its_greedy_policy_loads(tmp_path):
    run = rl_jax.train(
        "muzero",
        CARTPOLE,
        seeds=1,
        total_steps=24,
        config=SIMULATOR,
        out=tmp_path / "run",
        quiet=True,
    )
    policy = rl_jax.load_policy(run.run_dir)
    for obs in ([0.0, 0.0, 0.0, 0.0], [0.05, 0.3, -0.1, -0.4]):
        assert int(policy(np.array(obs, np.float32))) in (0, 1)
