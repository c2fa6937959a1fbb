"""The functional environment API shared by every env, wrapper and learner.

An environment is a stateless object holding only static configuration (shapes, episode limit);
everything that changes lives in an explicit ``state`` pytree, and everything a sweep may vary
(gravity, dt, goal tolerance, reward weights) in a ``params`` pytree. Both ``reset`` and ``step``
are pure, so they can be jitted, vmapped over envs and over params, and scanned.

``terminated`` (the MDP reached a terminal state: do not bootstrap) and ``truncated`` (the episode
was cut by the time limit: do bootstrap) are always reported separately, with gymnasium's
semantics: on the step that reaches the limit ``truncated`` is true even when ``terminated`` is.
"""

from __future__ import annotations

from typing import Any, Generic, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.spaces import Space

Array = jax.Array
PRNGKey = jax.Array


class TimeStep(NamedTuple):
    """What the agent sees after ``reset`` or ``step``."""

    obs: Array  # [*obs_shape] float32 (or the space's dtype)
    reward: Array  # [] float32; 0 after reset
    terminated: Array  # [] bool; the new state is terminal: no bootstrapping from it
    truncated: Array  # [] bool; the time limit cut the episode: bootstrap from ``obs``
    info: dict[str, Array]  # fixed keys and shapes per env, so it can live in a scan carry


@struct.dataclass
class EnvState:
    """Base of every env state: ``time`` counts steps since the last reset."""

    time: Array  # [] int32


@struct.dataclass
class EnvParams:
    """Base of every params pytree. Subclasses add dynamic (vmappable) fields."""


StateT = TypeVar("StateT", bound=EnvState)
ParamsT = TypeVar("ParamsT", bound=EnvParams)


def float32_field(value: float) -> Any:
    """A params field holding ``value`` as a float32 scalar (a fresh one per instance)."""
    return struct.field(default_factory=lambda: np.float32(value))


def keep_active(active: Array, new: Any, old: Any) -> Any:
    """``new`` where ``active`` (a scalar bool: one env), else ``old``, leaf by leaf."""
    active = jnp.asarray(active, jnp.bool_)
    return jax.tree.map(lambda n, o: jnp.where(active, n, o), new, old)


class Environment(Generic[StateT, ParamsT]):
    """Base class: subclasses implement ``reset_env`` and ``step_env`` for one unbatched env.

    The base class adds the time limit (``max_episode_steps``, static) and fills in default params.
    Batching is the caller's business: ``jax.vmap(env.step, in_axes=(0, 0, 0, None))``.
    """

    #: gymnasium-style id, e.g. "rl_jax/Rocket-v0"
    id: str = ""
    #: static episode limit; truncated is set when ``state.time`` reaches it
    max_episode_steps: int = 1000

    # ---- to implement -------------------------------------------------------------------------
    @property
    def default_params(self) -> ParamsT:
        """The params pytree used when ``reset``/``step`` get ``params=None``."""
        raise NotImplementedError

    def reset_env(self, key: PRNGKey, params: ParamsT) -> tuple[StateT, Array]:
        """Sample a start state; return ``(state, obs)``. ``state.time`` must be 0."""
        raise NotImplementedError

    def step_env(
        self, key: PRNGKey, state: StateT, action: Array, params: ParamsT
    ) -> tuple[StateT, Array, Array, Array, dict[str, Array]]:
        """Advance one agent step; return ``(state, obs, reward, terminated, info)``.

        Must increment ``state.time``. The base class derives ``truncated`` from it.
        """
        raise NotImplementedError

    def observation_space(self, params: ParamsT | None = None) -> Space:
        """The space of one unbatched observation."""
        raise NotImplementedError

    def action_space(self, params: ParamsT | None = None) -> Space:
        """The space of one unbatched action."""
        raise NotImplementedError

    # ---- optional -----------------------------------------------------------------------------
    def state_from_vector(
        self, vector: Array, params: ParamsT | None = None
    ) -> tuple[StateT, Array]:
        """Build an exact start state, as gymnasium's ``reset(options={"state": ...})``.

        Returns ``(state, obs)``. Envs that support exact starts override this.
        """
        raise NotImplementedError(f"{type(self).__name__} cannot start from a given state")

    def empty_info(self) -> dict[str, Array]:
        """The info dict of a first timestep: same keys/shapes/dtypes as ``step``'s info."""
        return {}

    def first_info(self, state: StateT) -> dict[str, Array]:
        """The info dict of the first timestep of an episode starting in ``state``:
        ``empty_info()`` unless an env reports something at the start (the legal actions of
        an env with an action mask)."""
        return self.empty_info()

    # ---- the public API -----------------------------------------------------------------------
    def reset(self, key: PRNGKey, params: ParamsT | None = None) -> tuple[StateT, TimeStep]:
        """Start an episode: returns ``(state, timestep)`` with reward 0 and both flags False.

        ``params`` defaults to ``default_params``; the key is consumed by the env's start sampling.
        """
        params = self.default_params if params is None else params
        state, obs = self.reset_env(key, params)
        return state, self._first_timestep(state, obs)

    def step(
        self, key: PRNGKey, state: StateT, action: Array, params: ParamsT | None = None
    ) -> tuple[StateT, TimeStep]:
        """Advance one agent step: returns ``(state, timestep)``.

        ``timestep.truncated`` is set when ``state.time`` reaches ``max_episode_steps``,
        independently of ``terminated``. ``params`` defaults to ``default_params``.
        """
        params = self.default_params if params is None else params
        return self._timestep(*self.step_env(key, state, action, params))

    def step_active(
        self,
        key: PRNGKey,
        state: StateT,
        action: Array,
        active: Array,
        params: ParamsT | None = None,
    ) -> tuple[StateT, TimeStep]:
        """``step`` where ``active`` (a bool per env, under vmap) is True; elsewhere the state is
        returned unchanged and the timestep is unspecified (read it only where active).

        For learners whose finished envs wait for the others (REINFORCE's batches of whole
        episodes). This default steps every env and keeps the old state where inactive; envs
        whose step is costly override it to skip the inactive envs' work (the MuJoCo C
        backends do, ``envs.mujoco.mujoco_env``).
        """
        new_state, timestep = self.step(key, state, action, params)
        return keep_active(active, new_state, state), timestep

    def _timestep(
        self, state: StateT, obs: Array, reward: Array, terminated: Array, info: dict[str, Array]
    ) -> tuple[StateT, TimeStep]:
        truncated = state.time >= self.max_episode_steps
        timestep = TimeStep(
            obs=obs,
            reward=jnp.asarray(reward, jnp.float32),
            terminated=jnp.asarray(terminated, jnp.bool_),
            truncated=jnp.asarray(truncated, jnp.bool_),
            info=info,
        )
        return state, timestep

    def reset_to(self, vector: Array, params: ParamsT | None = None) -> tuple[StateT, TimeStep]:
        """Start from an exact state vector (see ``state_from_vector``)."""
        params = self.default_params if params is None else params
        state, obs = self.state_from_vector(jnp.asarray(vector), params)
        return state, self._first_timestep(state, obs)

    def _first_timestep(self, state: StateT, obs: Array) -> TimeStep:
        return TimeStep(
            obs=obs,
            reward=jnp.zeros((), jnp.float32),
            terminated=jnp.zeros((), jnp.bool_),
            truncated=jnp.zeros((), jnp.bool_),
            info=self.first_info(state),
        )

    # ---- rendering (host side, optional) ------------------------------------------------------
    def render(self, state: StateT, params: ParamsT | None = None) -> Any:
        """Return an RGB frame (H, W, 3) uint8 for one unbatched state."""
        raise NotImplementedError(f"{type(self).__name__} has no renderer")

    @property
    def name(self) -> str:
        """The env's registered id, or its class name when it has none."""
        return self.id or type(self).__name__

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.id!r}>"
