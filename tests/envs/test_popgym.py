"""POPGym's memory tasks against the ``popgym`` package (1.0.7), step for step.

JAX's PRNG cannot draw numpy's shuffles, so each episode is popgym's own: popgym resets with a
seed, and ours starts from the deck it shuffled (its ``deck.idx`` in dealing order) through
``reset_to``, or from CartPole's state. Then both take the same actions and every observation
(popgym's integers one-hot), reward, ``terminated`` and ``truncated`` must agree, through the
functional API and through ``gymnasium.make`` of our id (its reset option ``state`` and
``TimeLimit``). Half the actions are the right answer, read from popgym's state, so that both
signs of every reward occur; the rest are uniform.
"""

import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env
from popgym.envs.autoencode import AutoencodeEasy
from popgym.envs.count_recall import CountRecallEasy
from popgym.envs.position_only_cartpole import PositionOnlyCartPoleEasy
from popgym.envs.repeat_first import RepeatFirstEasy
from popgym.envs.repeat_previous import RepeatPreviousEasy

from rl_jax import envs
from rl_jax.envs.core import registry
from rl_jax.envs.memory.cards import popgym_cards

SEEDS = range(4)
ATOL, RTOL = 4e-6, 1e-6  # CartPole's one-step float32 tolerance (tests/envs/test_classic_control)


def one_hot_of(obs, space: spaces.Space) -> np.ndarray:
    """popgym's observation as our envs show it: each integer one-hot, concatenated."""
    if isinstance(space, spaces.Discrete):
        return np.eye(int(space.n), dtype=np.float32)[int(obs)]
    if isinstance(space, spaces.MultiDiscrete):
        parts = zip(space.nvec, obs, strict=True)
        return np.concatenate([np.eye(int(n), dtype=np.float32)[int(o)] for n, o in parts])
    assert isinstance(space, spaces.Tuple)
    return np.concatenate([one_hot_of(o, s) for o, s in zip(obs, space.spaces, strict=True)])


# ---- what to read from popgym: the deck, and the right answer -----------------------------------
def repeat_previous_answer(env) -> int | None:
    hand = env.deck["player"]
    return int(env.deck.suits_idx[hand[-env.k]]) if len(hand) >= env.k else None


def autoencode_answer(env) -> int | None:
    hand = env.deck["system"]
    return int(env.deck.suits_idx[hand[-1]]) if int(env.mode) == 0 else None


CARD_TASKS = {
    "rl_jax/RepeatPreviousEasy-v0": (
        RepeatPreviousEasy,
        lambda env: popgym_cards(env.deck.idx),
        repeat_previous_answer,
    ),
    "rl_jax/RepeatFirstEasy-v0": (
        RepeatFirstEasy,
        lambda env: popgym_cards(env.deck.idx),
        lambda env: int(env.card),
    ),
    "rl_jax/CountRecallEasy-v0": (
        CountRecallEasy,
        lambda env: np.concatenate(
            [popgym_cards(env.value_deck.idx), popgym_cards(env.query_deck.idx)]
        ),
        lambda env: int(env.counts[env.query]),
    ),
    "rl_jax/AutoencodeEasy-v0": (
        AutoencodeEasy,
        lambda env: popgym_cards(env.deck.idx),
        autoencode_answer,
    ),
}


def popgym_episode(env_id: str, seed: int):
    """One of popgym's episodes: its start vector, first observation, the actions taken and
    ``(obs, reward, terminated, truncated)`` of every step."""
    make, start_of, answer_of = CARD_TASKS[env_id]
    env, rng = make(), np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed)
    start, first = start_of(env), one_hot_of(obs, env.observation_space)
    actions, steps = [], []
    for _ in range(1000):
        answer = answer_of(env)
        action = int(rng.integers(env.action_space.n))
        if answer is not None and rng.random() < 0.5:
            action = answer
        obs, reward, terminated, truncated, _ = env.step(action)
        actions.append(action)
        steps.append((one_hot_of(obs, env.observation_space), reward, terminated, truncated))
        if terminated or truncated:
            break
    return start, first, actions, steps


def assert_steps_agree(ours, theirs):
    """Our steps ``(obs, reward, terminated, truncated)`` equal popgym's: rewards as float32."""
    assert len(ours) == len(theirs)
    for t, ((obs, reward, terminated, truncated), expected) in enumerate(
        zip(ours, theirs, strict=True), 1
    ):
        np.testing.assert_array_equal(obs, expected[0], err_msg=f"step {t}")
        assert np.float32(reward) == np.float32(expected[1]), t
        assert (bool(terminated), bool(truncated)) == (expected[2], expected[3]), t


@pytest.mark.parametrize("env_id", CARD_TASKS)
def test_card_tasks_match_popgym_step_for_step(env_id):
    env = envs.make(env_id)
    reset_to, step = jax.jit(env.reset_to), jax.jit(env.step)
    rewards = []
    for seed in SEEDS:
        start, first, actions, expected = popgym_episode(env_id, seed)
        state, timestep = reset_to(start)
        np.testing.assert_array_equal(timestep.obs, first)
        ours = []
        for action in actions:
            state, timestep = step(jax.random.PRNGKey(0), state, jnp.int32(action))
            ours.append((timestep.obs, timestep.reward, timestep.terminated, timestep.truncated))
        assert_steps_agree(ours, expected)
        assert expected[-1][2]  # every episode ends by termination
        assert len(expected) < env.max_episode_steps  # and never reaches our limit
        rewards += [reward for _, reward, _, _ in expected]
    assert min(rewards) < 0 < max(rewards)


@pytest.mark.parametrize("env_id", CARD_TASKS)
def test_card_tasks_match_popgym_through_gymnasium(env_id):
    env = gymnasium.make(env_id)
    start, first, actions, expected = popgym_episode(env_id, seed=7)
    obs, _ = env.reset(seed=0, options={"state": start})
    np.testing.assert_array_equal(obs, first)
    assert_steps_agree([env.step(action)[:4] for action in actions], expected)


@pytest.mark.parametrize("env_id", CARD_TASKS)
def test_card_task_spaces_are_popgyms_one_hot(env_id):
    env, reference = envs.make(env_id), CARD_TASKS[env_id][0]()
    size = one_hot_of(reference.observation_space.sample(), reference.observation_space).size
    assert env.observation_space() == envs.Box(np.zeros(size), np.ones(size), (size,))
    assert env.action_space() == envs.Discrete(int(reference.action_space.n))


@pytest.mark.parametrize("env_id", CARD_TASKS)
def test_card_task_resets_deal_a_shuffled_deck(env_id):
    """Our own reset: a permutation of the pack per env, different across keys, and its first
    observation is the one ``reset_to`` gives for that deck."""
    env = envs.make(env_id)
    states, timesteps = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), 64))
    cards = np.asarray(states.cards)
    assert all(sorted(deck) == list(range(52)) for deck in cards)
    assert len({tuple(deck) for deck in cards}) == 64
    if hasattr(states, "queries"):  # CountRecall: the query deck follows
        cards = np.concatenate([cards, np.asarray(states.queries)], axis=1)
    _, again = jax.vmap(env.reset_to)(jnp.asarray(cards))
    np.testing.assert_array_equal(again.obs, timesteps.obs)


# ---- StatelessCartPole --------------------------------------------------------------------------
def popgym_cartpole(seed: int):
    """popgym's StatelessCartPole reset with ``seed``, its state rounded to float32 (given to
    both, as tests/envs/test_classic_control.py does for CartPole)."""
    env = PositionOnlyCartPoleEasy()
    env.reset(seed=seed)
    start = np.asarray(env.state, np.float32)
    env.state = start.astype(np.float64)
    return env, start


def test_stateless_cartpole_matches_popgym_on_random_episodes():
    env = envs.make("rl_jax/StatelessCartPoleEasy-v0")
    reset_to, step = jax.jit(env.reset_to), jax.jit(env.step)
    rng = np.random.default_rng(0)
    for seed in range(10):
        reference, start = popgym_cartpole(seed)
        state, timestep = reset_to(start)
        np.testing.assert_allclose(timestep.obs, start[[0, 2]])
        for _ in range(300):
            action = int(rng.integers(2))
            obs, reward, terminated, truncated, _ = reference.step(action)
            state, timestep = step(jax.random.PRNGKey(0), state, jnp.int32(action))
            np.testing.assert_allclose(timestep.obs, obs, rtol=RTOL, atol=ATOL)
            assert timestep.reward == np.float32(reward)
            assert (bool(timestep.terminated), bool(timestep.truncated)) == (terminated, truncated)
            if terminated or truncated:
                break
        assert terminated


def test_stateless_cartpole_truncates_at_200_like_popgym():
    """A balancing controller (reading popgym's full state) keeps the pole up for 200 steps; ours
    is re-synced to popgym's state before each step (the upright pole amplifies rounding), with
    its own step counter, and must truncate on the same step."""
    env = envs.make("rl_jax/StatelessCartPoleEasy-v0")

    @jax.jit
    def synced_step(vector, time, action):
        state = env.reset_to(vector)[0].replace(time=time)
        return env.step(jax.random.PRNGKey(0), state, action)

    reference, _ = popgym_cartpole(3)
    time, total = jnp.int32(0), 0.0
    for t in range(1, 201):
        x, x_dot, theta, theta_dot = reference.state
        action = int(theta + 0.5 * theta_dot + 0.01 * x + 0.1 * x_dot > 0)
        start = np.asarray(reference.state, np.float32)
        reference.state = start.astype(np.float64)
        obs, reward, terminated, truncated, _ = reference.step(action)
        state, timestep = synced_step(start, time, jnp.int32(action))
        time, total = state.time, total + float(timestep.reward)
        np.testing.assert_allclose(timestep.obs, obs, rtol=RTOL, atol=ATOL)
        assert timestep.reward == np.float32(reward) and not terminated
        assert bool(timestep.truncated) == truncated == (t == 200)
    assert total == pytest.approx(1.0, abs=1e-5)


def test_stateless_cartpole_spaces_are_popgyms():
    env, reference = envs.make("rl_jax/StatelessCartPoleEasy-v0"), PositionOnlyCartPoleEasy()
    space = reference.observation_space
    assert env.observation_space() == envs.Box(space.low, space.high, space.shape)
    assert env.action_space() == envs.Discrete(int(reference.action_space.n))


# ---- registration -------------------------------------------------------------------------------
POPGYM_IDS = [*CARD_TASKS, "rl_jax/StatelessCartPoleEasy-v0"]


@pytest.mark.parametrize("env_id", POPGYM_IDS)
def test_registered_with_gymnasium_and_passes_check_env(env_id):
    spec = gymnasium.spec(env_id)
    limit = envs.make(env_id).max_episode_steps
    assert spec.max_episode_steps == registry.max_episode_steps(env_id) == limit
    assert spec.vector_entry_point is not None
    drawn = env_id == "rl_jax/StatelessCartPoleEasy-v0"  # the card tasks draw nothing
    env = gymnasium.make(env_id, render_mode="rgb_array" if drawn else None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=not drawn)
    assert not [str(w.message) for w in caught]


def test_make_vec_restarts_a_finished_deck():
    """gymnasium's NEXT_STEP autoreset on a card task: the step after the 51st (terminal) one
    starts a new episode (reward 0, no flags), and the next one is scored again."""
    vec = gymnasium.make_vec(
        "rl_jax/RepeatFirstEasy-v0", num_envs=3, vectorization_mode="vector_entry_point"
    )
    vec.reset(seed=0)
    rewards, terminated = [], []
    for _ in range(53):
        _, reward, done, truncated, _ = vec.step(np.zeros(3, np.int64))
        rewards.append(reward)
        terminated.append(done)
        assert not truncated.any()
    assert [t for t in range(53) if terminated[t].all()] == [50]
    np.testing.assert_array_equal(rewards[51], 0.0)
    assert np.all(np.abs(rewards[52]) == np.float32(1 / 51))
