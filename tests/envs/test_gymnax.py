"""gymnax envs through envs.from_gymnax: step for step against gymnax's own step on the same keys
(terminated and truncated apart, no reset inside), the rl_jax/*-MinAtar ids through gymnasium, and
the MinAtar games against the numpy `minatar` package with sticky actions off: Breakout from the
same start, SpaceInvaders, and Freeway and Asterix given the same random draws (gymnax's, fed to
numpy's game in place of its generator), step for step (docs/using_envs.md, "MinAtar through
gymnax", lists where the two differ)."""

import functools
import subprocess
import sys
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from rl_jax import envs
from rl_jax.envs.core import registry

gymnax = pytest.importorskip("gymnax")
minatar = pytest.importorskip("minatar")

GAMES = ["Breakout", "SpaceInvaders", "Asterix", "Freeway"]
IDS = [f"rl_jax/{game}-MinAtar" for game in GAMES]


# ---- against gymnax itself ----------------------------------------------------------------------
def _rollouts(name: str, limit: int, steps: int, n_envs: int, seed: int):
    """Ours and gymnax's ``step`` driven by the same keys and actions, vmapped and jitted.

    Ours resets (with the reset key gymnax's step draws) where an episode ended, as AutoReset
    would; gymnax resets inside its step. Per step: ours (pre-reset obs, reward, terminated,
    truncated, obs after any reset) and gymnax's (``final_observation``, reward, terminated,
    truncated, obs)."""
    env = envs.from_gymnax(name, max_steps_in_episode=limit)
    gymnax_env, gymnax_params = gymnax.make(name)
    gymnax_params = gymnax_params.replace(max_steps_in_episode=limit)
    n_actions = env.action_space().n

    def one_env(key):
        key, reset_key = jax.random.split(key)
        state, first = env.reset(reset_key)
        gymnax_obs, gymnax_state = gymnax_env.reset(reset_key, gymnax_params)

        def step(carry, key):
            state, gymnax_state = carry
            action_key, step_key = jax.random.split(key)
            action = jax.random.randint(action_key, (), 0, n_actions)
            state, ts = env.step(step_key, state, action)
            done = ts.terminated | ts.truncated
            reset_state, reset_ts = env.reset(jax.random.split(step_key)[1])
            state = jax.tree.map(lambda r, s: jnp.where(done, r, s), reset_state, state)
            obs_after = jnp.where(done, reset_ts.obs, ts.obs)
            g_obs, gymnax_state, g_reward, g_term, g_trunc, info = gymnax_env.step(
                step_key, gymnax_state, action, gymnax_params
            )
            ours = (ts.obs, ts.reward, ts.terminated, ts.truncated, obs_after)
            theirs = (info["final_observation"], g_reward, g_term, g_trunc, g_obs)
            return (state, gymnax_state), (ours, theirs)

        keys = jax.random.split(key, steps)
        _, (ours, theirs) = jax.lax.scan(step, (state, gymnax_state), keys)
        return (first.obs, gymnax_obs), ours, theirs

    keys = jax.random.split(jax.random.key(seed), n_envs)
    return jax.jit(jax.vmap(one_env))(keys)


NAMES = ["obs", "reward", "terminated", "truncated", "obs after the reset"]


@pytest.mark.parametrize("game", GAMES)
def test_same_keys_give_gymnax_episodes_step_for_step(game):
    # A short limit, so that the rollouts hold truncations as well as terminations.
    (first, gymnax_first), ours, theirs = _rollouts(f"{game}-MinAtar", 25, 300, 8, seed=1)
    np.testing.assert_array_equal(first, gymnax_first)
    for mine, reference, what in zip(ours, theirs, NAMES, strict=True):
        assert mine.dtype == (jnp.bool_ if what in ("terminated", "truncated") else jnp.float32)
        np.testing.assert_array_equal(mine, reference, err_msg=what)
    terminated, truncated = np.asarray(ours[2]), np.asarray(ours[3])
    assert truncated.sum() > 0  # both ends, apart, in the compared rollouts
    if game != "Freeway":  # Freeway's game never ends before its limit
        assert terminated.sum() > 0


def test_default_limits_are_gymnax_and_truncation_is_not_termination():
    for env_id in IDS:
        env = envs.make(env_id)
        params = gymnax.make(env_id.removeprefix("rl_jax/"))[1]
        assert env.max_episode_steps == params.max_steps_in_episode
        assert env.max_episode_steps == registry.max_episode_steps(env_id)
    # Freeway never terminates; it is cut at 2,500 steps as truncated.
    env = envs.make("rl_jax/Freeway-MinAtar")

    def run(key):
        state, _ = env.reset(key)

        def step(state, key):
            state, ts = env.step(key, state, jnp.int32(1))
            return state, (ts.terminated, ts.truncated)

        return jax.lax.scan(step, state, jax.random.split(key, 2500))[1]

    terminated, truncated = jax.jit(run)(jax.random.key(0))
    assert not terminated.any()
    assert truncated[-1] and not truncated[:-1].any()


def test_constructor_and_params_keywords():
    env = envs.from_gymnax("Breakout-MinAtar", use_minimal_action_set=False)
    assert env.action_space().n == 6
    env = envs.make("rl_jax/Asterix-MinAtar", ramping=False, max_steps_in_episode=50)
    assert env.max_episode_steps == 50 and not bool(env.default_params.ramping)
    with pytest.raises(envs.UnknownEnvError.__mro__[1]):  # UnsupportedEnvError, a ValueError
        envs.from_gymnax("NoSuchGame-MinAtar")


def test_sticky_actions_keyword_executes_the_previous_action_as_minatar():
    """``sticky_actions=p`` (the original MinAtar's, which gymnax lacks): with the same key, a
    step is the plain env's step with the previous action where the wrapper's draw is below p,
    else with the agent's; the previous action after a reset is 0."""
    assert isinstance(envs.make("rl_jax/Breakout-MinAtar"), envs.adapters.gymnax_adapter.FromGymnax)
    env = envs.make("rl_jax/Breakout-MinAtar", sticky_actions=0.5)
    plain, plain_step = _env_and_step("rl_jax/Breakout-MinAtar")
    assert isinstance(env, envs.StickyActions) and env.repeat_action_probability == 0.5
    state, _ = env.reset(jax.random.key(0))
    plain_state, _ = plain.reset(jax.random.key(0))
    # both steps compiled: op by op, every step dispatches each of the game's many ops
    step = jax.jit(env.step)
    previous, stuck_steps = 0, 0
    for i in range(30):
        key, action = jax.random.key(10 + i), i % 3
        stick_key, env_key = jax.random.split(key)
        stuck = bool(jax.random.uniform(stick_key) < 0.5)
        executed = previous if stuck else action
        state, ts = step(key, state, jnp.int32(action))
        plain_state, plain_ts = plain_step(env_key, plain_state, jnp.int32(executed))
        np.testing.assert_array_equal(ts.obs, plain_ts.obs)
        assert int(state.last_action) == executed
        previous, stuck_steps = executed, stuck_steps + (stuck and executed != action)
        if bool(ts.terminated):
            break
    assert stuck_steps > 0  # the draw did replace some actions


def test_jit_vmap_over_envs_and_autoreset():
    env = envs.AutoReset(envs.make("rl_jax/Breakout-MinAtar"))
    keys = jax.random.split(jax.random.key(0), 16)
    state, ts = jax.jit(jax.vmap(env.reset))(keys)
    step = jax.jit(jax.vmap(env.step))
    for i in range(40):
        actions = jax.random.randint(jax.random.key(i), (16,), 0, 3)
        state, ts = step(jax.random.split(jax.random.key(100 + i), 16), state, actions)
    assert ts.obs.shape == (16, 10, 10, 4) and ts.obs.dtype == jnp.float32


def test_importing_envs_does_not_import_gymnax():
    code = (
        "import sys\nfrom rl_jax import envs\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('gymnax', 'seaborn')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("env_id", IDS)
def test_registered_with_gymnasium_and_passes_check_env(env_id):
    spec = gymnasium.spec(env_id)
    assert spec.max_episode_steps == registry.max_episode_steps(env_id)
    env = gymnasium.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    assert not caught, [str(w.message) for w in caught]
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (160, 160, 3) and frame.dtype == np.uint8


# ---- against the numpy minatar package -----------------------------------------------------------
def _numpy_game(game: str, seed: int):
    env = minatar.Environment(game.lower().replace("spaceinvaders", "space_invaders"), 0.0)
    env.seed(seed)
    env.reset()
    return env


@functools.cache
def _env_and_step(env_id: str):
    """``(env, its jitted step)``, made and traced once for every test and seed that plays it."""
    env = envs.make(env_id)
    return env, jax.jit(env.step)


def _play_against_numpy(game: str, seed: int, start) -> int:
    """One episode of random actions in ours and in numpy MinAtar from the same start state;
    observations, rewards and terminals compared at every step. Returns its length."""
    env, step = _env_and_step(f"rl_jax/{game}-MinAtar")
    action_set = np.asarray(env.gymnax_env.action_set)
    state, ts = env.reset(jax.random.key(seed))
    reference = _numpy_game(game, seed)
    start(reference.env, state.inner)
    np.testing.assert_array_equal(ts.obs, reference.state())
    rng = np.random.default_rng(seed)
    for t in range(env.max_episode_steps):
        action = int(rng.integers(len(action_set)))
        reward, terminal = reference.act(int(action_set[action]))
        state, ts = step(jax.random.key(t), state, jnp.int32(action))
        np.testing.assert_array_equal(ts.obs, reference.state(), err_msg=f"step {t}")
        assert (float(ts.reward), bool(ts.terminated)) == (reward, terminal), t
        if terminal:
            return t + 1
    return env.max_episode_steps


def _breakout_start(game, inner) -> None:
    # gymnax draws which side the ball starts from with its key, numpy with its generator
    game.ball_x, game.last_x = int(inner.ball_x), int(inner.last_x)
    game.ball_dir = int(inner.ball_dir)


@pytest.mark.parametrize("seed", range(6))
def test_breakout_matches_numpy_minatar_from_the_same_start(seed):
    assert _play_against_numpy("Breakout", seed, _breakout_start) > 1


def test_space_invaders_matches_numpy_minatar():
    # no randomness in either: the same actions give the same game
    lengths = [
        _play_against_numpy("SpaceInvaders", seed, lambda game, inner: None) for seed in (0, 1)
    ]
    assert min(lengths) > 1


def _episode(env, state, keys: jax.Array, actions: np.ndarray):
    """Ours stepped with ``keys`` and ``actions`` from ``state`` in one compiled scan, not one
    call from Python per step: ``(obs, reward, terminated, truncated)`` of every step, in numpy."""

    def one(state, step):
        state, ts = env.step(step[0], state, step[1])
        return state, (ts.obs, ts.reward, ts.terminated, ts.truncated)

    run = jax.jit(lambda state, steps: jax.lax.scan(one, state, steps)[1])
    return tuple(map(np.asarray, run(state, (keys, jnp.asarray(actions, jnp.int32)))))


def _car_draws(key) -> tuple[jax.Array, jax.Array]:
    """The car speeds and directions that gymnax's Freeway draws from ``key``."""
    key_speed, key_directions = jax.random.split(key)
    speeds = jax.random.randint(key_speed, (8,), 1, 6)
    return speeds, jax.random.choice(key_directions, jnp.array([-1, 1]), (8,))


class _GymnaxDraws:
    """Stands in for numpy Freeway's generator, answering with the car speeds and directions that
    gymnax draws from a key (``set``; ``use``: drawn already), so that both games draw the same
    cars."""

    def set(self, key) -> None:
        self.use(*_car_draws(key))

    def use(self, speeds, directions) -> None:
        self.speeds, self.directions = np.asarray(speeds), np.asarray(directions)

    def randint(self, low, high, size):
        return self.speeds.copy()

    def rand(self, size):
        return np.where(self.directions > 0, 0.75, 0.25)  # numpy takes the sign of rand - 0.5


@pytest.mark.parametrize("seed", [0])  # 2,500 steps, ours in one scan, numpy's from Python
def test_freeway_matches_numpy_minatar_given_the_same_car_draws(seed):
    env = envs.make("rl_jax/Freeway-MinAtar")
    action_set = np.asarray(env.gymnax_env.action_set)
    game, draws = _numpy_game("Freeway", seed), _GymnaxDraws()
    game.env.random = draws
    draws.set(jax.random.key(seed))  # gymnax's reset draws from its key as it is
    game.reset()
    state, ts = env.reset(jax.random.key(seed))
    np.testing.assert_array_equal(ts.obs, game.state())
    rng, wins, steps = np.random.default_rng(seed), 0, env.max_episode_steps
    # mostly up: crossings
    actions = [1 if rng.random() < 0.6 else int(rng.integers(3)) for _ in range(steps)]
    keys = jax.vmap(jax.random.key)(10_000 * seed + jnp.arange(steps))
    # each step's cars, drawn from the key gymnax's step gives its step_env
    speeds, directions = map(
        np.asarray, jax.jit(jax.vmap(lambda key: _car_draws(jax.random.split(key)[0])))(keys)
    )
    obs, rewards, terminated, truncated = _episode(env, state, keys, np.asarray(actions))
    for t, action in enumerate(actions):
        draws.use(speeds[t], directions[t])
        reward, terminal = game.act(int(action_set[action]))
        np.testing.assert_array_equal(obs[t], game.state(), err_msg=f"step {t}")
        assert float(rewards[t]) == reward and not terminated[t] and not terminal, t
        wins += int(reward)
    # gymnax cuts the game at 2,500 steps as truncated; numpy MinAtar ends it one step later,
    # as terminated
    assert truncated[-1] and wins > 0
    assert game.act(0) == (0, True)


class _GymnaxSpawns:
    """Stands in for numpy Asterix's generator, answering with the spawn that gymnax's own
    ``spawn_entity`` draws from the step's key (``set``): its side, whether it is gold, its row."""

    def __init__(self, game) -> None:
        from gymnax.environments.minatar import asterix

        self.game = game
        self.spawn = jax.jit(asterix.spawn_entity)

    def set(self, key, gymnax_state) -> None:
        entity, slot = self.spawn(key, gymnax_state)
        self.left_to_right, self.gold = bool(entity[2]), bool(entity[3])
        self.slot, self.found = int(slot), bool(entity[4])
        self.draws = iter([0.25 if self.left_to_right else 0.75, 0.1 if self.gold else 0.9])

    def rand(self):
        return next(self.draws)  # numpy: rand() < 1/2 for the side, then rand() < 1/3 for gold

    def randint(self, n):
        assert self.found, "gymnax's spawn found no free row (see the test below)"
        free = [row for row, entity in enumerate(self.game.entities) if entity is None]
        return free.index(self.slot)


@pytest.mark.parametrize("seed", range(4))
def test_asterix_matches_numpy_minatar_given_the_same_spawns(seed):
    env, step = _env_and_step("rl_jax/Asterix-MinAtar")
    action_set = np.asarray(env.gymnax_env.action_set)
    game = _numpy_game("Asterix", seed)
    spawns = _GymnaxSpawns(game.env)
    game.env.random = spawns
    state, ts = env.reset(jax.random.key(seed))
    np.testing.assert_array_equal(ts.obs, game.state())
    rng = np.random.default_rng(seed)
    for t in range(env.max_episode_steps):
        action = int(rng.integers(len(action_set)))
        key = jax.random.key(10_000 * seed + t)
        spawns.set(jax.random.split(key)[0], state.inner)  # gymnax's step_env key
        reward, terminal = game.act(int(action_set[action]))
        state, ts = step(key, state, jnp.int32(action))
        np.testing.assert_array_equal(ts.obs, game.state(), err_msg=f"step {t}")
        assert (float(ts.reward), bool(ts.terminated)) == (reward, terminal), t
        if terminal:
            break
    assert terminal and t > 10


def test_asterix_spawn_in_gymnax_can_miss_the_last_free_row():
    """Where gymnax's Asterix departs from MinAtar's: its spawn looks at the rows in a random
    order but never at the first of that order, so with one row free it misses it one time in 8
    and writes an empty entity over the last row it looked at, where numpy MinAtar always fills
    the free row."""
    env = envs.make("rl_jax/Asterix-MinAtar")
    state, _ = env.reset(jax.random.key(0))
    entities = np.array([[5, row + 1, 0, 0, 1] for row in range(8)])  # enemies mid-screen
    entities[3] = 0  # row 4 free
    inner = state.inner.replace(entities=jnp.asarray(entities), spawn_timer=0)
    full = state.replace(inner=inner)

    def occupied_after_a_step(key):
        next_state, _ = env.step(key, full, jnp.int32(0))
        return next_state.inner.entities[:, 4].sum()

    counts = np.asarray(
        jax.jit(jax.vmap(occupied_after_a_step))(jax.random.split(jax.random.key(1), 800))
    )
    assert set(counts.tolist()) == {6, 8}
    assert 0.08 < np.mean(counts == 6) < 0.17  # 1 in 8


def test_render_colours_cells_as_minatar_display_does():
    seaborn = pytest.importorskip("seaborn")
    env = envs.make("rl_jax/SpaceInvaders-MinAtar")
    state, ts = env.reset(jax.random.key(0))
    obs = np.asarray(ts.obs)
    palette = [(0, 0, 0), *seaborn.color_palette("cubehelix", obs.shape[-1])]
    # MinAtar's display: each cell in the colour of its highest set channel, black where none is
    index = np.max(obs * np.arange(1, obs.shape[-1] + 1), axis=-1).astype(int)
    expected = (np.asarray(palette)[index] * 255).round().astype(np.uint8)
    np.testing.assert_array_equal(env.render(state)[::16, ::16], expected)
