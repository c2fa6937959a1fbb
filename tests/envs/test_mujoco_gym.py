"""Our MuJoCo envs through the gymnasium front ends (envs/adapters/gym_adapter.py), against
gymnasium's own envs: check_env, exact starts from reset options, whole episodes, the vector env."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from test_mujoco_parity import ENV_IDS, POSITION_ULPS, _tracked_position

from rl_jax import envs  # noqa: F401  (registers the rl_jax ids with gymnasium)

# The MuJoCo C backend, named: on a GPU the default is MJX (float32 physics, and one compile of
# each env's step, a long one), which test_mujoco_parity.py checks against C on its own.
C = {"backend": "mujoco"}


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env(env_id):
    env = gymnasium.make("rl_jax/" + env_id, render_mode="rgb_array", **C)
    check_env(env.unwrapped)
    assert env.spec.max_episode_steps == gymnasium.spec(env_id).max_episode_steps
    assert env.metadata["render_fps"] == gymnasium.make(env_id).metadata["render_fps"]
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.std() > 0


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_qpos_qvel_reset_then_steps_match_gymnasium(env_id):
    """From the same start (given as reset options), 30 steps of the same actions agree with
    gymnasium's env to float32 output rounding: the C backend's physics is gymnasium's."""
    ours, theirs = gymnasium.make("rl_jax/" + env_id, **C), gymnasium.make(env_id)
    rng = np.random.default_rng(0)
    _, _ = theirs.reset(seed=1)
    data = theirs.unwrapped.data
    # the adapter passes float32 starts: give gymnasium the same (rounded) numbers
    qpos = data.qpos.astype(np.float32) + rng.uniform(-0.05, 0.05, data.qpos.shape).astype(
        np.float32
    )
    qvel = data.qvel.astype(np.float32)
    theirs.unwrapped.set_state(qpos.astype(np.float64), qvel.astype(np.float64))
    expected = theirs.unwrapped._get_obs()
    obs, info = ours.reset(seed=1, options={"qpos": qpos, "qvel": qvel})
    np.testing.assert_allclose(obs, expected, rtol=2e-7, atol=1e-7)
    assert not info["physics_diverged"]
    low, high = theirs.action_space.low, theirs.action_space.high
    for _ in range(30):
        action = rng.uniform(low, high).astype(np.float32)
        obs, reward, terminated, truncated, info = ours.step(action)
        before = _tracked_position(theirs.unwrapped, data)
        expected, expected_reward, expected_terminated, _, _ = theirs.step(action)
        np.testing.assert_allclose(obs, expected, rtol=2.5e-7, atol=1e-7)
        forward = _forward_reward_allowed(env_id, theirs.unwrapped, before)
        assert reward == pytest.approx(expected_reward, rel=1e-6, abs=1e-6 + forward)
        assert terminated == expected_terminated
        if terminated:
            break


def _forward_reward_allowed(env_id: str, env, before: np.ndarray) -> float:
    """Ant and Humanoid: what the float32 positions of the velocity may cost the forward reward
    (see test_mujoco_parity.POSITION_ULPS)."""
    if env_id not in POSITION_ULPS:
        return 0.0
    size = max(before[1, 0], _tracked_position(env, env.data)[1, 0])
    ulps = POSITION_ULPS[env_id] * np.spacing(np.float32(size))
    return env._forward_reward_weight * float(ulps) / env.dt


def test_vector_env_steps_many_envs():
    vector = gymnasium.make_vec(
        "rl_jax/HalfCheetah-v5", num_envs=8, vectorization_mode="vector_entry_point"
    )
    obs, info = vector.reset(seed=0)
    assert obs.shape == (8, 17) and info["physics_diverged"].shape == (8,)
    for _ in range(3):
        obs, reward, terminated, truncated, info = vector.step(vector.action_space.sample())
    assert obs.shape == (8, 17) and reward.shape == (8,) and not terminated.any()
    assert np.isfinite(obs).all() and set(info) >= {"x_velocity", "reward_ctrl"}
