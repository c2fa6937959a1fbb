"""TD3/DDPG losses alone: hand-computed values, gradients, and where gradients may not flow. The
pure maths is what every deterministic actor-critic shares (``rl_jax.agents.actor_critic``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from rl_jax.agents import actor_critic
from rl_jax.agents.actor_critic import (
    CriticBatch,
    Networks,
    clipped_double_q_target,
    critic_loss,
    deterministic_policy_loss,
    smoothed_target_action,
    target_action,
)
from rl_jax.agents.common import polyak_update
from rl_jax.agents.td3 import Agent, Config, Hyperparams, actor_loss_fn, critic_loss_fn
from rl_jax.envs.core.spaces import Box
from rl_jax.training import networks
from rl_jax.training.replay import Transition

# Every pure loss runs plain and jitted: both must give the hand-computed value.
modes = pytest.mark.parametrize("transform", [lambda f: f, jax.jit], ids=["nojit", "jit"])

OBS_DIM, ACTION_DIM, BATCH = 3, 2, 5
# Asymmetric bounds with half-range 2 in dim 0 and 0.5 in dim 1: noise must scale with them.
ACTION_SPACE = Box(np.array([-2.0, 0.0]), np.array([2.0, 1.0]), (2,))
HPARAMS = Hyperparams().as_arrays()


@modes
def test_smoothed_target_action_clips_noise_then_action(transform):
    a_t = jnp.array([0.9, -0.2, 0.0, 0.1])
    noise = jnp.array([0.3, -0.7, 0.2, -0.6])
    got = transform(smoothed_target_action)(a_t, noise, 0.5, -1.0, 1.0)
    # 0.9 + 0.3 leaves the box -> 1; -0.7 is clipped to -0.5; 0.2 passes; -0.6 -> -0.5.
    np.testing.assert_allclose(got, [1.0, -0.7, 0.2, -0.4], rtol=0, atol=1e-7)


@modes
def test_clipped_double_q_target_takes_min_of_twins_and_stops_at_termination(transform):
    q_t = jnp.array([[1.0, 5.0, -2.0], [3.0, 2.0, -1.0]])  # [critics, batch]
    r_t = jnp.array([0.5, 1.0, 0.0])
    discount_t = jnp.array([0.9, 0.0, 0.5])
    got = transform(clipped_double_q_target)(r_t, discount_t, q_t)
    # min over critics = [1, 2, -2]; the second transition is terminal (discount 0).
    np.testing.assert_allclose(got, [0.5 + 0.9 * 1.0, 1.0, 0.5 * -2.0], rtol=0, atol=1e-7)


@modes
def test_clipped_double_q_target_with_one_critic_is_the_ddpg_target(transform):
    got = transform(clipped_double_q_target)(
        jnp.array([1.0, 2.0]), jnp.array([0.99, 0.99]), jnp.array([[3.0, -4.0]])
    )
    np.testing.assert_allclose(got, [1.0 + 0.99 * 3.0, 2.0 - 0.99 * 4.0], rtol=1e-7)


@modes
def test_critic_loss_value(transform):
    q_tm1 = jnp.array([[1.0, 2.0], [0.0, 1.0]])
    q_t = jnp.array([[1.0, 5.0], [3.0, 2.0]])
    r_t, discount_t = jnp.array([0.5, 1.0]), jnp.array([0.9, 0.0])
    # Target [1.4, 1.0]. Critic 1: mean(0.16, 1) = 0.58; critic 2: mean(1.96, 0) = 0.98.
    got = transform(critic_loss)(q_tm1, r_t, discount_t, q_t)
    np.testing.assert_allclose(got, 0.58 + 0.98, rtol=1e-6)


@modes
def test_deterministic_policy_loss_and_polyak_values(transform):
    np.testing.assert_allclose(transform(deterministic_policy_loss)(jnp.array([1.0, 2.0, 6.0])), -3)
    target = {"w": jnp.array([0.0, 2.0]), "b": jnp.array(4.0)}
    online = {"w": jnp.array([1.0, 0.0]), "b": jnp.array(0.0)}
    got = transform(polyak_update)(target, online, 0.25)
    np.testing.assert_allclose(got["w"], [0.25, 1.5], rtol=1e-7)
    np.testing.assert_allclose(got["b"], 3.0, rtol=1e-7)


def test_pure_losses_check_grads():
    key = jax.random.key(0)
    q_tm1, q_t = jax.random.normal(key, (2, 2, 7))
    r_t = jnp.linspace(-1.0, 1.0, 7)
    discount_t = jnp.full((7,), 0.9)
    # The target is a constant for differentiation (stop_gradient), so differentiate w.r.t.
    # the online values only; numerical and automatic derivatives must agree to 2nd order.
    check_grads(
        jax.jit(lambda q: critic_loss(q, r_t, discount_t, q_t)), (q_tm1,), order=2, eps=1e-2
    )
    check_grads(jax.jit(deterministic_policy_loss), (q_t[0],), order=2, eps=1e-2)
    # Away from the clip kinks the smoothed action is affine in the action and the noise.
    a_t, noise = jnp.array([0.1, -0.3]), jnp.array([0.2, 0.1])
    check_grads(
        jax.jit(lambda a, n: smoothed_target_action(a, n, 0.5, -1.0, 1.0)),
        (a_t, noise),
        order=2,
        eps=1e-3,
    )
    check_grads(jax.jit(lambda t, o: polyak_update(t, o, 0.1)), (q_t, q_tm1), order=2, eps=1e-2)


def test_critic_loss_target_has_no_gradient():
    q_tm1, q_t = jnp.ones((2, 3)), jnp.full((2, 3), 2.0)
    grad_q_t = jax.grad(critic_loss, argnums=3)(q_tm1, jnp.ones(3), jnp.full(3, 0.9), q_t)
    assert np.all(np.asarray(grad_q_t) == 0.0)


# ---- losses on networks -----------------------------------------------------------------------
def build_networks(config: Config) -> Networks:
    """TD3's networks for ``config`` as ``td3.make_networks`` builds them, but for
    ``ACTION_SPACE`` (asymmetric bounds, which no registered env has) instead of the env's."""
    low, high = actor_critic.bounds(ACTION_SPACE, "TD3/DDPG")
    dtype, init = jnp.dtype(config.compute_dtype), config.network_init
    actor_layers = networks.Layers(
        hidden=config.actor_hidden,
        activation=config.actor_activation,
        initializer=init,
        dtype=dtype,
    )
    critic_layers = networks.Layers(
        hidden=config.critic_hidden,
        activation=config.critic_activation,
        initializer=init,
        dtype=dtype,
    )
    actor = networks.Actor(layers=actor_layers, action_low=low, action_high=high)
    critic = networks.Critic(layers=critic_layers)
    return Networks(actor, critic, ACTION_SPACE.low.copy(), ACTION_SPACE.high.copy())


@pytest.fixture(scope="module")
def setup():
    config = Config(env_id="unused", actor_hidden=(16, 16), critic_hidden=(16, 16))
    nets = build_networks(config)
    keys = jax.random.split(jax.random.key(1), 8)
    obs = jnp.zeros(OBS_DIM)
    action = jnp.zeros(ACTION_DIM)
    init_actor = jax.jit(nets.actor.init)
    init_critics = jax.jit(lambda key: networks.init_stacked(nets.critic, key, 2, obs, action))
    params = {
        "actor": init_actor(keys[0], obs),
        "critics": init_critics(keys[1]),
        "target_actor": init_actor(keys[2], obs),
        "target_critics": init_critics(keys[3]),
    }
    batch = Transition(
        obs=jax.random.normal(keys[4], (BATCH, OBS_DIM)),
        action=jax.random.uniform(keys[5], (BATCH, ACTION_DIM), minval=-1.0, maxval=1.0),
        reward=jnp.linspace(-1.0, 1.0, BATCH),
        next_obs=jax.random.normal(keys[6], (BATCH, OBS_DIM)),
        terminated=jnp.array([False, True, False, False, True]),
        truncated=jnp.array([False, False, True, False, True]),
    )
    noise = jax.random.normal(keys[7], (BATCH, ACTION_DIM))
    return nets, params, batch, noise


def _agent(critics, target_actor, target_critics) -> Agent:
    """What TD3's critic loss reads of an agent: its target networks (the online critics are
    the loss's argument; no actor or optimizer state)."""
    return Agent(
        actor=None,
        critics=critics,
        target_actor=target_actor,
        target_critics=target_critics,
        actor_opt=(),
        critic_opt=(),
    )


def _critic_loss(setup, critics, target_actor, target_critics, hparams=HPARAMS):
    nets, _, batch, noise = setup
    agent = _agent(critics, target_actor, target_critics)
    critic_batch = CriticBatch.one_step(batch, hparams.gamma)
    return critic_loss_fn(critics, agent, critic_batch, noise, hparams, nets)[0]


def test_critic_loss_fn_matches_hand_assembled_target(setup):
    nets, p, batch, noise = setup
    loss = _critic_loss(setup, p["critics"], p["target_actor"], p["target_critics"])
    # Assemble the TD3 target by hand with numpy, one target critic at a time.
    half_range = np.array([2.0, 0.5])
    a_t = np.asarray(nets.actor.apply(p["target_actor"], batch.next_obs))
    a_t = a_t + np.clip(0.2 * half_range * np.asarray(noise), -0.5 * half_range, 0.5 * half_range)
    a_t = np.clip(a_t, ACTION_SPACE.low, ACTION_SPACE.high)
    q_t = [
        np.asarray(
            nets.critic.apply(
                jax.tree.map(lambda x, i=i: x[i], p["target_critics"]), batch.next_obs, a_t
            )
        )
        for i in range(2)
    ]
    not_terminal = 1.0 - np.asarray(batch.terminated, np.float32)
    target = np.asarray(batch.reward) + 0.99 * not_terminal * np.minimum(q_t[0], q_t[1])
    expected = 0.0
    for i in range(2):
        q_tm1 = nets.critic.apply(
            jax.tree.map(lambda x, i=i: x[i], p["critics"]), batch.obs, batch.action
        )
        expected += np.mean((np.asarray(q_tm1) - target) ** 2)
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    assert not np.allclose(q_t[0], q_t[1])  # the min was a real choice


def test_target_action_noise_is_relative_to_action_scale_and_clipped(setup):
    nets, p, batch, _ = setup
    mean_action = np.asarray(nets.actor.apply(p["target_actor"], batch.next_obs))
    huge = jnp.full((BATCH, ACTION_DIM), 100.0)
    got = target_action(mean_action, huge, HPARAMS, nets)
    # The clip is 0.5 x half-range = (1.0, 0.25), then the bounds apply.
    expected = np.clip(mean_action + np.array([1.0, 0.25]), ACTION_SPACE.low, ACTION_SPACE.high)
    np.testing.assert_allclose(got, expected, rtol=1e-6)
    small = jnp.full((BATCH, ACTION_DIM), -0.5)
    got = target_action(mean_action, small, HPARAMS, nets)
    expected = np.clip(
        mean_action - 0.1 * np.array([2.0, 0.5]), ACTION_SPACE.low, ACTION_SPACE.high
    )
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-7)
    no_smoothing = HPARAMS.replace(target_noise=jnp.float32(0.0))
    got = target_action(mean_action, huge, no_smoothing, nets)
    np.testing.assert_array_equal(got, mean_action)


def test_critic_loss_has_exactly_zero_gradient_wrt_target_networks(setup):
    _, p, _, _ = setup
    # Jitted (as in training) rather than dispatched op by op: faster, the same zeros.
    grads = jax.jit(jax.grad(lambda *args: _critic_loss(setup, *args), argnums=(0, 1, 2)))(
        p["critics"], p["target_actor"], p["target_critics"]
    )
    online, target_actor, target_critics = grads
    for leaf in jax.tree.leaves((target_actor, target_critics)):
        assert np.all(np.asarray(leaf) == 0.0)
    assert all(np.any(np.asarray(leaf) != 0.0) for leaf in jax.tree.leaves(online))


def test_actor_gradient_flows_only_through_first_critic(setup):
    nets, p, batch, _ = setup
    # One jitted gradient program for all three gradients below (as in training).
    gradients = jax.jit(jax.grad(lambda *args: actor_loss_fn(*args, nets), argnums=(0, 1)))
    grad_actor, grad_critics = gradients(p["actor"], p["critics"], batch.obs)
    for leaf in jax.tree.leaves(grad_critics):
        assert np.any(np.asarray(leaf[0]) != 0.0)
        assert np.all(np.asarray(leaf[1]) == 0.0)
    # Replacing the second critic changes nothing about the actor's gradient.
    other = p["target_critics"]
    mixed = jax.tree.map(lambda a, b: a.at[1].set(b[1]), p["critics"], other)
    grad_mixed, _ = gradients(p["actor"], mixed, batch.obs)
    jax.tree.map(np.testing.assert_array_equal, grad_actor, grad_mixed)
    # ... while replacing the first one does.
    mixed = jax.tree.map(lambda a, b: a.at[0].set(b[0]), p["critics"], other)
    grad_mixed, _ = gradients(p["actor"], mixed, batch.obs)
    assert not np.allclose(jax.tree.leaves(grad_actor)[0], jax.tree.leaves(grad_mixed)[0])


def test_network_losses_check_grads(setup):
    # ReLU kinks and float32 rounding make finite differences of whole networks unreliable, so
    # this one check runs in float64 (locally; library code stays float32).
    with jax.enable_x64(True):
        config = Config(
            env_id="unused", actor_hidden=(8,), critic_hidden=(8,), compute_dtype="float64"
        )
        nets = build_networks(config)
        _, p, batch, noise = setup
        to64 = lambda tree: jax.tree.map(  # noqa: E731
            lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x, tree
        )
        keys = jax.random.split(jax.random.key(3), 4)
        obs, action = jnp.zeros(OBS_DIM), jnp.zeros(ACTION_DIM)
        actor, target_actor = (to64(nets.actor.init(k, obs)) for k in keys[:2])
        critics, target_critics = (
            to64(networks.init_stacked(nets.critic, k, 2, obs, action)) for k in keys[2:]
        )
        batch, noise = to64(batch), to64(noise)
        hparams = to64(HPARAMS)

        agent = _agent(critics, target_actor, target_critics)
        critic_batch = CriticBatch.one_step(batch, hparams.gamma)

        def critic_objective(critics):
            return critic_loss_fn(critics, agent, critic_batch, noise, hparams, nets)[0]

        check_grads(jax.jit(critic_objective), (critics,), order=1, modes=("rev",), eps=1e-6)
        check_grads(
            jax.jit(lambda a: actor_loss_fn(a, critics, batch.obs, nets)),
            (actor,),
            order=1,
            modes=("rev",),
            eps=1e-6,
        )
