"""Gymnasium front ends for the JAX envs: ``gymnasium.make`` and ``gymnasium.make_vec``.

Importing ``rl_jax.envs`` calls ``register_with_gymnasium()``, so every id of ``envs.core.registry``
works as::

    env = gymnasium.make("rl_jax/Rocket-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)                       # jax key derived from the seed
    obs, info = env.reset(options={"state": [1.0, -0.5]})         # exact start (classic envs)
    obs, info = env.reset(options={"qpos": qpos, "qvel": qvel})   # exact start (MuJoCo envs)
    vec = gymnasium.make_vec("rl_jax/Rocket-v0", num_envs=1024,
                             vectorization_mode="vector_entry_point")

Keyword arguments of ``make`` go to the env's constructor when it takes them, otherwise they set
params fields (``gymnasium.make("rl_jax/Pendulum-v1", g=9.81)``, as gymnasium's Pendulum).

Time limits. ``GymnasiumEnv`` (one env) does not truncate by itself: ``gymnasium.make`` adds
gymnasium's ``TimeLimit`` with the registered ``max_episode_steps`` (the JAX env's own limit), as
for gymnasium's classic envs, so ``make(id, max_episode_steps=N)`` and ``-1`` behave as users
know and no step is counted twice. ``GymnasiumVectorEnv`` (``envs.adapters.gym_vector``)
truncates inside the jitted step at the ``max_episode_steps`` that ``make_vec`` passes (the
registered one unless overridden).

Seeding. Each env owns a jax key. ``reset(seed=s)`` reseeds gymnasium's ``np_random`` with ``s``
and draws the key from it; every later reset and step splits that key. The vector env seeds env
``i`` with ``s + i`` the same way, so it reproduces ``SyncVectorEnv`` over ``GymnasiumEnv``s.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from typing import Any, NamedTuple

import gymnasium
import jax
import numpy as np

from rl_jax.envs.core import registry
from rl_jax.envs.core.batched import reset_where, select_envs
from rl_jax.envs.core.core import Array, Environment, EnvParams, PRNGKey

# gymnasium's reward thresholds for the references of our ids (its registry is the source).
_REWARD_THRESHOLDS = {
    "rl_jax/CartPole-v1": 475.0,
    "rl_jax/InvertedPendulum-v5": 950.0,
    "rl_jax/InvertedDoublePendulum-v5": 9100.0,
    "rl_jax/HalfCheetah-v5": 4800.0,
    "rl_jax/Hopper-v5": 3800.0,
    "rl_jax/Swimmer-v5": 360.0,
    "rl_jax/Reacher-v5": -3.75,
    "rl_jax/Ant-v5": 6000.0,  # gymnasium registers none for Walker2d-v5 and Humanoid-v5
}
_NO_LIMIT = np.iinfo(np.int32).max


def register_with_gymnasium() -> None:
    """Register every id of ``envs.core.registry`` with gymnasium (ids already there are kept).

    Entry points stay strings, so nothing is imported until an env is made. ``MODULE:ID`` and
    ``gymnasium:ID`` ids are left out: gymnasium reads ``MODULE:`` as a module to import, and
    their plain ``ID`` is registered on its own (or is gymnasium's already).
    """
    for env_id in registry.registered_ids():
        if env_id in gymnasium.registry or ":" in env_id:
            continue
        gymnasium.register(
            id=env_id,
            entry_point=f"{__name__}:GymnasiumEnv",
            vector_entry_point="rl_jax.envs.adapters.gym_vector:GymnasiumVectorEnv",
            max_episode_steps=registry.max_episode_steps(env_id),
            reward_threshold=_REWARD_THRESHOLDS.get(env_id),
            kwargs={"env_id": env_id},
        )


def key_from_rng(rng: np.random.Generator) -> jax.Array:
    """A jax key drawn from a numpy generator (deterministic given the generator's state)."""
    return jax.random.PRNGKey(rng.integers(0, 2**32, dtype=np.uint32))


# ---- compiled functions, shared by every instance of the same env configuration -----------------
class _Programs(NamedTuple):
    env: Environment
    reset: Any  # (key, params) -> (key, state, timestep)
    step: Any  # (key, state, action, params) -> (key, state, timestep)
    reset_to: Any  # (vector, params) -> (state, timestep)
    vector_reset: Any  # (keys, params) -> (keys, states, timestep)
    vector_reset_to: Any  # (vectors, params) -> (states, timestep)
    vector_step: Any  # (keys, states, pending, actions, params) -> (keys, states, timestep)
    select: Any  # (mask, new, old) -> per env, new where mask else old


def _split_reset(env: Environment):
    def reset(key: PRNGKey, params: EnvParams | None):
        key, subkey = jax.random.split(key)
        state, timestep = env.reset(subkey, params)
        return key, state, timestep

    return reset


def _split_step(env: Environment):
    def step(key: PRNGKey, state: object, action: Array, params: EnvParams | None):
        key, subkey = jax.random.split(key)
        state, timestep = env.step(subkey, state, action, params)
        return key, state, timestep

    return step


def _vector_step(env: Environment):
    """NEXT_STEP autoreset: an env whose last step ended is reset now and its action ignored."""
    step = jax.vmap(_split_step(env), (0, 0, 0, None))

    def vector_step(
        keys: Array, states: object, pending: Array, actions: Array, params: EnvParams | None
    ):
        new_keys, stepped, timestep = step(keys, states, actions, params)

        def reset(pending_keys: Array):
            # The same split of each key as a lone env's reset() (and as the step above).
            _, reset_states, reset_timestep = jax.vmap(_split_reset(env), (0, None))(
                pending_keys, params
            )
            return reset_states, reset_timestep

        states, timestep = reset_where(reset, keys, pending, (stepped, timestep))
        return new_keys, states, timestep

    return vector_step


@functools.lru_cache(maxsize=64)
def _programs(env_id: str, constructor_items: tuple, limit: int) -> _Programs:
    env = registry.make(env_id, **dict(constructor_items))
    env.max_episode_steps = limit
    return _Programs(
        env=env,
        reset=jax.jit(_split_reset(env)),
        step=jax.jit(_split_step(env)),
        reset_to=jax.jit(env.reset_to),
        vector_reset=jax.jit(jax.vmap(_split_reset(env), (0, None))),
        vector_reset_to=jax.jit(jax.vmap(env.reset_to, (0, None))),
        vector_step=jax.jit(_vector_step(env)),
        select=jax.jit(select_envs),
    )


def build(env_id: str, kwargs: dict[str, Any], limit: int) -> tuple[_Programs, Any]:
    """Split ``kwargs`` into constructor arguments and params fields; compile (cached)."""
    signature = inspect.signature(registry.factory(env_id))
    takes_any = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in signature.parameters.values())
    constructor = {k: v for k, v in kwargs.items() if takes_any or k in signature.parameters}
    overrides = {k: v for k, v in kwargs.items() if k not in constructor}
    try:
        programs = _programs(env_id, tuple(sorted(constructor.items())), limit)
    except TypeError:  # an unhashable constructor argument: compile for this instance only
        programs = _programs.__wrapped__(env_id, tuple(sorted(constructor.items())), limit)
    return programs, _replace_params(programs.env.default_params, overrides, env_id)


def _replace_params(params: Any, overrides: dict[str, Any], env_id: str) -> Any:
    if not overrides:
        return params
    fields = {f.name: getattr(params, f.name) for f in dataclasses.fields(params)}
    unknown = sorted(set(overrides) - set(fields))
    if unknown:
        raise TypeError(
            f"{env_id} got unknown keyword argument(s) {unknown}; params fields: {sorted(fields)}"
        )
    cast = {k: np.asarray(v, np.asarray(fields[k]).dtype) for k, v in overrides.items()}
    return params.replace(**cast)


# ---- reset options ------------------------------------------------------------------------------
def take_state_vector(options: dict[str, Any]) -> np.ndarray | None:
    """Pop ``state`` or ``qpos``+``qvel`` from ``options``: the vector for ``env.reset_to``."""
    has_state, has_q = "state" in options, "qpos" in options or "qvel" in options
    if has_state and has_q:
        raise ValueError("reset options: give either 'state' or 'qpos'/'qvel', not both")
    if has_state:
        return np.asarray(options.pop("state"), np.float32)
    if has_q:
        if "qpos" not in options or "qvel" not in options:
            raise ValueError("reset options: 'qpos' and 'qvel' must be given together")
        qpos = np.asarray(options.pop("qpos"), np.float32)
        qvel = np.asarray(options.pop("qvel"), np.float32)
        return np.concatenate([qpos, qvel], axis=-1)
    return None


def take_reset_params(options: dict[str, Any], env: Environment, params: Any, env_id: str):
    """Pop the env's gymnasium reset options (e.g. CartPole's ``low``/``high``) into params."""
    names = getattr(env, "reset_option_params", {})
    overrides = {names[k]: float(options.pop(k)) for k in list(options) if k in names}
    return _replace_params(params, overrides, env_id)


def check_no_options_left(options: dict[str, Any], env: Environment) -> None:
    """Raise ``ValueError`` naming any reset option nobody consumed, with the known ones."""
    if options:
        known = ["state", "qpos", "qvel", *getattr(env, "reset_option_params", {})]
        raise ValueError(f"unknown reset option(s) {sorted(options)}; known: {known}")


def _to_numpy_info(info: dict[str, Any]) -> dict[str, Any]:
    return {k: _to_numpy_info(v) if isinstance(v, dict) else np.array(v) for k, v in info.items()}


# ---- one env ------------------------------------------------------------------------------------
class GymnasiumEnv(gymnasium.Env):
    """A ``gymnasium.Env`` running a JAX env's jitted ``reset``/``step``; numpy in and out.

    Args:
        env_id: a registered id, e.g. ``"rl_jax/CartPole-v1"``.
        render_mode: ``None`` or ``"rgb_array"``.
        max_episode_steps: truncate after this many steps. Leave ``None`` under
            ``gymnasium.make``, whose ``TimeLimit`` does it (see the module docstring).
        **kwargs: env constructor arguments, or params fields to override.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        env_id: str,
        render_mode: str | None = None,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.env_id = registry.resolve_id(env_id)
        self._programs, self.params = build(self.env_id, kwargs, _NO_LIMIT)
        self.jax_env = self._programs.env
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": getattr(self.jax_env, "render_fps", 50)}
        self.observation_space = self.jax_env.observation_space(self.params).to_gymnasium()
        self.action_space = self.jax_env.action_space(self.params).to_gymnasium()
        self._jax_action_space = self.jax_env.action_space(self.params)
        self.max_episode_steps = max_episode_steps
        self._key: jax.Array | None = None
        self._jax_state: Any = None
        self._elapsed_steps = 0

    @property
    def jax_state(self) -> Any:
        """The current JAX state pytree (``None`` before the first reset)."""
        return self._jax_state

    @property
    def state(self) -> np.ndarray | None:
        """The state as gymnasium's ``env.unwrapped.state`` vector (classic envs)."""
        if self._jax_state is None:
            return None
        # Only the classic envs define it (Environment does not): others have no ``state``.
        to_vector = getattr(self.jax_env, "state_to_vector", None)
        if to_vector is None:
            raise AttributeError(f"{type(self.jax_env).__name__} has no state vector")
        return np.asarray(to_vector(self._jax_state))

    @state.setter
    def state(self, vector: Any) -> None:
        state, _ = self._programs.reset_to(np.asarray(vector, np.float32), self.params)
        self._jax_state = state

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """gymnasium's ``reset``: ``options`` may hold an exact start (``state``, or
        ``qpos``/``qvel``) and params overrides; returns ``(obs, info)``.
        """
        super().reset(seed=seed)
        if seed is not None or self._key is None:
            self._key = key_from_rng(self.np_random)
        options = dict(options or {})
        vector = take_state_vector(options)
        params = take_reset_params(options, self.jax_env, self.params, self.env_id)
        check_no_options_left(options, self.jax_env)
        if vector is None:
            self._key, self._jax_state, timestep = self._programs.reset(self._key, params)
        else:
            self._jax_state, timestep = self._reset_to(vector, params)
        self._elapsed_steps = 0
        timestep = jax.device_get(timestep)
        return np.array(timestep.obs), _to_numpy_info(timestep.info)

    def _reset_to(self, vector: np.ndarray, params: Any):
        try:
            return self._programs.reset_to(vector, params)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.env_id} cannot start from {vector!r}: {error}") from error

    def step(self, action: Any):
        """gymnasium's ``step``: returns ``(obs, reward, terminated, truncated, info)`` as numpy
        values.
        """
        if self._jax_state is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        action = _check_action(action, self._jax_action_space)
        self._key, self._jax_state, timestep = self._programs.step(
            self._key, self._jax_state, action, self.params
        )
        self._elapsed_steps += 1
        timestep = jax.device_get(timestep)
        truncated = (
            self.max_episode_steps is not None and self._elapsed_steps >= self.max_episode_steps
        )
        return (
            np.array(timestep.obs),
            float(timestep.reward),
            bool(timestep.terminated),
            bool(truncated),
            _to_numpy_info(timestep.info),
        )

    def render(self) -> np.ndarray | None:
        """The current frame in ``rgb_array`` mode; None (with a warning) without a render mode."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                f"render() without a render mode; use gymnasium.make({self.env_id!r}, "
                "render_mode='rgb_array')"
            )
            return None
        if self._jax_state is None:
            return None
        return np.asarray(self.jax_env.render(self._jax_state, self.params), np.uint8)


def _check_action(action: Any, space: Any) -> np.ndarray:
    """Cast to the JAX space's dtype/shape (so the jitted step never retraces)."""
    array = np.asarray(action)
    if np.issubdtype(np.dtype(space.dtype), np.integer):
        if array.size != 1 or not np.issubdtype(array.dtype, np.integer):
            raise ValueError(f"expected an integer action in [0, {space.n}), got {action!r}")
        if not 0 <= int(array) < space.n:
            raise ValueError(f"action {int(array)} outside [0, {space.n})")
        return np.asarray(int(array), space.dtype)
    if array.size != int(np.prod(space.shape)):
        raise ValueError(f"expected an action of shape {space.shape}, got shape {array.shape}")
    return array.astype(space.dtype).reshape(space.shape)
