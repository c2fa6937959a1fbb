"""The preprocessing wrappers against gymnasium's own where it has one, driven on the same
dynamics (our CartPole through our gymnasium adapter, or a small game of lives and flickering
sprites shown to gymnasium's ``AtariPreprocessing`` as an ALE env), and against plain Python
references of their semantics otherwise."""

import sys
import types

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import struct
from gymnasium.wrappers import (
    AtariPreprocessing,
    ClipReward,
    FrameStackObservation,
    RepeatAction,
    StickyAction,
    TransformReward,
)

from rl_jax import envs
from rl_jax.envs.core import batched
from rl_jax.envs.core import preprocessing as pre
from rl_jax.envs.core.core import Environment, EnvParams, EnvState
from rl_jax.envs.core.probes import FatalIllegalActions

# ---- a game with lives: the player walks a row; pushing into the left wall costs a life ---------
WIDTH = 8
NOOP, RIGHT, LEFT = 0, 1, 2


@struct.dataclass
class GameState(EnvState):
    x: jax.Array  # [] int32, the player's column
    lives: jax.Array  # [] int32


class LivesGame(Environment):
    """One step is one frame. The frame shows the player in row 0 and a sprite that flickers
    (row 2 on even frames, row 3 on odd ones), so that max-pooling two frames shows both. The
    reward, ``(x - 3) / 2``, is fractional and of either sign; the game ends with the last of 3
    lives, or is cut after 58 frames (not a multiple of 4: a skipped step is cut short)."""

    max_episode_steps = 58

    @property
    def default_params(self):
        return EnvParams()

    def observation_space(self, params=None):
        return envs.Box(0, 255, (WIDTH, WIDTH), np.uint8)

    def action_space(self, params=None):
        return envs.Discrete(3)

    def empty_info(self):
        return {pre.LIVES: jnp.zeros((), jnp.int32)}

    def frame(self, state):
        rows, cols = jnp.arange(WIDTH)[:, None], jnp.arange(WIDTH)[None, :]
        even = state.time % 2 == 0
        player = (rows == 0) & (cols == state.x)
        sprite_even = even & (rows == 2) & (cols == state.time % WIDTH)
        sprite_odd = ~even & (rows == 3) & (cols == (3 * state.time) % WIDTH)
        return (200 * player + 100 * sprite_even + 50 * sprite_odd).astype(jnp.uint8)

    def reset_env(self, key, params):
        state = GameState(time=jnp.int32(0), x=jax.random.randint(key, (), 2, 6), lives=3)
        return state, self.frame(state)

    def reset(self, key, params=None):
        state, ts = super().reset(key, params)
        return state, ts._replace(info={pre.LIVES: jnp.asarray(state.lives, jnp.int32)})

    def step_env(self, key, state, action, params):
        action = jnp.asarray(action, jnp.int32)
        lost = (state.x == 0) & (action == LEFT)
        step = jnp.where(action == RIGHT, 1, jnp.where(action == LEFT, -1, 0))
        x = jnp.where(lost, WIDTH // 2, jnp.clip(state.x + step, 0, WIDTH - 1))
        lives = jnp.asarray(state.lives - lost.astype(jnp.int32), jnp.int32)
        state = GameState(time=state.time + 1, x=x, lives=lives)
        reward = (x - 3) * 0.5
        return state, self.frame(state), reward, lives == 0, {pre.LIVES: lives}


class GameAsALE(gymnasium.Env):
    """The same game as gymnasium's ``AtariPreprocessing`` sees an ALE env: one frame a step,
    the screen and the lives read through ``.ale``. ``reset(options={"key": key})`` starts it
    from the same jax key as ours."""

    def __init__(self, game):
        self.game = game
        self._frameskip = 1
        self.observation_space = gymnasium.spaces.Box(0, 255, (WIDTH, WIDTH), np.uint8)
        self.action_space = gymnasium.spaces.Discrete(3)
        self._reset, self._step = jax.jit(game.reset), jax.jit(game.step)

    @property
    def ale(self):
        return self

    def get_action_meanings(self):
        return ["NOOP", "RIGHT", "LEFT"]

    def lives(self):
        return int(self.state.lives)

    def getScreenGrayscale(self, out):  # noqa: N802  (the ALE's name)
        out[...] = self.screen

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.state, ts = self._reset(options["key"])
        self.screen = np.asarray(ts.obs)
        return self.screen.copy(), {"lives": self.lives()}

    def step(self, action):
        self.state, ts = self._step(jax.random.key(0), self.state, jnp.int32(action))
        self.screen = np.asarray(ts.obs)
        flags = bool(ts.terminated), bool(ts.truncated)
        return self.screen.copy(), float(ts.reward), *flags, {"lives": self.lives()}


@pytest.fixture
def fake_cv2(monkeypatch):
    """``AtariPreprocessing`` resizes with OpenCV, which is not a dependency here; at the
    frame's own size ``cv2.resize`` is the identity, which this stands in for."""

    def resize(image, size, interpolation):
        assert image.shape == size[::-1]
        return image.copy()

    module = types.SimpleNamespace(resize=resize, INTER_AREA=3)
    monkeypatch.setitem(sys.modules, "cv2", module)


def atari(game, **kwargs):
    return AtariPreprocessing(
        GameAsALE(game), noop_max=0, frame_skip=4, screen_size=WIDTH, scale_obs=False, **kwargs
    )


def actions_for(seed, size, left=0.6):
    return np.random.default_rng(seed).choice(3, size, p=[(1 - left) / 2, (1 - left) / 2, left])


def rollout(env, key, actions, start=None):
    """Our env stepped with ``actions`` until its episode ends: the reset timestep, then each
    step's (state, timestep), on host."""
    reset = jax.jit(env.reset) if start is None else jax.jit(env.reset_to)
    step = jax.jit(env.step)
    state, first = reset(key if start is None else start)
    out = []
    for t, action in enumerate(actions):
        state, ts = step(jax.random.fold_in(key, t), state, jnp.asarray(action))
        out.append(jax.device_get((state, ts)))
        if ts.terminated or ts.truncated:
            break
    return jax.device_get(first), out


def gym_rollout(env, actions, **reset):
    """A gymnasium env stepped with ``actions`` until its episode ends: the reset observation,
    then each step's ``(obs, reward, terminated, truncated, info)``."""
    first, _ = env.reset(**reset)
    out = []
    for action in actions:
        out.append(env.step(int(action)))
        if out[-1][2] or out[-1][3]:
            break
    return first, out


# ---- frame skip ---------------------------------------------------------------------------------
def skip_reference(game, key, actions, skip=4):
    """Frame skip by hand over the bare game: per step the summed reward, the flags, and the
    max of the last two frames of the step (the last alone when only one was played)."""
    step = jax.jit(game.step)
    state, _ = jax.jit(game.reset)(key)
    out = []
    for action in actions:
        frames, reward = [], 0.0
        for _ in range(skip):
            state, ts = step(jax.random.key(0), state, jnp.int32(action))
            frames.append(np.asarray(ts.obs))
            reward += float(ts.reward)
            if ts.terminated or ts.truncated:
                break
        obs = np.maximum(frames[-1], frames[-2]) if len(frames) > 1 else frames[-1]
        out.append((obs, reward, bool(ts.terminated), bool(ts.truncated), len(frames)))
        if ts.terminated or ts.truncated:
            break
    return out


@pytest.mark.parametrize("left", [0.8, 0.1], ids=["game-over", "time-limit"])
def test_frame_skip_against_atari_preprocessing_and_by_hand(fake_cv2, left):
    game, key = LivesGame(), jax.random.key(1)
    actions = actions_for(0, 20, left)  # the game ends on a step's first frame
    first, ours = rollout(pre.FrameSkip(game, 4), key, actions)
    reference = skip_reference(game, key, actions)
    gym_first, theirs = gym_rollout(atari(game), actions, options={"key": key})
    np.testing.assert_array_equal(first.obs, gym_first)
    assert len(ours) == len(reference) == len(theirs)
    stopped_early = False
    for (_, ts), (obs, reward, terminated, truncated, frames), gym in zip(
        ours, reference, theirs, strict=True
    ):
        np.testing.assert_array_equal(ts.obs, obs)
        np.testing.assert_allclose(ts.reward, reward, rtol=1e-6)
        assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated)
        assert (gym[2], gym[3]) == (terminated, truncated)
        np.testing.assert_allclose(gym[1], reward, rtol=1e-6)
        assert int(ts.info[pre.LIVES]) == gym[4]["lives"]
        if not (terminated or truncated):  # gymnasium's pool misses an episode's last frame
            np.testing.assert_array_equal(gym[0], obs)
        stopped_early |= frames < 4
    assert stopped_early  # the game's end, or its 58-frame limit, falls inside a step
    # The pool shows both flickering sprites (rows 2 and 3), where the last frame has one.
    assert np.any(ours[0][1].obs[2]) and np.any(ours[0][1].obs[3])


def test_frame_skip_without_pooling_is_gymnasiums_repeat_action():
    start = np.array([0.01, 0.02, 0.03, -0.01], np.float32)
    actions = actions_for(5, 60, left=0.0) % 2
    env = pre.FrameSkip(envs.make("rl_jax/CartPole-v1"), 3, max_pool=False)
    _, ours = rollout(env, jax.random.key(0), actions, start=start)
    _, theirs = gym_rollout(
        RepeatAction(gymnasium.make("rl_jax/CartPole-v1"), 3), actions, options={"state": start}
    )
    assert len(ours) == len(theirs) and bool(ours[-1][1].terminated)
    for (_, ts), (obs, reward, terminated, truncated, _) in zip(ours, theirs, strict=True):
        np.testing.assert_allclose(ts.obs, obs, rtol=1e-6, atol=1e-7)
        assert (float(ts.reward), bool(ts.terminated), bool(ts.truncated)) == (
            reward,
            terminated,
            truncated,
        )


def test_frame_skip_counts_its_time_limit_in_agent_steps():
    game = LivesGame()
    env = pre.FrameSkip(game, 4)
    assert env.max_episode_steps == 15  # 58 frames
    env.max_episode_steps = 10
    assert game.max_episode_steps == 40


# ---- episodic life ------------------------------------------------------------------------------
def test_episodic_life_terminates_as_atari_preprocessing_does_on_a_lost_life(fake_cv2):
    game, key = LivesGame(), jax.random.key(1)
    actions = actions_for(6, 20, left=0.9)
    _, ours = rollout(pre.FrameSkip(pre.EpisodicLife(game), 4), key, actions)
    _, theirs = gym_rollout(atari(game, terminal_on_life_loss=True), actions, options={"key": key})
    assert len(ours) == len(theirs) and bool(ours[-1][1].terminated)
    assert int(ours[-1][1].info[pre.LIVES]) == 2  # the first life lost, the game not over
    for (_, ts), (obs, reward, terminated, truncated, info) in zip(ours, theirs, strict=True):
        assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated)
        np.testing.assert_allclose(ts.reward, reward, rtol=1e-6)
        assert int(ts.info[pre.LIVES]) == info["lives"]
        if not terminated:
            np.testing.assert_array_equal(ts.obs, obs)


def autoreset_step(env, key, state, action):
    """Same-step autoreset through ``reset_after``: what AutoReset does with the hook."""
    step_key, reset_key = jax.random.split(key)
    next_state, ts = env.step(step_key, state, action)
    reset_state, reset_ts = pre.reset_after(env, reset_key, next_state, ts)
    done = ts.terminated | ts.truncated
    state = jax.tree.map(lambda a, b: jnp.where(done, a, b), reset_state, next_state)
    obs = jnp.where(done, reset_ts.obs, ts.obs)
    return state, ts._replace(obs=obs, info={**ts.info, "final_obs": ts.obs})


def autoreset_wrapper_step(env, flatten):
    """``envs.AutoReset``'s own step (around ``FlattenObservation`` with ``flatten``), with the
    observations shown in the game's shape."""
    wrapped = envs.AutoReset(envs.FlattenObservation(env) if flatten else env)

    def step(key, state, action):
        state, ts = wrapped.step(key, state, action)
        info = {**ts.info, "final_obs": ts.info["final_obs"].reshape(WIDTH, WIDTH)}
        return state, ts._replace(obs=ts.obs.reshape(WIDTH, WIDTH), info=info)

    return step


@pytest.mark.parametrize("autoreset", ["by hand", "AutoReset", "AutoReset(FlattenObservation)"])
def test_episodic_life_goes_on_after_a_lost_life_and_restarts_after_the_game(autoreset):
    game, key = LivesGame(), jax.random.key(2)
    env = pre.EpisodicLife(game)
    actions = actions_for(7, 120, left=0.7)
    if autoreset == "by hand":
        step = jax.jit(lambda key, state, action: autoreset_step(env, key, state, action))
    else:
        step = jax.jit(autoreset_wrapper_step(env, flatten=autoreset != "AutoReset"))
    state, _ = env.reset(key)
    # By hand: the bare game played straight through, one game after another.
    bare_step = jax.jit(game.step)
    bare, _ = game.reset(key)
    lives, games, losses = 3, 0, 0
    for t, action in enumerate(actions):
        state, ts = step(jax.random.fold_in(key, t), state, jnp.int32(action))
        bare, expected = bare_step(key, bare, jnp.int32(action))
        np.testing.assert_array_equal(ts.info["final_obs"], expected.obs)
        np.testing.assert_allclose(ts.reward, expected.reward)
        lost = int(expected.info[pre.LIVES]) < lives
        game_over = bool(expected.terminated | expected.truncated)
        assert bool(ts.terminated) == (lost or bool(expected.terminated))
        assert bool(ts.truncated) == bool(expected.truncated)
        if game_over:  # a new game, as the bare game's own reset from the hook's key
            games += 1
            start_state, start = game.reset(jax.random.split(jax.random.fold_in(key, t))[1])
            np.testing.assert_array_equal(ts.obs, start.obs)
            assert int(state.time) == 0 and int(state.lives) == 3
            bare, lives = start_state, 3
        else:  # the same game goes on: the next episode starts where the life was lost
            np.testing.assert_array_equal(ts.obs, expected.obs)
            assert int(state.time) == int(bare.time)
            losses += lost
            lives = int(expected.info[pre.LIVES])
    assert games >= 2 and losses >= 4


def test_episodic_life_needs_lives():
    with pytest.raises(TypeError, match="lives"):
        pre.EpisodicLife(envs.make("rl_jax/CartPole-v1"))


# ---- sticky actions -----------------------------------------------------------------------------
class Uniforms:
    """Stands in for gymnasium's ``np_random``: hands out given uniforms in order."""

    def __init__(self, values):
        self.values = list(values)

    def uniform(self):
        return self.values.pop(0)

    def integers(self, low, high):  # the number of repeats, always 1 here
        assert (low, high) == (1, 2)
        return 1


def test_sticky_actions_match_gymnasiums_sticky_action_draw_for_draw():
    start = np.array([0.0, 0.1, -0.02, 0.05], np.float32)
    actions = actions_for(8, 200, left=0.0) % 2
    key = jax.random.key(5)
    env = pre.StickyActions(envs.make("rl_jax/CartPole-v1"), 0.5)
    _, ours = rollout(env, key, actions, start=start)
    # The uniform our wrapper draws at step t, from the first half of that step's key.
    draws = [
        float(jax.random.uniform(jax.random.split(jax.random.fold_in(key, t))[0]))
        for t in range(len(ours))
    ]
    theirs = StickyAction(gymnasium.make("rl_jax/CartPole-v1"), repeat_action_probability=0.5)
    theirs.reset(options={"state": start})
    theirs.np_random = Uniforms(draws[1:])  # gymnasium draws none before the first action
    stuck = 0
    for t, (state, ts) in enumerate(ours):
        obs, reward, terminated, truncated, _ = theirs.step(int(actions[t]))
        np.testing.assert_allclose(ts.obs, obs, rtol=1e-6, atol=1e-7)
        assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated)
        assert int(state.last_action) == int(theirs.last_action)
        stuck += int(state.last_action) != int(actions[t])
    assert bool(ours[-1][1].terminated) and stuck >= 3


@pytest.mark.parametrize("probability", [0.25, 0.1])
def test_sticky_action_rates(probability):
    """The executed action is the previous one with the given probability, and after a reset
    the first action is always the agent's, or stuck to ``reset_action`` as in the ALE."""
    cartpole, num_envs, steps = envs.make("rl_jax/CartPole-v1"), 20000, 6
    for reset_action in (None, 0):
        env = pre.StickyActions(cartpole, probability, reset_action=reset_action)
        keys = jax.random.split(jax.random.key(int(probability * 100)), num_envs)
        previous, stuck = jax.device_get(sticky_run(env, keys, steps))
        first_rate = stuck[0].mean()
        if reset_action is None:
            assert first_rate == 0.0
        else:
            assert abs(first_rate - probability) < 5 * np.sqrt(probability / num_envs)
        # Later steps: stuck only where the previous action differs from the one chosen.
        chosen = (np.arange(steps) % 2 == 0)[:, None]
        differs = previous[1:] != chosen[1:]
        rate = stuck[1:][differs].mean()
        assert abs(rate - probability) < 5 * np.sqrt(probability / differs.sum())
        assert not stuck[1:][~differs].any()


def sticky_run(env, keys, steps):
    """Each env's previous action before each step, and whether the executed action differs
    from the chosen one, the agents choosing 1, 0, 1, ...: ``[steps, num_envs]`` each."""

    def body(state, t):
        chosen = jnp.full(keys.shape[:1], t % 2 == 0, jnp.int32)
        previous = state.last_action
        keys_t = jax.vmap(jax.random.fold_in, (0, None))(keys, t)
        state, _ = jax.vmap(env.step)(keys_t, state, chosen)
        return state, (previous, state.last_action != chosen)

    @jax.jit
    def run(keys):
        state, _ = jax.vmap(env.reset)(keys)
        return jax.lax.scan(body, state, jnp.arange(steps))[1]

    return run(keys)


def test_sticky_actions_check_their_settings():
    cartpole = envs.make("rl_jax/CartPole-v1")
    with pytest.raises(ValueError, match=r"\[0, 1\)"):
        pre.StickyActions(cartpole, 1.0)
    with pytest.raises(ValueError, match="reset_action"):
        pre.StickyActions(cartpole, 0.25, reset_action=2)


# ---- frame stack --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "padding",
    ["reset", "zero", np.array([1.0, -1.0, 0.0, 2.0], np.float32)],
    ids=["reset", "zero", "custom"],
)
def test_frame_stack_against_gymnasium_over_two_episodes(padding):
    starts = [np.array([0.0, 0.3, 0.05, 0.2], np.float32), np.array([0.02, 0.0, -0.1, 0.0])]
    actions = actions_for(9, 100, left=0.0) % 2
    ours = pre.FrameStack(envs.make("rl_jax/CartPole-v1"), 3, padding=padding)
    theirs = FrameStackObservation(gymnasium.make("rl_jax/CartPole-v1"), 3, padding_type=padding)
    assert ours.observation_space().to_gymnasium() == theirs.observation_space
    for start in starts:  # the second episode starts padded again, nothing left of the first
        first, steps = rollout(ours, jax.random.key(0), actions, start=start.astype(np.float32))
        gym_obs, _ = theirs.reset(options={"state": start})
        np.testing.assert_allclose(first.obs, gym_obs, rtol=1e-6)
        for t, (_, ts) in enumerate(steps):
            obs, _, terminated, truncated, _ = theirs.step(int(actions[t]))
            np.testing.assert_allclose(ts.obs, obs, rtol=1e-6, atol=1e-7)
            assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated)
        assert bool(steps[-1][1].terminated)


def test_frame_stack_on_a_trailing_axis_and_under_autoreset():
    game, key = LivesGame(), jax.random.key(4)
    leading = pre.FrameStack(game, 4)
    trailing = pre.FrameStack(game, 4, axis=-1)
    assert trailing.observation_space().shape == (WIDTH, WIDTH, 4)
    assert trailing.observation_space().dtype == np.uint8
    actions = actions_for(10, 12, left=0.0)
    _, lead = rollout(leading, key, actions)
    _, trail = rollout(trailing, key, actions)
    for (_, a), (_, b) in zip(lead, trail, strict=True):
        np.testing.assert_array_equal(np.moveaxis(a.obs, 0, -1), b.obs)
    # Under AutoReset: the finished episode's stack in final_obs, a fresh padded one in obs.
    env = envs.AutoReset(leading)
    state, ts = env.reset(key)
    step = jax.jit(env.step)
    for t in range(60):
        state, ts = step(jax.random.fold_in(key, t), state, jnp.int32(NOOP))
        if ts.truncated:
            break
    assert bool(ts.truncated)
    np.testing.assert_array_equal(ts.info["final_obs"][1:], lead_frames_after(game, key, t + 1))
    assert all(np.array_equal(ts.obs[i], ts.obs[-1]) for i in range(3))
    with pytest.raises(TypeError, match="inside AutoReset"):
        pre.FrameStack(envs.AutoReset(game), 4)


def lead_frames_after(game, key, steps):
    """The bare game's last three frames after ``steps`` NOOPs from the reset of ``key``."""
    state, ts = game.reset(key)
    frames = [np.asarray(ts.obs)]
    for _ in range(steps):
        state, ts = game.step(key, state, jnp.int32(NOOP))
        frames.append(np.asarray(ts.obs))
    return np.stack(frames[-3:])


def test_frame_stack_restarts_its_stack_after_a_lost_life():
    game, key = LivesGame(), jax.random.key(2)
    env = pre.FrameStack(pre.EpisodicLife(game), 2)
    state, _ = env.reset(key)
    step = jax.jit(lambda key, state, action: autoreset_step(env, key, state, action))
    for t in range(40):
        state, ts = step(jax.random.fold_in(key, t), state, jnp.int32(LEFT))
        if ts.terminated:
            break
    assert bool(ts.terminated) and int(ts.info[pre.LIVES]) == 2
    # The game goes on: the new stack is the frame the life was lost on, twice.
    np.testing.assert_array_equal(ts.obs, np.stack([ts.info["final_obs"][-1]] * 2))
    assert int(state.env_state.lives) == 2 and int(state.time) == t + 1


# ---- rewards ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "ours, theirs",
    [
        (pre.ClipReward, lambda env: ClipReward(env, -1.0, 1.0)),
        (lambda env: pre.ClipReward(env, -0.5, 1.5), lambda env: ClipReward(env, -0.5, 1.5)),
        (pre.SignReward, lambda env: TransformReward(env, np.sign)),
    ],
    ids=["clip", "clip-bounds", "sign"],
)
def test_reward_transforms_against_gymnasium(ours, theirs):
    game, key = LivesGame(), jax.random.key(6)
    actions = [LEFT] * 6 + [RIGHT] * 9 + [LEFT] * 4  # every column, and a life lost
    _, steps = rollout(ours(game), key, actions)
    _, reference = gym_rollout(theirs(GameAsALE(game)), actions, options={"key": key})
    rewards = np.array([float(ts.reward) for _, ts in steps])
    np.testing.assert_allclose(rewards, [step[1] for step in reference], rtol=1e-6)
    assert len(set(rewards)) >= 3  # the game's rewards span both signs


# ---- all of them together -----------------------------------------------------------------------
def atari_stack(game):
    env = pre.FrameSkip(pre.EpisodicLife(pre.StickyActions(game, 0.25, reset_action=NOOP)), 4)
    return pre.FrameStack(pre.SignReward(env), 4, axis=-1)


def test_the_atari_stack_jits_vmaps_and_keeps_its_structure():
    env = atari_stack(LivesGame())
    assert env.observation_space().shape == (WIDTH, WIDTH, 4)
    keys = jax.random.split(jax.random.key(7), 16)
    state, first = jax.vmap(env.reset)(keys)

    @jax.jit
    def run(state):
        def body(state, t):
            keys_t = jax.vmap(jax.random.fold_in, (0, None))(keys, t)
            actions = jax.vmap(lambda k: jax.random.randint(k, (), 0, 3))(keys_t)
            step = jax.vmap(lambda key, state, action: autoreset_step(env, key, state, action))
            return step(keys_t, state, actions)

        return jax.lax.scan(body, state, jnp.arange(30))

    state, ts = run(state)
    assert ts.obs.shape == (30, 16, WIDTH, WIDTH, 4) and ts.obs.dtype == np.uint8
    assert set(np.unique(ts.reward)) <= {-1.0, 0.0, 1.0}
    assert np.any(ts.terminated) and np.any(ts.info[pre.LIVES] < 3)
    one = jax.tree.map(lambda x: x[0], first)
    _, stepped = env.step(keys[0], jax.tree.map(lambda x: x[0], state), jnp.int32(0))
    assert jax.tree.structure(one) == jax.tree.structure(stepped)
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(stepped), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype


# ---- action masks -------------------------------------------------------------------------------
def test_the_fatal_illegal_actions_env_reports_its_mask():
    import rl_jax.envs.core.probes  # noqa: F401  (registers the probe ids)

    env = envs.make("rl_jax/ProbeFatalIllegalActions-v0")
    assert pre.has_action_mask(env) and not pre.has_action_mask(envs.make("rl_jax/CartPole-v1"))
    keys = jax.random.split(jax.random.key(8), 30000)
    state, first = jax.vmap(env.reset)(keys)
    mask = np.asarray(first.info[pre.ACTION_MASK])
    np.testing.assert_array_equal(mask, np.asarray(first.obs) > 0.5)
    assert mask.any(axis=1).all()
    # Uniform over the 15 non-empty subsets of 4 actions.
    subsets = mask @ (1 << np.arange(4))
    counts = np.bincount(subsets, minlength=16)
    assert counts[0] == 0 and np.all(np.abs(counts[1:] / len(keys) - 1 / 15) < 0.006)
    # The highest legal action, then one illegal action: paid, and fatal.
    best = mask.shape[1] - 1 - np.argmax(mask[:, ::-1], axis=1)
    state, ts = jax.vmap(env.step)(keys, state, jnp.asarray(best, jnp.int32))
    np.testing.assert_allclose(ts.reward, (best + 1) / 4)
    assert not ts.terminated.any()
    np.testing.assert_allclose(np.mean(ts.reward), env.best_reward(), atol=0.01)
    mask = np.asarray(ts.info[pre.ACTION_MASK])
    np.testing.assert_array_equal(mask, np.asarray(ts.obs) > 0.5)
    has_illegal = ~mask.all(axis=1)
    illegal = np.argmin(mask, axis=1)
    _, ts = jax.vmap(env.step)(keys, state, jnp.asarray(illegal, jnp.int32))
    np.testing.assert_array_equal(ts.terminated, has_illegal)
    np.testing.assert_allclose(ts.reward[has_illegal], -10.0)


def test_wrappers_pass_the_mask_on():
    env = FatalIllegalActions()
    for wrapped in (pre.FrameStack(env, 2), pre.FrameSkip(env, 2), pre.StickyActions(env, 0.1)):
        assert pre.has_action_mask(wrapped)
        state, ts = wrapped.reset(jax.random.key(0))
        np.testing.assert_array_equal(ts.info[pre.ACTION_MASK], state_mask(state))
    info = {"other": jnp.zeros(())}
    np.testing.assert_array_equal(pre.action_mask(info, 3, (2,)), np.ones((2, 3), bool))


def state_mask(state):
    while not hasattr(state, "legal"):
        state = state.env_state
    return state.legal


def test_autoreset_takes_the_new_episodes_mask_and_keeps_the_ended_ones():
    env = FatalIllegalActions()
    wrapped = envs.AutoReset(env)
    assert pre.has_action_mask(wrapped)
    empty = wrapped.empty_info()
    np.testing.assert_array_equal(empty["final_action_mask"], empty[pre.ACTION_MASK])
    keys = jax.random.split(jax.random.key(3), 64)
    state, first = jax.vmap(wrapped.reset)(keys)
    np.testing.assert_array_equal(first.info["final_action_mask"], first.info[pre.ACTION_MASK])
    # Half the envs take an illegal action (their episode ends), half a legal one.
    mask = np.asarray(first.info[pre.ACTION_MASK])
    illegal = np.argmin(mask, axis=1)
    legal = np.argmax(mask, axis=1)
    ending = ~mask.all(axis=1) & (np.arange(64) % 2 == 0)
    actions = jnp.asarray(np.where(ending, illegal, legal), jnp.int32)
    step_keys = jax.random.split(jax.random.key(4), 64)
    for step in (jax.vmap(wrapped.step), lambda k, s, a: batched.autoreset_step(env, k[0], s, a)):
        _, ts = step(step_keys, state, actions)
        np.testing.assert_array_equal(ts.terminated, ending)
        # The mask goes with the obs: the new episode's where one ended, as obs does ...
        np.testing.assert_array_equal(ts.info[pre.ACTION_MASK], np.asarray(ts.obs) > 0.5)
        # ... and the ended one's goes with final_obs.
        final_mask = np.asarray(ts.info["final_action_mask"])
        np.testing.assert_array_equal(final_mask, np.asarray(ts.info["final_obs"]) > 0.5)
        same = ~ending
        np.testing.assert_array_equal(final_mask[same], np.asarray(ts.info[pre.ACTION_MASK])[same])


def test_batched_autoreset_continues_the_game_after_a_lost_life():
    game = LivesGame()
    env = pre.EpisodicLife(game)
    keys = jax.random.split(jax.random.key(5), 8)
    state, first = jax.vmap(env.reset)(keys)
    # Walk every player into the left wall: each loses a life, and its game goes on.
    step = jax.jit(lambda key, state, action: batched.autoreset_step(env, key, state, action))
    lefts = jnp.full(8, LEFT, jnp.int32)
    lost = np.zeros(8, bool)
    for t in range(WIDTH):
        state, ts = step(jax.random.key(t), state, lefts)
        lost |= np.asarray(ts.terminated)
        assert not (np.asarray(ts.terminated) & (np.asarray(state.lives) == 3)).any()
    assert lost.all()
    # The games went on: no game restarted its clock or its lives.
    np.testing.assert_array_equal(state.env_state.time, WIDTH)
    assert (np.asarray(state.lives) < 3).all()


def test_a_mask_that_does_not_fit_is_refused():
    class WrongMask(FatalIllegalActions):
        def empty_info(self):
            return {pre.ACTION_MASK: jnp.ones((3,), jnp.bool_)}

    with pytest.raises(TypeError, match="bool \\[4\\]"):
        pre.has_action_mask(WrongMask())
