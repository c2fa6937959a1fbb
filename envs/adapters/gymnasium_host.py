"""Any gymnasium env as an rl_jax ``Environment``, stepped on the host from inside jit.

    from rl_jax import envs

    env = envs.from_gymnasium("MountainCarContinuous-v0")   # an id, a gymnasium.Env or a factory
    state, ts = jax.vmap(env.reset)(jax.random.split(key, 8))
    state, ts = jax.vmap(env.step)(jax.random.split(key, 8), state, actions)

    python experiments/train.py --algo td3 --env gymnasium:Pendulum-v1

No rewrite: ``reset`` and ``step`` reach the real gymnasium envs through ``jax.pure_callback``,
so the learners' compiled programs, the seed and hyperparameter vmaps and ``shard_map`` run on
them unchanged, only at the speed of the envs' Python code (``python -m bench gym_adapter``).

Where the env state lives. A gymnasium env's state (its physics, its ``np_random``) is a Python
object, not a pytree, so it stays on the host in a pool owned by the adapter. The JAX state
(``HostEnvState``) is a *handle* to one episode running there: ``(pool id, episode serial)``,
plus the step count, the episode's reset seed, the latest observation and whether the episode
has ended. The host checks every step against the handle: the episode must be running in this
pool at that step count.

Lazy start. ``AutoReset`` (and every learner's rollout under vmap) computes a reset for every env
on every step and keeps it only where an episode ended, so a reset must not take a host env, or
the pool would fill with episodes nobody continues. ``reset`` therefore only draws the seed from
its key and returns the start observation, computed by resetting a scratch env with that seed;
the handle says "not started". The first ``step`` of that state takes an idle env from the pool
(or makes one), resets it with the same seed (the same start, by gymnasium's seeding contract)
and steps it. An episode that ends (terminated or truncated) returns its env to the idle list at
once, so the pool holds about one env per live episode: the batch, whatever its shape.

Batching. Under any nesting of vmaps (envs, seeds, hyperparameters) the callbacks receive the
whole batch at once (``vmap_method="broadcast_all"``) and step its envs one after another in one
host call; under ``shard_map`` each device calls with its own block, serialised by a lock. Every
lane of a batch is its own gymnasium env, so seeds never share one. Each env's inputs and outputs
cross as one uint32 row (see ``_pack``): every array crossing a callback costs more than a
classic env's step. Under ``AutoReset`` every env also pays a gymnasium ``reset(seed=...)`` per
step (on the scratch env); ``envs.core.batched.autoreset_step`` resets only the envs that finished.

Determinism. The reset seed is drawn from the JAX reset key and is the only randomness the host
uses (a gymnasium env's stochastic steps draw from the ``np_random`` that ``reset(seed=...)``
seeds), so the same JAX seed gives the same run. Pool ids and serials are bookkeeping: results
do not depend on them. An env whose reset is not a function of its seed breaks this; the adapter
warns once when a start differs from the one ``reset`` reported.

Resume. The host envs are not in a checkpoint (they cannot be saved in general). A handle that
this pool does not hold at that step count (a run resumed in a new process, or a state stepped
twice) cannot continue its episode: the step cuts it, reporting ``truncated=True``, reward 0, the
last observation again and ``info["host_state_lost"]=True``, and ``AutoReset`` starts a fresh
episode. A resumed run therefore continues without crashing, but the episodes in flight at the
checkpoint are cut, and it is not bit-identical to a run that never stopped. In the same process
a run resumed from the state it stopped at continues its episodes exactly.

Spaces. gymnasium ``Box`` observations become float32 ``Box``es (values cast to float32); ``Box``
actions of a float dtype become float32 ``Box``es with the same bounds, ``Discrete(n, start)``
actions become ``Discrete(n)`` (``start`` is added on the host). Other spaces are refused with
``UnsupportedEnvError``.

Terminated and truncated stay apart: each is gymnasium's own flag from ``step``; ``truncated`` is
also set when the step count reaches ``max_episode_steps`` (gymnasium's ``TimeLimit`` for an id,
the adapter's count for an env without one). Learners bootstrap through truncation.

Limits: params are empty (a gymnasium env's settings are constructor keyword arguments, fixed per
adapter, not vmappable); gymnasium's ``info`` dicts are dropped (their keys vary); no rendering;
``reset_to`` is unsupported; the step is not differentiable.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.adapters.gymnasium_pool import (
    HANDLE,
    NOT_STARTED,
    OUT_LOST,
    OUT_OBS,
    OUT_REWARD,
    OUT_TERMINATED,
    OUT_TRUNCATED,
    HostPool,
)
from rl_jax.envs.core import registry
from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey, TimeStep
from rl_jax.envs.core.registry import UnknownEnvError, UnsupportedEnvError
from rl_jax.envs.core.spaces import Box, Discrete, Space

ID_PREFIX = "gymnasium:"
LOST_KEY = "host_state_lost"


@struct.dataclass
class HostEnvState(EnvState):
    """The JAX-side state of an env that lives in a host process pool."""

    handle: Array  # [2] uint32: (pool id, episode serial); serial 0: not started on the host yet
    seed: Array  # [] uint32: the gymnasium reset seed of this episode, drawn from the reset key
    obs: Array  # [*obs_shape] float32: the latest observation
    terminated: Array  # [] bool: the episode has ended in a terminal state
    truncated: Array  # [] bool: the episode has been cut (time limit or lost host state)


def _bits(value: Array) -> Array:
    """A 32-bit array (or bool) as a flat uint32 vector of its bits."""
    value = jnp.asarray(value)
    if value.dtype == jnp.bool_:
        value = value.astype(jnp.uint32)
    return jax.lax.bitcast_convert_type(value, jnp.uint32).reshape(-1)


def _pack(state: HostEnvState, action: Array) -> Array:
    """The step's input row: handle, seed, time, ended flags, last obs, action."""
    parts = (state.handle, state.seed, state.time, state.terminated, state.truncated, state.obs)
    return jnp.concatenate([*(_bits(part) for part in parts), _bits(action)])


# ---- spaces -------------------------------------------------------------------------------------
def observation_space_from(space: gymnasium.Space, name: str) -> Box:
    """Our float32 ``Box`` for a gymnasium ``Box`` observation space."""
    if not isinstance(space, gymnasium.spaces.Box):
        raise UnsupportedEnvError(
            f"{name}: observation space {space} is not supported (the adapter takes Box "
            "observations; wrap the env, e.g. with gymnasium.wrappers.FlattenObservation)"
        )
    return Box(space.low.astype(np.float32), space.high.astype(np.float32), space.shape)


def action_space_from(space: gymnasium.Space, name: str) -> Space:
    """Our ``Box`` (float32) or ``Discrete`` for a gymnasium action space."""
    if isinstance(space, gymnasium.spaces.Box) and np.issubdtype(space.dtype, np.floating):
        return Box(space.low.astype(np.float32), space.high.astype(np.float32), space.shape)
    if isinstance(space, gymnasium.spaces.Discrete):
        return Discrete(int(space.n))
    raise UnsupportedEnvError(
        f"{name}: action space {space} is not supported (the adapter takes float Box or "
        "Discrete actions)"
    )


# ---- the JAX side -------------------------------------------------------------------------------
class HostGymnasiumEnv(Environment[HostEnvState, EnvParams]):
    """A gymnasium env behind the functional API (see the module docstring).

    ``make_env`` builds one gymnasium env (called for every env the pool needs);
    ``max_episode_steps`` is the time limit (the step count at which ``truncated`` is set).
    """

    def __init__(
        self,
        make_env: Callable[[], gymnasium.Env],
        name: str,
        max_episode_steps: int,
        first_env: gymnasium.Env | None = None,
    ):
        first_env = make_env() if first_env is None else first_env
        self.id = name
        self.max_episode_steps = int(max_episode_steps)
        self._observation_space = observation_space_from(first_env.observation_space, name)
        self._action_space = action_space_from(first_env.action_space, name)
        self.pool = HostPool(
            make_env,
            first_env.action_space,
            self._observation_space.shape,
            self.max_episode_steps,
        )
        self.pool.idle.append(first_env)

    @property
    def default_params(self) -> EnvParams:
        """Empty params: the host env's settings are fixed at construction."""
        return EnvParams()

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """The host env's observation space, as a float32 box."""
        return self._observation_space

    def action_space(self, params: EnvParams | None = None) -> Space:
        """The host env's action space."""
        return self._action_space

    def empty_info(self) -> dict[str, Array]:
        """``host_state_lost=False``: the host still holds the episode (see the module
        docstring).
        """
        return {LOST_KEY: jnp.zeros((), jnp.bool_)}

    def reset_env(self, key: PRNGKey, params: EnvParams) -> tuple[HostEnvState, Array]:
        """Draw the episode's reset seed and compute its start observation; the host episode
        itself starts on the first step.
        """
        seed = jax.random.bits(key, (), jnp.uint32)
        shape = jax.ShapeDtypeStruct(self._observation_space.shape, jnp.float32)
        obs = jax.pure_callback(
            self.pool.start_observations, shape, seed, vmap_method="broadcast_all"
        )
        false = jnp.zeros((), jnp.bool_)
        handle = jnp.array([0, NOT_STARTED], jnp.uint32)
        state = HostEnvState(jnp.int32(0), handle, seed, obs, false, false)
        return state, obs

    def _host_step(self, state: HostEnvState, action: Array) -> tuple[HostEnvState, TimeStep]:
        space = self._action_space
        action = jnp.reshape(jnp.asarray(action, space.dtype), space.shape)
        obs_size = int(np.prod(self._observation_space.shape, dtype=np.int64))
        result = jax.ShapeDtypeStruct((OUT_OBS + obs_size,), jnp.uint32)
        row = jax.pure_callback(
            self.pool.step, result, _pack(state, action), vmap_method="broadcast_all"
        )
        terminated, truncated = row[OUT_TERMINATED] != 0, row[OUT_TRUNCATED] != 0
        reward = jax.lax.bitcast_convert_type(row[OUT_REWARD], jnp.float32)
        obs = jax.lax.bitcast_convert_type(row[OUT_OBS:], jnp.float32)
        obs = obs.reshape(self._observation_space.shape)
        new_state = dataclasses.replace(
            state,
            time=state.time + 1,
            handle=row[HANDLE],
            obs=obs,
            terminated=terminated,
            truncated=truncated,
        )
        info = {LOST_KEY: row[OUT_LOST] != 0}
        return new_state, TimeStep(obs, reward, terminated, truncated, info)

    def step_env(self, key: PRNGKey, state: HostEnvState, action: Array, params: EnvParams):
        """Step the episode in the host pool through a callback."""
        new_state, ts = self._host_step(state, action)
        return new_state, ts.obs, ts.reward, ts.terminated, ts.info

    def step(
        self, key: PRNGKey, state: HostEnvState, action: Array, params: EnvParams | None = None
    ) -> tuple[HostEnvState, TimeStep]:
        """gymnasium's own ``truncated`` (its TimeLimit, or a cut), not only the step count."""
        return self._host_step(state, action)


# ---- construction -------------------------------------------------------------------------------
class _Source(NamedTuple):
    """How to build the pool's envs, what to call the adapter, its limit, and one env made."""

    make_env: Callable[[], gymnasium.Env]
    name: str
    max_episode_steps: int
    first_env: gymnasium.Env | None


def _spec_of(env_id: str) -> Any:
    try:
        return gymnasium.spec(env_id)
    except gymnasium.error.Error as error:
        message = " ".join(str(error).split())
        raise UnknownEnvError(f"unknown gymnasium environment {env_id!r}: {message}") from None


def _checked_limit(limit: int | None, name: str) -> int:
    if limit is None or limit < 1:
        raise UnsupportedEnvError(
            f"{name} has no time limit: pass max_episode_steps=N to envs.from_gymnasium"
        )
    return int(limit)


def _source_from_id(env_id: str, max_episode_steps: int | None, kwargs: dict[str, Any]) -> _Source:
    limit = _checked_limit(max_episode_steps or _spec_of(env_id).max_episode_steps, env_id)
    make = functools.partial(gymnasium.make, env_id, max_episode_steps=limit, **kwargs)
    try:
        first_env = make()  # missing extras (box2d, ...) and bad keyword arguments: one line now
    except (gymnasium.error.Error, TypeError, ImportError) as error:
        message = " ".join(str(error).split())
        raise UnsupportedEnvError(f"gymnasium {env_id!r} cannot be made: {message}") from None
    return _Source(make, f"{ID_PREFIX}{env_id}", limit, first_env)


def _source_from_object(source: Any, max_episode_steps: int | None) -> _Source:
    if isinstance(source, gymnasium.Env):
        # Copies are stepped, never the user's object, which keeps whatever state it had.
        make, probe, first_env = functools.partial(copy.deepcopy, source), source, None
    elif callable(source):
        make = source
        probe = first_env = source()
    else:
        raise UnsupportedEnvError(
            "envs.from_gymnasium takes a gymnasium id, a gymnasium.Env or a function returning "
            f"one, got {type(source).__name__}"
        )
    spec = getattr(probe, "spec", None)
    name = ID_PREFIX + (spec.id if spec is not None else type(probe.unwrapped).__name__)
    limit = _checked_limit(max_episode_steps or getattr(spec, "max_episode_steps", None), name)
    return _Source(make, name, limit, first_env)


def from_gymnasium(
    env: str | gymnasium.Env | Callable[[], gymnasium.Env],
    max_episode_steps: int | None = None,
    **make_kwargs: Any,
) -> HostGymnasiumEnv:
    """Wrap a gymnasium env as an rl_jax ``Environment`` (see the module docstring).

    ``env`` is a gymnasium id (``"Pendulum-v1"``, with or without the ``gymnasium:`` prefix;
    ``make_kwargs`` go to ``gymnasium.make``), a ``gymnasium.Env`` (deep-copied for every env of
    the pool, so it must be copyable; the object itself is never stepped) or a function that
    returns a new ``gymnasium.Env``. The episode limit is ``max_episode_steps``, else the env's
    registered one; an env with neither is refused, since evaluation needs episodes that end.
    Unknown ids raise ``UnknownEnvError``; untranslatable spaces ``UnsupportedEnvError``.
    """
    if isinstance(env, str):
        source = _source_from_id(env.removeprefix(ID_PREFIX), max_episode_steps, make_kwargs)
    elif make_kwargs:
        raise UnsupportedEnvError(
            f"keyword arguments ({', '.join(make_kwargs)}) are for gymnasium ids; bind them in "
            "the function that makes the env"
        )
    else:
        source = _source_from_object(env, max_episode_steps)
    return HostGymnasiumEnv(*source)


def register_gymnasium_id(name: str) -> str:
    """Register ``gymnasium:ID`` (for ``envs.make`` and ``--env``) as gymnasium's env ``ID`` and
    return it. The id, its time limit and its spaces are checked now, so that a bad one is one
    line before anything compiles."""
    env_id = name.removeprefix(ID_PREFIX)
    source = _source_from_id(env_id, None, {})
    first_env = source.first_env
    assert first_env is not None  # _source_from_id always makes one
    observation_space_from(first_env.observation_space, env_id)
    action_space_from(first_env.action_space, env_id)
    first_env.close()
    factory = functools.partial(from_gymnasium, env_id)
    registry.register(name, factory, max_episode_steps=source.max_episode_steps)
    return name
