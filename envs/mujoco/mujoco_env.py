"""Shared base of the MuJoCo envs (one file each in ``envs/mujoco``).

Each env reproduces one gymnasium 1.4.0 ``*-v5`` env — same MJCF file (loaded from the installed
gymnasium package), frame skip, observation layout, reward terms, termination rule, reset noise and
episode limit (1,000 steps; Reacher 50) — on either physics backend of
``envs.mujoco.mujoco_backend``::

    env = envs.make("rl_jax/HalfCheetah-v5")                  # default backend for the platform
    env = envs.make("rl_jax/HalfCheetah-v5", backend="mjx")   # pure JAX
    env = envs.make("rl_jax/HalfCheetah-v5", backend="mujoco", ctrl_cost_weight=0.2)

The backend defaults to ``$RL_JAX_MUJOCO_BACKEND``, else MuJoCo C ("mujoco") on CPU and MJX on
GPU/TPU; "mujoco_callback" forces MuJoCo C through ``jax.pure_callback`` instead of the FFI op
(see ``envs.mujoco.mujoco_backend``). Keyword arguments named like gymnasium's constructor arguments
(``reset_noise_scale``, ``ctrl_cost_weight``, ...) set the default params; the params pytree can
also be passed to ``reset``/``step`` and vmapped. Structural ones
(``exclude_current_positions_from_observation``, ``terminate_when_unhealthy``) are constructor
arguments; gymnasium's ``xml_file``, ``frame_skip`` and ``default_camera_config`` are refused.

Solver fidelity (``fidelity=``): ``"gymnasium"`` keeps the model's own solver limits (100
iterations, 50 line-search ones unless its XML sets others); ``"parity"`` (default) the cheapest
that still match gymnasium: gymnasium's own on the C backend (it stops at convergence, and is
bit-identical to gymnasium), each env's ``mjx_solver`` limits on MJX, where every env of a vmapped
batch pays the full cap (``tests/envs/test_mujoco_parity.py`` checks the hardest states).

Exact starts: ``state_from_vector(concatenate([qpos, qvel]))`` (optionally ``qacc_warmstart``
appended). On the C backend a float64 numpy vector is kept bit for bit; a float32 or traced vector
is widened exactly.

Non-finite physics: if a step leaves the physics state non-finite (or beyond MuJoCo's 1e10
divergence limit, where MuJoCo C itself resets the simulation), or the action is non-finite, the
step reports ``terminated=True``, ``reward=0``, zero reward terms, ``info["physics_diverged"]=True``
(a fixed key, ``False`` on every other step) and, as the observation, the last finite one of the
episode; the returned state is the model's default pose, and ``AutoReset`` starts a fresh episode.
Terminated rather than truncated: like gymnasium's own "state is not finite" rule (InvertedPendulum,
Hopper), a blown-up simulation is treated as a terminal failure, so no TD target bootstraps from an
observation that is not the true successor state.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from rl_jax.envs.core.core import (
    Array,
    Environment,
    EnvParams,
    EnvState,
    ParamsT,
    PRNGKey,
    TimeStep,
    keep_active,
)
from rl_jax.envs.core.spaces import Box
from rl_jax.envs.mujoco.mujoco_backend import (
    DIVERGENCE_LIMIT,
    Measurement,
    Physics,
    engine,
    extra_field,
    load_model,
    resolve_backend,
)
from rl_jax.envs.mujoco.mujoco_callback import MujocoCallbackPhysics
from rl_jax.envs.mujoco.mujoco_ffi import MujocoFfiPhysics
from rl_jax.envs.mujoco.mujoco_render import SceneRenderer

DIVERGED_KEY = "physics_diverged"
GYMNASIUM_SOLVER = (100, 50)  # MuJoCo's defaults, which most of gymnasium's models keep
FIDELITIES = ("parity", "gymnasium")
# gymnasium constructor keywords that pick another model file, substep count or camera: an env
# class fixes these (it is tested for parity with exactly them), so they are refused by name.
FIXED_GYMNASIUM_KEYWORDS = ("xml_file", "frame_skip", "default_camera_config")


def make_physics(
    backend: str,
    model: Any,
    frame_skip: int,
    extras: tuple[str, ...] = (),
    nthread: int | None = None,
    mjx_chunk: int | None = None,
) -> Physics:
    """The physics of ``backend`` (a name of ``BACKEND_NAMES``, or None: the default)."""
    backend = resolve_backend(backend)
    if backend == "mjx":
        from rl_jax.envs.mujoco.mjx_physics import MjxPhysics  # heavy: MJX is imported on first use

        return MjxPhysics(model, frame_skip, extras, mjx_chunk)
    if backend == "mujoco_ffi":
        return MujocoFfiPhysics(model, frame_skip, extras, nthread)
    return MujocoCallbackPhysics(model, frame_skip, extras, nthread)


@struct.dataclass
class MujocoState(EnvState):
    """A MuJoCo env's state: the backend's physics, the last observation, what a step remembers."""

    # backend-specific: float32 (qpos, qvel, qacc_warmstart) for mjx, uint32 float64 bits for C
    physics: Any
    obs: Array  # [obs_size] float32, the last observation, reported again if the physics diverges


@struct.dataclass
class RememberingState(MujocoState):
    """The state of an env that reads last step's derived quantities (``MujocoEnv.remember``)."""

    memory: Array  # [remembers] float32


REMEMBERED_KEY = "remembered"  # the extra under which evaluate() finds last step's memory


@struct.dataclass
class MujocoParams(EnvParams):
    """Base of the MuJoCo envs' params; every env scales its reset noise."""

    reset_noise_scale: Array


class MujocoEnv(Environment[MujocoState, ParamsT]):
    """Subclasses set the class attributes and implement the four hooks at the bottom."""

    xml_file: str = ""
    frame_skip: int = 1
    max_episode_steps: int = 1000
    #: MJX (solver iterations, line-search iterations) of the "parity" fidelity
    mjx_solver: tuple[int, int] = GYMNASIUM_SOLVER
    #: on CPU, vmapped MJX steps run this many envs at a time (see ``MjxPhysics``); None: all
    mjx_cpu_chunk: int | None = None
    #: derived mjData fields the env reads after a step (see ``Measurement.extras``)
    extras: tuple[str, ...] = ()
    #: whether the reset observation needs ``mj_forward`` (constraint forces, site positions)
    forward_at_reset: bool = False
    #: float32 scalar reward terms in ``info``, in addition to ``physics_diverged``
    info_keys: tuple[str, ...] = ()
    #: size of what ``remember`` keeps from one step for the next (0: nothing)
    remembers: int = 0
    #: gymnasium's free-camera settings for ``render``, or the name of a camera of the model
    camera: dict[str, Any] | str = {}
    params_type: type = MujocoParams
    #: gymnasium's ``(low, high)`` range keywords (``healthy_z_range``) -> the two params fields
    #: that hold them, so either spelling may be given
    range_keywords: dict[str, tuple[str, str]] = {}
    #: leading qpos entries (the free position along x, or x and y) that gymnasium leaves out of
    #: the observation unless ``exclude_current_positions_from_observation=False``; 0: the env
    #: has no such keyword
    current_positions: int = 0

    def __init__(
        self,
        backend: str | None = None,
        fidelity: str = "parity",
        nthread: int | None = None,
        **param_overrides: float,
    ):
        if fidelity not in FIDELITIES:
            raise ValueError(f"unknown fidelity {fidelity!r}; choose from {FIDELITIES}")
        for keyword in FIXED_GYMNASIUM_KEYWORDS:
            if keyword in param_overrides:
                raise TypeError(
                    f"{type(self).__name__} does not take gymnasium's keyword {keyword!r}: the "
                    f"model ({self.xml_file}), frame skip ({self.frame_skip}) and camera are "
                    "fixed by the env class (subclass it to change them)"
                )
        param_overrides = split_ranges(param_overrides, self.range_keywords)
        keyword = "exclude_current_positions_from_observation"
        excluded = bool(param_overrides.pop(keyword, True)) if self.current_positions else False
        self.exclude_current_positions = excluded
        physics_backend = resolve_backend(backend)  # e.g. "mujoco_ffi"
        self.backend = engine(physics_backend)  # "mujoco" or "mjx"
        self.fidelity = fidelity
        self.model = self.build_model(self.backend, fidelity)
        chunk = self.mjx_cpu_chunk if jax.default_backend() == "cpu" else None
        self.physics: Physics = make_physics(
            physics_backend, self.model, self.frame_skip, self.extras, nthread, chunk
        )
        self.dt = float(self.model.opt.timestep * self.frame_skip)
        self._params = self._make_default_params(param_overrides)
        self._init_qpos = np.array(self.model.qpos0, np.float32)
        self._initial_obs = self._compute_initial_obs()
        self._scene: SceneRenderer | None = None

    def build_model(self, backend: str, fidelity: str) -> Any:
        """gymnasium's MjModel with this backend's solver limits. MJX implements the CG and
        Newton solvers, not PGS: a PGS model (Humanoid) solves the same constraint problem with
        Newton there, matching gymnasium to the solvers' convergence rather than to rounding."""
        model = load_model(self.xml_file, *self.solver_limits(backend, fidelity))
        if backend == "mjx" and model.opt.solver == mujoco.mjtSolver.mjSOL_PGS:
            model.opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
        return model

    def solver_limits(self, backend: str, fidelity: str) -> tuple[int | None, int | None]:
        """(iterations, line-search iterations) of the constraint solver; None: the model's."""
        if backend == "mjx" and fidelity == "parity":
            return self.mjx_solver
        return None, None

    def _make_default_params(self, overrides: dict[str, float]):
        fields = {f.name for f in dataclasses.fields(self.params_type)}
        unknown = sorted(set(overrides) - fields)
        if unknown:
            raise TypeError(f"{type(self).__name__} has no parameter(s) {unknown}; known: {fields}")
        defaults = self.params_type()
        return defaults.replace(**{k: jnp.float32(v) for k, v in overrides.items()})

    @property
    def default_params(self):
        """The params built from the class defaults and the constructor's keyword overrides."""
        return self._params

    @property
    def render_fps(self) -> int:
        """Frames per second of real time, as gymnasium's ``metadata["render_fps"]``."""
        return int(np.round(1.0 / self.dt))

    # ---- spaces -------------------------------------------------------------------------------
    @property
    def obs_size(self) -> int:
        """Length of the observation vector (each env defines it)."""
        raise NotImplementedError

    def observation_space(self, params: ParamsT | None = None) -> Box:
        """An unbounded box of ``obs_size`` values, as gymnasium's."""
        return Box(-np.inf, np.inf, (self.obs_size,))

    def action_space(self, params: ParamsT | None = None) -> Box:
        """The actuators' control ranges from the model."""
        low, high = np.asarray(self.model.actuator_ctrlrange, np.float32).T
        return Box(low, high, low.shape)

    def empty_info(self) -> dict[str, Array]:
        """Zero for each of ``info_keys`` and ``physics_diverged=False``."""
        info = {key: jnp.zeros((), jnp.float32) for key in self.info_keys}
        return {**info, DIVERGED_KEY: jnp.zeros((), jnp.bool_)}

    # ---- reset --------------------------------------------------------------------------------
    def reset(self, key: PRNGKey, params: ParamsT | None = None) -> tuple[MujocoState, TimeStep]:
        """Start an episode from ``sample_start``'s random ``(qpos, qvel)``."""
        params = self.default_params if params is None else params
        qpos, qvel = self.sample_start(key, params)
        return self.start_from_physics(self.physics.from_qpos_qvel(qpos, qvel), params)

    def reset_env(self, key: PRNGKey, params: ParamsT) -> tuple[MujocoState, Array]:
        """``reset``'s state and first observation."""
        state, timestep = self.reset(key, params)
        return state, timestep.obs

    def reset_to(self, vector: Any, params: ParamsT | None = None) -> tuple[MujocoState, TimeStep]:
        """Start from ``[qpos, qvel(, qacc_warmstart)]``, with optional leading batch axes.

        A float64 numpy vector is kept bit for bit on the C backend (do not wrap it in
        ``jnp.asarray`` first: without x64 that rounds it to float32).
        """
        params = self.default_params if params is None else params
        nq, nv = self.physics.nq, self.physics.nv
        if not isinstance(vector, np.ndarray):
            vector = jnp.asarray(vector)
        if vector.shape[-1] not in (nq + nv, nq + 2 * nv):
            raise ValueError(
                f"{self.name}: a state vector is [qpos ({nq}), qvel ({nv})] optionally followed "
                f"by qacc_warmstart ({nv}); got length {vector.shape[-1]}"
            )
        qpos, qvel = vector[..., :nq], vector[..., nq : nq + nv]
        warm = vector[..., nq + nv :] if vector.shape[-1] == nq + 2 * nv else None
        physics = self.physics.from_qpos_qvel(qpos, qvel, warm)
        start = lambda p: self.start_from_physics(p, params)
        for _ in range(vector.ndim - 1):
            start = jax.vmap(start)
        return start(physics)

    def state_from_vector(
        self, vector: Any, params: ParamsT | None = None
    ) -> tuple[MujocoState, Array]:
        """``reset_to``'s state and first observation, from ``[qpos, qvel(, qacc_warmstart)]``."""
        state, timestep = self.reset_to(vector, params)
        return state, timestep.obs

    def start_from_physics(
        self, physics: Any, params: ParamsT | None = None
    ) -> tuple[MujocoState, TimeStep]:
        """First timestep of an episode starting at a backend physics state (one env)."""
        params = self.default_params if params is None else params
        if self.forward_at_reset:
            measurement = self.physics.forward(physics)
        else:
            # qpos/qvel are all the observation needs: no physics call
            qpos, qvel = self.physics.qpos_qvel(physics)
            finite = jnp.all(jnp.abs(jnp.concatenate([qpos, qvel], -1)) <= DIVERGENCE_LIMIT)
            extras = self.physics.empty_extras()
            measurement = Measurement(qpos, qvel, jnp.zeros_like(qpos), extras, ~finite)
        obs = self.observe(measurement)
        diverged = measurement.diverged | ~jnp.all(jnp.isfinite(obs))
        obs = jnp.where(jnp.isfinite(obs), obs, 0.0)
        info = {**self.empty_info(), **self.reset_info(measurement), DIVERGED_KEY: diverged}
        info = {k: jnp.where(diverged, jnp.zeros_like(v), v) for k, v in info.items()}
        info[DIVERGED_KEY] = diverged
        state = self._state(jnp.zeros((), jnp.int32), physics, obs, self.remember(measurement))
        timestep = TimeStep(
            obs=obs,
            reward=jnp.zeros((), jnp.float32),
            terminated=jnp.zeros((), jnp.bool_),
            truncated=jnp.zeros((), jnp.bool_),
            info=info,
        )
        return state, timestep

    # ---- step ---------------------------------------------------------------------------------
    def step_env(
        self, key: PRNGKey, state: MujocoState, action: Array, params: ParamsT
    ) -> tuple[MujocoState, Array, Array, Array, dict[str, Array]]:
        """Apply the action for ``frame_skip`` substeps; reward, termination and info from
        ``evaluate``, or the divergence handling of the module docstring.
        """
        return self._step_env(state, action, params)

    def step_active(
        self,
        key: PRNGKey,
        state: MujocoState,
        action: Array,
        active: Array,
        params: ParamsT | None = None,
    ):
        """``Environment.step_active``: the MuJoCo C backends step only the active envs (the
        others' physics is not computed at all); MJX computes them and discards the result."""
        params = self.default_params if params is None else params
        new_state, *rest = self._step_env(state, action, params, jnp.asarray(active, jnp.bool_))
        return self._timestep(keep_active(active, new_state, state), *rest)

    def _step_env(
        self, state: MujocoState, action: Array, params: ParamsT, active: Array | None = None
    ):
        action = jnp.asarray(action, jnp.float32)
        physics, measurement = self.physics.step(state.physics, action, active)
        if self.remembers:
            assert isinstance(state, RememberingState)  # _state makes one when the env remembers
            extras = {**measurement.extras, REMEMBERED_KEY: state.memory}
            measurement = measurement._replace(extras=extras)
        obs = self.observe(measurement)
        reward, terminated, info = self.evaluate(measurement, action, params)
        diverged = (
            measurement.diverged
            | ~jnp.all(jnp.isfinite(action))
            | ~jnp.all(jnp.isfinite(obs))
            | ~jnp.isfinite(reward)
        )
        initial = self._initial_physics()
        physics = jax.tree.map(lambda a, b: jnp.where(diverged, a, b), initial, physics)
        last_finite_obs = _finite_or_zero(state.obs)
        memory = jnp.where(diverged, self._initial_memory, self.remember(measurement))
        state = self._state(
            state.time + 1, physics, jnp.where(diverged, self._initial_obs, obs), memory
        )
        obs = jnp.where(diverged, last_finite_obs, obs)
        reward = jnp.where(diverged, 0.0, reward)
        info = {k: jnp.where(diverged, jnp.zeros_like(v), v) for k, v in info.items()}
        return state, obs, reward, terminated | diverged, {**info, DIVERGED_KEY: diverged}

    def _state(self, time: Array, physics: Any, obs: Array, memory: Array) -> MujocoState:
        if self.remembers:
            return RememberingState(time=time, physics=physics, obs=obs, memory=memory)
        return MujocoState(time=time, physics=physics, obs=obs)

    def _initial_physics(self) -> Any:
        zeros = np.zeros(self.physics.nv, np.float64)
        return self.physics.from_qpos_qvel(np.asarray(self.model.qpos0, np.float64), zeros)

    def _compute_initial_obs(self) -> np.ndarray:
        """Observation at the model's default pose (host-side float64 forward pass)."""
        data = mujoco.MjData(self.model)
        mujoco.mj_forward(self.model, data)
        # Envs may be built while a learner's init is traced (jax.eval_shape of the state):
        # computed eagerly, this stays a constant instead of becoming a tracer.
        with jax.ensure_compile_time_eval():
            # float32 jax arrays, as the measurement of a step holds
            as32 = lambda x: jnp.asarray(np.asarray(x, np.float32))
            extras = {name: as32(extra_field(name, data, np)) for name in self.extras}
            qpos, qvel = as32(data.qpos), as32(data.qvel)
            diverged = jnp.zeros((), jnp.bool_)
            measurement = Measurement(qpos, qvel, jnp.zeros_like(qpos), extras, diverged)
            self._initial_memory = np.asarray(self.remember(measurement), np.float32)
            return np.asarray(self.observe(measurement), np.float32)

    # ---- rendering ----------------------------------------------------------------------------
    def render(
        self, state: MujocoState, params: ParamsT | None = None, width: int = 320, height: int = 240
    ):
        """RGB frame ``[height, width, 3]`` uint8 of one unbatched state (host side)."""
        qpos, qvel, _ = self.physics.to_numpy(state.physics)
        if self._scene is None:
            self._scene = SceneRenderer(self.model, self.camera)
        return self._scene.render(qpos, qvel, width, height)

    # ---- hooks --------------------------------------------------------------------------------
    #: gymnasium's reset noise on qvel: "normal" (std ``reset_noise_scale``) or "uniform" (in
    #: +-``reset_noise_scale``); qpos is always uniform in +-``reset_noise_scale`` around qpos0.
    qvel_noise = "normal"

    def sample_start(self, key: PRNGKey, params: ParamsT) -> tuple[Array, Array]:
        """float32 ``(qpos, qvel)`` of a random start, as gymnasium's ``reset_model``."""
        key_qpos, key_qvel = jax.random.split(key)
        # every env that keeps this start has MujocoParams (Reacher, whose are not, overrides it)
        assert isinstance(params, MujocoParams)
        scale = params.reset_noise_scale
        nq, nv = self._init_qpos.shape[0], self.model.nv
        noise = jax.random.uniform(key_qpos, (nq,), jnp.float32, -scale, scale)
        qpos = jnp.asarray(self._init_qpos) + noise
        if self.qvel_noise == "uniform":
            qvel = jax.random.uniform(key_qvel, (nv,), jnp.float32, -scale, scale)
        else:
            qvel = scale * jax.random.normal(key_qvel, (nv,), jnp.float32)
        return qpos, qvel

    def observed_qpos(self, measurement: Measurement) -> Array:
        """qpos as the observation starts with it: without the current positions unless asked."""
        skipped = self.current_positions if self.exclude_current_positions else 0
        return measurement.qpos[skipped:]

    @property
    def observed_qpos_size(self) -> int:
        """How many qpos entries the observation holds."""
        return self.model.nq - (self.current_positions if self.exclude_current_positions else 0)

    def observe(self, measurement: Measurement) -> Array:
        """The observation of a measurement, as gymnasium's ``_get_obs`` (each env defines it)."""
        raise NotImplementedError

    def evaluate(
        self, measurement: Measurement, action: Array, params: ParamsT
    ) -> tuple[Array, Array, dict[str, Array]]:
        """``(reward, terminated, info)`` of a step; ``info`` has exactly ``info_keys``."""
        raise NotImplementedError

    def reset_info(self, measurement: Measurement) -> dict[str, Array]:
        """Entries of ``info_keys`` that gymnasium reports at reset (the rest are 0)."""
        return {}

    def remember(self, measurement: Measurement) -> Array:
        """What the next step's ``evaluate`` needs of this one (``remembers`` float32 values),
        found there as ``measurement.extras["remembered"]``: gymnasium's Ant and Humanoid take
        their velocity from a body position read before the step, i.e. the one MuJoCo left at
        the previous step (computed at the start of its last substep) or at the reset."""
        return jnp.zeros((self.remembers,), jnp.float32)


def split_ranges(keywords: dict[str, Any], ranges: dict[str, tuple[str, str]]) -> dict[str, Any]:
    """gymnasium's ``(low, high)`` range keywords (``healthy_z_range=(0.8, 2.0)``) as the two
    params fields that hold them; every other keyword is passed through."""
    fields = {k: v for k, v in keywords.items() if k not in ranges}
    for keyword, names in ranges.items():
        if keyword not in keywords:
            continue
        given = sorted(set(names) & set(fields))
        if given:
            raise TypeError(f"give either {keyword} or {given}, not both")
        low, high = keywords[keyword]
        fields.update(zip(names, (low, high), strict=True))
    return fields


def planar_position_info(qpos: Array) -> dict[str, Array]:
    """gymnasium's ``x_position``, ``y_position`` and ``distance_from_origin`` of a body moving in
    the plane (its first two qpos), as Ant, Humanoid and Swimmer report them."""
    return {
        "x_position": qpos[0],
        "y_position": qpos[1],
        "distance_from_origin": jnp.hypot(qpos[0], qpos[1]),
    }


def _finite_or_zero(x: Array) -> Array:
    return jnp.where(jnp.isfinite(x), x, 0.0)
