"""DQN and PPO on an env whose illegal actions are fatal (``rl_jax/ProbeFatalIllegalActions-v0``):
with the env's action mask they never take an illegal action, in training or evaluation, and
DQN's Q-values of the legal actions approach the exact ones; the same learners with the mask
hidden from them do take illegal actions, so that the env tells the two apart."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)
from rl_jax import envs
from rl_jax.agents import dqn, ppo
from rl_jax.envs.core.preprocessing import ACTION_MASK
from rl_jax.envs.core.probes import FatalIllegalActions

ENV_ID = "rl_jax/ProbeFatalIllegalActions-v0"
OPTIMUM = 10 * FatalIllegalActions().best_reward()  # the best policy's return over 10 steps


class HideMask(envs.Wrapper):
    """The env without its action mask: a learner sees only the observation."""

    @staticmethod
    def _hidden(info):
        return {key: value for key, value in info.items() if key != ACTION_MASK}

    def empty_info(self):
        return self._hidden(self.env.empty_info())

    def reset(self, key, params=None):
        state, ts = self.env.reset(key, params)
        return state, ts._replace(info=self._hidden(ts.info))

    def step(self, key, state, action, params=None):
        state, ts = self.env.step(key, state, action, params)
        return state, ts._replace(info=self._hidden(ts.info))


@dataclasses.dataclass(frozen=True)
class PPONoMask(ppo.Config):
    def make_env(self):
        return HideMask(super().make_env())


@dataclasses.dataclass(frozen=True)
class DQNNoMask(dqn.Config):
    def make_env(self):
        return HideMask(super().make_env())


def _without_mask(config, config_type):
    return config_type(**{f.name: getattr(config, f.name) for f in dataclasses.fields(config)})


PPO_CONFIG = {
    "num_envs": 8,
    "num_steps": 16,
    "num_epochs": 4,
    "num_minibatches": 2,
    "iterations_per_chunk": 40,
    "hidden": (32, 32),
    "num_eval_envs": 16,
}


@functools.cache
def _ppo_run(masked: bool, chunks: int):
    config = ppo.default_config(ENV_ID, **PPO_CONFIG)
    if not masked:
        config = _without_mask(config, PPONoMask)
    hparams = ppo.default_hyperparams(gamma=0.9, learning_rate=3e-3, ent_coef=0.0)
    state = ppo.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(ppo.train_chunk, static_argnums=1)
    deaths = []
    for _ in range(chunks):
        before = state
        state, metrics = chunk(state, config, hparams)
        deaths.append(_ppo_deaths(before, config))
    return state, config, metrics, deaths


def _ppo_deaths(state, config):
    """Illegal actions of one rollout of the stochastic policy of ``state``: terminations."""
    rollout = ppo.collect(
        state.agent, state.env_state, state.obs, state.key, config, state.action_mask
    )[-1]
    return int(jnp.sum(rollout.terminated))


def test_ppo_with_the_mask_never_takes_an_illegal_action_and_learns_the_best_legal_one():
    state, config, metrics, deaths = _ppo_run(True, 3)
    assert state.action_mask is not None and state.action_mask.shape == (8, 4)
    assert deaths == [0, 0, 0]  # from the first rollout on: the policy draws legal actions only
    assert _ppo_deaths(state, config) == 0
    # The deterministic policy, as evaluation runs it, takes the highest legal action.
    assert float(metrics.eval_return) > 0.9 * OPTIMUM  # random legal: 6.25; 16 episodes: std ~0.2
    legal = jnp.array([[True, False, True, False], [False, True, False, False]])
    actions = ppo.act(state.agent, legal.astype(jnp.float32), config, legal)
    np.testing.assert_array_equal(actions, [2, 1])


def test_ppo_without_the_mask_takes_illegal_actions():
    state, config, metrics, deaths = _ppo_run(False, 1)
    assert state.action_mask is None
    assert deaths[0] > 0


# ---- DQN ----------------------------------------------------------------------------------------
DQN_GAMMA = 0.5
DQN_CONFIG = {
    "num_envs": 8,
    "learning_starts": 256,
    "batch_size": 64,
    "buffer_size": 8000,  # 1,000 rows of 8: every transition of 4 chunks
    "iterations_per_chunk": 250,
    "hidden": (32, 32),
    "target_update_period": 1,
    "num_eval_envs": 16,
}


@functools.cache
def _dqn_run(masked: bool, chunks: int, **options):
    config = dqn.default_config(ENV_ID, **DQN_CONFIG, **options)
    if not masked:
        config = _without_mask(config, DQNNoMask)
    hparams = dqn.default_hyperparams(
        gamma=DQN_GAMMA,
        tau=0.05,
        learning_rate=1e-3,
        epsilon_start=1.0,
        epsilon_end=0.2,
        epsilon_decay_steps=4000,
    )
    state = dqn.init(jax.random.key(0), config, hparams)
    chunk = jax.jit(dqn.train_chunk, static_argnums=1)
    for _ in range(chunks):
        state, metrics = chunk(state, config, hparams)
    return state, config, metrics


def _stored_deaths(state):
    """Illegal actions among every transition of training (the buffer holds them all)."""
    return int(jnp.sum(state.buffer.data.terminated))


SUBSETS = np.array([[(s >> a) & 1 for a in range(4)] for s in range(1, 16)], bool)


def test_dqn_with_the_mask_never_takes_an_illegal_action_and_learns_the_legal_q_values():
    state, config, metrics = _dqn_run(True, 4)
    assert state.action_mask is not None and state.action_mask.shape == (8, 4)
    assert state.buffer.data.next_legal.shape[-1] == 4
    # Exploration (epsilon from 1), warm-up and greedy acting all took legal actions only.
    assert int(state.buffer.rows_filled) == 4 * 250
    assert _stored_deaths(state) == 0
    assert float(metrics.eval_return) > 0.9 * OPTIMUM  # random legal: 6.25; 16 episodes: std ~0.2
    # The greedy action of every legal set is its highest legal action ...
    legal = jnp.asarray(SUBSETS)
    actions = dqn.act(state.agent, legal.astype(jnp.float32), config, legal)
    np.testing.assert_array_equal(actions, 3 - np.argmax(SUBSETS[:, ::-1], axis=1))
    # ... and the legal actions' values approach the exact ones (bootstrapped over legal actions).
    q = np.asarray(dqn.make_network(config).apply(state.agent.online, legal.astype(jnp.float32)))
    env = FatalIllegalActions()
    expected = np.stack([env.true_q(row, DQN_GAMMA) for row in SUBSETS])
    np.testing.assert_allclose(q[SUBSETS], expected[SUBSETS], atol=0.1)


def test_dqn_without_the_mask_takes_illegal_actions():
    state, _, _ = _dqn_run(False, 1)
    assert state.action_mask is None
    assert "next_legal" not in state.buffer.data._asdict() or state.buffer.data.next_legal is None
    assert _stored_deaths(state) > 0


def test_frame_replay_keeps_the_next_observations_mask():
    """DQN's replay of frames (``PixelConfig``) keeps the mask in its rows as the flat one does,
    and hands it on with the window's last step (n-step targets bootstrap from there)."""
    from rl_jax.training import frame_replay, replay
    from rl_jax.training.replay import Transition

    width, steps, rows = 2, 6, 8
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.integers(0, 255, (steps, width, 5, 5, 4)), jnp.uint8)
    legal = jnp.asarray(rng.random((steps, width, 4)) < 0.5)
    false = jnp.zeros((steps, width), bool)
    played = Transition(obs, jnp.zeros((steps, width), jnp.int32), false * 1.0, obs, false, false)
    played = played._replace(next_legal=legal)
    example = jax.tree.map(lambda leaf: leaf[0, 0], played)
    buffer = frame_replay.init(example, lambda row: replay.init(row, rows * width, width))
    for t in range(steps):
        step = jax.tree.map(lambda leaf, t=t: leaf[t], played)
        buffer = frame_replay.add(buffer, step, replay.add)
    starts = jnp.array([0, 1, 2], jnp.int32)
    columns = jnp.array([0, 1, 0], jnp.int32)
    window, stored = replay.gather_windows(buffer.storage, starts, columns, 3)
    windows = frame_replay.transitions(buffer, window, starts, columns)
    np.testing.assert_array_equal(windows.next_legal[:, 0], legal[starts, columns])
    batch = replay.n_step_batch(windows, stored, 0.9)
    np.testing.assert_array_equal(batch.next_legal, legal[starts + 2, columns])


def test_rendering_and_load_policy_hand_the_policy_the_mask():
    """The GIF's rollout and ``load_policy``'s numpy callable act legally too."""
    from rl_jax.run.policy import Policy
    from rl_jax.run.render import rollout

    state, config, _ = _dqn_run(True, 4)
    env = dqn.dqn.make_env(config)
    act = dqn.dqn.policy(state, config)
    episodes = rollout(env, act, jax.random.key(9), 4)
    # Never dead: every episode runs to the 10-step limit, each step paying a legal reward.
    assert [len(episode["states"]) for episode in episodes] == [11] * 4
    assert all(episode["return"] > 0 for episode in episodes)

    class Loaded:
        def env(self):
            return env

        def act(self):
            return act

    policy = Policy(Loaded())
    legal = SUBSETS.astype(np.float32)
    best = 3 - np.argmax(SUBSETS[:, ::-1], axis=1)
    np.testing.assert_array_equal(policy(legal, SUBSETS), best)
    assert int(policy(legal[0], SUBSETS[0])) == best[0]
