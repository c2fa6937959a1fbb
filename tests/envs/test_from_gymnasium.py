"""``envs.from_gymnasium``: gymnasium's own envs stepped on the host from inside jit. Step for step
against gymnasium itself, terminated and truncated kept apart, jit and nested vmaps, seeds,
handles the pool no longer holds (resume), bad input in one line, and TD3 training through it."""

import contextlib
import dataclasses
import os
import re
import shutil
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax import envs
from rl_jax.agents.td3 import ENV_CONFIGS, td3
from rl_jax.envs.adapters.gymnasium_host import LOST_KEY, HostGymnasiumEnv
from rl_jax.envs.core.registry import UnsupportedEnvError
from rl_jax.errors import guard
from rl_jax.run import cli
from rl_jax.run.metrics import METRICS_FILE, read_rows
from rl_jax.training import episodes, parallel

ROOT = Path(__file__).resolve().parents[2]
# The off-policy loop, tiny: 4 envs x 25 iterations = 100 env steps per chunk; TD3's networks.
LOOP = {
    "num_envs": 4,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 25,
    "learning_starts": 100,
    "batch_size": 32,
    "buffer_size": 2000,
    "num_eval_envs": 2,
}
TINY = {**LOOP, "actor_hidden": (16, 16), "critic_hidden": (16, 16)}


@contextlib.contextmanager
def _xla_flags_kept():
    """The CLI sets the device count for a process not started yet: keep it out of the
    environment of later tests' subprocesses."""
    saved = os.environ.get("XLA_FLAGS")
    try:
        yield
    finally:
        if saved is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = saved


@pytest.fixture(autouse=True)
def _restore_xla_flags():
    with _xla_flags_kept():
        yield


class Countdown(gymnasium.Env):
    """Counts down from a seeded start in ``[low, high)``; the action (1 or 2) is subtracted and
    paid as reward; terminated at 0. No time limit of its own."""

    observation_space = gymnasium.spaces.Box(0.0, 100.0, (1,), np.float32)
    action_space = gymnasium.spaces.Discrete(2, start=1)

    def __init__(self, low: int = 13, high: int = 20):
        self.low, self.high, self.remaining = low, high, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.remaining = int(self.np_random.integers(self.low, self.high))
        return np.array([self.remaining], np.float32), {}

    def step(self, action):
        self.remaining = max(self.remaining - int(action), 0)
        obs = np.array([self.remaining], np.float32)
        return obs, float(action), self.remaining == 0, False, {}


def _keys(count: int, seed: int = 0) -> jax.Array:
    return jax.random.split(jax.random.key(seed), count)


def _rollout(env, keys, actions):
    """Reset a batch from ``keys`` and step it with ``actions`` [T, N, ...] in one jitted scan."""

    @jax.jit
    def run(keys, actions):
        state, first = jax.vmap(env.reset)(keys)

        def body(state, action):
            state, ts = jax.vmap(env.step)(keys, state, action)
            return state, ts

        return first, *jax.lax.scan(body, state, actions)

    return run(keys, actions)


# ---- against gymnasium ---------------------------------------------------------------------------
def test_pendulum_matches_gymnasium_step_for_step():
    """3 envs in one vmapped scan vs 3 gymnasium Pendulums seeded with each episode's seed, up
    to the 200-step truncation and one step past it (where the episode stays ended)."""
    env = envs.from_gymnasium("Pendulum-v1")
    actions = np.random.default_rng(0).uniform(-2.0, 2.0, (201, 3, 1)).astype(np.float32)
    first, state, ts = jax.device_get(_rollout(env, _keys(3), actions))
    for lane in range(3):
        theirs = gymnasium.make("Pendulum-v1")
        obs, _ = theirs.reset(seed=int(state.seed[lane]))
        np.testing.assert_array_equal(first.obs[lane], obs)
        for t in range(200):
            obs, reward, terminated, truncated, _ = theirs.step(actions[t, lane])
            np.testing.assert_array_equal(ts.obs[t, lane], obs)
            assert ts.reward[t, lane] == np.float32(reward)
            assert (ts.terminated[t, lane], ts.truncated[t, lane]) == (terminated, truncated)
        assert truncated and not terminated  # at step 200, gymnasium's TimeLimit
        np.testing.assert_array_equal(ts.obs[200, lane], obs)  # ended: no further step
        assert ts.reward[200, lane] == 0.0 and ts.truncated[200, lane]
    assert not ts.info[LOST_KEY].any()


def test_terminated_and_truncated_stay_apart():
    """Countdown with a 12-step limit: counting by 2 from 13..19 terminates first, by 1 is cut
    by the limit, and from exactly 12 by 1 both happen on step 12 (gymnasium's semantics)."""
    limited = envs.from_gymnasium(lambda: Countdown(13, 20), max_episode_steps=12)
    exact = envs.from_gymnasium(lambda: Countdown(12, 13), max_episode_steps=12)
    assert limited.action_space() == envs.Discrete(2)
    actions = np.tile(np.array([1, 0], np.int32), (12, 1))  # index 1 is action 2, 0 is 1
    _, _, ts = jax.device_get(_rollout(limited, _keys(2), actions))
    assert np.all(ts.reward[:, 1] == 1.0) and ts.reward[0, 0] == 2.0  # Discrete start added
    ended_by_two = int(np.argmax(ts.terminated[:, 0]))
    assert ended_by_two < 11 and not ts.truncated[ended_by_two, 0]
    assert ts.truncated[11, 1] and not ts.terminated[:, 1].any()
    _, _, both = jax.device_get(_rollout(exact, _keys(1), np.zeros((12, 1), np.int32)))
    assert both.terminated[11, 0] and both.truncated[11, 0]
    assert not both.terminated[:11].any() and not both.truncated[:11].any()


def test_autoreset_keeps_final_obs_and_flags_of_the_finishing_step():
    env = envs.AutoReset(envs.from_gymnasium(lambda: Countdown(13, 20), max_episode_steps=12))
    actions = np.tile(np.array([1, 0], np.int32), (12, 1))
    first, _, ts = jax.device_get(_rollout(env, _keys(2), actions))
    t = int(np.argmax(ts.terminated[:, 0]))
    assert ts.info["final_obs"][t, 0, 0] == 0.0 and ts.obs[t, 0, 0] >= 13  # a new episode
    assert not ts.truncated[t, 0] and ts.truncated[11, 1] and not ts.terminated[11, 1]
    assert ts.info["final_obs"][11, 1, 0] == first.obs[1, 0] - 12


# ---- jit, vmap, seeds, the pool ------------------------------------------------------------------
def test_nested_vmaps_equal_the_flat_batch():
    """Seeds x envs through two vmaps step the same episodes as one flat batch."""
    env = envs.from_gymnasium("Pendulum-v1")
    keys = _keys(6, seed=3)
    actions = np.random.default_rng(1).uniform(-2, 2, (5, 6, 1)).astype(np.float32)

    @jax.jit
    def nested(keys, actions):
        state, _ = jax.vmap(jax.vmap(env.reset))(keys)
        for action in actions:
            state, ts = jax.vmap(jax.vmap(env.step))(keys, state, action)
        return ts

    grid = nested(keys.reshape(2, 3), actions.reshape(5, 2, 3, 1))
    _, _, flat = _rollout(env, keys, actions)
    np.testing.assert_array_equal(np.asarray(grid.obs).reshape(6, 3), flat.obs[-1])
    np.testing.assert_array_equal(np.asarray(grid.reward).reshape(6), flat.reward[-1])


def test_same_seed_same_run_and_autoreset_does_not_grow_the_pool():
    """Two adapters (two pools) from the same key give the same 450 steps of 4 envs through
    AutoReset, and the pool holds one running episode per env."""

    def run(adapter: HostGymnasiumEnv):
        wrapped = envs.AutoReset(adapter)
        actions = jnp.full((450, 4, 1), 0.3, jnp.float32)
        return jax.device_get(_rollout(wrapped, _keys(4, seed=7), actions)[2])

    first_adapter, second_adapter = (
        envs.make("gymnasium:Pendulum-v1"),
        envs.make("gymnasium:Pendulum-v1"),
    )
    first, second = run(first_adapter), run(second_adapter)
    np.testing.assert_array_equal(first.obs, second.obs)
    np.testing.assert_array_equal(first.reward, second.reward)
    assert first.truncated.sum() == 8  # two episodes of 200 steps per env
    assert len(first_adapter.pool.running) == 4 and len(first_adapter.pool.idle) <= 4


def test_a_handle_the_pool_does_not_hold_is_cut_as_truncated():
    """A state from another pool (a resume in a new process) or stepped a second time cannot
    continue: truncated, reward 0, the last obs again, info flag; AutoReset starts afresh."""
    first, second = envs.from_gymnasium("Pendulum-v1"), envs.from_gymnasium("Pendulum-v1")
    step = jax.jit(first.step)
    state, _ = first.reset(jax.random.key(0))
    state, ts = step(jax.random.key(1), state, jnp.zeros(1))
    _, again = step(jax.random.key(1), state, jnp.zeros(1))
    assert not again.info[LOST_KEY]
    _, twice = step(jax.random.key(1), state, jnp.zeros(1))  # the pool has moved on
    _, foreign = jax.jit(second.step)(jax.random.key(1), state, jnp.zeros(1))
    for cut in (twice, foreign):
        assert cut.info[LOST_KEY] and cut.truncated and not cut.terminated
        assert cut.reward == 0.0
        np.testing.assert_array_equal(cut.obs, ts.obs)
    wrapped = envs.AutoReset(second)
    fresh_state, fresh = jax.jit(wrapped.step)(jax.random.key(2), state, jnp.zeros(1))
    assert fresh.truncated and int(fresh_state.time) == 0
    _, continued = jax.jit(wrapped.step)(jax.random.key(3), fresh_state, jnp.zeros(1))
    assert not continued.info[LOST_KEY] and not continued.truncated


# ---- spaces and bad input ------------------------------------------------------------------------
def test_spaces_are_translated():
    env = envs.from_gymnasium(gymnasium.make("MountainCarContinuous-v0"))  # an instance: copied
    assert env.observation_space() == envs.Box([-1.2, -0.07], [0.6, 0.07])
    assert env.action_space() == envs.Box(-1.0, 1.0, (1,))
    assert env.max_episode_steps == 999 and env.id == "gymnasium:MountainCarContinuous-v0"
    cartpole = envs.make("gymnasium:CartPole-v1")
    assert cartpole.action_space() == envs.Discrete(2) and cartpole.max_episode_steps == 500


@pytest.mark.parametrize(
    ("make", "error", "message"),
    [
        (lambda: envs.from_gymnasium("NoSuchEnv-v0"), envs.UnknownEnvError, "unknown gymnasium"),
        (lambda: envs.make("gymnasium:FrozenLake-v1"), UnsupportedEnvError, "observation space"),
        (lambda: envs.from_gymnasium(Countdown), UnsupportedEnvError, "max_episode_steps"),
        (lambda: envs.make("no_such_module_here:X-v0"), envs.UnknownEnvError, "cannot import"),
        (
            lambda: envs.make("rl_jax.envs.classic.rocket:NoSuchEnv-v0"),
            envs.UnknownEnvError,
            "registers no",
        ),
    ],
)
def test_bad_input_is_one_user_error(make, error, message):
    with pytest.raises(error, match=message) as raised:
        make()
    assert "\n" not in str(raised.value)


@pytest.mark.parametrize(
    ("env_id", "message"),
    [
        ("gymnasium:NoSuchEnv-v0", "unknown gymnasium environment 'NoSuchEnv-v0'"),
        ("gymnasium:FrozenLake-v1", "observation space Discrete(16) is not supported"),
        ("no_such_module_here:X-v0", "cannot import module 'no_such_module_here'"),
        (
            "gymnasium:CartPole-v1",
            "td3 cannot run gymnasium:CartPole-v1: TD3/DDPG needs a bounded 1-D Box action space",
        ),
    ],
)
def test_the_cli_reports_bad_env_ids_in_one_line(env_id, message, capsys, tmp_path):
    argv = ["--algo", "td3", "--env", env_id, "--out", str(tmp_path / "run")]
    assert guard(lambda: cli.run_experiment(None, None, "", argv)) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert not (tmp_path / "run").exists()


# ---- learners on it ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("algorithm", "env_id", "config"),
    [  # a Box env discretised for DQN, and a Discrete one for REINFORCE's categorical policy
        ("dqn", "gymnasium:Pendulum-v1", {**LOOP, "hidden": (16,), "target_update_period": 10}),
        (
            "reinforce",
            "gymnasium:CartPole-v1",
            {"num_envs": 2, "iterations_per_chunk": 2, "num_eval_envs": 2, "hidden": (8,)},
        ),
    ],
)
def test_dqn_and_reinforce_run_on_gymnasium_envs(algorithm, env_id, config, tmp_path):
    run = rl_jax.train(
        algorithm, env_id, seeds=2, total_steps=200, out=tmp_path, config=config, quiet=True
    )
    assert np.all(np.isfinite(run.results.returns)) and np.all(run.results.best > 0) == (
        algorithm == "reinforce"
    )


GYMNASIUM_SECTION = "Any gymnasium environment"


def _readme_section(title: str) -> str:
    page = (ROOT / "docs" / "using_envs.md").read_text()
    return page.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0]


@pytest.fixture(scope="module")
def readme_command_run(tmp_path_factory) -> Path:
    """The docs' command (docs/using_envs.md), tiny, as a sweep: TD3 on gymnasium's Pendulum,
    2 configs x 2 seeds in one program. Its compiled program steps gymnasium through a host
    callback, which the persistent cache does not keep, so the tests below share this one run."""
    command = re.findall(r"```bash\n(.*?)```", _readme_section(GYMNASIUM_SECTION), flags=re.S)[0]
    argv = command.replace("\\\n", " ").split()[2:]
    assert argv[:4] == ["--algo", "td3", "--env", "gymnasium:Pendulum-v1"]
    tiny = [f"--{name.replace('_', '-')}={_flag(value)}" for name, value in TINY.items()]
    out = tmp_path_factory.mktemp("readme") / "run"
    smaller = [*argv, *tiny, "--seeds=2", "--total-steps=200", f"--out={out}"]
    sweep = ["--grid", "tau=0.005,0.02"]  # and a sweep: 2 configs x 2 seeds in one program
    with _xla_flags_kept():  # module-scoped: set up before the autouse fixture saves the flags
        assert guard(lambda: cli.run_experiment(None, None, "", [*smaller, *sweep])) == 0
    return out


def test_the_readme_gymnasium_blocks_run(readme_command_run):
    code = re.findall(r"```python\n(.*?)```", _readme_section(GYMNASIUM_SECTION), flags=re.S)[0]
    namespace: dict = {}
    exec(code, namespace)
    assert namespace["ts"].obs.shape == (16, 2) and namespace["heavy"].max_episode_steps == 100
    rows = read_rows(readme_command_run / METRICS_FILE)
    assert len(rows) == 2 * 2 * 2 and all(np.isfinite(row["eval_return"]) for row in rows)
    assert {row["tau"] for row in rows} == {0.005, 0.02}


def _flag(value) -> str:
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value)


def _forget_programs_and_envs() -> None:
    """Trace again with new adapters (new pools), as a resume in a new process would."""
    for cache in (episodes.make_eval_env, episodes.make_train_env):
        cache.cache_clear()
    parallel._PROGRAMS.clear()
    parallel._COMPILED.clear()


def test_td3_resumes_without_its_host_state(readme_command_run, tmp_path):
    """The docs' sweep resumed as in a new process (a new adapter and pool: every env's
    episode is cut) trains on to finite results. Learning itself: the slow test below."""
    out = tmp_path / "run"
    shutil.copytree(readme_command_run, out)
    _forget_programs_and_envs()
    resumed = rl_jax.resume(out, total_steps=300, quiet=True)
    assert len(resumed.results) == 2  # one result per config of the sweep
    for result in resumed.results:
        assert result.step == 300 and np.all(np.isfinite(result.returns))
    config = dataclasses.replace(td3.default_config("gymnasium:Pendulum-v1"), **TINY)
    adapter = episodes.make_eval_env(config)
    assert adapter.pool.cut_episodes == 2 * 2 * TINY["num_envs"]  # configs x seeds x envs


@pytest.mark.slow  # it trains; the resume path is test_td3_resumes_without_its_host_state
def test_td3_learns_gymnasium_pendulum_and_resumes_without_its_host_state(tmp_path):
    """TD3's Pendulum recipe (3 seeds) on gymnasium's own Pendulum-v1: after 6,000 env steps per
    seed the deterministic policy scores far above the untrained one evaluated at step 1,000.
    Then a resume as in a new process (a new adapter and pool: every env's episode is cut)
    trains on to finite results."""
    env_id, out = "gymnasium:Pendulum-v1", tmp_path / "run"
    config = {**ENV_CONFIGS["rl_jax/Pendulum-v1"], "iterations_per_chunk": 250}
    run = rl_jax.train("td3", env_id, seeds=3, total_steps=6000, out=out, config=config, quiet=True)
    rows = read_rows(out / METRICS_FILE)
    untrained = np.mean([row["eval_return"] for row in rows if row["step"] == 1000])
    final = np.mean(run.results.returns)
    print(f"untrained {untrained:.0f}, final {np.round(run.results.returns)}")
    assert final > untrained + 300 and final > -900
    _forget_programs_and_envs()
    resumed = rl_jax.resume(out, total_steps=7000, quiet=True)
    assert resumed.results.step == 7000 and np.all(np.isfinite(resumed.results.returns))
    adapter = episodes.make_eval_env(dataclasses.replace(td3.default_config(env_id), **config))
    assert adapter.pool.cut_episodes == 3 * config["num_envs"]
