"""CrossQ's maths alone: the critics' one forward pass over both halves of the batch (batch
renormalisation in training mode), the actor's gradient through the critics in evaluation mode,
and Adam at CrossQ's first-moment decay, recorded in the optimizer state."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from rl_jax.agents import actor_critic, crossq
from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.training import networks, validation

# Pendulum: observations of 3 numbers, one action in [-2, 2]; plain batch norm from the start.
CONFIG = crossq.Config(
    env_id="rl_jax/Pendulum-v1", actor_hidden=(8,), critic_hidden=(8, 8), renorm_warmup=0
)


@pytest.fixture(scope="module")
def setup():
    """``(nets, agent, batch, noise, hparams)``: fresh networks and statistics, 5 transitions."""
    nets = crossq.make_networks(CONFIG)
    keys = jax.random.split(jax.random.key(7), 6)
    obs, action = jnp.zeros(3), jnp.zeros(1)
    variables = dict(networks.init_stacked(nets.critic, keys[1], 2, obs, action))
    stats = variables.pop("batch_stats")
    agent = crossq.Agent(
        actor=nets.actor.init(keys[0], obs),
        critics=variables,
        actor_opt=(),
        critic_opt=(),
        critic_stats=stats,
    )
    batch = CriticBatch(
        obs=jax.random.normal(keys[2], (5, 3)),
        action=jax.random.uniform(keys[3], (5, 1), minval=-2.0, maxval=2.0),
        r_t=jnp.linspace(-1.0, 1.0, 5),
        discount_t=jnp.full(5, 0.99),
        next_obs=jax.random.normal(keys[4], (5, 3)),
    )
    noise = jax.random.normal(keys[5], (5, 1))
    return nets, agent, batch, noise, crossq.Hyperparams().as_arrays()


def test_critic_loss_is_one_forward_pass_over_both_halves_of_the_batch(setup):
    nets, agent, batch, noise, hparams = setup

    def loss(critics, actor):
        return crossq.critic_loss_fn(
            critics, agent.replace(actor=actor), batch, noise, hparams, nets
        )

    (value, (q_tm1, stats)), grads = jax.jit(
        jax.value_and_grad(loss, argnums=(0, 1), has_aux=True)
    )(agent.critics, agent.actor)
    a_t = nets.actor.apply(agent.actor, batch.next_obs)  # the online actor: no target networks
    a_t = actor_critic.target_action(a_t, noise, hparams, nets)
    inputs = np.concatenate(
        [np.concatenate([batch.obs, batch.action], -1), np.concatenate([batch.next_obs, a_t], -1)]
    )
    first = stats["MLP_0"]["BatchRenorm_0"]
    np.testing.assert_array_equal(first["steps"], [1, 1])  # one training call per critic
    expected_mean = 0.01 * inputs.mean(axis=0)  # from mean 0: one step towards both halves
    np.testing.assert_allclose(first["mean"], np.stack([expected_mean] * 2), rtol=1e-5)
    # The same numbers by hand: both halves through each critic in training mode at once.
    q = [
        np.asarray(
            nets.critic.apply(
                {
                    "params": jax.tree.map(lambda x, i=i: x[i], agent.critics)["params"],
                    "batch_stats": jax.tree.map(lambda x, i=i: x[i], agent.critic_stats),
                },
                jnp.asarray(inputs[:, :3]),
                jnp.asarray(inputs[:, 3:]),
                train=True,
                mutable=["batch_stats"],
            )[0]
        )
        for i in range(2)
    ]
    np.testing.assert_allclose(q_tm1, np.stack([qi[:5] for qi in q]), rtol=1e-5, atol=1e-6)
    target = np.asarray(batch.r_t) + 0.99 * np.minimum(q[0][5:], q[1][5:])
    np.testing.assert_allclose(value, sum(np.mean((qi[:5] - target) ** 2) for qi in q), 1e-5)
    assert all(np.any(np.asarray(g) != 0.0) for g in jax.tree.leaves(grads[0]))
    assert all(np.all(np.asarray(g) == 0.0) for g in jax.tree.leaves(grads[1]))  # a' is data


def test_the_actor_gradient_reads_the_critic_in_evaluation_mode(setup):
    nets, agent, batch, _, _ = setup
    moved = jax.tree.map(lambda x: x + 0.5 if x.dtype == jnp.float32 else x, agent.critic_stats)
    first = jax.tree.map(lambda x: x[0], {**agent.critics, "batch_stats": moved})

    def by_hand(actor):  # the first critic, running statistics (evaluation mode, the default)
        action = nets.actor.apply(actor, batch.obs)
        return -jnp.mean(nets.critic.apply(first, batch.obs, action))

    def loss(actor, stats):
        return crossq.actor_loss_fn(actor, agent.replace(critic_stats=stats), batch.obs, nets)

    value, grads = jax.jit(jax.value_and_grad(loss))(agent.actor, moved)
    expected, expected_grads = jax.jit(jax.value_and_grad(by_hand))(agent.actor)
    np.testing.assert_allclose(value, expected, rtol=1e-5)
    same = lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)  # noqa: E731
    jax.tree.map(same, grads, expected_grads)


def test_adam_b1_sets_the_first_moment_decay_and_is_recorded_in_the_state():
    """CrossQ's Adam (b1 0.5) against Adam's update written out: after two steps with gradients
    g1 then g2, m = b1 (1 - b1) g1 + (1 - b1) g2 and v likewise at b2 0.999, bias-corrected."""
    params = {"w": jnp.array([1.0, -2.0])}
    g1, g2 = jnp.array([0.5, -1.0]), jnp.array([-2.0, 0.25])
    rate, (b1, b2, eps) = 0.1, (0.5, 0.999, 1e-8)
    state = crossq.adam(3e-4).init(params)
    step = jax.jit(crossq._adam, static_argnums=4)
    new, state = step({"w": g1}, state, params, jnp.float32(rate), b1)
    new, state = step({"w": g2}, state, new, jnp.float32(rate), b1)
    m = b1 * (1 - b1) * g1 + (1 - b1) * g2
    v = b2 * (1 - b2) * g1**2 + (1 - b2) * g2**2
    m_hat, v_hat = m / (1 - b1**2), v / (1 - b2**2)
    first = params["w"] - rate * g1 / (jnp.abs(g1) + eps)  # m_hat = g1, v_hat = g1^2
    expected = first - rate * m_hat / (jnp.sqrt(v_hat) + eps)
    np.testing.assert_allclose(new["w"], expected, rtol=1e-5)
    assert float(state.hyperparams["b1"]) == b1
    # Adam's default keeps the plain optimizer's state and step exactly.
    plain_state = crossq.adam(3e-4).init(params)
    plain, _ = crossq.adam(3e-4).update({"w": g1}, plain_state, params)
    ours, _ = step({"w": g1}, crossq.adam(3e-4).init(params), params, jnp.float32(3e-4), 0.9)
    np.testing.assert_array_equal(ours["w"], params["w"] + plain["w"])
    config = crossq.crossq.default_config("rl_jax/Pendulum-v1", adam_b1=1.0)
    with pytest.raises(validation.RangeError, match=r"--adam-b1 must be in \[0, 1\)"):
        validation.check_ranges(crossq.crossq, config, [crossq.Hyperparams()])
