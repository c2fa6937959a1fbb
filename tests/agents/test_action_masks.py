"""The masked Q-learning and categorical-policy maths, against values worked out by hand (numpy),
under jit and without, as rlax tests its own."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from rl_jax.agents import policy_gradient as pg
from rl_jax.agents import q_learning as ql
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.probes import FatalIllegalActions

VARIANTS = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])

Q = np.array(
    [
        [1.0, 5.0, 3.0, -2.0],  # the best action is illegal
        [-4.0, -1.0, -3.0, -2.0],  # all negative: -inf masking must not win
        [2.0, 2.0, 7.0, 2.0],  # equal legal values: the first is taken
        [0.5, 9.0, -1.0, 3.0],  # nothing legal: read as all legal
    ],
    np.float32,
)
LEGAL = np.array(
    [
        [True, False, True, False],
        [True, False, True, False],
        [False, True, False, True],
        [False, False, False, False],
    ]
)


@VARIANTS
def test_masked_argmax_and_max(transform):
    np.testing.assert_array_equal(transform(ql.masked_argmax)(Q, LEGAL), [2, 2, 1, 1])
    np.testing.assert_array_equal(transform(ql.masked_max)(Q, LEGAL), [3.0, -3.0, 2.0, 9.0])
    # With every action legal they are the plain ones.
    everything = np.ones_like(LEGAL)
    np.testing.assert_array_equal(ql.masked_argmax(Q, everything), np.argmax(Q, axis=-1))
    np.testing.assert_array_equal(ql.masked_max(Q, everything), ql.greedy_values(jnp.asarray(Q)))


def test_masked_max_is_finite_and_bootstraps_zero_through_a_termination():
    # A terminal state's mask may allow nothing: the value must stay finite, so that the target
    # r + discount * v with discount 0 is r, not nan.
    v_t = ql.masked_max(jnp.asarray(Q), jnp.zeros_like(LEGAL))
    assert np.all(np.isfinite(v_t))
    target = ql.n_step_target(jnp.ones((4, 1)), jnp.zeros((4, 1)), v_t)
    np.testing.assert_array_equal(target, np.ones(4))


@VARIANTS
def test_masked_double_q_values(transform):
    selector = Q
    value = np.arange(16, dtype=np.float32).reshape(4, 4) * 10.0
    # Selected by the masked argmax above: actions 2, 2, 1, 1.
    expected = [value[0, 2], value[1, 2], value[2, 1], value[3, 1]]
    np.testing.assert_array_equal(
        transform(ql.masked_double_q_values)(value, selector, LEGAL), expected
    )


def test_masked_epsilon_greedy_explores_only_legal_actions():
    legal = jnp.asarray(np.tile(LEGAL[:3], (2000, 1)))
    q = jnp.asarray(np.tile(Q[:3], (2000, 1)))
    greedy = ql.masked_epsilon_greedy(jax.random.key(0), q, legal, 0.0)
    np.testing.assert_array_equal(greedy, ql.masked_argmax(q, legal))
    explored = np.asarray(ql.masked_epsilon_greedy(jax.random.key(1), q, legal, 1.0))
    assert np.all(np.take_along_axis(np.asarray(legal), explored[:, None], axis=1))
    # Uniform over the two legal actions of each row: about half each (6,000 draws, 5 sigma).
    rows = explored.reshape(2000, 3)
    assert abs(np.mean(rows[:, 0] == 0) - 0.5) < 0.06
    assert abs(np.mean(rows[:, 2] == 3) - 0.5) < 0.06
    half = np.asarray(ql.masked_epsilon_greedy(jax.random.key(2), q, legal, 0.5)).reshape(2000, 3)
    # epsilon 0.5: greedy half the time, and half of the explorations hit the greedy action too.
    assert abs(np.mean(half[:, 0] == 2) - 0.75) < 0.06


LOGITS = np.array([[1.0, 2.0, 3.0, 4.0], [0.0, -1.0, 0.5, 2.0]], np.float32)
PG_LEGAL = np.array([[True, False, True, False], [True, True, True, True]])


def _reference_log_probs(logits, legal):
    """log softmax over the legal entries, by hand; -inf for the illegal ones."""
    out = np.full(logits.shape, -np.inf)
    for row in range(logits.shape[0]):
        kept = logits[row][legal[row]].astype(np.float64)
        out[row, legal[row]] = kept - np.log(np.sum(np.exp(kept)))
    return out


@VARIANTS
def test_masked_categorical_log_prob(transform):
    reference = _reference_log_probs(LOGITS, PG_LEGAL)
    # Row 0: log(e^1 / (e^1 + e^3)) and log(e^3 / (e^1 + e^3)).
    np.testing.assert_allclose(reference[0, [0, 2]], [-2.126928, -0.126928], rtol=1e-6)
    for action in ([0, 3], [2, 1]):
        got = transform(pg.masked_categorical_log_prob)(LOGITS, np.array(action), PG_LEGAL)
        np.testing.assert_allclose(got, reference[[0, 1], action], rtol=1e-6)
    # Every action legal: the plain categorical.
    plain = pg.categorical_log_prob(jnp.asarray(LOGITS), jnp.array([1, 3]))
    everything = np.ones_like(PG_LEGAL)
    masked = pg.masked_categorical_log_prob(LOGITS, np.array([1, 3]), everything)
    np.testing.assert_allclose(masked, plain, rtol=1e-6)


@VARIANTS
def test_masked_categorical_entropy(transform):
    reference = _reference_log_probs(LOGITS, PG_LEGAL)
    expected = [
        -sum(np.exp(lp) * lp for lp in row if np.isfinite(lp)) for row in reference
    ]  # row 0: a two-way softmax of logits 1 and 3
    got = transform(pg.masked_categorical_entropy)(LOGITS, PG_LEGAL)
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    nothing = np.zeros_like(PG_LEGAL)  # no legal action: the plain softmax's entropy
    plain = pg.entropy({"logits": jnp.asarray(LOGITS)})
    np.testing.assert_allclose(pg.masked_categorical_entropy(LOGITS, nothing), plain, rtol=1e-6)


def test_masked_categorical_gradients_are_finite_and_zero_on_illegal_logits():
    logits = jnp.asarray(LOGITS)

    def loss(logits):
        log_prob = pg.masked_categorical_log_prob(logits, jnp.array([2, 1]), PG_LEGAL)
        return jnp.sum(log_prob) + jnp.sum(pg.masked_categorical_entropy(logits, PG_LEGAL))

    grad = np.asarray(jax.grad(loss)(logits))
    assert np.all(np.isfinite(grad))
    np.testing.assert_array_equal(grad[~PG_LEGAL], 0.0)
    # The legal entries' gradient is the two-way softmax's: d log pi(2) / d logit = onehot - pi,
    # plus the entropy's -pi_i (log pi_i + H).
    reference = _reference_log_probs(LOGITS, PG_LEGAL)[0, [0, 2]]
    pi = np.exp(reference)
    entropy = -np.sum(pi * reference)
    expected = np.array([0.0, 1.0]) - pi - pi * (reference + entropy)
    np.testing.assert_allclose(grad[0, [0, 2]], expected, rtol=1e-5, atol=1e-6)
    legal_only = jnp.asarray(LOGITS[1:])
    check_grads(lambda x: pg.masked_categorical_entropy(x, PG_LEGAL[1:]), (legal_only,), order=1)


def test_masked_categorical_sample_follows_the_legal_softmax():
    logits = jnp.asarray(np.tile(LOGITS[:1], (20000, 1)))
    legal = jnp.asarray(np.tile(PG_LEGAL[:1], (20000, 1)))
    actions = np.asarray(pg.masked_categorical_sample(jax.random.key(3), logits, legal))
    assert set(np.unique(actions)) <= {0, 2}
    p2 = np.exp(_reference_log_probs(LOGITS, PG_LEGAL)[0, 2])  # 0.881
    std = np.sqrt(p2 * (1 - p2) / actions.size)
    assert abs(np.mean(actions == 2) - p2) < 5 * std


def test_acting_on_the_exact_q_values_of_the_fatal_env():
    """On ``FatalIllegalActions``, whose illegal actions end the episode at -10: Q-values that
    rank the actions as its exact ones rank the legal ones (the last first) act as the best
    policy under the mask: never dying, earning the best mean reward. Without the mask they
    take the last action, legal or not, and die."""
    env = FatalIllegalActions()
    gamma, num_envs = 0.9, 4096
    keys = jax.random.split(jax.random.key(0), num_envs)
    state, ts = jax.vmap(env.reset)(keys)
    legal = ts.info[ACTION_MASK]
    exact = jnp.asarray(np.stack([env.true_q(row, gamma) for row in np.asarray(legal)]))
    np.testing.assert_allclose(
        exact[0], np.where(legal[0], (np.arange(4) + 1) / 4 + gamma * env.best_reward() / 0.1, -10)
    )
    optimistic = jnp.broadcast_to(jnp.arange(4.0), (num_envs, 4))  # the last action looks best
    greedy = ql.masked_argmax(optimistic, legal)
    np.testing.assert_array_equal(greedy, ql.masked_argmax(exact, legal))

    def returns(choose):
        def body(carry, key):
            state, legal, alive, total = carry
            action = choose(legal)
            state, ts = jax.vmap(env.step)(jax.random.split(key, num_envs), state, action)
            total = total + jnp.where(alive, ts.reward, 0.0)
            alive = alive & ~ts.terminated
            return (state, ts.info[ACTION_MASK], alive, total), None

        carry = (state, legal, jnp.ones(num_envs, bool), jnp.zeros(num_envs))
        keys = jax.random.split(jax.random.key(1), env.max_episode_steps)
        return jax.lax.scan(body, carry, keys)[0][2:]

    alive, total = returns(lambda legal: ql.masked_argmax(optimistic, legal))
    assert bool(jnp.all(alive))
    np.testing.assert_allclose(jnp.mean(total) / 10, env.best_reward(), atol=0.01)
    alive, total = returns(lambda legal: jnp.argmax(optimistic, axis=-1))
    assert float(jnp.mean(alive)) < 0.01 and float(jnp.mean(total)) < -5
