"""Our MuJoCo envs against gymnasium's own MuJoCo envs, on every physics backend.

From the same qpos/qvel/qacc_warmstart and action, one step of ours and one of gymnasium's
(``*-v5``, its default solver settings) must give the same observation, reward and termination
(on the C backends also every reward term gymnasium reports in ``info``, with gymnasium's default
keywords and with non-default ones); for the two pendulums also over 50-step trajectories
(open-loop random actions, and a balancing feedback policy), for Ant and Humanoid over 60-step
open-loop ones on the C backends (their velocity starts from the position remembered at the
previous step); and the backends must agree: MJX with C to its tolerance, the two ways of calling
MuJoCo C (``mujoco_ffi``, the XLA FFI op, and ``mujoco_callback``) bit for bit.
States: 200 drawn from random-policy rollouts of gymnasium's env (10,000 states with their solver
warm starts, stepped past termination so fallen pendulums are included; fewer for Ant and
Humanoid, whose steps cost more: ``SMALL_POOLS``), the 24 of that pool where
gymnasium's constraint solver needed the most iterations, and, for every limited joint, states at
and beyond both limits moving into them. Actions: uniform in 1.2x the action bounds, so
MuJoCo's control clamping (and half cheetah's unclipped control cost) is exercised.

Tolerances, and why:

* ``mujoco_ffi`` and ``mujoco_callback`` (C, float64) backends — exact. They run gymnasium's
  model with gymnasium's solver settings in float64, so the physics state after a step must be
  bit-identical to gymnasium's.
  Observations then differ from gymnasium's float64 ones only by our float32 output: <= 2 float32
  ulps. Rewards are evaluated in float32 from float32 quantities: a few float32 roundings of the
  largest term, ``1e-6 * (1 + |r|)``; the same for each ``info`` term. Reacher's fingertip-target
  vector is the difference of two body positions the backend hands over in float32: 2 float32
  ulps of the positions' size, not of the difference (``POSITION_DIFFERENCES``); likewise Ant's and
  Humanoid's velocities (and forward reward) are differences of float32 positions over dt
  (``POSITION_ULPS``). (Closed-loop
  trajectories feed each side's own float32 observation to the policy, so they get the float32
  allowance of the next item on top.)
* ``mjx`` (float32) backend. Its error is float32 rounding propagated through ``frame_skip``
  substeps, whose size depends strongly on the state. We measure that conditioning per case with
  gymnasium itself: ``s`` is how much gymnasium's own float64 result changes when its state is
  rounded to float32 (before the step; before every step of a trajectory) — what storing the
  state in float32 alone costs (largest change over the observation). MJX also rounds inside
  every operation of every substep (``frame_skip`` forward passes and constraint solves), which
  compounds to far more than one rounding of the state: each case may be off by
  ``SENSITIVITY_FACTOR * s`` (100; the largest factor any case needed was 35, half cheetah) plus
  ``MJX_FLOOR * (1 + |value|)``. The floor (3e-4, ~2,500 float32 ulps) is for active stiff
  constraints — joint limits, floor contacts — whose soft-constraint impedance amplifies the
  float32 error of the solve itself even where rounding the state alone moves little. Measured
  worst: 2.3e-4 absolute for half cheetah in floor contact (DESIGN.md measured ~3e-4 there too),
  7.6e-5 at the pendulum's hinge and slider limits at once, 1.4e-4 accumulated over a 50-step
  trajectory pressed against them. Typical cases are far closer (median relative error 4e-7 for
  the pendulums, 2e-6 for half cheetah), and a systematic mistake (a stale field, a wrong weight)
  would show in most of them, so the median case must also be within
  ``MJX_MEDIAN`` (1e-5) relative. Trajectories are compared while they are predictable in float32
  at all: up to the first step where ``s`` exceeds ``PREDICTABLE`` (1e-5) — past it the double
  pendulum's chaos amplifies any rounding, float64 included — and most balanced trajectories must
  stay predictable for all 50 steps, so the check is not vacuous. Termination may differ only
  where the terminating quantity is within the tolerance of its threshold. Two exceptions, each
  measured and explained where it is defined: Reacher's floor is relative to the case's largest
  observed value (``MJX_FLOOR_PER_CASE``: a fast elbow hitting its limit), and MJX is not
  compared on the constructed hopper state whose leg crosses the torso, where the contact normal
  is undefined and MJX picks another (``_has_contact_without_normal``). Ant and Humanoid are not
  held to it: MJX's physics differs from MuJoCo C 4.0's there beyond rounding (free-joint RK4,
  friction-pyramid orientation, Newton for PGS), so they are compared statistically
  (``FREE_BODY_MEDIAN``).
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from gymnasium.envs.mujoco.ant_v5 import AntEnv
from gymnasium.envs.mujoco.humanoid_v5 import HumanoidEnv, mass_center
from scipy import linalg

from rl_jax import envs
from rl_jax.envs.mujoco import mujoco_ffi_build

ENV_IDS = [
    "InvertedPendulum-v5",
    "InvertedDoublePendulum-v5",
    "HalfCheetah-v5",
    "Hopper-v5",
    "Walker2d-v5",
    "Swimmer-v5",
    "Reacher-v5",
    "Ant-v5",
    "Humanoid-v5",
]
PENDULUMS = ENV_IDS[:2]
WALKERS = ["Hopper-v5", "Walker2d-v5"]  # terminated by gymnasium's health ranges
# 3-D bodies on a free joint whose forward reward is the velocity of a body position that
# gymnasium reads as MuJoCo left it at the previous step, so our envs remember it (Ant: the main
# body's xpos; Humanoid: the bodies' mass centre, from xipos); terminated by the torso's height.
FREE_BODIES = ["Ant-v5", "Humanoid-v5"]
# Envs whose 256-env MJX step is slow to compile and run on a CPU with a cold compilation cache
# (docs/testing.md has the times): their MJX tests are marked slow. The default suite steps MJX on
# the inverted pendulum (one hinge) and half cheetah (contacts, joint limits); the double pendulum
# runs on MJX with the slow tests, and on the C backends in every run.
SLOW_MJX = ("InvertedDoublePendulum-v5", "Hopper-v5", "Walker2d-v5", "Swimmer-v5", "Reacher-v5")
# Ant and Humanoid on MJX differ from gymnasium by more than float32 rounding, for reasons outside
# our envs: they have an MJX test of their own (test_mjx_free_body_one_step_is_close_to_gymnasium),
# slow to compile and run too.
SLOW_FREE_BODY_MJX = ("Ant-v5", "Humanoid-v5")


def mjx_params(env_ids) -> list:
    """``env_ids`` as test parameters, those of ``SLOW_MJX`` marked slow."""
    return [
        pytest.param(env_id, marks=pytest.mark.slow) if env_id in SLOW_MJX else env_id
        for env_id in env_ids
    ]


MJX_ENV_IDS = mjx_params(env_id for env_id in ENV_IDS if env_id not in FREE_BODIES)
C_BACKENDS = ["mujoco_ffi", "mujoco_callback"]
BATCH = 256  # every check of one env/backend runs through one compiled program of this size
N_RANDOM = 200
N_HARDEST = 24
POOL_EPISODES, POOL_EPISODE_STEPS = 100, 100
# Smaller pools where gymnasium's steps are dear: (episodes, random states). An Ant or Humanoid step
# (5 RK4 substeps of a 3-D body) costs several times the others'; Humanoid's 17 limited
# joints give 68 joint-limit states, so it draws 150 random ones to stay within BATCH.
SMALL_POOLS = {"Ant-v5": (30, N_RANDOM), "Humanoid-v5": (20, 150)}
TRAJECTORY_STEPS = 50
FREE_TRAJECTORIES, FREE_TRAJECTORY_STEPS = 16, 60  # of Ant and Humanoid (FREE_BODIES)

C_REWARD_RTOL = 1e-6
SENSITIVITY_FACTOR = 100.0
MJX_FLOOR = 3e-4
MJX_MEDIAN = 1e-5
PREDICTABLE = 1e-5


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
    before = _has_contact_without_normal(env)
    step = _gym_step_on(env, action)
    step["contact_without_normal"] |= before
    return step


def _gym_step_on(env, action: np.ndarray) -> dict:
    before = _tracked_position(env, env.data)
    obs, reward, terminated, _, info = env.step(action)
    data = env.data
    return {
        "obs": obs,
        "reward": float(reward),
        "terminated": bool(terminated),
        "state": np.concatenate([data.qpos, data.qvel, data.qacc_warmstart]),
        "tip_height": float(data.site_xpos[0, 2]) if env.model.nsite else np.nan,
        # Humanoid's info also holds the tendon lengths and velocities: arrays, not reward terms
        # (our Humanoid leaves them out)
        "info": {key: float(value) for key, value in info.items() if np.ndim(value) == 0},
        "contact_without_normal": _has_contact_without_normal(env),
        # [before/after, position/size, x/y]
        "position": np.stack([before, _tracked_position(env, data)]),
    }


def _tracked_position(env, data) -> np.ndarray:
    """[2, x/y]: the x, y whose change over a step, divided by dt, gymnasium's Ant and Humanoid
    reward as velocity, read from ``data`` as they read it, and the largest size of the body
    positions it is computed from (NaN for the other envs)."""
    if isinstance(env, AntEnv):
        position = data.body(env._main_body).xpos[:2].copy()
        return np.stack([position, np.abs(position)])
    if isinstance(env, HumanoidEnv):  # the bodies' mass centre
        return np.stack([mass_center(env.model, data), np.max(np.abs(data.xipos[:, :2]), axis=0)])
    return np.full((2, 2), np.nan)


def _reward_constants(env) -> dict:
    """What the velocity tolerance of a case needs of gymnasium's env (see _velocity_allowed)."""
    return {"dt": env.dt, "forward_weight": getattr(env, "_forward_reward_weight", 0.0)}


def _has_contact_without_normal(env) -> bool:
    """Whether a contact of the current data has a normal that no joint can move along.

    Two capsules whose axes cross have no defined contact normal. The hopper is planar: MuJoCo C
    picks one out of its plane, where the contact exerts no force, and MJX one in the plane, where
    it pushes. Only the constructed joint-limit states reach this (a leg forced through the torso;
    none of 10,000 random-policy states), so MJX is not compared on such cases.
    """
    model, data = env.model, env.data
    body_jacobians = [np.zeros((3, model.nv)), np.zeros((3, model.nv))]
    # Indexed one by one: iterating a slice of ``data.contact`` is slow even when it is empty, and
    # every gymnasium reference step calls this.
    for index in range(data.ncon):
        contact = data.contact[index]
        for jacobian, geom in zip(body_jacobians, (contact.geom1, contact.geom2), strict=True):
            mujoco.mj_jac(model, data, jacobian, None, contact.pos, model.geom_bodyid[geom])
        if not np.any(contact.frame[:3] @ (body_jacobians[1] - body_jacobians[0])):
            return True
    return False


def _step_counting_solver_iterations(env, action: np.ndarray) -> int:
    """gymnasium's ``do_simulation`` substep by substep; returns the most solver iterations."""
    env.data.ctrl[:] = action
    worst = 0
    for _ in range(env.frame_skip):
        mujoco.mj_step(env.model, env.data)
        worst = max(worst, int(env.data.solver_niter[0]))
    mujoco.mj_rnePostConstraint(env.model, env.data)
    return worst


def _state_pool(env, rng: np.random.Generator, episodes: int) -> tuple[np.ndarray, np.ndarray]:
    """States of random-policy episodes (action scale varied) and the solver effort from each."""
    low, high = env.action_space.low, env.action_space.high
    states, effort = [], []
    for _ in range(episodes):
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
    episodes, n_random = SMALL_POOLS.get(env_id, (POOL_EPISODES, N_RANDOM))
    pool, effort = _state_pool(env, rng, episodes)
    random_rows = rng.choice(len(pool), n_random, replace=False)
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
    return {
        "n": len(states),
        "n_random": n_random,
        **_reward_constants(env),
        "start": np.stack(states),
        "actions": np.stack(actions),
        "hardest_effort": effort[hardest_rows],
        **_stack_steps(reference),
        "obs_sensitivity": _sensitivity(reference, rounded, "obs"),
        "reward_sensitivity": _sensitivity(reference, rounded, "reward"),
    }


def _stack_steps(steps: list[dict]) -> dict:
    stacked = {key: np.stack([s[key] for s in steps]) for key in steps[0] if key != "info"}
    info = {key: np.array([s["info"][key] for s in steps]) for key in steps[0]["info"]}
    return {**stacked, "info": info}


def _balancing_gain(env) -> np.ndarray:
    """LQR gain of the agent-step dynamics, linearised (central differences) at the upright pose.

    Both pendulums have only scalar joints, so qpos is its own tangent space.
    """
    model, data = env.model, mujoco.MjData(env.model)
    nv, nu, eps = model.nv, model.nu, 1e-6

    def agent_step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:], data.ctrl[:] = x[:nv], x[nv:], u
        mujoco.mj_step(model, data, nstep=env.frame_skip)
        return np.concatenate([data.qpos, data.qvel])

    x0, u0 = np.concatenate([model.qpos0, np.zeros(nv)]), np.zeros(nu)
    jacobian = lambda f, n: np.stack(
        [(f(eps * e) - f(-eps * e)) / (2 * eps) for e in np.eye(n)], axis=1
    )
    a = jacobian(lambda dx: agent_step(x0 + dx, u0), 2 * nv)
    b = jacobian(lambda du: agent_step(x0, u0 + du), nu)
    cost_state, cost_action = np.diag([1.0] * nv + [0.1] * nv), np.eye(nu)
    riccati = linalg.solve_discrete_are(a, b, cost_state, cost_action)
    return np.linalg.solve(cost_action + b.T @ riccati @ b, b.T @ riccati @ a)


def _state_from_obs(env_id: str, obs: np.ndarray) -> np.ndarray:
    """[qpos, qvel] recovered from a pendulum observation (what the balancing policy sees)."""
    if env_id == "InvertedPendulum-v5":
        return np.asarray(obs, np.float64)
    angles = np.arctan2(obs[..., 1:3], obs[..., 3:5])
    return np.concatenate([obs[..., :1], angles, obs[..., 5:8]], axis=-1)


def _balancing_policy(env_id: str, gain: np.ndarray, low: np.ndarray, high: np.ndarray):
    """Linear feedback on the (float32) observation plus a given exploration noise."""

    def policy(obs: np.ndarray, noise: np.ndarray) -> np.ndarray:
        obs32 = np.asarray(obs, np.float32)
        action = -_state_from_obs(env_id, obs32) @ gain.T + noise
        return np.clip(action, low, high).astype(np.float32)

    return policy


def _rounded(vector: np.ndarray) -> np.ndarray:
    return vector.astype(np.float32).astype(np.float64)


def _run_gym_trajectory(env, start, open_loop, noise, policy, round_each_step: bool) -> list:
    _set(env, start)
    obs, steps = env.unwrapped._get_obs(), []
    for t in range(TRAJECTORY_STEPS):
        if round_each_step:  # what float32 storage of the state costs, step after step
            state = np.concatenate([env.data.qpos, env.data.qvel, env.data.qacc_warmstart])
            _set(env, _rounded(state))
        action = open_loop[t] if policy is None else policy(obs, noise[t])
        steps.append(_gym_step_on(env, action))
        obs = steps[-1]["obs"]
    return steps


@functools.cache
def trajectory_cases(env_id: str) -> dict:
    """BATCH 50-step trajectories from gymnasium resets (seeded), stepped past termination.

    Even rows: open-loop random actions (the pendulums fall, hit joint limits; the double
    pendulum then swings chaotically, where float32 and float64 part ways within a few steps and
    the rounding sensitivity below grows accordingly). Odd rows: a balancing linear feedback on
    each simulator's own observation plus exploration noise, which keeps them in the upright
    regime learners care about, where errors stay bounded.
    """
    env, rng = _gym_env(env_id), np.random.default_rng(11)
    low, high = env.action_space.low, env.action_space.high
    shape = (TRAJECTORY_STEPS, BATCH, len(low))
    open_loop = rng.uniform(low, high, shape).astype(np.float32)
    noise = rng.normal(0.0, 0.2 * (high - low) / 2, shape)
    policy = _balancing_policy(env_id, _balancing_gain(env), low, high)
    starts, exact, rounded = [], [], []
    for i in range(BATCH):
        env.reset(seed=i)
        start = np.concatenate([env.data.qpos, env.data.qvel, env.data.qacc_warmstart])
        starts.append(start)
        row_policy = policy if i % 2 else None
        args = (start, open_loop[:, i], noise[:, i], row_policy)
        exact.append(_run_gym_trajectory(env, *args, round_each_step=False))
        rounded.append(_run_gym_trajectory(env, *args, round_each_step=True))
    field = lambda runs, key: np.asarray([[step[key] for step in run] for run in runs]).swapaxes(
        0, 1
    )
    sensitivity = np.abs(field(exact, "obs") - field(rounded, "obs")).max(axis=-1)
    reward_sensitivity = np.abs(field(exact, "reward") - field(rounded, "reward"))
    return {
        "start": np.stack(starts),
        "open_loop": open_loop,
        "noise": noise,
        "policy": policy,
        "closed_loop": np.arange(BATCH) % 2 == 1,
        "obs": field(exact, "obs"),  # [time, batch, obs]
        "reward": field(exact, "reward"),
        "terminated": field(exact, "terminated"),
        "tip_height": field(exact, "tip_height"),
        "obs_sensitivity": sensitivity,  # [time, batch]
        "reward_sensitivity": reward_sensitivity,
    }


def _full_state(data) -> np.ndarray:
    return np.concatenate([data.qpos, data.qvel, data.qacc_warmstart])


@functools.cache
def free_trajectory_cases(env_id: str) -> dict:
    """FREE_TRAJECTORIES trajectories of gymnasium's Ant or Humanoid from seeded resets, under
    open-loop random actions (uniform in 1.2x the bounds) for FREE_TRAJECTORY_STEPS steps, past
    termination (every humanoid falls, after 17-42 steps, and then lies in floor contact; 7 of the
    16 ants leave the healthy height range).

    The velocity of every step but the first starts from the position MuJoCo left at the previous
    step, one substep stale; ``current_position`` is the position at the step's start, what an env
    that forgot the previous step would start from.
    """
    env, rng = _gym_env(env_id), np.random.default_rng(13)
    low, high = env.action_space.low, env.action_space.high
    shape = (FREE_TRAJECTORIES, FREE_TRAJECTORY_STEPS, len(low))
    actions = rng.uniform(1.2 * low, 1.2 * high, shape).astype(np.float32)
    scratch = mujoco.MjData(env.model)
    starts, steps = [], []
    for row in range(FREE_TRAJECTORIES):
        env.reset(seed=1000 + row)
        starts.append(_full_state(env.data))
        for action in actions[row]:
            scratch.qpos[:] = env.data.qpos
            mujoco.mj_kinematics(env.model, scratch)
            current = _tracked_position(env, scratch)[0]
            steps.append({**_gym_step_on(env, action), "current_position": current})
    by_trajectory = lambda x: x.reshape(shape[:2] + x.shape[1:])
    return {
        **_reward_constants(env),
        "start": np.stack(starts),
        "actions": actions,
        **jax.tree.map(by_trajectory, _stack_steps(steps)),  # [trajectory, time, ...]
    }


# ---- our envs, one compiled step per env and backend ----------------------------------------
@functools.cache
def engine(env_id: str, backend: str):
    if backend == "mujoco_ffi" and not mujoco_ffi_build.available():
        pytest.skip("the MuJoCo FFI op cannot be built here")
    env = envs.make("rl_jax/" + env_id, backend=backend)
    start = jax.jit(jax.vmap(env.start_from_physics))
    step = jax.jit(jax.vmap(env.step))
    return env, start, step


def _pad(x: np.ndarray) -> np.ndarray:
    return np.concatenate([x, np.repeat(x[:1], BATCH - len(x), axis=0)]) if len(x) < BATCH else x


def _start_batch(env_id: str, backend: str, vectors: np.ndarray):
    env, start, _ = engine(env_id, backend)
    return _start_on(env, start, vectors)


def _start_on(env, start, vectors: np.ndarray):
    nq, nv = env.physics.nq, env.physics.nv
    vectors = _pad(vectors)
    physics = env.physics.from_qpos_qvel(
        vectors[:, :nq], vectors[:, nq : nq + nv], vectors[:, nq + nv :]
    )
    return start(physics)


@functools.cache
def one_step_outputs(env_id: str, backend: str) -> dict:
    return _one_step_on(*engine(env_id, backend), one_step_cases(env_id))


def _one_step_on(env, start, step, cases: dict) -> dict:
    """One step of ours from each case's start state: outputs, reward terms and next state."""
    state, _ = _start_on(env, start, cases["start"])
    keys = jax.random.split(jax.random.PRNGKey(0), BATCH)
    next_state, ts = step(keys, state, jnp.asarray(_pad(cases["actions"])))
    n = cases["n"]
    out = {
        "obs": np.asarray(ts.obs)[:n],
        "reward": np.asarray(ts.reward)[:n],
        "terminated": np.asarray(ts.terminated)[:n],
        "diverged": np.asarray(ts.info["physics_diverged"])[:n],
        "info": {key: np.asarray(value)[:n] for key, value in ts.info.items()},
    }
    if hasattr(state, "memory"):  # the position remembered at the start (see FREE_BODIES)
        out["memory"] = np.asarray(state.memory)[:n]
    qpos, qvel, warm = env.physics.to_numpy(jax.device_get(next_state.physics))
    out["state"] = np.concatenate([qpos, qvel, warm], axis=-1)[:n]
    return out


@functools.cache
def trajectory_outputs(env_id: str, backend: str) -> dict:
    _, _, step = engine(env_id, backend)
    cases = trajectory_cases(env_id)
    state, ts = _start_batch(env_id, backend, cases["start"])
    keys = jax.random.split(jax.random.PRNGKey(1), BATCH)
    obs, rewards, terminated = [], [], []
    closed = cases["closed_loop"][:, None]
    for t in range(TRAJECTORY_STEPS):
        feedback = cases["policy"](np.asarray(ts.obs), cases["noise"][t])
        actions = np.where(closed, feedback, cases["open_loop"][t])
        state, ts = step(keys, state, jnp.asarray(actions))
        obs.append(np.asarray(ts.obs))
        rewards.append(np.asarray(ts.reward))
        terminated.append(np.asarray(ts.terminated))
    return {"obs": np.stack(obs), "reward": np.stack(rewards), "terminated": np.stack(terminated)}


@functools.cache
def free_trajectory_outputs(env_id: str, backend: str) -> dict:
    """Our env over the trajectories of ``free_trajectory_cases``, in one compiled scan."""
    env = engine(env_id, backend)[0]
    cases = free_trajectory_cases(env_id)

    def run(physics, actions):
        state, _ = env.start_from_physics(physics)

        def step(state, action):
            state, ts = env.step(jax.random.PRNGKey(0), state, action)
            return state, (ts, state.physics)

        return jax.lax.scan(step, state, actions)[1]

    nq, nv, start = env.physics.nq, env.physics.nv, cases["start"]
    physics = env.physics.from_qpos_qvel(start[:, :nq], start[:, nq : nq + nv], start[:, nq + nv :])
    ts, physics = jax.jit(jax.vmap(run))(physics, jnp.asarray(cases["actions"]))
    qpos, qvel, warm = env.physics.to_numpy(jax.device_get(physics))
    return {
        "obs": np.asarray(ts.obs),
        "reward": np.asarray(ts.reward),
        "terminated": np.asarray(ts.terminated),
        "diverged": np.asarray(ts.info["physics_diverged"]),
        "info": {key: np.asarray(value) for key, value in ts.info.items()},
        "state": np.concatenate([qpos, qvel, warm], axis=-1),
    }


# ---- tolerances -----------------------------------------------------------------------------
def _per_case(values: np.ndarray, like: np.ndarray) -> np.ndarray:
    """Broadcast one value per case over the trailing (observation) axis of ``like``."""
    return values.reshape(values.shape + (1,) * (like.ndim - values.ndim))


def _float32_ulps(reference: np.ndarray, ulps: float) -> np.ndarray:
    return ulps * np.spacing(np.abs(np.asarray(reference, np.float32)))


# Observation entries that are differences of two body positions, which the C backend hands to the
# env in float32: exact to 2 float32 ulps of the positions' size, not of the (smaller) difference.
# Reacher: fingertip - target; every coordinate of either is below 0.3 (the arm reaches 0.21, the
# target's slides end at 0.27).
POSITION_DIFFERENCES = {"Reacher-v5": (slice(8, 10), 0.3)}


# Ant's and Humanoid's velocities are (position after - position before) / dt of positions our
# envs compute in float32 from the float32 body positions the C backend hands over, where
# gymnasium subtracts float64 ones: each position is off by float32 rounding of the body
# positions' size (Ant: its main body's xpos, so half an ulp; Humanoid: the mass-weighted mean of
# 14 bodies' xipos summed in float32, whose products and additions round too: measured within
# 1.1 ulps of the largest |xipos| on the one-step cases), so a velocity component may be off by
# POSITION_ULPS[env] ulps (twice one position's bound, rounded up) over dt, and the forward reward
# by that times its weight, whatever the (possibly small) velocity: at |x| ~ 1, 2 ulps are 2.4e-7
# m, 4.8e-6 m/s over Ant's 0.05 s; 3 ulps over Humanoid's 0.015 s are 2.4e-5 m/s.
POSITION_ULPS = {"Ant-v5": 2, "Humanoid-v5": 3}


def _velocity_allowed(env_id: str, cases: dict) -> np.ndarray:
    """[..., x/y] what float32 positions may cost each velocity component of each case."""
    positions = cases["position"]  # [..., before/after, position/size, x/y]
    if env_id not in POSITION_ULPS:
        return np.zeros(positions.shape[:-3] + (2,))
    size = np.max(positions[..., 1, :], axis=-2)
    return _float32_ulps(size, POSITION_ULPS[env_id]) / cases["dt"]


def _c_reward_allowed(env_id: str, cases: dict) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """C backends: the reward's allowance and each info term's (float32 evaluation, and the
    velocity's float32 positions where there are any)."""
    velocity = _velocity_allowed(env_id, cases)
    forward = cases["forward_weight"] * velocity[..., 0]
    position_terms = {
        "x_velocity": velocity[..., 0],
        "y_velocity": velocity[..., 1],
        "reward_forward": forward,
    }
    info = {
        key: C_REWARD_RTOL * (1.0 + np.abs(reference)) + position_terms.get(key, 0.0)
        for key, reference in cases["info"].items()
    }
    return C_REWARD_RTOL * (1.0 + np.abs(cases["reward"])) + forward, info


def _c_obs_allowed(env_id: str, reference: np.ndarray) -> np.ndarray:
    allowed = _float32_ulps(reference, 2)
    if env_id in POSITION_DIFFERENCES:
        columns, size = POSITION_DIFFERENCES[env_id]
        allowed[..., columns] += 2 * np.spacing(np.float32(size))
    return allowed


# Envs whose MJX floor is relative to the case's largest observed value instead of each value's
# own. Reacher: when the elbow hits its limit at up to ~30 rad/s, the constraint impulse moves
# momentum into the shoulder, whose velocity then carries float32 error of the impulse's size
# (worst measured: 9.8e-4 on a shoulder velocity of 0.69 after a 29 rad/s impact, 1.5x the
# per-value floor; MJX run in float64 reproduces gymnasium there to 1e-8).
MJX_FLOOR_PER_CASE = {"Reacher-v5"}


def _mjx_obs_allowed(env_id: str, cases: dict, obs: np.ndarray) -> np.ndarray:
    """MJX's allowance on the observations ``obs`` of one-step ``cases`` (see the module
    docstring), NaN (not compared) on the cases with a contact without a normal."""
    allowed = _allowed("mjx", obs, cases["obs_sensitivity"])
    if env_id in MJX_FLOOR_PER_CASE:
        case_size = np.max(np.abs(obs), axis=-1, keepdims=True)
        allowed = np.maximum(allowed, MJX_FLOOR * (1.0 + case_size))
    return _hide_contacts_without_normal(cases, allowed)


def _hide_contacts_without_normal(cases: dict, allowed: np.ndarray) -> np.ndarray:
    hidden = cases["contact_without_normal"]
    assert hidden.mean() < 0.02  # a few constructed states, not a way around the comparison
    return np.where(_per_case(hidden, allowed), np.nan, allowed)


def _allowed(backend: str, reference: np.ndarray, sensitivity: np.ndarray) -> np.ndarray:
    rounding = SENSITIVITY_FACTOR * _per_case(sensitivity, reference)
    if backend in C_BACKENDS:
        return rounding + _float32_ulps(reference, 2)
    return rounding + MJX_FLOOR * (1.0 + np.abs(reference))


def _assert_close(label: str, ours, reference, allowed) -> None:
    error = np.where(np.isnan(allowed), 0.0, np.abs(ours - reference))
    allowed = np.where(np.isnan(allowed), 1.0, allowed)
    worst = np.unravel_index(np.argmax(error / allowed), error.shape)
    assert (error <= allowed).all(), (
        f"{label}: error {error[worst]:.3g} > allowed {allowed[worst]:.3g} at {worst}"
    )


def _assert_typically_close(label: str, ours, reference, compared: np.ndarray) -> None:
    relative = np.abs(ours - reference)[compared] / (1.0 + np.abs(reference[compared]))
    per_case = relative.reshape(-1, relative.shape[-1]).max(axis=-1)
    assert np.median(per_case) <= MJX_MEDIAN, f"{label}: median error {np.median(per_case):.3g}"


def _borderline(env_id: str, cases: dict, allowed_obs: np.ndarray) -> np.ndarray:
    """Cases whose terminating quantity is within tolerance of its threshold."""
    if env_id == "InvertedPendulum-v5":
        return np.abs(np.abs(cases["obs"][..., 1]) - 0.2) <= allowed_obs[..., 1]
    if env_id == "InvertedDoublePendulum-v5":
        return np.abs(cases["tip_height"] - 1.0) <= np.max(allowed_obs, axis=-1)
    if env_id in WALKERS:
        return _near_health_bounds(_gym_env(env_id), cases["state"], np.max(allowed_obs, axis=-1))
    if env_id in FREE_BODIES:  # the torso's height, the observation's first entry
        z, tolerance = cases["obs"][..., 0], allowed_obs[..., 0]
        bounds = _gym_env(env_id)._healthy_z_range
        return np.any([np.abs(z - b) <= tolerance * (1 + b) for b in bounds], axis=0)
    return np.zeros(cases["terminated"].shape, bool)


def _near_health_bounds(env, state: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """Hopper/walker states whose height, angle or (hopper) any other state component is within
    ``tolerance`` (relative to the bound's size) of gymnasium's health range."""
    nq, nv = env.model.nq, env.model.nv

    def near(values: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
        finite = [b for b in bounds if np.isfinite(b)]
        scale = _per_case(tolerance, values)
        return np.any([np.abs(values - b) <= scale * (1 + abs(b)) for b in finite], axis=0)

    border = near(state[:, 1], env._healthy_z_range) | near(state[:, 2], env._healthy_angle_range)
    if hasattr(env, "_healthy_state_range"):
        border |= near(state[:, 2 : nq + nv], env._healthy_state_range).any(axis=-1)
    return border


def _assert_same_episode_ends(env_id, ours, cases, allowed_obs) -> None:
    mismatch = ours["terminated"] != cases["terminated"]
    assert not (mismatch & ~_borderline(env_id, cases, allowed_obs)).any()


# ---- tests ----------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_cases_cover_random_hard_and_joint_limit_states(env_id):
    cases = one_step_cases(env_id)
    assert cases["n"] >= cases["n_random"] + N_HARDEST
    assert cases["hardest_effort"].min() >= 2  # the solver had constraints to work on
    model = _gym_env(env_id).model
    at_limit = cases["start"][cases["n_random"] + N_HARDEST :]
    for joint in np.flatnonzero(model.jnt_limited):
        low, high = model.jnt_range[joint]
        values = at_limit[:, model.jnt_qposadr[joint]]
        assert np.any(values <= low) and np.any(values >= high)


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_c_backend_state_is_bit_identical_to_gymnasium(env_id, backend):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, backend)
    np.testing.assert_array_equal(ours["state"], cases["state"])


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_c_backend_one_step_matches_gymnasium(env_id, backend):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, backend)
    _assert_c_step_matches(env_id, ours, cases)


def _assert_c_step_matches(env_id: str, ours: dict, cases: dict) -> None:
    """Exact physics; float32 outputs; every reward term gymnasium reports in ``info``."""
    np.testing.assert_array_equal(ours["state"], cases["state"])
    _assert_close("obs", ours["obs"], cases["obs"], _c_obs_allowed(env_id, cases["obs"]))
    reward_allowed, info_allowed = _c_reward_allowed(env_id, cases)
    _assert_close("reward", ours["reward"], cases["reward"], reward_allowed)
    np.testing.assert_array_equal(ours["terminated"], cases["terminated"])
    assert not ours["diverged"].any()
    assert set(cases["info"]) <= set(ours["info"]), set(cases["info"]) - set(ours["info"])
    for key, reference in cases["info"].items():
        _assert_close(f"info[{key!r}]", ours["info"][key], reference, info_allowed[key])


# Non-default gymnasium keywords: structural ones (constructor arguments) and numeric ones (params),
# ranges given as gymnasium's (low, high) tuples.
KEYWORD_CASES = {
    "Hopper-no-termination": (
        "Hopper-v5",
        {
            "terminate_when_unhealthy": False,
            "healthy_z_range": (1.0, 1.35),
            "healthy_angle_range": (-0.1, 0.3),
            "healthy_state_range": (-20.0, 20.0),
            "healthy_reward": 2.0,
            "ctrl_cost_weight": 0.01,
            "forward_reward_weight": 0.5,
        },
    ),
    "Hopper-ranges": (
        "Hopper-v5",
        {"healthy_z_range": (1.0, 1.35), "exclude_current_positions_from_observation": False},
    ),
    "Walker2d": (
        "Walker2d-v5",
        {
            "exclude_current_positions_from_observation": False,
            "healthy_z_range": (1.0, 1.5),
            "healthy_angle_range": (-0.5, 0.5),
            "forward_reward_weight": 2.0,
        },
    ),
    "Swimmer": (
        "Swimmer-v5",
        {
            "exclude_current_positions_from_observation": False,
            "forward_reward_weight": 3.0,
            "ctrl_cost_weight": 0.01,
        },
    ),
    "Reacher": ("Reacher-v5", {"reward_dist_weight": 2.5, "reward_control_weight": 0.3}),
    "Ant": (
        "Ant-v5",
        {
            "include_cfrc_ext_in_observation": False,
            "healthy_z_range": (0.3, 0.9),
            "contact_cost_weight": 0.01,
            "main_body": "torso",  # by name: body 1, as the default main_body=1
        },
    ),
    "Humanoid": (
        "Humanoid-v5",
        {
            "terminate_when_unhealthy": False,
            "include_cinert_in_observation": False,
            "contact_cost_range": (0.0, 5.0),
        },
    ),
}


@pytest.mark.parametrize("case", KEYWORD_CASES)
def test_c_backend_with_gymnasium_keywords_matches_gymnasium(case):
    env_id, keywords = KEYWORD_CASES[case]
    gym_env = gymnasium.make(env_id, **keywords).unwrapped
    gym_env.reset(seed=0)
    cases = dict(one_step_cases(env_id))
    pairs = zip(cases["start"], cases["actions"], strict=True)
    cases.update(_stack_steps([_gym_step(gym_env, s, a) for s, a in pairs]))
    cases.update(_reward_constants(gym_env))
    ours = envs.make("rl_jax/" + env_id, backend="mujoco", **keywords)
    start, step = jax.jit(jax.vmap(ours.start_from_physics)), jax.jit(jax.vmap(ours.step))
    _assert_c_step_matches(env_id, _one_step_on(ours, start, step, cases), cases)
    if env_id == "Hopper-v5":  # the changed health ranges decide some of these cases
        healthy = cases["info"]["reward_survive"] > 0
        assert healthy.any() and not healthy.all()
        terminates = keywords.get("terminate_when_unhealthy", True)
        np.testing.assert_array_equal(cases["terminated"], ~healthy & terminates)
    if env_id in FREE_BODIES:  # the changed ranges decide some cases, termination follows
        healthy = cases["info"]["reward_survive"] > 0
        assert healthy.any() and not healthy.all()
        terminates = keywords.get("terminate_when_unhealthy", True)
        np.testing.assert_array_equal(cases["terminated"], ~healthy & terminates)
    if env_id == "Humanoid-v5":  # the contact cost reaches the range's cap on some cases
        capped = cases["info"]["reward_contact"] == -5.0
        assert capped.any() and not capped.all()


@pytest.mark.parametrize("env_id", MJX_ENV_IDS)
def test_mjx_backend_one_step_matches_gymnasium(env_id):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, "mjx")
    allowed_obs = _mjx_obs_allowed(env_id, cases, cases["obs"])
    _assert_close("obs", ours["obs"], cases["obs"], allowed_obs)
    _assert_typically_close("obs", ours["obs"], cases["obs"], ~cases["contact_without_normal"])
    allowed = _allowed("mjx", cases["reward"], cases["reward_sensitivity"])
    allowed = _hide_contacts_without_normal(cases, allowed)
    _assert_close("reward", ours["reward"], cases["reward"], allowed)
    _assert_same_episode_ends(env_id, ours, cases, np.nan_to_num(allowed_obs, nan=np.inf))
    assert not ours["diverged"].any()


# Ant and Humanoid on MJX, measured on the one-step cases: MJX differs from gymnasium by more than
# float32 rounding, for three reasons outside our envs, each found in float64 (MJX with x64 against
# MuJoCo C 4.0): (1) MuJoCo C's RK4 advances a free joint's orientation differently from MJX's
# textbook RK4 (a spinning free box: 1e-8 to 7e-7 in qpos per substep, while MJX equals textbook RK4
# built on MuJoCo C's own forward pass to 1e-16; an Ant substep without contacts, at joint limits:
# 6e-6; with Euler both agree to 1e-16); (2) MJX builds a capsule-plane contact's tangent frame from
# the world axes where MuJoCo C aligns it with the capsule's horizontal direction, which turns the
# pyramidal friction cone of the Ant's feet (the Humanoid's feet are spheres, where both frames
# agree, but its fallen limbs are capsules): 30% of the Ant's random-policy cases end with a joint
# velocity off by more than 1e-3 relative, up to 0.72; (3) Humanoid solves with Newton instead of
# PGS (measured in envs/mujoco/humanoid.py). So the comparison is statistical: in each part of the
# observation and in the reward and each reward term, the median random-policy case must be within
# FREE_BODY_MEDIAN relative (1e-3; the largest measured median was 6.3e-5, the Humanoid's contact
# forces), where a systematic mistake (a stale or misplaced field, a wrong weight, velocity from the
# wrong previous position: a fifth of the velocity) moves most cases by 1e-2 or more; and, since a
# step moves positions by velocity times 0.05 s at most, every case's qpos must be within
# FREE_BODY_QPOS (0.05 relative; measured: 0.011 Ant, 6.4e-4 Humanoid). Termination may differ only
# within that of the height bounds.
FREE_BODY_MEDIAN = 1e-3
FREE_BODY_QPOS = 0.05
# The observation's parts in order: sizes (the cfrc_ext, cinert and cvel of the 13 or 14 bodies).
OBS_PARTS = {
    "Ant-v5": {"qpos": 13, "qvel": 14, "cfrc_ext": 78},
    "Humanoid-v5": {
        "qpos": 22,
        "qvel": 23,
        "cinert": 130,
        "cvel": 78,
        "qfrc_actuator": 17,
        "cfrc_ext": 78,
    },
}


@pytest.mark.parametrize(
    "env_id",
    [pytest.param(env_id, marks=pytest.mark.slow) for env_id in SLOW_FREE_BODY_MJX],
)
def test_mjx_free_body_one_step_is_close_to_gymnasium(env_id):
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, "mjx")
    random = slice(cases["n_random"])
    relative = lambda x, reference: np.abs(x - reference) / (1.0 + np.abs(reference))
    error = relative(ours["obs"], cases["obs"])
    parts = np.cumsum([0, *OBS_PARTS[env_id].values()])
    assert parts[-1] == error.shape[-1]
    for name, start, end in zip(OBS_PARTS[env_id], parts[:-1], parts[1:], strict=True):
        median = np.median(error[random, start:end].max(axis=-1))
        assert median <= FREE_BODY_MEDIAN, f"obs {name}: median error {median:.3g}"
    assert error[:, : parts[1]].max() <= FREE_BODY_QPOS
    median = np.median(relative(ours["reward"], cases["reward"])[random])
    assert median <= FREE_BODY_MEDIAN, f"reward: median error {median:.3g}"
    for key, reference in cases["info"].items():
        median = np.median(relative(ours["info"][key], reference)[random])
        assert median <= FREE_BODY_MEDIAN, f"info[{key!r}]: median error {median:.3g}"
    allowed_obs = FREE_BODY_QPOS * (1.0 + np.abs(cases["obs"]))
    _assert_same_episode_ends(env_id, ours, cases, allowed_obs)
    assert not ours["diverged"].any()


@pytest.mark.parametrize("env_id", MJX_ENV_IDS)
def test_backends_agree(env_id):
    """MJX against our C backend directly (which equals gymnasium to float32 output rounding)."""
    cases = one_step_cases(env_id)
    c, mjx = one_step_outputs(env_id, "mujoco_callback"), one_step_outputs(env_id, "mjx")
    allowed = _mjx_obs_allowed(env_id, cases, c["obs"]) + _c_obs_allowed(env_id, c["obs"])
    _assert_close("obs", mjx["obs"], c["obs"], allowed)
    allowed = _allowed("mjx", c["reward"], cases["reward_sensitivity"])
    allowed = _hide_contacts_without_normal(cases, allowed)
    _assert_close("reward", mjx["reward"], c["reward"], allowed + C_REWARD_RTOL)


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", PENDULUMS)
def test_c_backend_trajectories_match_gymnasium(env_id, backend):
    cases, ours = trajectory_cases(env_id), trajectory_outputs(env_id, backend)
    allowed_obs = _allowed(backend, cases["obs"], cases["obs_sensitivity"])
    _assert_close("obs", ours["obs"], cases["obs"], allowed_obs)
    allowed = _allowed(backend, cases["reward"], cases["reward_sensitivity"])
    _assert_close("reward", ours["reward"], cases["reward"], allowed + C_REWARD_RTOL)
    _assert_same_episode_ends(env_id, ours, cases, allowed_obs)
    # open loop: same inputs, same float64 physics, so exact up to the float32 output rounding
    open_loop = ~cases["closed_loop"]
    ours_open, reference_open = ours["obs"][:, open_loop], cases["obs"][:, open_loop]
    _assert_close("open-loop obs", ours_open, reference_open, _float32_ulps(reference_open, 2))


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", FREE_BODIES)
def test_c_backend_start_remembers_gymnasiums_position_before_the_first_step(env_id, backend):
    """gymnasium's set_state runs mj_forward, so its first step's velocity starts from the
    position at the start state; reset_to computes ours there too (float32 of the same value)."""
    cases, ours = one_step_cases(env_id), one_step_outputs(env_id, backend)
    before, size = cases["position"][:, 0, 0], cases["position"][:, 0, 1]
    if env_id == "Ant-v5":  # a body position MuJoCo computed in float64, rounded once
        np.testing.assert_array_equal(ours["memory"], before.astype(np.float32))
    _assert_close("memory", ours["memory"], before, _float32_ulps(size, POSITION_ULPS[env_id] / 2))


@pytest.mark.parametrize("backend", C_BACKENDS)
@pytest.mark.parametrize("env_id", FREE_BODIES)
def test_c_backend_free_body_trajectories_match_gymnasium(env_id, backend):
    """Step after step, not only from fresh starts: the velocity of every step but the first
    starts from the position our env remembered at the previous one."""
    cases, ours = free_trajectory_cases(env_id), free_trajectory_outputs(env_id, backend)
    _assert_c_step_matches(env_id, ours, cases)
    # Not vacuous: an env that started each step's velocity from the position at the step's start
    # (one substep later than the one gymnasium reads) would be off by more than the tolerance on
    # almost every step but the first, where both are the reset's position.
    after = cases["position"][..., 1, 0, :]
    forgetful = (after - cases["current_position"]) / cases["dt"]
    velocity = np.stack([cases["info"]["x_velocity"], cases["info"]["y_velocity"]], axis=-1)
    allowed = _velocity_allowed(env_id, cases) + C_REWARD_RTOL * (1.0 + np.abs(velocity))
    off = (np.abs(forgetful - velocity) > allowed).any(axis=-1)
    assert not off[:, 0].any() and off[:, 1:].mean() > 0.95, off[:, 1:].mean()


@pytest.mark.parametrize("env_id", mjx_params(PENDULUMS))
def test_mjx_backend_trajectories_match_gymnasium(env_id):
    cases, ours = trajectory_cases(env_id), trajectory_outputs(env_id, "mjx")
    # compare each trajectory up to the first step float32 cannot predict (see module docstring)
    predictable = np.cumprod(cases["obs_sensitivity"] <= PREDICTABLE, axis=0).astype(bool)
    assert predictable[:, cases["closed_loop"]].all(axis=0).mean() >= 0.8
    hide = lambda x: np.where(_per_case(predictable, x), x, np.nan)
    allowed_obs = hide(_allowed("mjx", cases["obs"], cases["obs_sensitivity"]))
    _assert_close("obs", ours["obs"], cases["obs"], allowed_obs)
    allowed = hide(_allowed("mjx", cases["reward"], cases["reward_sensitivity"]))
    _assert_close("reward", ours["reward"], cases["reward"], allowed)
    mismatch = ours["terminated"] != cases["terminated"]
    borderline = _borderline(env_id, cases, np.nan_to_num(allowed_obs, nan=np.inf))
    assert not (mismatch & ~borderline & predictable).any()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_ffi_and_callback_backends_are_bit_identical(env_id):
    """The FFI op and the pure_callback path: the same state bits and float32 outputs."""
    ffi, callback = (
        one_step_outputs(env_id, "mujoco_ffi"),
        one_step_outputs(env_id, "mujoco_callback"),
    )
    _assert_bit_identical(ffi, callback)
    if env_id in PENDULUMS:
        _assert_bit_identical(*(trajectory_outputs(env_id, b) for b in C_BACKENDS))
    if env_id in FREE_BODIES:
        _assert_bit_identical(*(free_trajectory_outputs(env_id, b) for b in C_BACKENDS))


def _assert_bit_identical(ffi: dict, callback: dict) -> None:
    assert set(ffi) == set(callback)
    for key in callback:
        if key == "info":
            for name in callback["info"]:
                np.testing.assert_array_equal(ffi[key][name], callback[key][name], err_msg=name)
        else:
            np.testing.assert_array_equal(ffi[key], callback[key], err_msg=key)
