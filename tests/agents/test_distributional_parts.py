"""Distributional Q-learning's maths alone: C51's projection and cross-entropy, QR-DQN's quantile
levels and quantile Huber loss, each against plain numpy loops written here from the papers
(Bellemare et al. 2017, Algorithm 1; Dabney et al. 2018, eq. 10) and against hand-worked cases,
with their gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from rl_jax.agents import distributional_parts as parts

modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])


# ---- references: loops over atoms and quantile pairs ------------------------------------------
def projection_reference(support, probs, total, discount):
    """The C51 paper's Algorithm 1: each moved atom's mass to floor/ceil of its position."""
    support = np.asarray(support, np.float64)
    v_min, v_max, n = support[0], support[-1], len(support)
    spacing = (v_max - v_min) / (n - 1)
    out = np.zeros((len(total), n))
    for b in range(len(total)):
        for i in range(n):
            moved = min(max(total[b] + discount[b] * support[i], v_min), v_max)
            position = (moved - v_min) / spacing
            low, high = int(np.floor(position)), int(np.ceil(position))
            if low == high:
                out[b, low] += probs[b][i]
            else:
                out[b, low] += probs[b][i] * (high - position)
                out[b, high] += probs[b][i] * (position - low)
    return out


def quantile_loss_reference(theta, target, kappa):
    """sum_i (1/M) sum_j |tau_i - 1{u<0}| L_kappa(u) / kappa, u = target_j - theta_i."""
    n = len(theta)
    total = 0.0
    for i in range(n):
        tau = (2 * i + 1) / (2 * n)
        for j in range(len(target)):
            u = target[j] - theta[i]
            huber = 0.5 * u * u if abs(u) <= kappa else kappa * (abs(u) - 0.5 * kappa)
            total += abs(tau - (1.0 if u < 0 else 0.0)) * huber / kappa / len(target)
    return total


# ---- n-step returns -----------------------------------------------------------------------------
@modes
def test_n_step_return_and_discount(transform):
    # full window; window cut after 2 steps (r 0, d 1 after); terminated on its second step
    r_t = jnp.array([[1.0, 2.0, 3.0], [1.0, 2.0, 0.0], [1.0, 2.0, 0.0]])
    discount_t = jnp.array([[0.9] * 3, [0.9, 0.9, 1.0], [0.9, 0.0, 1.0]])
    total, discount = transform(parts.n_step_return)(r_t, discount_t)
    np.testing.assert_allclose(total, [1 + 1.8 + 0.81 * 3, 1 + 1.8, 1 + 1.8], rtol=1e-6)
    np.testing.assert_allclose(discount, [0.729, 0.81, 0.0], rtol=1e-6)


# ---- C51 ----------------------------------------------------------------------------------------
def test_support_and_q_values():
    support = parts.categorical_support(-2.0, 2.0, 5)
    np.testing.assert_allclose(support, [-2, -1, 0, 1, 2])
    logits = jnp.log(jnp.array([[[0.1, 0.2, 0.4, 0.2, 0.1], [0.0, 0.0, 0.0, 0.5, 0.5]]]) + 1e-30)
    q = parts.categorical_q_values(logits, support)
    np.testing.assert_allclose(q, [[0.0, 1.5]], atol=1e-5)


@modes
def test_projection_hand_worked_cases(transform):
    support = parts.categorical_support(0.0, 4.0, 5)  # atoms 0 1 2 3 4, spacing 1
    one_hot = jnp.eye(5)
    probs = jnp.stack([one_hot[1], one_hot[1], one_hot[2], one_hot[3], one_hot[4], one_hot[0]])
    total = jnp.array([0.5, 1.0, 10.0, -7.0, 3.0, 1.25])
    discount = jnp.array([1.0, 1.0, 0.5, 1.0, 0.0, 0.9])
    got = transform(parts.categorical_projection)(support, probs, total, discount)
    expected = np.zeros((6, 5))
    expected[0, 1:3] = [0.5, 0.5]  # 0.5 + 1 = 1.5: exactly between atoms 1 and 2
    expected[1, 2] = 1.0  # 1 + 1 = 2: on atom 2, all of it there
    expected[2, 4] = 1.0  # 10 + 0.5 * 2 = 11: clipped at v_max
    expected[3, 0] = 1.0  # -7 + 3 = -4: clipped at v_min
    expected[4, 3] = 1.0  # terminal (D = 0): the n-step return 3 alone, whatever z was
    expected[5, 1:3] = [0.75, 0.25]  # 1.25 + 0.9 * 0: a quarter of the way from atom 1 to 2
    np.testing.assert_allclose(got, expected, atol=1e-6)


@modes
def test_projection_matches_the_papers_algorithm_on_random_cases(transform):
    rng = np.random.default_rng(0)
    support = parts.categorical_support(-10.0, 10.0, 51)
    probs = rng.dirichlet(np.ones(51), size=16).astype(np.float32)
    total = rng.uniform(-6.0, 6.0, size=16).astype(np.float32)
    discount = rng.choice([0.0, 0.9, 0.99**3], size=16).astype(np.float32)
    got = transform(parts.categorical_projection)(support, probs, total, discount)
    np.testing.assert_allclose(
        got, projection_reference(support, probs, total, discount), atol=1e-5
    )
    np.testing.assert_allclose(np.sum(got, axis=-1), np.ones(16), rtol=1e-5)


@modes
def test_categorical_loss_is_weighted_cross_entropy_of_the_taken_action(transform):
    rng = np.random.default_rng(1)
    logits = jnp.asarray(rng.normal(size=(4, 3, 5)), jnp.float32)
    target = jnp.asarray(rng.dirichlet(np.ones(5), size=4), jnp.float32)
    actions = jnp.array([0, 2, 1, 2])
    weights = jnp.array([1.0, 0.5, 2.0, 0.0])
    loss, per_sample = transform(parts.categorical_loss)(logits, actions, target, weights)
    expected = []
    for b in range(4):
        row = np.asarray(logits[b, int(actions[b])], np.float64)
        log_p = row - np.log(np.sum(np.exp(row)))
        expected.append(-sum(float(target[b, j]) * log_p[j] for j in range(5)))
    np.testing.assert_allclose(per_sample, expected, rtol=1e-5)
    np.testing.assert_allclose(loss, np.mean(np.asarray(weights) * expected), rtol=1e-5)


def test_categorical_loss_gradients():
    rng = np.random.default_rng(2)
    logits = jnp.asarray(
        rng.normal(size=(3, 2, 4)), jnp.float64 if jax.config.x64_enabled else jnp.float32
    )
    target = jnp.asarray(rng.dirichlet(np.ones(4), size=3), logits.dtype)
    actions, weights = jnp.array([1, 0, 1]), jnp.array([1.0, 0.5, 2.0], logits.dtype)
    loss = lambda x: parts.categorical_loss(x, actions, target, weights)[0]
    check_grads(loss, (logits,), order=1, modes=("rev",), atol=1e-2, rtol=1e-2)
    # d CE / d logits of the taken action = softmax - target; other actions get nothing
    grads = jax.grad(loss)(logits)
    expected = np.zeros(logits.shape)
    for b in range(3):
        a = int(actions[b])
        expected[b, a] = float(weights[b]) * (jax.nn.softmax(logits[b, a]) - target[b]) / 3
    np.testing.assert_allclose(grads, expected, atol=1e-6)


def test_projection_has_no_gradient():
    support = parts.categorical_support(0.0, 4.0, 5)
    probs = jnp.full((2, 5), 0.2)
    grads = jax.grad(
        lambda p: jnp.sum(parts.categorical_projection(support, p, jnp.ones(2), jnp.ones(2)) ** 2)
    )(probs)
    np.testing.assert_array_equal(grads, np.zeros((2, 5)))


# ---- QR-DQN -------------------------------------------------------------------------------------
def test_quantile_midpoints():
    np.testing.assert_allclose(parts.quantile_midpoints(4), [0.125, 0.375, 0.625, 0.875])
    np.testing.assert_allclose(parts.quantile_midpoints(1), [0.5])


@modes
def test_quantile_huber_loss_hand_worked(transform):
    # Two quantiles (tau 0.25, 0.75) at 0 and 2, one target sample 1: u = +1 for i=0 (weight
    # 0.25, Huber 0.5) and -1 for i=1 (weight |0.75 - 1| = 0.25, Huber 0.5): 0.125 + 0.125.
    theta = jnp.array([[[0.0, 2.0]]])
    loss, per_sample = transform(parts.quantile_huber_loss)(
        theta, jnp.array([0]), jnp.array([[1.0]]), jnp.ones(1), 1.0
    )
    np.testing.assert_allclose(per_sample, [0.25], rtol=1e-6)
    # Beyond kappa the loss is linear: u = 3 for tau 0.5 gives 0.5 * (3 - 0.5) = 1.25.
    _, far = transform(parts.quantile_huber_loss)(
        jnp.array([[[0.0]]]), jnp.array([0]), jnp.array([[3.0]]), jnp.ones(1), 1.0
    )
    np.testing.assert_allclose(far, [1.25], rtol=1e-6)
    # Asymmetry: a low quantile (tau 0.25) pays 3x more for being above a sample than below it.
    _, above = parts.quantile_huber_loss(
        jnp.array([[[0.5, 9.0]]]), jnp.array([0]), jnp.array([[0.0]]), jnp.ones(1), 1.0
    )
    _, below = parts.quantile_huber_loss(
        jnp.array([[[-0.5, 9.0]]]), jnp.array([0]), jnp.array([[0.0]]), jnp.ones(1), 1.0
    )
    np.testing.assert_allclose(above - 0.25 * 8.5, 3 * (below - 0.25 * 8.5), rtol=1e-5)


@modes
def test_quantile_huber_loss_matches_the_loop_reference(transform):
    rng = np.random.default_rng(3)
    quantiles = jnp.asarray(rng.normal(scale=2.0, size=(5, 3, 8)), jnp.float32)
    target = jnp.asarray(rng.normal(scale=2.0, size=(5, 8)), jnp.float32)
    actions = jnp.array([0, 1, 2, 1, 0])
    weights = jnp.array([1.0, 0.3, 2.0, 1.0, 0.5])
    for kappa in (1.0, 0.5):
        loss, per_sample = transform(parts.quantile_huber_loss)(
            quantiles, actions, target, weights, kappa
        )
        expected = [
            quantile_loss_reference(
                np.asarray(quantiles[b, int(actions[b])], np.float64),
                np.asarray(target[b], np.float64),
                kappa,
            )
            for b in range(5)
        ]
        np.testing.assert_allclose(per_sample, expected, rtol=1e-5)
        np.testing.assert_allclose(loss, np.mean(np.asarray(weights) * expected), rtol=1e-5)


def test_quantile_loss_gradients_and_minimum_at_the_quantiles():
    rng = np.random.default_rng(4)
    quantiles = jnp.asarray(rng.normal(size=(2, 2, 4)), jnp.float32)
    target = jnp.asarray(rng.normal(size=(2, 6)), jnp.float32)
    actions, weights = jnp.array([1, 0]), jnp.ones(2)
    loss = lambda q: parts.quantile_huber_loss(q, actions, target, weights, 1.0)[0]
    check_grads(loss, (quantiles,), order=1, modes=("rev",), atol=1e-2, rtol=1e-2)
    # the target gets no gradient
    target_grad = jax.grad(
        lambda t: parts.quantile_huber_loss(quantiles, actions, t, weights, 1.0)[0]
    )(target)
    np.testing.assert_array_equal(target_grad, np.zeros(target.shape))
    # Gradient descent on samples drawn from U(0, 1) moves the quantiles to ~tau_i
    # (kappa small: the plain quantile regression loss).
    samples = jnp.linspace(0.0, 1.0, 401)[None, :]
    theta = jnp.zeros((1, 1, 4))
    step = jax.jit(
        jax.grad(
            lambda q: parts.quantile_huber_loss(q, jnp.array([0]), samples, jnp.ones(1), 0.01)[0]
        )
    )
    for _ in range(3000):
        theta = theta - 0.01 * step(theta)
    np.testing.assert_allclose(theta[0, 0], parts.quantile_midpoints(4), atol=0.02)
