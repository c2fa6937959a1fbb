"""The gymnasium front ends: registration, check_env, time limits, reset options, seeding, and
make_vec's NEXT_STEP autoreset against gymnasium's own SyncVectorEnv on the same env."""

import subprocess
import sys
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

from rl_jax import envs
from rl_jax.envs.adapters.gym_adapter import register_with_gymnasium
from rl_jax.envs.classic.rocket import Rocket, RocketState
from rl_jax.envs.core import registry

CLASSIC_IDS = ["rl_jax/Rocket-v0", "rl_jax/CartPole-v1", "rl_jax/Pendulum-v1"]
# The contract of DESIGN.md (other tests may register extra envs of their own).
MUJOCO_IDS = [
    "rl_jax/InvertedPendulum-v5",
    "rl_jax/InvertedDoublePendulum-v5",
    "rl_jax/HalfCheetah-v5",
    "rl_jax/Hopper-v5",
    "rl_jax/Walker2d-v5",
    "rl_jax/Swimmer-v5",
    "rl_jax/Reacher-v5",
    "rl_jax/Ant-v5",
    "rl_jax/Humanoid-v5",
]
ALL_IDS = CLASSIC_IDS + MUJOCO_IDS
# The gymnasium env each of our ids mirrors (the rocket is our own spec).
REFERENCE = {env_id: env_id.removeprefix("rl_jax/") for env_id in ALL_IDS}
REFERENCE.pop("rl_jax/Rocket-v0")


def _importable(env_id: str) -> bool:
    try:
        registry.factory(env_id)
    except ModuleNotFoundError:
        return False
    return True


def _skip_unless_importable(env_id: str) -> None:
    if not _importable(env_id):
        pytest.skip(f"{env_id}'s module is not in this checkout yet")


# A registered env whose step info is not empty, to check the vector env's info layout.
class InfoRocket(Rocket):
    """The rocket plus an info dict: ``speed`` (float32) and ``crashed`` (bool)."""

    def empty_info(self):
        return {"speed": jnp.zeros((), jnp.float32), "crashed": jnp.zeros((), jnp.bool_)}

    def step_env(self, key, state: RocketState, action, params):
        state, obs, reward, terminated, _ = super().step_env(key, state, action, params)
        crashed = (jnp.abs(state.x) > params.bound) | (jnp.abs(state.v) > params.bound)
        return state, obs, reward, terminated, {"speed": jnp.abs(state.v), "crashed": crashed}


INFO_ID = "rl_jax/InfoRocketTest-v0"
envs.register(INFO_ID, f"{__name__}:InfoRocket", max_episode_steps=40)
register_with_gymnasium()


def _warnings_of(function) -> set[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        function()
    return {str(w.message) for w in caught}


# ---- registration -------------------------------------------------------------------------------
def test_import_registers_every_id_without_importing_mujoco():
    code = (
        "import sys, gymnasium\nfrom rl_jax import envs\n"
        "ids = set(envs.registered_ids())\n"
        "assert ids <= set(gymnasium.registry), ids - set(gymnasium.registry)\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('mujoco', 'brax')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_registered_limits_match_the_env_and_gymnasium(env_id):
    spec = gymnasium.spec(env_id)
    assert spec.max_episode_steps == registry.max_episode_steps(env_id)
    assert spec.vector_entry_point is not None
    if env_id in REFERENCE:
        reference = gymnasium.spec(REFERENCE[env_id])
        assert spec.max_episode_steps == reference.max_episode_steps
        assert spec.reward_threshold == reference.reward_threshold
    _skip_unless_importable(env_id)
    assert registry.factory(env_id).max_episode_steps == spec.max_episode_steps


# ---- check_env ----------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ALL_IDS)
def test_passes_check_env_with_no_warning_its_reference_does_not_give(env_id):
    _skip_unless_importable(env_id)
    env = gymnasium.make(env_id, render_mode="rgb_array")
    ours = _warnings_of(lambda: check_env(env.unwrapped))
    allowed = set()
    if env_id in REFERENCE:
        # gymnasium's classic envs render through pygame (not installed): skip their render check.
        reference = gymnasium.make(REFERENCE[env_id]).unwrapped
        allowed = _warnings_of(lambda: check_env(reference, skip_render_check=True))
    if jax.default_backend() != "cpu":
        # MJX on a GPU (seen for Ant on an H100): XLA's GPU kernels sum contact forces in an
        # order that can differ between two runs of the same step, so check_env's two same-seed
        # steps agree only "similarly". XLA_FLAGS=--xla_gpu_deterministic_ops=true orders them.
        ours = {w for w in ours if "not equal although similar" not in w}
    assert ours <= allowed, ours - allowed


# ---- time limits ------------------------------------------------------------------------------
def _steps_until_truncated(env, limit: int) -> int | None:
    env.reset(seed=0, options={"state": [0.5, 0.0]})  # at rest: never terminates
    for t in range(1, limit + 1):
        _, _, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        assert not terminated
        if truncated:
            return t
    return None


def test_time_limit_is_the_registered_one_and_can_be_overridden():
    env = gymnasium.make("rl_jax/Rocket-v0")
    assert env.spec.max_episode_steps == 500
    assert _steps_until_truncated(env, 600) == 500
    assert (
        _steps_until_truncated(gymnasium.make("rl_jax/Rocket-v0", max_episode_steps=20), 600) == 20
    )
    # Longer than the JAX env's own 500: nothing inside truncates earlier (no double counting).
    longer = gymnasium.make("rl_jax/Rocket-v0", max_episode_steps=700)
    assert _steps_until_truncated(longer, 800) == 700
    assert (
        _steps_until_truncated(gymnasium.make("rl_jax/Rocket-v0", max_episode_steps=-1), 800)
        is None
    )


# ---- reset options ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("env_id", "vector", "expected_obs"),
    [
        ("rl_jax/Rocket-v0", [0.7, -0.3], [0.7, -0.3]),
        ("rl_jax/CartPole-v1", [0.1, -0.2, 0.05, 0.3], [0.1, -0.2, 0.05, 0.3]),
        ("rl_jax/Pendulum-v1", [2.0, -0.5], [np.cos(2.0), np.sin(2.0), -0.5]),
    ],
)
def test_reset_options_state_is_an_exact_start(env_id, vector, expected_obs):
    env = gymnasium.make(env_id)
    obs, info = env.reset(seed=1, options={"state": vector})
    np.testing.assert_allclose(obs, expected_obs, rtol=1e-6)
    np.testing.assert_allclose(env.unwrapped.state, vector, rtol=1e-7)
    action = env.action_space.sample()
    obs, reward, terminated, _, _ = env.step(action)
    jax_env = envs.make(env_id)
    state, _ = jax_env.reset_to(jnp.asarray(vector))
    _, expected = jax_env.step(jax.random.PRNGKey(0), state, jnp.asarray(action))
    np.testing.assert_allclose(obs, expected.obs, rtol=1e-6, atol=1e-7)
    assert (reward, terminated) == pytest.approx(
        (float(expected.reward), bool(expected.terminated))
    )


def test_state_attribute_can_be_set_as_in_gymnasium():
    """``env.unwrapped.state = ...`` then ``step``, as gymnasium users do with CartPole."""
    ours, reference = gymnasium.make("rl_jax/CartPole-v1"), gymnasium.make("CartPole-v1")
    ours.reset(seed=0), reference.reset(seed=0)
    start = np.array([0.5, -0.2, 0.1, 0.3], np.float32)
    ours.unwrapped.state = start
    reference.unwrapped.state = start.astype(np.float64)
    for action in (1, 1, 0):
        np.testing.assert_allclose(ours.step(action)[0], reference.step(action)[0], atol=4e-6)


def test_qpos_qvel_options_are_concatenated_into_the_state():
    env = gymnasium.make("rl_jax/Rocket-v0")
    obs, _ = env.reset(options={"qpos": [0.25], "qvel": [-0.75]})
    np.testing.assert_array_equal(obs, np.float32([0.25, -0.75]))


@pytest.mark.parametrize(
    "options",
    [
        {"state": [0.1, 0.2], "qpos": [0.1]},
        {"qpos": [0.1]},
        {"stat": [0.1, 0.2]},
        {"state": [0.1, 0.2, 0.3]},
    ],
    ids=["state_and_qpos", "qpos_alone", "misspelt", "wrong_size"],
)
def test_bad_reset_options_raise(options):
    with pytest.raises(ValueError):
        gymnasium.make("rl_jax/Rocket-v0").reset(options=options)


def test_cartpole_reset_bounds_options_apply_to_that_reset_only():
    env = gymnasium.make("rl_jax/CartPole-v1")
    wide = np.array([env.reset(options={"low": -0.3, "high": 0.3})[0] for _ in range(50)])
    assert np.abs(wide).max() > 0.1 and np.abs(wide).max() <= 0.3
    default = np.array([env.reset()[0] for _ in range(50)])
    assert np.abs(default).max() <= 0.05


def test_params_keyword_arguments_like_gymnasium_constructor_arguments():
    ours = gymnasium.make("rl_jax/Pendulum-v1", g=9.81)
    reference = gymnasium.make("Pendulum-v1", g=9.81)
    ours.reset(options={"state": [1.0, 0.5]})
    reference.reset(seed=0)
    reference.unwrapped.state = np.array([1.0, 0.5])
    for _ in range(20):
        action = np.array([0.7], np.float32)
        np.testing.assert_allclose(ours.step(action)[0], reference.step(action)[0], atol=1e-5)
    # Constructor arguments go to the env: gymnasium's sutton_barto_reward gives -1 on failure.
    cartpole = gymnasium.make("rl_jax/CartPole-v1", sutton_barto_reward=True)
    cartpole.reset(options={"state": [2.39, 1.0, 0.0, 0.0]})
    assert cartpole.step(1)[1:3] == (-1.0, True)
    with pytest.raises(TypeError, match="gravity"):
        gymnasium.make("rl_jax/Pendulum-v1", gravity=9.81)


def test_invalid_discrete_action_raises():
    env = gymnasium.make("rl_jax/CartPole-v1", disable_env_checker=True)
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(2)


# ---- seeding ------------------------------------------------------------------------------------
def _trajectory(env, seed, steps: int = 30):
    obs, _ = env.reset(seed=seed)
    env.action_space.seed(0)
    out = [obs]
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        out.append(np.append(obs, reward))
        if terminated or truncated:
            out.append(env.reset()[0])
    return out


@pytest.mark.parametrize("env_id", CLASSIC_IDS)
def test_same_seed_same_trajectory(env_id):
    first = _trajectory(gymnasium.make(env_id), seed=42)
    again = _trajectory(gymnasium.make(env_id), seed=42)
    other = _trajectory(gymnasium.make(env_id), seed=43)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first[0], other[0])


# ---- make_vec -----------------------------------------------------------------------------------
def _make_pair(env_id: str, num_envs: int, limit: int):
    kwargs = dict(num_envs=num_envs, max_episode_steps=limit)
    ours = gymnasium.make_vec(env_id, vectorization_mode="vector_entry_point", **kwargs)
    sync = gymnasium.make_vec(env_id, vectorization_mode="sync", **kwargs)
    return ours, sync


def _assert_same_info(info: dict, ref_info: dict) -> None:
    assert info.keys() == ref_info.keys()
    for key in info:
        np.testing.assert_allclose(info[key], ref_info[key], rtol=1e-6, atol=1e-6)
        assert info[key].dtype == ref_info[key].dtype, key


def _assert_same_reset(ours, reference) -> None:
    np.testing.assert_allclose(ours[0], reference[0], rtol=1e-6, atol=1e-6)
    _assert_same_info(ours[1], reference[1])


def _assert_same_step(ours, reference) -> None:
    obs, reward, terminated, truncated, info = ours
    ref_obs, ref_reward, ref_terminated, ref_truncated, ref_info = reference
    # Same per-env key streams; the vmapped program may round an ulp differently from the
    # single-env one (fused multiply-adds), and the pendulum carries such a difference through its
    # episode: 1.5e-6 relative in a reward after 20-odd steps (jax 0.12 at the tests' -O0). Hence
    # 1e-5 rather than exact; a wrong key stream or autoreset would differ in the first digits.
    np.testing.assert_allclose(obs, ref_obs, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(reward, ref_reward, rtol=1e-5, atol=1e-5)
    assert reward.dtype == ref_reward.dtype
    np.testing.assert_array_equal(terminated, ref_terminated)
    np.testing.assert_array_equal(truncated, ref_truncated)
    _assert_same_info(info, ref_info)


# The rocket with an info dict stands in for the rocket (same code path, plus infos).
@pytest.mark.parametrize("env_id", [INFO_ID, "rl_jax/CartPole-v1", "rl_jax/Pendulum-v1"])
def test_make_vec_matches_sync_vector_env(env_id):
    """Same seed and actions through our one-call vector env and gymnasium's SyncVectorEnv over
    our single env: identical results, autoresets (NEXT_STEP) and infos included."""
    ours, sync = _make_pair(env_id, num_envs=4, limit=25)
    assert ours.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP == sync.autoreset_mode
    assert ours.observation_space == sync.observation_space
    assert ours.action_space == sync.action_space
    assert ours.spec.max_episode_steps == gymnasium.spec(env_id).max_episode_steps
    _assert_same_reset(ours.reset(seed=3), sync.reset(seed=3))
    sync.action_space.seed(5)
    dones = np.zeros(4, bool)
    saw_autoreset = False
    for _ in range(70):
        actions = sync.action_space.sample()
        result, reference = ours.step(actions), sync.step(actions)
        _assert_same_step(result, reference)
        if dones.any():  # NEXT_STEP: the envs that ended last step were reset, action ignored
            saw_autoreset = True
            assert np.all(result[1][dones] == 0) and not np.any(result[2][dones] | result[3][dones])
        dones = result[2] | result[3]
    assert saw_autoreset


def _seeded_obs(env_id: str, seed: int) -> np.ndarray:
    return gymnasium.make(env_id).reset(seed=seed)[0]


def test_vector_env_seeds_env_i_with_seed_plus_i():
    vec = gymnasium.make_vec(
        "rl_jax/Rocket-v0", num_envs=3, vectorization_mode="vector_entry_point"
    )
    obs, _ = vec.reset(seed=10)
    for i in range(3):
        np.testing.assert_array_equal(obs[i], _seeded_obs("rl_jax/Rocket-v0", 10 + i))
    obs_list, _ = vec.reset(seed=[7, None, 9])
    np.testing.assert_array_equal(obs_list[0], _seeded_obs("rl_jax/Rocket-v0", 7))
    np.testing.assert_array_equal(obs_list[2], _seeded_obs("rl_jax/Rocket-v0", 9))


def test_vector_reset_mask_and_state_options_match_sync():
    # Sizes as in test_make_vec_matches_sync_vector_env, so the compiled programs are reused.
    ours, sync = _make_pair("rl_jax/CartPole-v1", num_envs=4, limit=25)
    ours.reset(seed=0), sync.reset(seed=0)
    for _ in range(5):
        actions = np.array([0, 1, 1, 0])
        ours.step(actions), sync.step(actions)
    mask = np.array([True, False, True, False])
    _assert_same_reset(
        ours.reset(options={"reset_mask": mask}), sync.reset(options={"reset_mask": mask})
    )
    for _ in range(3):
        actions = np.array([1, 0, 1, 1])
        _assert_same_step(ours.step(actions), sync.step(actions))
    states = np.array([[0.1, 0, 0, 0], [0.2, 0, 0, 0], [0.3, 0, 0, 0], [0.4, 0, 0, 0]], np.float32)
    obs, _ = ours.reset(options={"state": states})
    np.testing.assert_array_equal(obs, states)
    first_only = np.array([True, False, False, False])
    obs, _ = ours.reset(options={"state": states[1], "reset_mask": first_only})
    np.testing.assert_array_equal(obs, states[[1, 1, 2, 3]])


def test_gymnasium_vector_episode_statistics_on_our_vector_env():
    """The standard user stack: RecordEpisodeStatistics reads NEXT_STEP from our metadata."""
    vec = gymnasium.wrappers.vector.RecordEpisodeStatistics(
        gymnasium.make_vec(
            "rl_jax/CartPole-v1",
            num_envs=4,
            vectorization_mode="vector_entry_point",
            max_episode_steps=25,  # as in test_make_vec_matches_sync_vector_env: no recompiling
        )
    )
    vec.reset(seed=0)
    returns, running = [], np.zeros(4)
    for _ in range(200):
        _, reward, terminated, truncated, info = vec.step(vec.action_space.sample())
        running += reward
        for i in np.nonzero(terminated | truncated)[0]:
            assert info["_episode"][i]
            assert info["episode"]["r"][i] == pytest.approx(running[i])
            returns.append(running[i])
            running[i] = 0
    assert len(returns) > 10 and all(r >= 8 for r in returns)  # CartPole random play: >= 8 steps


# ---- rendering ----------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", CLASSIC_IDS)
def test_render_rgb_array(env_id):
    env = gymnasium.make(env_id, render_mode="rgb_array")
    assert env.unwrapped.render() is None  # before reset, as gymnasium's envs
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert env.metadata["render_fps"] == env.unwrapped.jax_env.render_fps
    vec = gymnasium.make_vec(
        env_id, num_envs=2, vectorization_mode="vector_entry_point", render_mode="rgb_array"
    )
    vec.reset(seed=0)
    frames = vec.render()
    assert len(frames) == 2 and frames[0].shape == frame.shape
    silent = gymnasium.make(env_id)
    silent.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert silent.render() is None


def test_step_before_reset_is_an_error():
    with pytest.raises(gymnasium.error.ResetNeeded):
        gymnasium.make("rl_jax/Rocket-v0", disable_env_checker=True).unwrapped.step(np.zeros(1))
    vec = gymnasium.make_vec(
        "rl_jax/Rocket-v0", num_envs=2, vectorization_mode="vector_entry_point"
    )
    with pytest.raises(gymnasium.error.ResetNeeded):
        vec.step(np.zeros((2, 1)))
