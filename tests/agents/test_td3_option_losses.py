"""The maths of TD3's TD7/CrossQ/SimBa options alone: hand-computed values (plain and jitted, as
rlax tests its losses), and exactly zero gradient into what must stay fixed."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax.agents import td3, td7_parts
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


def test_a_lap_update_writes_floored_priorities_and_samples_without_weights():
    config = td3.td3.default_config(
        "rl_jax/ProbeActionReward-v0",
        actor_hidden=(8,),
        critic_hidden=(8,),
        batch_size=4,
        buffer_size=16,
        num_envs=2,
        learning_starts=0,
        lap=True,
    )
    hparams = td3.td3.default_hyperparams(lap_alpha=0.5)
    state = td3.td3.init(jax.random.key(3), config, hparams)
    buffer = state.buffer
    add = jax.jit(td3.add_to_buffer, static_argnums=2)
    for row in range(5):  # rewards -5 .. 4: some TD errors are above 1, some below
        reward = jnp.array([2.0 * row - 5.0, 2.0 * row - 4.0]) * 0.5
        buffer = add(buffer, _transitions(reward), config, hparams)
    key, agent = jax.random.key(4), state.agent

    @jax.jit
    def sample_and_td_errors(agent, buffer):  # as the update draws and computes them
        sample_key, noise_key = jax.random.split(key)
        batch, indices = td3.sample(buffer, sample_key, config, hparams)
        nets = td3.make_networks(config)
        noise = jax.random.normal(noise_key, batch.action.shape, jnp.float32)
        _, aux = td3.critic_loss_fn(
            agent.critics, agent.target_actor, agent.target_critics, batch, noise, hparams, nets
        )
        return indices, aux

    (rows, columns), aux = sample_and_td_errors(agent, buffer)
    _, updated, _ = jax.jit(td3.update, static_argnums=3)(
        agent, buffer, key, config, hparams, jnp.int32(0)
    )
    slots = np.asarray(rows * 2 + columns)
    assert len(set(slots.tolist())) == slots.size
    floored = np.maximum(np.max(np.abs(np.asarray(aux.td_tm1)), axis=0), 1.0)
    assert np.any(floored > 1.0) and np.any(floored == 1.0)
    np.testing.assert_allclose(updated.sums[updated.leaves + slots], floored**0.5, rtol=1e-5)
    np.testing.assert_allclose(updated.max_priority, np.max(floored), rtol=1e-6)


def _transitions(reward):
    return Transition(
        obs=jnp.zeros((2, 1)),
        action=jnp.array([[0.5], [-0.5]]),
        reward=reward,
        next_obs=jnp.ones((2, 1)),
        terminated=jnp.array([True, False]),
        truncated=jnp.zeros(2, bool),
    )
