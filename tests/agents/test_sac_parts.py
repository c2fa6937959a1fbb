"""SAC's pure maths (``rl_jax.agents.sac_parts``): the soft target and the losses' exact values
and gradients under jit and no-jit, the temperature's gradient, and terminated vs truncated (and
n-step windows) in the soft target."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from rl_jax.agents.actor_critic import CriticBatch
from rl_jax.agents.sac_parts import (
    soft_critic_loss,
    soft_policy_loss,
    soft_td_target,
    temperature_loss,
)
from rl_jax.training import replay, squashed_gaussian
from rl_jax.training.replay import Transition

modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])


# ---- the losses' maths ---------------------------------------------------------------------------
@modes
def test_soft_target_and_losses_exact_values(transform):
    r_t, discount_t = jnp.array([1.0, 0.5]), jnp.array([0.9, 0.0])
    q_t = jnp.array([[2.0, 3.0], [1.0, 4.0]])  # min per column: 1, 3
    log_pi_t, alpha = jnp.array([-1.0, 2.0]), 0.5
    # y = r + d (min q - alpha log pi): 1 + 0.9 (1 + 0.5) = 2.35; 0.5 + 0 = 0.5
    target = transform(soft_td_target)(r_t, discount_t, q_t, log_pi_t, alpha)
    np.testing.assert_allclose(target, [2.35, 0.5], rtol=1e-6)
    q_tm1 = jnp.array([[2.35, 1.5], [1.35, 0.5]])
    # 1/2 sum over critics of the mean squared error: 1/2 (0.5 + 0.5)
    loss = transform(soft_critic_loss)(q_tm1, r_t, discount_t, q_t, log_pi_t, alpha)
    assert float(loss) == pytest.approx(0.5, rel=1e-6)
    # mean(alpha log pi - min q): (0.5 * -1 - 1.35 + 0.5 * 2 - 0.5) / 2
    policy = transform(soft_policy_loss)(q_tm1, log_pi_t, alpha)
    assert float(policy) == pytest.approx((-0.5 - 1.35 + 1.0 - 0.5) / 2, rel=1e-6)


def test_temperature_gradient_is_entropy_minus_target():
    log_pi = jnp.array([-0.2, 0.4, 1.3])  # entropy estimate -0.5
    target_entropy = -2.0
    grad = jax.grad(temperature_loss)(jnp.float32(0.3), log_pi, target_entropy)
    assert float(grad) == pytest.approx(-0.5 - target_entropy, rel=1e-6)  # 1.5 > 0: alpha falls
    eps = 1e-2
    loss = lambda x: temperature_loss(x, log_pi, target_entropy)  # noqa: E731
    numeric = (loss(0.3 + eps) - loss(0.3 - eps)) / (2 * eps)
    assert float(grad) == pytest.approx(float(numeric), rel=1e-3)
    # value: -0.3 * (0.5 - 2)
    assert float(loss(0.3)) == pytest.approx(0.45, rel=1e-6)
    # The log-densities are data for the temperature: no gradient reaches them.
    assert np.all(np.asarray(jax.grad(temperature_loss, argnums=1)(0.3, log_pi, -2.0)) == 0.0)


def test_soft_target_has_no_gradient():
    args = (jnp.ones(3), jnp.full(3, 0.9), jnp.full((2, 3), 2.0), jnp.zeros(3), 0.2)
    grads = jax.grad(soft_critic_loss, argnums=(3, 4))(jnp.ones((2, 3)), *args)
    assert all(np.all(np.asarray(g) == 0.0) for g in grads)


def test_pure_losses_check_grads():
    q_tm1, q_t = jax.random.normal(jax.random.key(0), (2, 2, 7))
    r_t, discount_t = jnp.linspace(-1.0, 1.0, 7), jnp.full((7,), 0.9)
    log_pi = jnp.linspace(-2.0, 1.0, 7)
    check_grads(
        jax.jit(lambda q: soft_critic_loss(q, r_t, discount_t, q_t, log_pi, 0.3)),
        (q_tm1,),
        order=2,
        eps=1e-2,
    )
    check_grads(jax.jit(lambda q, lp: soft_policy_loss(q, lp, 0.3)), (q_t, log_pi), 2, eps=1e-2)
    check_grads(jax.jit(lambda x: temperature_loss(x, log_pi, -1.0)), (0.1,), order=2, eps=1e-2)
    check_grads(jax.jit(squashed_gaussian.tanh_log_det_jacobian), (q_t,), order=2, eps=1e-3)


# ---- terminated vs truncated ---------------------------------------------------------------------
def test_target_stops_at_termination_and_bootstraps_through_truncation():
    """Four hand-made transitions: running, truncated, terminated, both flags. Only termination
    zeroes the bootstrap; truncation keeps gamma x the soft value of the true next obs."""
    gamma, alpha = 0.9, 0.5
    batch = Transition(
        obs=jnp.zeros((4, 1)),
        action=jnp.zeros((4, 1)),
        reward=jnp.array([1.0, 2.0, 3.0, 4.0]),
        next_obs=jnp.ones((4, 1)),
        terminated=jnp.array([False, False, True, True]),
        truncated=jnp.array([False, True, False, True]),
    )
    critic_batch = CriticBatch.one_step(batch, gamma)
    np.testing.assert_allclose(critic_batch.discount_t, [0.9, 0.9, 0.0, 0.0])
    q_t = jnp.array([[5.0, 6.0, 7.0, 8.0], [4.0, 9.0, 9.0, 9.0]])
    log_pi_t = jnp.array([-1.0, 1.0, -1.0, 1.0])
    target = soft_td_target(critic_batch.r_t, critic_batch.discount_t, q_t, log_pi_t, alpha)
    # 1 + 0.9 (4 + 0.5); 2 + 0.9 (6 - 0.5); 3; 4
    np.testing.assert_allclose(target, [5.05, 6.95, 3.0, 4.0], rtol=1e-6)


def test_n_step_window_stops_at_episode_ends():
    """3-step windows of one env (gamma 0.5): one runs through, one is cut by a truncation (it
    bootstraps after 2 steps), one by a termination (no bootstrap)."""
    ones = jnp.ones((3, 3))
    window = Transition(
        obs=jnp.zeros((3, 3, 1)),
        action=jnp.zeros((3, 3, 1)),
        reward=ones,
        next_obs=jnp.arange(9.0).reshape(3, 3, 1),
        terminated=jnp.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]], bool),
        truncated=jnp.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], bool),
    )
    batch = CriticBatch.n_step(replay.n_step_batch(window, jnp.ones((3, 3), bool), 0.5))
    np.testing.assert_allclose(batch.r_t, [1.75, 1.5, 1.5])
    np.testing.assert_allclose(batch.discount_t, [0.125, 0.25, 0.0])
    np.testing.assert_allclose(batch.next_obs[:, 0], [2.0, 4.0, 7.0])
