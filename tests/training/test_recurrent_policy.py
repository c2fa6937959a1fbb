"""A policy may carry state: a recurrent learner's state starts every episode afresh in training
rollouts (after an autoreset), evaluation, GIF rollouts, ``load_policy`` and the gymnasium-style
loop, and feed-forward learners are asked nothing new.

The learner (``tests/recurrent_learner.py``) counts steps in its state; its env rewards 0 only for
the step count since the episode's start, so a return of exactly 0 says the state was reset at
every episode start and nowhere else.
"""

from __future__ import annotations

import fake_algorithm as fake
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import recurrent_learner as learner

import rl_jax
import rl_jax.agents.ppo
import rl_jax.envs.core.probes  # noqa: F401  (registers the probes)
from rl_jax.run import api, render
from rl_jax.run.policy import LoadedPolicy, Policy, RecurrentPolicy
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec
from rl_jax.training import episodes
from rl_jax.training.algorithm import hooks


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("recurrent") / "run"
    config = learner.default_config()
    spec = RunSpec(
        learner,
        learner.ENV_ID,
        config,
        (learner.default_hyperparams(),),
        out,
        seeds=2,
        total_steps=3 * learner.env_steps_per_chunk(config),
        log_interval=1e9,
    )
    run(spec, notify=lambda message: None)
    return out


def test_feed_forward_learners_have_no_policy_state():
    assert hooks(fake).initial_policy_state(fake.default_config()) is None
    ppo = rl_jax.agents.ppo.ppo
    assert hooks(ppo).initial_policy_state(ppo.default_config("rl_jax/CartPole-v1")) is None


def test_reset_policy_state_resets_only_where_an_episode_starts():
    state = {"h": jnp.arange(6.0).reshape(3, 2), "n": jnp.array([4, 5, 6])}
    initial = {"h": jnp.array([-1.0, -2.0]), "n": jnp.int32(0)}
    reset = episodes.reset_policy_state(jnp.array([False, True, False]), state, initial)
    np.testing.assert_array_equal(reset["h"], [[0, 1], [-1, -2], [4, 5]])
    np.testing.assert_array_equal(reset["n"], [4, 0, 6])


def test_training_rollouts_and_evaluation_reset_at_episode_starts():
    config = learner.default_config()
    hparams = learner.default_hyperparams()
    state = learner.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(lambda s: learner.train_chunk(s, config, hparams))
    for _ in range(3):  # 60 steps of 3 envs: episodes end (and restart) all along
        state, metrics = chunk(state)
        assert float(metrics.train_return) == 0.0
        assert float(metrics.eval_return) == 0.0
    # an offset policy misses: the zero above is no accident of the env
    off = learner.init(jax.random.key(0), config, learner.Hyperparams(offset=0.5))
    _, metrics = chunk(off)
    assert float(metrics.eval_return) < 0.0


def test_a_state_never_reset_misses():
    """Without the reset after an autoreset the counter runs on into the next episode."""
    config = learner.default_config()
    env = episodes.make_train_env(config)
    env_state, ts = jax.vmap(env.reset)(jax.random.split(jax.random.key(1), 3))
    counter, total = jnp.zeros(3), jnp.zeros(3)
    for t in range(30):
        action, counter = learner._act({"offset": 0.0}, counter, ts.obs, config)
        keys = jax.random.split(jax.random.key(t), 3)
        env_state, ts = jax.vmap(env.step)(keys, env_state, action)
        total = total + ts.reward
    assert float(jnp.sum(total)) < 0.0


def test_a_run_evaluates_and_loads_its_recurrent_policy(run_dir):
    loaded = LoadedPolicy(run_dir, algorithm=learner)
    assert float(loaded.initial_policy_state()) == 0.0
    returns = api.evaluate_policy(
        loaded.env(), loaded.act(), jax.random.key(0), 8, loaded.initial_policy_state()
    )
    np.testing.assert_array_equal(returns, np.zeros(8))

    policy = rl_jax.load_policy(run_dir, algorithm=learner)
    assert isinstance(policy, RecurrentPolicy) and not isinstance(policy, Policy)
    obs = np.zeros(1, np.float32)
    assert [float(policy(obs)[0]) for _ in range(3)] == [0.0, 1.0, 2.0]
    policy.reset()
    assert float(policy(obs)[0]) == 0.0
    # a batch keeps one state per env; reset(done) restarts those that are done only
    policy.reset()
    batch = np.zeros((3, 1), np.float32)
    policy(batch)
    policy(batch)
    policy.reset(np.array([False, True, False]))
    np.testing.assert_array_equal(policy(batch)[:, 0], [2.0, 0.0, 2.0])


def test_the_loaded_policy_in_a_step_by_step_loop(run_dir):
    """The gymnasium loop of the docs: ``reset()`` at each episode start."""
    policy = rl_jax.load_policy(run_dir, algorithm=learner)
    env = learner.ClockEnv()
    key = jax.random.key(3)
    step = jax.jit(env.step)
    for _ in range(4):
        key, key_reset = jax.random.split(key)
        state, ts = env.reset(key_reset)
        policy.reset()
        total, done = 0.0, False
        while not done:
            key, key_step = jax.random.split(key)
            state, ts = step(key_step, state, jnp.asarray(policy(np.asarray(ts.obs))))
            total += float(ts.reward)
            done = bool(ts.terminated) or bool(ts.truncated)
        assert total == 0.0


def test_gif_rollouts_carry_the_state(run_dir):
    loaded = LoadedPolicy(run_dir, algorithm=learner)
    played = render.rollout(
        loaded.env(), loaded.act(), jax.random.key(0), 3, loaded.initial_policy_state()
    )
    assert [episode["return"] for episode in played] == [0.0, 0.0, 0.0]
    assert all(len(episode["states"]) >= 2 for episode in played)


def test_a_recurrent_policy_is_given_the_legal_actions_where_the_env_has_a_mask():
    """The highest legal action, chosen from the mask alone (the observation ignored), never
    dies in the fatal-actions probe; the state still counts the steps."""
    env = rl_jax.envs.make("rl_jax/ProbeFatalIllegalActions-v0")

    def policy(counter, obs, legal):
        highest = legal.shape[-1] - 1 - jnp.argmax(legal[..., ::-1], axis=-1)
        return highest.astype(jnp.int32), counter + 1.0

    returns = jax.jit(
        lambda key: episodes.recurrent_episode_returns(policy, jnp.float32(0), env, key, 16)
    )(jax.random.key(0))
    assert np.all(np.asarray(returns) > 0)  # an illegal action pays -10 and ends the episode
    played = render.rollout(env, policy, jax.random.key(1), 2, jnp.float32(0))
    assert all(episode["return"] > 0 for episode in played)
