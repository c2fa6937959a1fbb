"""The velocity-masked ids (envs/memory/masked.py): RL Zoo's CartPoleNoVel-v1 and PendulumNoVel-v1
against gymnasium's envs with the velocity entries zeroed, and the position-only MuJoCo variants
against gymnasium's observation layout and our unmasked envs; check_env and the episode limits;
gymnasium's twins of the masked ids (``gymnasium_twin``, where --gymnasium replays) against ours."""

import re
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from rl_jax import envs
from rl_jax.envs.core import registry
from rl_jax.envs.memory.masked import GYMNASIUM_BASES, GymnasiumMask, gymnasium_twin

ATOL, RTOL = 4e-6, 1e-6  # the classic envs' one-step float32 tolerance (test_classic_control)
C = {"backend": "mujoco"}  # MuJoCo C, also on a GPU (where MJX is the default)

#: our id -> gymnasium's env and RL Zoo's velocity entries, which read zero
NO_VELOCITY = {
    "rl_jax/CartPoleNoVel-v1": ("CartPole-v1", [1, 3]),
    "rl_jax/PendulumNoVel-v1": ("Pendulum-v1", [2]),
}
#: our id -> gymnasium's env, the qpos entries it leaves out of its observation, and the
#: observation entries the variant keeps
POSITIONS_ONLY = {
    "rl_jax/Hopper-P-v5": ("Hopper-v5", 1, 5),
    "rl_jax/Walker2d-P-v5": ("Walker2d-v5", 1, 8),
    "rl_jax/HalfCheetah-P-v5": ("HalfCheetah-v5", 1, 8),
    "rl_jax/Ant-P-v5": ("Ant-v5", 2, 13),
}
MASKED_IDS = [*NO_VELOCITY, *POSITIONS_ONLY]


def rl_zoo_masked(obs: np.ndarray, velocities: list[int]) -> np.ndarray:
    """gymnasium's observation as RL Zoo's ``MaskVelocityWrapper`` shows it: velocities zero."""
    obs = np.array(obs, np.float32)
    obs[velocities] = 0.0
    return obs


@pytest.mark.parametrize("env_id", NO_VELOCITY)
def test_no_velocity_ids_are_gymnasiums_envs_with_the_velocities_zeroed(env_id):
    """Its space, limit and first observation against gymnasium's env; whole episodes against
    our unmasked env (checked against gymnasium's in test_classic_control) from the same seed:
    the same observations with the velocities zeroed, the same rewards and flags."""
    reference_id, velocities = NO_VELOCITY[env_id]
    ours, theirs = gymnasium.make(env_id), gymnasium.make(reference_id)
    unmasked = gymnasium.make("rl_jax/" + reference_id)
    assert ours.observation_space == theirs.observation_space  # RL Zoo leaves the space as it is
    assert ours.spec.max_episode_steps == theirs.spec.max_episode_steps
    rng = np.random.default_rng(0)
    for seed in range(3):
        theirs.reset(seed=seed)
        start = np.asarray(theirs.unwrapped.state, np.float32)
        theirs.unwrapped.state = start.astype(np.float64)
        obs, _ = ours.reset(options={"state": start})
        np.testing.assert_allclose(obs, rl_zoo_masked(_observe(theirs), velocities), RTOL, ATOL)
        ours.reset(seed=seed)
        unmasked.reset(seed=seed)
        for _ in range(ours.spec.max_episode_steps):
            action = _action(theirs, rng)
            expected, reward, terminated, truncated, _ = unmasked.step(action)
            obs, our_reward, our_terminated, our_truncated, _ = ours.step(action)
            np.testing.assert_array_equal(obs, rl_zoo_masked(expected, velocities))
            assert (our_reward, our_terminated, our_truncated) == (reward, terminated, truncated)
            if terminated or truncated:
                break
        assert terminated or truncated


def _observe(env) -> np.ndarray:
    """gymnasium's observation of its classic env's current state."""
    unwrapped = env.unwrapped
    if hasattr(unwrapped, "_get_obs"):  # Pendulum
        return unwrapped._get_obs()
    return np.array(unwrapped.state, np.float32)  # CartPole observes its state


def _action(env, rng):
    if isinstance(env.action_space, gymnasium.spaces.Discrete):
        return int(rng.integers(env.action_space.n))
    space = env.action_space
    return rng.uniform(space.low, space.high).astype(np.float32)


@pytest.mark.parametrize("env_id", POSITIONS_ONLY)
def test_positions_only_variants_observe_gymnasiums_qpos_part(env_id):
    """From the same start, our variant's observation is the leading part of gymnasium's, and
    that part is exactly qpos without the current positions."""
    reference_id, excluded, kept = POSITIONS_ONLY[env_id]
    ours, theirs = gymnasium.make(env_id, **C), gymnasium.make(reference_id)
    assert ours.observation_space.shape == (kept,)
    theirs.reset(seed=0)
    data = theirs.unwrapped.data
    qpos, qvel = data.qpos.astype(np.float32), data.qvel.astype(np.float32)
    theirs.unwrapped.set_state(qpos.astype(np.float64), qvel.astype(np.float64))
    expected = theirs.unwrapped._get_obs()
    np.testing.assert_array_equal(expected[:kept], qpos[excluded:])
    np.testing.assert_array_equal(expected[kept : kept + qvel.size], qvel)
    obs, _ = ours.reset(seed=0, options={"qpos": qpos, "qvel": qvel})
    np.testing.assert_allclose(obs, expected[:kept], rtol=2e-7, atol=1e-7)


@pytest.mark.parametrize("env_id", POSITIONS_ONLY)
def test_positions_only_variants_are_the_unmasked_envs_seen_in_part(env_id):
    """Vmapped from the same keys with the same actions: the unmasked env's observation cut to
    its qpos part, and its very rewards and flags."""
    reference_id, _, kept = POSITIONS_ONLY[env_id]
    ours, full = envs.make(env_id, **C), envs.make("rl_jax/" + reference_id, **C)
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    (state, ts), (full_state, full_ts) = jax.vmap(ours.reset)(keys), jax.vmap(full.reset)(keys)
    np.testing.assert_array_equal(ts.obs, full_ts.obs[:, :kept])
    step, full_step = jax.jit(jax.vmap(ours.step)), jax.jit(jax.vmap(full.step))
    space = full.action_space()
    for t in range(5):
        step_keys = jax.random.split(jax.random.PRNGKey(t + 1), 4)
        actions = jax.vmap(space.sample)(step_keys)
        state, ts = step(step_keys, state, actions)
        full_state, full_ts = full_step(step_keys, full_state, actions)
        np.testing.assert_array_equal(ts.obs, full_ts.obs[:, :kept])
        np.testing.assert_array_equal(ts.reward, full_ts.reward)
        np.testing.assert_array_equal(ts.terminated, full_ts.terminated)
        np.testing.assert_array_equal(ts.truncated, full_ts.truncated)


def test_positions_only_follow_the_observation_keywords():
    with_x = envs.make("rl_jax/Hopper-P-v5", exclude_current_positions_from_observation=False, **C)
    assert with_x.observation_space().shape == (6,)
    no_contacts = envs.make("rl_jax/Ant-P-v5", include_cfrc_ext_in_observation=False, **C)
    assert no_contacts.observation_space().shape == (13,)


@pytest.mark.parametrize("env_id", NO_VELOCITY)
def test_no_velocity_twins_observe_as_ours_step_for_step(env_id):
    """gymnasium's twin against our id from gymnasium's own starts, ours re-synced to the twin's
    state before each step (as test_classic_control compares Pendulum): the same observations,
    zero exactly at the velocities and gymnasium's unmasked observation elsewhere."""
    reference_id, velocities = NO_VELOCITY[env_id]
    twin, ours = gymnasium_twin(env_id), gymnasium.make(env_id)
    assert isinstance(twin, GymnasiumMask) and GYMNASIUM_BASES[env_id] == reference_id
    assert twin.spec.id == reference_id and twin.observation_space == ours.observation_space
    kept = [i for i in range(twin.observation_space.shape[0]) if i not in velocities]
    rng = np.random.default_rng(1)
    for seed in range(2):
        obs, _ = twin.reset(seed=seed)
        np.testing.assert_array_equal(obs, rl_zoo_masked(_observe(twin), velocities))
        for _ in range(twin.spec.max_episode_steps):
            start = np.asarray(twin.unwrapped.state, np.float32)
            twin.unwrapped.state = start.astype(np.float64)
            ours.reset(options={"state": start})
            action = _action(twin, rng)
            obs, reward, terminated, _, _ = twin.step(action)
            our_obs, our_reward, our_terminated, _, _ = ours.step(action)
            assert np.all(obs[velocities] == 0.0)
            np.testing.assert_array_equal(obs[kept], _observe(twin)[kept])
            np.testing.assert_allclose(our_obs, obs, RTOL, ATOL)
            assert our_terminated == terminated
            np.testing.assert_allclose(our_reward, reward, RTOL, ATOL)
            if terminated:
                break


def test_positions_only_twin_is_gymnasiums_hopper_cut_to_its_qpos_part():
    """Hopper-P-v5's twin from gymnasium's seeds: the first 5 entries of gymnasium Hopper-v5's
    observation, step for step, and our variant's observation from the same start; the count
    follows exclude_current_positions_from_observation."""
    twin, theirs = gymnasium_twin("rl_jax/Hopper-P-v5"), gymnasium.make("Hopper-v5")
    assert twin.observation_space.shape == (5,)
    np.testing.assert_array_equal(twin.observation_space.low, theirs.observation_space.low[:5])
    obs, _ = twin.reset(seed=3)
    expected, _ = theirs.reset(seed=3)
    assert obs.shape == (5,)
    np.testing.assert_array_equal(obs, expected[:5])
    rng = np.random.default_rng(3)
    for _ in range(10):
        action = _action(theirs, rng)
        obs, reward, *_ = twin.step(action)
        expected, expected_reward, *_ = theirs.step(action)
        np.testing.assert_array_equal(obs, expected[:5])
        assert reward == expected_reward
    data = twin.unwrapped.data
    qpos, qvel = data.qpos.astype(np.float32), data.qvel.astype(np.float32)
    twin.unwrapped.set_state(qpos.astype(np.float64), qvel.astype(np.float64))
    ours = gymnasium.make("rl_jax/Hopper-P-v5", **C)
    our_obs, _ = ours.reset(seed=0, options={"qpos": qpos, "qvel": qvel})
    np.testing.assert_allclose(our_obs, twin.observation(twin.unwrapped._get_obs()), 2e-7, 1e-7)
    with_x = gymnasium_twin("rl_jax/Hopper-P-v5", exclude_current_positions_from_observation=False)
    assert with_x.observation_space.shape == with_x.reset(seed=0)[0].shape == (6,)


@pytest.mark.parametrize("env_id", MASKED_IDS)
def test_registered_and_passes_check_env_as_its_unmasked_env_does(env_id):
    reference_id = {**NO_VELOCITY, **POSITIONS_ONLY}[env_id][0]
    spec = gymnasium.spec(env_id)
    assert spec.max_episode_steps == gymnasium.spec(reference_id).max_episode_steps
    assert spec.max_episode_steps == registry.max_episode_steps(env_id)
    assert spec.vector_entry_point is not None
    mujoco = env_id in POSITIONS_ONLY
    env = gymnasium.make(env_id, render_mode="rgb_array", **(C if mujoco else {}))
    assert envs.make(env_id, **(C if mujoco else {})).max_episode_steps == spec.max_episode_steps
    with warnings.catch_warnings(record=True) as ours:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    with warnings.catch_warnings(record=True) as allowed:
        warnings.simplefilter("always")
        # gymnasium's classic envs render through pygame: their render check is skipped
        check_env(gymnasium.make(reference_id).unwrapped, skip_render_check=True)
    assert {str(w.message) for w in ours} <= {str(w.message) for w in allowed}


def test_make_vec_limit_reaches_the_masked_env():
    """make_vec's own max_episode_steps truncates inside the jitted step: the wrapper passes the
    limit to the env it wraps."""
    vec = gymnasium.make_vec(
        "rl_jax/PendulumNoVel-v1",
        num_envs=2,
        vectorization_mode="vector_entry_point",
        max_episode_steps=7,
    )
    vec.reset(seed=0)
    truncated = [vec.step(np.zeros((2, 1), np.float32))[3] for _ in range(7)]
    assert [bool(t.all()) for t in truncated] == [False] * 6 + [True]


def test_classic_variants_do_not_import_mujoco():
    code = (
        "import sys\nfrom rl_jax import envs\n"
        "envs.make('rl_jax/CartPoleNoVel-v1'); envs.make('rl_jax/PendulumNoVel-v1')\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'mujoco'))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_jit_and_vmap_through_autoreset():
    env = envs.AutoReset(envs.make("rl_jax/CartPoleNoVel-v1"))
    keys = jax.random.split(jax.random.PRNGKey(0), 8)
    state, ts = jax.vmap(env.reset)(keys)
    state, ts = jax.jit(jax.vmap(env.step))(keys, state, jnp.ones(8, jnp.int32))
    assert ts.obs.shape == ts.info["final_obs"].shape == (8, 4)
    assert np.all(ts.info["final_obs"][:, [1, 3]] == 0.0)


def test_the_docs_example_runs():
    """docs/using_envs.md, "Partially observed envs and memory tasks": its Python block."""
    page = (Path(__file__).resolve().parents[2] / "docs" / "using_envs.md").read_text()
    section = page.split("## Partially observed envs and memory tasks\n", 1)[1].split("\n## ")[0]
    namespace: dict = {}
    exec(re.findall(r"```python\n(.*?)```", section, flags=re.S)[0], namespace)
    assert namespace["hopper_angles"].observation_space().shape == (4,)
    _, ts = namespace["no_velocity"].reset(jax.random.PRNGKey(0))
    assert ts.obs.shape == (4,) and ts.obs[1] == ts.obs[3] == 0.0
