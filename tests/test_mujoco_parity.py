"""Our MuJoCo envs against gymnasium's own MuJoCo envs, on both physics backends.

From the same qpos/qvel/qacc_warmstart and action, one step of ours and one of gymnasium's
(``*-v5``, its default solver settings) must give the same observation, reward and termination;
for the two pendulums also over 50-step open-loop trajectories; and the two backends must agree.
States: 200 drawn from random-policy rollouts of gymnasium's env (10,000 states with their solver
warm starts, stepped past termination so fallen pendulums are included), the 24 of that pool where
gymnasium's constraint solver needed the most iterations, and, for every limited joint, states at
and beyond both limits moving into them. Actions: uniform in
1.2x the action bounds, so MuJoCo's control clamping (and half cheetah's unclipped control cost)
is exercised.

Tolerances, and why:

* ``mujoco`` (C, float64) backend — exact. It runs gymnasium's model with gymnasium's solver
  settings in float64, so its physics state after a step must be bit-identical to gymnasium's.
  Observations then differ from gymnasium's float64 ones only by our float32 output: <= 2 float32
  ulps. Rewards are evaluated in float32 from float32 quantities: a few float32 roundings of the
  largest term, ``1e-6 * (1 + |r|)``.
* ``mjx`` (float32) backend. Its error is float32 rounding propagated through ``frame_skip``
  substeps, whose size depends strongly on the state (soft contacts and joint limits are stiff).
  We measure that conditioning per case with gymnasium itself: the float64 step started from the
  float32-rounded state differs from the exact one by ``s`` (largest change over the observation)
  — what storing the state in float32 alone costs. MJX also rounds at every operation of every substep, so we allow
  ``MJX_SENSITIVITY_FACTOR * s`` plus a floor of ``MJX_FLOOR * (1 + |value|)`` (about 80 float32
  ulps, for well-conditioned cases where ``s`` is ~0). Measured worst cases are listed next to the
  constants.
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs

ENV_IDS = ["InvertedPendulum-v5", "InvertedDoublePendulum-v5", "HalfCheetah-v5"]
PENDULUMS = ENV_IDS[:2]
BACKENDS = ["mujoco", "mjx"]
BATCH = 256  # every check of one env/backend runs through one compiled program of this size
N_RANDOM = 200
N_HARDEST = 24
POOL_EPISODES, POOL_EPISODE_STEPS = 100, 100
TRAJECTORY_STEPS = 50

C_REWARD_RTOL = 1e-6
MJX_SENSITIVITY_FACTOR = 30.0
MJX_FLOOR = 5e-6


# ---- gymnasium reference --------------------------------------------------------------------
def _gym_env(env_id: str):
    env = gymnasium.make(env_id).unwrapped
    env.reset(seed=0)
    return env


def _set(env, vector: np.ndarray) -> None:
    nq, nv = env.model.nq, env.model.nv
    env.set_state(vector[:nq], vector[nq : nq + nv])
    env.data.qacc_warmstart[:] = vector[nq + nv :]


def _gym_step(env, vector: np.ndarray, action: np.ndarray) -> dict:
    _set(env, vector)
    return _gym_step_on(env, action)


def _gym_step_on(env, action: np.ndarray) -> dict:
    obs, reward, terminated, _, _ = env.step(action)
    data = env.data
    return {
        "obs": obs,
        "reward": float(reward),
        "terminated": bool(terminated),
        "state": np.concatenate([data.qpos, data.qvel, data.qacc_warmstart]),
        "tip_height": float(data.site_xpos[0, 2]) if env.model.nsite else np.nan,
    }


def _step_counting_solver_iterations(env, action: np.ndarray) -> int:
    """gymnasium's ``do_simulation`` substep by substep; returns the most solver iterations."""
    env.data.ctrl[:] = action
    worst = 0
    for _ in range(env.frame_skip):
        mujoco.mj_step(env.model, env.data)
        worst = max(worst, int(env.data.solver_niter[0]))
    mujoco.mj_rnePostConstraint(env.model, env.data)
    return worst


def _state_pool(env, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """States of random-policy episodes (action scale varied) and the solver effort from each."""
    low, high = env.action_space.low, env.action_space.high
    states, effort = [], []
    for _ in range(POOL_EPISODES):
        env.reset(seed=int(rng.integers(1 << 30)))
        scale = rng.choice([0.3, 1.0, 1.2])
        for _ in range(POOL_EPISODE_STEPS):  # past termination: fallen and at-limit states too
            states.append(np.concatenate([env.data.qpos, env.data.qvel, env.data.qacc_warmstart]))
            action = (scale * rng.uniform(low, high)).astype(np.float32)
            effort.append(_step_counting_solver_iterations(env, action))
    return np.stack(states), np.asarray(effort)


def _joint_limit_states(env, rng: np.random.Generator, pool: np.ndarray) -> list:
    """For each limited joint: at and beyond each bound, moving into it."""
    model, states = env.model, []
    for joint in range(model.njnt):
        if not model.jnt_limited[joint]:
            continue
        qpos_index, dof = model.jnt_qposadr[joint], model.nq + model.jnt_dofadr[joint]
        for bound, outward in ((model.jnt_range[joint, 0], -1.0), (model.jnt_range[joint, 1], 1.0)):
            for depth in (0.0, 0.01):
                vector = pool[rng.integers(len(pool))].copy()
                vector[qpos_index] = bound + outward * depth
                vector[dof] = outward * (abs(vector[dof]) + 0.5)
                states.append(vector)
    return states


def _sensitivity(reference: list[dict], rounded: list[dict], key: str) -> np.ndarray:
    """Per case, the largest change of ``key`` caused by rounding the start state to float32."""
    return np.array(
        [
            np.max(np.abs(np.subtract(r[key], q[key])))
            for r, q in zip(reference, rounded, strict=True)
        ]
    )


@functools.cache
def one_step_cases(env_id: str) -> dict:
    env, rng = _gym_env(env_id), np.random.default_rng(7)
    pool, effort = _state_pool(env, rng)
    random_rows = rng.choice(len(pool), N_RANDOM, replace=False)
    hardest_rows = np.setdiff1d(np.argsort(effort)[::-1][: 2 * N_HARDEST], random_rows)[:N_HARDEST]
    states = [pool[i] for i in random_rows] + [pool[i] for i in hardest_rows]
    states += _joint_limit_states(env, rng, pool)
    assert len(states) <= BATCH
    low, high = env.action_space.low, env.action_space.high
    actions = [rng.uniform(1.2 * low, 1.2 * high).astype(np.float32) for _ in states]
    pairs = list(zip(states, actions, strict=True))
    reference = [_gym_step(env, s, a) for s, a in pairs]
    # What float32 storage of the start state alone costs, in exact float64 physics.
    rounded = [_gym_step(env, s.astype(np.float32).astype(np.float64), a) for s, a in pairs]
    stack = lambda key: np.stack([r[key] for r in reference])
    return {
        "n": len(states),
        "start": np.stack(states),
        "actions": np.stack(actions),
        "hardest_effort": effort[hardest_rows],
        "obs": stack("obs"),
        "reward": stack("reward"),
        "terminated": stack("terminated"),
        "state": stack("state"),
        "tip_height": stack("tip_height"),
        "obs_sensitivity": _sensitivity(reference, rounded, "obs"),
        "reward_sensitivity": _sensitivity(reference, rounded, "reward"),
    }


@functools.cache
def trajectory_cases(env_id: str) -> dict:
    """BATCH open-loop trajectories from gymnasium resets (seeded), stepped past termination."""
    env, rng = _gym_env(env_id), np.random.default_rng(11)
    low, high = env.action_space.low, env.action_space.high
    actions = rng.uniform(low, high, (TRAJECTORY_STEPS, BATCH, len(low))).astype(np.float32)
    starts, runs = [], {"exact": [], "rounded": []}
    for i in range(BATCH):
        env.reset(seed=i)
        start = np.concatenate([env.data.qpos, env.data.qvel, env.data.qacc_warmstart])
        starts.append(start)
        for name, vector in (
            ("exact", start),
            ("rounded", start.astype(np.float32).astype(np.float64)),
        ):
            _set(env, vector)
            runs[name].append([_gym_step_on(env, actions[t, i]) for t in range(TRAJECTORY_STEPS)])
    field = lambda name, key: np.asarray([[step[key] for step in run] for run in runs[name]])
    sensitivity = np.abs(field("exact", "obs") - field("rounded", "obs")).max(axis=-1)
    return {
        "start": np.stack(starts),
        "actions": actions,
        "obs": field("exact", "obs").transpose(1, 0, 2),  # [time, batch, obs]
        "reward": field("exact", "reward").T,
        "terminated": field("exact", "terminated").T,
        "tip_height": field("exact", "tip_height").T,
        "obs_sensitivity": sensitivity.T,  # [time, batch]
    }


# ---- our envs, one compiled step per env and backend ----------------------------------------
@functools.cache
def engine(env_id: str, backend: str):
    env = envs.make("rl_jax/" + env_id, backend=backend)
    start = jax.jit(jax.vmap(env.start_from_physics))
    step = jax.jit(jax.vmap(env.step))
    return env, start, step


def _pad(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x, np.repeat(x[:1], BATCH - len(x), axis=0)]) if len(x) < BATCH else x


def _start_batch(env_id: str, backend: str, vectors: np.ndarray):
    env, start, _ = engine(env_id, backend)
    nq, nv = env.physics.nq, env.physics.nv
    vectors = _pad(vectors)
    physics = env.physics.from_qpos_qvel(
        vectors[:, :nq], vectors[:, nq : nq + nv], vectors[:, nq + nv :]
    )
    return start(physics)


@functools.cache
def one_step_outputs(env_id: str, backend: str) -> dict:
    env, _, step = engine(env_id, backend)
    cases = one_step_cases(env_id)
    state, _ = _start_batch(env_id, backend, cases["start"])
    keys = jax.random.split(jax.random.PRNGKey(0), BATCH)
    next_state, ts = step(keys, state, jnp.asarray(_pad(cases["actions"])))
    n = cases["n"]
    out = {
        "obs": np.asarray(ts.obs)[:n],
        "reward": np.asarray(ts.reward)[:n],
        "terminated": np.asarray(ts.terminated)[:n],
        "diverged": np.asarray(ts.info["physics_diverged"])[:n],
    }
    qpos, qvel, warm = env.physics.to_numpy(jax.device_get(next_state.physics))
    out["state"] = np.concatenate([qpos, qvel, warm], axis=-1)[:n]
    return out


@functools.cache
def trajectory_outputs(env_id: str, backend: str) -> dict:
    _, _, step = engine(env_id, backend)
    cases = trajectory_cases(env_id)
    state, _ = _start_batch(env_id, backend, cases["start"])
    keys = jax.random.split(jax.random.PRNGKey(1), BATCH)
    obs, rewards, terminated = [], [], []
    for t in range(TRAJECTORY_STEPS):
        state, ts = step(keys, state, jnp.asarray(cases["actions"][t]))
        obs.append(np.asarray(ts.obs))
        rewards.append(np.asarray(ts.reward))
        terminated.append(np.asarray(ts.terminated))
    return {"obs": np.stack(obs), "reward": np.stack(rewards), "terminated": np.stack(terminated)}


# ---- tolerances -----------------------------------------------------------------------------
def _ulp_close(ours: np.ndarray, reference: np.ndarray, ulps: float) -> np.ndarray:
    reference32 = np.asarray(reference, np.float32)
    return np.abs(ours - reference32) <= ulps * np.spacing(np.abs(reference32))


def _mjx_tolerance(reference: np.ndarray, sensitivity: np.ndarray) -> np.ndarray:
    """``sensitivity`` has one value per case (the reference's leading axes)."""
    sensitivity = sensitivity.reshape(
        sensitivity.shape + (1,) * (reference.ndim - sensitivity.ndim)
    )
    return MJX_SENSITIVITY_FACTOR * sensitivity + MJX_FLOOR * (1.0 + np.abs(reference))


def _termination_is_borderline(env_id: str, cases: dict, tolerance: np.ndarray) -> np.ndarray:
    """Cases whose terminating quantity is within tolerance of its threshold."""
    if env_id == "InvertedPendulum-v5":
        return np.abs(np.abs(cases["obs"][..., 1]) - 0.2) <= tolerance[..., 1]
    if env_id == "InvertedDoublePendulum-v5":
        return np.abs(cases["tip_height"] - 1.0) <= np.max(tolerance, axis=-1)
    return np.zeros(cases["terminated"].shape, bool)


def _report(label: str, error: np.ndarray, allowed: np.ndarray) -> str:
    worst = np.unravel_index(np.argmax(error / allowed), error.shape)
    return f"{label}: worst error {error[worst]:.3g} vs allowed {allowed[worst]:.3g} at {worst}"


# ---- tests ----------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_cases_cover_random_hard_and_joint_limit_states(env_id):
    cases = one_step_cases(env_id)
    assert cases["n"] >= N_RANDOM + N_HARDEST
    assert cases["hardest_effort"].min() >= 2  # the solver had constraints to work on
    model = _gym_env(env_id).model
    at_limit = cases["start"][N_RANDOM + N_HARDEST :]
    for joint in np.flatnonzero(model.jnt_limited):
        low, high = model.jnt_range[joint]
        values = at_limit[:, model.jnt_qposadr[joint]]
        assert np.any(values <= low) and np.any(values >= high)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_c_backend_state_is_bit_identical_to_gymnasium(env_id):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, "mujoco")
    np.testing.assert_array_equal(ours["state"], cases["state"])


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_c_backend_one_step_matches_gymnasium(env_id):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, "mujoco")
    close = _ulp_close(ours["obs"], cases["obs"], ulps=2)
    assert close.all(), _report(
        "obs", np.abs(ours["obs"] - cases["obs"]), np.ones_like(ours["obs"])
    )
    np.testing.assert_allclose(
        ours["reward"], cases["reward"], rtol=C_REWARD_RTOL, atol=C_REWARD_RTOL
    )
    np.testing.assert_array_equal(ours["terminated"], cases["terminated"])
    assert not ours["diverged"].any()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_mjx_backend_one_step_matches_gymnasium(env_id):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, "mjx")
    allowed = _mjx_tolerance(cases["obs"], cases["obs_sensitivity"])
    error = np.abs(ours["obs"] - cases["obs"])
    assert (error <= allowed).all(), _report("obs", error, allowed)
    allowed = _mjx_tolerance(cases["reward"], cases["reward_sensitivity"])
    error = np.abs(ours["reward"] - cases["reward"])
    assert (error <= allowed).all(), _report("reward", error, allowed)
    obs_allowed = _mjx_tolerance(cases["obs"], cases["obs_sensitivity"])
    borderline = _termination_is_borderline(env_id, cases, obs_allowed)
    mismatch = ours["terminated"] != cases["terminated"]
    assert not (mismatch & ~borderline).any()
    assert not ours["diverged"].any()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_backends_agree(env_id):
    cases = one_step_cases(env_id)
    c, mjx = one_step_outputs(env_id, "mujoco"), one_step_outputs(env_id, "mjx")
    # C equals gymnasium to float32 precision, so the MJX tolerance applies unchanged.
    allowed = _mjx_tolerance(c["obs"], cases["obs_sensitivity"])
    error = np.abs(mjx["obs"] - c["obs"])
    assert (error <= allowed).all(), _report("obs", error, allowed)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("env_id", PENDULUMS)
def test_trajectories_match_gymnasium(env_id, backend):
    cases, ours = trajectory_cases(env_id), trajectory_outputs(env_id, backend)
    if backend == "mujoco":
        assert _ulp_close(ours["obs"], cases["obs"], ulps=2).all()
        np.testing.assert_array_equal(ours["terminated"], cases["terminated"])
        np.testing.assert_allclose(ours["reward"], cases["reward"], rtol=C_REWARD_RTOL, atol=1e-6)
        return
    allowed = _mjx_tolerance(cases["obs"], cases["obs_sensitivity"])
    error = np.abs(ours["obs"] - cases["obs"])
    assert (error <= allowed).all(), _report("obs", error, allowed)
    borderline = _termination_is_borderline(env_id, cases, allowed)
    assert not ((ours["terminated"] != cases["terminated"]) & ~borderline).any()
