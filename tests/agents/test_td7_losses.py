"""TD7's maths alone (LAP, SALE, value clipping, hard target copies, policy checkpoints):
hand-computed values (plain and jitted, as rlax tests its losses), and exactly zero gradient into
what must stay fixed."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import actor_critic, td7, td7_parts
from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.agents.td7_parts import Encoders, ValueRange
from rl_jax.training import networks, offpolicy, policy_checkpoints, prioritized
from rl_jax.training.replay import Transition

modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])


# ---- LAP ---------------------------------------------------------------------------------------
@modes
def test_lap_huber_is_quadratic_below_one_and_linear_above(transform):
    td = jnp.array([-2.0, -0.5, 0.0, 0.9, 1.0, 3.0])
    got = transform(td7_parts.lap_huber)(td)
    # TD7's form: 0.5 td^2 inside, |td| outside (not shifted by 0.5: the value jumps at 1).
    np.testing.assert_allclose(got, [2.0, 0.125, 0.0, 0.405, 1.0, 3.0], rtol=1e-6)


@modes
def test_lap_loss_sums_critics_and_averages_the_batch(transform):
    td = jnp.array([[0.5, -3.0], [2.0, 0.1]])  # [critics, batch]
    got = transform(td7_parts.lap_loss)(td)
    # Critic 1: mean(0.125, 3) = 1.5625; critic 2: mean(2, 0.005) = 1.0025.
    np.testing.assert_allclose(got, 1.5625 + 1.0025, rtol=1e-6)


def test_lap_loss_gradient_is_the_huber_gradient():
    td = jnp.array([[0.5, -3.0, 1.5], [-0.25, 0.1, -1.2]])
    grad = jax.grad(td7_parts.lap_loss)(td)
    expected = np.where(np.abs(td) < 1.0, td, np.sign(td)) / 3.0  # mean over a batch of 3
    np.testing.assert_allclose(grad, expected, rtol=1e-6)


@modes
def test_lap_priorities_take_the_largest_critic_error_floored_at_one(transform):
    td = jnp.array([[0.5, -3.0, 0.2, -1.5], [-0.7, 2.0, 0.1, 4.0]])
    got = transform(td7_parts.lap_priorities)(td)
    np.testing.assert_allclose(got, [1.0, 3.0, 1.0, 4.0], rtol=0)


def _probe_config(**overrides):
    """A tiny TD7 on the one-step probe env, updating from the first step."""
    return td7.td7.default_config(
        "rl_jax/ProbeActionReward-v0",
        actor_hidden=(8,),
        critic_hidden=(8,),
        embedding_dim=4,
        embedding_hidden=(8,),
        batch_size=4,
        buffer_size=16,
        num_envs=2,
        learning_starts=0,
        **overrides,
    )


def _transitions(reward):
    return Transition(
        obs=jnp.zeros((2, 1)),
        action=jnp.array([[0.5], [-0.5]]),
        reward=reward,
        next_obs=jnp.ones((2, 1)),
        terminated=jnp.array([True, False]),
        truncated=jnp.zeros(2, bool),
    )


def _filled(config, hparams, rewards, key=3):
    """``(state, buffer)``: a fresh TD7 state and its replay with a row per reward pair."""
    state = td7.td7.init(jax.random.key(key), config, hparams)
    buffer = state.buffer
    add = jax.jit(td7_parts.add_to_buffer, static_argnums=2)
    for reward in rewards:
        buffer = add(buffer, _transitions(jnp.asarray(reward)), config, hparams)
    return state, buffer


def test_a_lap_update_writes_floored_priorities_and_samples_without_weights():
    config = _probe_config()
    hparams = td7.td7.default_hyperparams(lap_alpha=0.5)
    # rewards -2.5 .. 2: some TD errors are above 1, some below
    rewards = [[(2.0 * row - 5.0) * 0.5, (2.0 * row - 4.0) * 0.5] for row in range(5)]
    state, buffer = _filled(config, hparams, rewards)
    key, agent = jax.random.key(4), state.agent

    @jax.jit
    def sample_and_td_errors(agent, buffer):  # as the update draws and computes them
        sample_key, noise_key = jax.random.split(key)
        rows, columns, _ = prioritized.sample_indices(buffer, sample_key, config.batch_size, 0.0)
        batch = actor_critic.gather_batch(buffer.buffer, rows, columns, hparams.gamma)
        noise = jax.random.normal(noise_key, batch.action.shape, jnp.float32)
        _, (_, td_tm1, _) = td7.critic_loss_fn(
            agent.critics, agent, batch, noise, hparams, td7.make_networks(config)
        )
        return (rows, columns), td_tm1

    (rows, columns), td_tm1 = sample_and_td_errors(agent, buffer)
    _, updated, _ = jax.jit(td7.update, static_argnums=3)(
        agent, buffer, key, config, hparams, jnp.int32(0)
    )
    slots = np.asarray(rows * 2 + columns)
    assert len(set(slots.tolist())) == slots.size
    floored = np.maximum(np.max(np.abs(np.asarray(td_tm1)), axis=0), 1.0)
    assert np.any(floored > 1.0) and np.any(floored == 1.0)
    np.testing.assert_allclose(updated.sums[updated.leaves + slots], floored**0.5, rtol=1e-5)
    np.testing.assert_allclose(updated.max_priority, np.max(floored), rtol=1e-6)


# ---- SALE --------------------------------------------------------------------------------------
@modes
def test_avg_l1_norm_scales_features_to_mean_magnitude_one(transform):
    x = jnp.array([[1.0, -3.0, 2.0, -2.0], [0.0, 0.0, 0.0, 0.0]])
    got = transform(networks.avg_l1_norm)(x)
    # Row 1: mean |x| = 2. Row 2: all zero, the floor (1e-8) keeps it finite and zero.
    np.testing.assert_allclose(got, [[0.5, -1.5, 1.0, -1.0], [0.0, 0.0, 0.0, 0.0]], rtol=1e-7)


@modes
def test_sale_loss_value_and_its_target_gets_no_gradient(transform):
    zsa = jnp.array([[1.0, 2.0], [3.0, 4.0]])
    zs_next = jnp.array([[0.0, 2.0], [1.0, 1.0]])
    # Differences 1, 0, 2, 3: mean of squares (1 + 0 + 4 + 9) / 4.
    np.testing.assert_allclose(transform(td7_parts.sale_loss)(zsa, zs_next), 3.5, rtol=1e-7)
    grad_zsa, grad_target = transform(jax.grad(td7_parts.sale_loss, argnums=(0, 1)))(zsa, zs_next)
    np.testing.assert_allclose(grad_zsa, (zsa - zs_next) / 2.0, rtol=1e-7)
    assert np.all(np.asarray(grad_target) == 0.0)


# Pendulum: observations of 3 numbers, one action in [-2, 2].
SALE_CONFIG = td7.Config(
    env_id="rl_jax/Pendulum-v1",
    actor_hidden=(8, 8),
    critic_hidden=(8, 8),
    embedding_dim=4,
    embedding_hidden=(6,),
)


@pytest.fixture(scope="module")
def sale_setup():
    """``(agent, batch)``: a TD7 agent whose three encoders (online, fixed, fixed target) all
    differ, and a batch of 5 transitions."""
    nets, sale = td7.make_networks(SALE_CONFIG)
    keys = jax.random.split(jax.random.key(5), 9)
    obs, action, z, z2 = jnp.zeros(3), jnp.zeros(1), jnp.zeros(4), jnp.zeros(8)
    online, fixed, fixed_target = (sale.init(k, obs, action) for k in keys[:3])
    actor = nets.actor.init(keys[3], obs, z)
    critics = networks.init_stacked(nets.critic, keys[4], 2, obs, action, z2)
    agent = td7.Agent(
        actor=actor,
        critics=critics,
        target_actor=nets.actor.init(keys[8], obs, z),
        target_critics=critics,
        actor_opt=(),
        critic_opt=(),
        encoders=Encoders(online=online, fixed=fixed, fixed_target=fixed_target, opt=()),
        checkpoint=None,
        value_range=ValueRange.initial(),
    )
    batch = CriticBatch(
        obs=jax.random.normal(keys[5], (5, 3)),
        action=jax.random.uniform(keys[6], (5, 1), minval=-2.0, maxval=2.0),
        r_t=jnp.linspace(-1.0, 1.0, 5),
        discount_t=jnp.full(5, 0.99),
        next_obs=jax.random.normal(keys[7], (5, 3)),
    )
    return agent, batch


def test_sale_networks_read_normalised_features_and_the_embeddings(sale_setup):
    agent, batch = sale_setup
    _, sale = td7.make_networks(SALE_CONFIG)
    actor, fixed = agent.actor, agent.encoders.fixed
    first = actor["params"]["Dense_0"]
    assert first["kernel"].shape == (3, 8)  # obs -> the first hidden width, then AvgL1Norm
    assert actor["params"]["MLP_0"]["Dense_0"]["kernel"].shape == (8 + 4, 8)  # [features, z_s]
    critic_mlp = agent.critics["params"]["MLP_0"]["Dense_0"]["kernel"]
    assert critic_mlp.shape == (2, 8 + 2 * 4, 8)  # per critic: [features, z_sa, z_s]
    zs = sale.apply(fixed, batch.obs, method="embed_state")
    np.testing.assert_allclose(np.mean(np.abs(zs), axis=-1), 1.0, rtol=1e-5)  # AvgL1Norm'd
    features = networks.avg_l1_norm(batch.obs @ first["kernel"] + first["bias"][None])
    mlp = {"params": actor["params"]["MLP_0"]}
    actor_mlp = networks.MLP(networks.Layers((8, 8)), 1, output_gain=0.01)
    raw = actor_mlp.apply(mlp, jnp.concatenate([features, zs], -1))
    got = td7.policy_action(td7.make_networks(SALE_CONFIG), actor, fixed, batch.obs)
    # tanh stretched onto Pendulum's [-2, 2]
    np.testing.assert_allclose(got, 2.0 * jnp.tanh(raw), rtol=1e-5, atol=1e-6)


def test_sale_losses_send_no_gradient_into_fixed_or_target_encoders(sale_setup):
    agent, batch = sale_setup
    hparams = td7.Hyperparams().as_arrays()
    noise = jnp.ones((5, 1))
    wide = ValueRange.initial().replace(low=jnp.float32(-1e6), high=jnp.float32(1e6))
    agent = agent.replace(value_range=wide)  # the targets' values pass unclipped

    def critic_objective(critics, fixed, fixed_target):
        encoders = agent.encoders.replace(fixed=fixed, fixed_target=fixed_target)
        with_encoders = agent.replace(encoders=encoders)
        return td7.critic_loss_fn(
            critics, with_encoders, batch, noise, hparams, td7.make_networks(SALE_CONFIG)
        )[0]

    encoders = agent.encoders
    grads = jax.jit(jax.grad(critic_objective, argnums=(0, 1, 2)))(
        agent.critics, encoders.fixed, encoders.fixed_target
    )
    assert all(np.any(np.asarray(g) != 0.0) for g in jax.tree.leaves(grads[0]))
    for leaf in jax.tree.leaves(grads[1:]):
        assert np.all(np.asarray(leaf) == 0.0)

    def actor_objective(actor, encoder):
        return td7.actor_loss_fn(
            actor, agent.critics, encoder, batch.obs, td7.make_networks(SALE_CONFIG)
        )

    actor_grads = jax.jit(jax.grad(actor_objective, argnums=(0, 1)))(agent.actor, encoders.fixed)
    assert all(np.any(np.asarray(g) != 0.0) for g in jax.tree.leaves(actor_grads[0]))
    assert all(np.all(np.asarray(g) == 0.0) for g in jax.tree.leaves(actor_grads[1]))


def test_sale_encoder_loss_regresses_on_a_stopped_next_state_embedding(sale_setup):
    agent, batch = sale_setup
    _, sale = td7.make_networks(SALE_CONFIG)
    online = agent.encoders.online
    zs_next = sale.apply(online, batch.next_obs, method="embed_state")
    zsa = sale.apply(online, batch.obs, batch.action)[1]
    loss = td7.encoder_loss_fn(online, batch, sale)
    np.testing.assert_allclose(loss, np.mean((np.asarray(zsa) - np.asarray(zs_next)) ** 2), 1e-6)

    def with_constant_target(params):  # the same loss with f(s') a constant from outside
        zsa = sale.apply(params, batch.obs, batch.action)[1]
        return jnp.mean((zsa - zs_next) ** 2)

    grads = jax.jit(jax.grad(lambda p: td7.encoder_loss_fn(p, batch, sale)))(online)
    expected = jax.jit(jax.grad(with_constant_target))(online)
    # Equal to the last bit on the pinned jax; jax 0.12 compiles the two programs into other
    # fusions and one entry in 272 moved by 1 ulp. A gradient through f(s') would move many
    # entries by far more than that.
    same = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)  # noqa: E731
    jax.tree.map(same, grads, expected)


# ---- TD7's value clipping -----------------------------------------------------------------------
@modes
def test_value_clipped_target_clips_the_bootstrap_value_not_the_reward(transform):
    q_t = jnp.array([[5.0, -4.0, 1.0], [6.0, -3.0, 2.0]])  # min over critics: 5, -4, 1
    r_t, discount_t = jnp.array([10.0, 0.0, -1.0]), jnp.array([0.5, 0.5, 0.0])
    got = transform(td7_parts.value_clipped_target)(r_t, discount_t, q_t, -2.0, 3.0)
    np.testing.assert_allclose(got, [10.0 + 0.5 * 3.0, 0.5 * -2.0, -1.0], rtol=1e-7)
    grad = jax.grad(lambda q: jnp.sum(td7_parts.value_clipped_target(r_t, discount_t, q, -9, 9)))
    assert np.all(np.asarray(grad(q_t)) == 0.0)


def test_the_value_range_widens_with_targets_until_a_target_copy():
    values = ValueRange.initial()
    assert (float(values.low), float(values.high)) == (0.0, 0.0)  # TD7 starts at [0, 0]
    values = values.seeing((jnp.float32(-2.0), jnp.float32(1.0)))
    values = values.seeing((jnp.float32(-1.0), jnp.float32(4.0)))
    assert (float(values.seen_min), float(values.seen_max)) == (-2.0, 4.0)
    assert (float(values.low), float(values.high)) == (0.0, 0.0)  # until a target copy
    renewed = values.renewed()
    assert (float(renewed.low), float(renewed.high)) == (-2.0, 4.0)


def test_critic_loss_uses_and_reports_the_clipped_targets(sale_setup):
    agent, batch = sale_setup
    hparams = td7.Hyperparams().as_arrays()
    bounds = ValueRange.initial().replace(low=jnp.float32(-0.01), high=jnp.float32(0.01))
    noise = jnp.ones((5, 1))
    nets = td7.make_networks(SALE_CONFIG)
    loss, (q_tm1, td_tm1, target_range) = td7.critic_loss_fn(
        agent.critics, agent.replace(value_range=bounds), batch, noise, hparams, nets
    )
    target = np.asarray(q_tm1 - td_tm1)[0]
    np.testing.assert_allclose(np.asarray(q_tm1 - td_tm1)[1], target, rtol=1e-6)  # shared
    bootstrap = (target - np.asarray(batch.r_t)) / 0.99
    assert np.all(np.abs(bootstrap) <= 0.01 + 1e-6)
    np.testing.assert_allclose(target_range, (target.min(), target.max()), rtol=1e-6)
    # LAP's loss of those errors: half the square below 1, the magnitude above
    td = np.asarray(td_tm1)
    huber = np.where(np.abs(td) < 1.0, td**2 / 2, np.abs(td))
    np.testing.assert_allclose(loss, np.sum(np.mean(huber, -1)), 1e-6)


# ---- hard target copies -------------------------------------------------------------------------
def test_copy_targets_copies_rotates_the_fixed_encoders_and_renews_the_value_range():
    leaf = lambda value: {"w": jnp.full(2, value)}  # noqa: E731
    values = ValueRange.initial().seeing((jnp.float32(-2.0), jnp.float32(4.0)))
    agent = td7.Agent(
        actor=leaf(1.0),
        critics=leaf(2.0),
        target_actor=leaf(-1.0),
        target_critics=leaf(-2.0),
        actor_opt=(),
        critic_opt=(),
        encoders=Encoders(online=leaf(3.0), fixed=leaf(4.0), fixed_target=leaf(5.0), opt=()),
        checkpoint=None,
        value_range=values,
    )
    got = jax.jit(td7.copy_targets)(agent)
    assert float(got.target_actor["w"][0]) == 1.0 and float(got.target_critics["w"][0]) == 2.0
    encoders = got.encoders
    assert [float(e["w"][0]) for e in (encoders.online, encoders.fixed, encoders.fixed_target)] == [
        3.0,
        3.0,
        4.0,
    ]
    assert (float(got.value_range.low), float(got.value_range.high)) == (-2.0, 4.0)


def test_reset_max_priority_takes_the_largest_stored_priority():
    buffer = prioritized.init(jnp.zeros(()), 8, 1)
    for _ in range(4):
        buffer = prioritized.add(buffer, jnp.zeros(1), 0.5)
    buffer = prioritized.update_priorities(
        buffer, jnp.arange(4), jnp.zeros(4, jnp.int32), jnp.array([9.0, 1.0, 4.0, 2.25]), 0.5
    )
    buffer = prioritized.update_priorities(
        buffer, jnp.array([0]), jnp.array([0]), jnp.array([1.0]), 0.5
    )
    assert float(buffer.max_priority) == 9.0  # the largest ever given, since corrected
    reset = jax.jit(prioritized.reset_max_priority)(buffer, 0.5)
    np.testing.assert_allclose(reset.max_priority, 4.0, rtol=1e-6)


def test_targets_are_copied_every_period_and_never_stepped_between():
    config = _probe_config(target_update_period=3)
    hparams = td7.td7.default_hyperparams()
    state, buffer = _filled(config, hparams, [[4.0 * row, -3.0] for row in range(5)])
    update = jax.jit(td7.update, static_argnums=3)
    agent, targets = state.agent, state.agent.target_critics
    for index in range(6):
        agent, buffer, _ = update(agent, buffer, jax.random.key(index), config, hparams, index)
        copied = index in (2, 5)  # after the 3rd and the 6th update
        same = jax.tree.map(np.array_equal, agent.target_critics, agent.critics)
        assert all(jax.tree.leaves(same)) == copied
        # between copies the targets stay exactly what the last copy (or init) made them
        expected = agent.critics if copied else targets
        jax.tree.map(np.testing.assert_array_equal, agent.target_critics, expected)
        targets = agent.target_critics
        if index == 5:
            stored = np.max(np.asarray(buffer.sums[buffer.leaves :]))
            np.testing.assert_allclose(buffer.max_priority, stored ** (1 / 0.4), rtol=1e-5)


# ---- policy checkpoints -------------------------------------------------------------------------
@modes
def test_assess_episodes_counts_passes_and_fails(transform):
    assess = transform(policy_checkpoints.assess_episodes)
    no = policy_checkpoints.NO_EPISODE
    counted, returns = jnp.array([True, False, True]), jnp.array([4.0, -50.0, 6.0])
    # Two counted episodes (the uncounted -50 is ignored), 3 required: going on.
    lowest, episodes, passed, ended = assess(no, 0, 1.0, returns, counted, 3)
    assert (float(lowest), int(episodes), bool(passed), bool(ended)) == (4.0, 2, False, False)
    # A third at 5: all three >= the score 1 -> passed.
    got = assess(lowest, episodes, 1.0, jnp.array([5.0]), jnp.array([True]), 3)
    assert [float(v) for v in got] == [4.0, 3.0, 1.0, 1.0]
    # One below the score ends the assessment at once, without passing.
    got = assess(lowest, episodes, 4.5, jnp.array([9.0]), jnp.array([True]), 3)
    assert [float(v) for v in got] == [4.0, 3.0, 0.0, 1.0]
    # Nothing ended: nothing changes, even below the score (no episode is below it yet).
    got = assess(no, 0, 1.0, jnp.array([-9.0]), jnp.array([False]), 1)
    assert [float(v) for v in got] == [no, 0.0, 0.0, 0.0]


def _checkpoint_agent(actor_value: float, num_envs: int = 2, learning_starts: int = 0):
    """``(config, agent)``: a TD7 agent whose actor is one number, its policy checkpoint as
    ``init_agent`` starts it, assessments of 2 episodes from env step 100."""
    config = td7.Config(
        env_id="unused",
        num_envs=num_envs,
        learning_starts=learning_starts,
        checkpoint_episodes=2,
        checkpoint_episodes_from=100,
    )
    agent = td7.Agent(
        actor={"w": jnp.float32(actor_value)},
        critics=(),
        target_actor=(),
        target_critics=(),
        actor_opt=(),
        critic_opt=(),
        encoders=Encoders(online=(), fixed=(), fixed_target=(), opt=()),
        checkpoint=None,
        value_range=ValueRange.initial(),
    )
    checkpoint = policy_checkpoints.init(agent.current_policy(), num_envs, learning_starts)
    return config, agent.replace(checkpoint=checkpoint)


def _observe(agent, config, returns, done, env_steps, actor):
    """One env step of the schedule at ``env_steps``, the online actor now ``actor``."""
    clock = offpolicy.Clock(jnp.int32(env_steps), jnp.int32(0), jnp.int32(0))
    agent = agent.replace(actor={"w": jnp.float32(actor)})
    hparams = td7.Hyperparams().as_arrays()
    step = jax.jit(td7.observe, static_argnums=5)
    return step(agent, None, jnp.array(returns), jnp.array(done), clock, config, hparams)


def _weights(agent):
    """(checkpoint's actor, assessed copy's actor)."""
    return float(agent.checkpoint.best.actor["w"]), float(agent.checkpoint.assessed.actor["w"])


def test_the_copy_follows_the_actor_until_a_counted_episode_begins():
    config, agent = _checkpoint_agent(0.0, learning_starts=4)
    # Warm-up (random actions): nothing counts, even an episode that ends.
    agent = _observe(agent, config, [1.0, 1.0], [True, False], 0, 1.0)
    assert _weights(agent) == (0.0, 1.0) and not np.any(agent.checkpoint.counting)
    # Env 0's episode ends as the warm-up ends: its next one counts, under the actor of now.
    agent = _observe(agent, config, [1.0, 1.0], [True, False], 2, 2.0)
    assert _weights(agent) == (0.0, 2.0) and agent.checkpoint.counting.tolist() == [True, False]
    agent = _observe(agent, config, [1.0, 1.0], [False, False], 4, 3.0)
    assert _weights(agent) == (0.0, 2.0)  # frozen from here on


def test_assessments_freeze_the_acting_copy_and_checkpoint_only_passed_ones():
    config, agent = _checkpoint_agent(0.0)

    def observe(agent, returns, done, env_steps, actor):
        return _observe(agent, config, returns, done, env_steps, actor)

    weights = _weights

    # Before env step 100 one episode is an assessment: env 0 ends at 5 -> the copy (actor 0)
    # passes and becomes the checkpoint; the next copy is the online actor (1).
    agent = observe(agent, [5.0, 0.0], [True, False], 0, 1.0)
    assert weights(agent) == (0.0, 1.0) and float(agent.checkpoint.score) == 5.0
    # Env 1's episode began under the old copy: it does not count.
    agent = observe(agent, [-9.0, -9.0], [False, True], 2, 2.0)
    assert weights(agent) == (0.0, 1.0) and int(agent.checkpoint.episodes) == 0
    # Crossing env step 100: the score is scaled by 0.9 and two episodes are required.
    agent = observe(agent, [7.0, 0.0], [True, False], 98, 3.0)
    assert float(agent.checkpoint.score) == pytest.approx(4.5)
    assert weights(agent) == (0.0, 1.0) and int(agent.checkpoint.episodes) == 1
    agent = observe(agent, [0.0, 4.6], [False, True], 102, 4.0)
    assert weights(agent) == (1.0, 4.0) and float(agent.checkpoint.score) == pytest.approx(4.6)
    # Env 0 was in mid-episode at the copy (its 9 does not count); env 1's 4 is below 4.6 and
    # fails the assessment: no new checkpoint, a new copy.
    agent = observe(agent, [9.0, 4.0], [True, True], 104, 5.0)
    assert weights(agent) == (1.0, 5.0) and float(agent.checkpoint.score) == pytest.approx(4.6)
