"""Wrappers that adapt an env to a learner, each a pure transform of ``reset``/``step``.

Usual stack for training: ``EpisodeStatistics(AutoReset(RescaleAction(env)))`` — statistics sit
outside autoreset so they see the step that ended an episode, not the reset that followed it.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvParams, ParamsT, PRNGKey, StateT, TimeStep
from rl_jax.envs.core.spaces import Box, Discrete, Space

ACTION_MASK = "action_mask"  # info key: bool [n], the legal actions of the timestep's obs
FINAL_ACTION_MASK = "final_action_mask"  # info key: the action mask of ``final_obs``


def reset_after(
    env: Environment, key: PRNGKey, state: Any, timestep: TimeStep, params: Any = None
) -> tuple[Any, TimeStep]:
    """The start of the episode that follows one that ended in ``state`` with ``timestep``.

    ``env.reset_after`` where the env's class defines it (it may go on from ``state``:
    ``EpisodicLife`` after a lost life), else ``env.reset(key, params)``. Looked up on the class,
    so a wrapper without its own ``reset_after`` never hands its state to its env's.
    """
    if getattr(type(env), "reset_after", None) is None:
        return env.reset(key, params)
    return env.reset_after(key, state, timestep, params)  # type: ignore[attr-defined]


class Wrapper(Environment[StateT, ParamsT]):
    """Delegates everything to the wrapped env; subclasses override what they change."""

    def __init__(self, env: Environment):
        self.env = env
        self.id = env.id
        self.max_episode_steps = env.max_episode_steps

    def __getattr__(self, name: str) -> Any:
        # Only reached for attributes not found normally: expose the inner env's extras.
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    @property
    def unwrapped(self) -> Environment:
        """The innermost environment, below every layer of wrappers."""
        return self.env.unwrapped if isinstance(self.env, Wrapper) else self.env

    @property
    def default_params(self):
        """The wrapped env's default params."""
        return self.env.default_params

    def observation_space(self, params: ParamsT | None = None) -> Space:
        """The wrapped env's observation space (wrappers that change observations override this)."""
        return self.env.observation_space(params)

    def action_space(self, params: ParamsT | None = None) -> Space:
        """The wrapped env's action space (wrappers that change actions override this)."""
        return self.env.action_space(params)

    def empty_info(self) -> dict[str, Array]:
        """The wrapped env's reset info: same keys, shapes and dtypes as its step info."""
        return self.env.empty_info()

    def reset(self, key: PRNGKey, params: ParamsT | None = None):
        """Reset the wrapped env; returns ``(state, timestep)``."""
        return self.env.reset(key, params)

    def step(self, key: PRNGKey, state: StateT, action: Array, params: ParamsT | None = None):
        """Step the wrapped env; returns ``(state, timestep)``."""
        return self.env.step(key, state, action, params)

    def reset_after(
        self, key: PRNGKey, state: StateT, timestep: TimeStep, params: ParamsT | None = None
    ):
        """The start after an episode that ended in ``state`` (``reset_after``): the wrapped
        env's, which may continue a game after a lost life, where this wrapper keeps the env's
        state and reset as they are; else this wrapper's own ``reset``. A wrapper that changes
        the state or the reset and should pass a continuing reset on overrides this."""
        if type(self).reset is not Wrapper.reset:
            return self.reset(key, params)
        return reset_after(self.env, key, state, timestep, params)

    def reset_to(self, vector: Array, params: ParamsT | None = None):
        """Start the wrapped env from an exact state vector (``Environment.reset_to``)."""
        return self.env.reset_to(vector, params)

    def render(self, state: StateT, params: ParamsT | None = None):
        """RGB frame of the wrapped env's state."""
        return self.env.render(state, params)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"


def _select(pred: Array, on_true: Any, on_false: Any) -> Any:
    """``where(pred, a, b)`` over matching pytrees; ``pred`` is a scalar per env."""
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


class AutoReset(Wrapper):
    """Resets inside ``step`` when an episode ends ("same-step" autoreset).

    The returned ``obs`` is the first observation of the new episode; the true last observation
    of the finished episode is kept in ``info["final_obs"]`` so that a learner can bootstrap
    from it at truncation. ``reward``, ``terminated`` and ``truncated`` are those of the
    finishing step. ``info["final_obs"]`` equals ``obs`` on steps that did not end an episode.

    The reset branch is computed every step and selected per env (under vmap a ``cond`` would
    run both branches anyway); envs whose reset is expensive can override ``reset`` cheaply.
    The reset is ``reset_after(env, ...)``: an env that continues after an episode's end
    (``EpisodicLife`` after a lost life) goes on from the ended state. For an env with a
    legal-action mask, ``info["action_mask"]`` is the new episode's first observation's, as
    ``obs`` is, and ``info["final_action_mask"]`` keeps the ended one's, as ``final_obs`` does.
    """

    def empty_info(self) -> dict[str, Array]:
        """The wrapped env's info plus ``final_obs``, zeros shaped like an observation (and
        ``final_action_mask``, all True, for an env with an action mask)."""
        obs_space = self.observation_space()
        final_obs = jnp.zeros(obs_space.shape, obs_space.dtype)
        info = {**self.env.empty_info(), "final_obs": final_obs}
        if ACTION_MASK in info:
            info[FINAL_ACTION_MASK] = info[ACTION_MASK]
        return info

    @staticmethod
    def _first(state: object, ts: TimeStep):
        info = {**ts.info, "final_obs": ts.obs}
        if ACTION_MASK in info:
            info[FINAL_ACTION_MASK] = info[ACTION_MASK]
        return state, ts._replace(info=info)

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset; ``info["final_obs"]`` is the first observation itself."""
        return self._first(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start from an exact state; ``info["final_obs"]`` is the first observation itself."""
        return self._first(*self.env.reset_to(vector, params))

    def reset_after(
        self, key: PRNGKey, state: object, timestep: TimeStep, params: EnvParams | None = None
    ):
        """The wrapped env's ``reset_after``, with ``final_obs`` its first observation."""
        return self._first(*reset_after(self.env, key, state, timestep, params))

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step, and where the episode ended (terminated or truncated) start a new one at once.

        The returned ``obs`` is then the new episode's first observation, while
        ``info["final_obs"]`` keeps the last observation of the ended one, which a truncated TD
        target bootstraps from. The reset is computed on every step and selected where done, so the
        step stays branch-free under vmap.
        """
        key_step, key_reset = jax.random.split(key)
        next_state, ts = self.env.step(key_step, state, action, params)
        reset_state, reset_ts = reset_after(self.env, key_reset, next_state, ts, params)
        done = jnp.logical_or(ts.terminated, ts.truncated)
        state = _select(done, reset_state, next_state)
        obs = jnp.where(done, reset_ts.obs, ts.obs)
        info = {**ts.info, "final_obs": ts.obs}
        if ACTION_MASK in ts.info:
            info[ACTION_MASK] = jnp.where(done, reset_ts.info[ACTION_MASK], ts.info[ACTION_MASK])
            info[FINAL_ACTION_MASK] = ts.info[ACTION_MASK]
        return state, ts._replace(obs=obs, info=info)


@struct.dataclass
class StatisticsState:
    """``EpisodeStatistics``'s state: the wrapped env's state plus running and last-finished
    episode totals.
    """

    env_state: Any
    episode_return: Array  # [] float32, running return of the current episode
    episode_length: Array  # [] int32
    returned_episode_return: Array  # [] float32, return of the last finished episode
    returned_episode_length: Array  # [] int32

    @property
    def time(self) -> Array:
        """Steps since the wrapped env's last reset."""
        return self.env_state.time


class EpisodeStatistics(Wrapper):
    """Tracks undiscounted return and length; reports them in ``info``.

    ``info["episode_done"]`` is true on the step that ended an episode, and then
    ``info["episode_return"]``/``info["episode_length"]`` hold that episode's totals (otherwise
    they hold the last finished episode's, or 0 before the first one ends).
    """

    def empty_info(self) -> dict[str, Array]:
        """The wrapped env's info plus zero ``episode_return``, ``episode_length`` and
        ``episode_done``.
        """
        return {
            **self.env.empty_info(),
            "episode_return": jnp.zeros((), jnp.float32),
            "episode_length": jnp.zeros((), jnp.int32),
            "episode_done": jnp.zeros((), jnp.bool_),
        }

    def _wrap(self, env_state: object, ts: TimeStep) -> tuple[StatisticsState, TimeStep]:
        zero_f, zero_i = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
        state = StatisticsState(env_state, zero_f, zero_i, zero_f, zero_i)
        info = {**ts.info, "episode_return": zero_f, "episode_length": zero_i}
        return state, ts._replace(info={**info, "episode_done": jnp.zeros((), jnp.bool_)})

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset the wrapped env with zeroed episode totals."""
        return self._wrap(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start the wrapped env from an exact state, with zeroed episode totals."""
        return self._wrap(*self.env.reset_to(vector, params))

    def reset_after(
        self,
        key: PRNGKey,
        state: StatisticsState,
        timestep: TimeStep,
        params: EnvParams | None = None,
    ):
        """The wrapped env's ``reset_after``, with zeroed episode totals."""
        return self._wrap(*reset_after(self.env, key, state.env_state, timestep, params))

    def step(
        self, key: PRNGKey, state: StatisticsState, action: Array, params: EnvParams | None = None
    ):
        """Step and add the reward to the running totals.

        On the step that ends an episode, ``info`` reports its return and length with
        ``episode_done=True`` and the running totals restart from zero; on other steps it reports
        the last finished episode's.
        """
        env_state, ts = self.env.step(key, state.env_state, action, params)
        done = jnp.logical_or(ts.terminated, ts.truncated)
        episode_return = state.episode_return + ts.reward
        episode_length = state.episode_length + 1
        new_state = StatisticsState(
            env_state=env_state,
            episode_return=jnp.where(done, 0.0, episode_return),
            episode_length=jnp.where(done, 0, episode_length),
            returned_episode_return=jnp.where(done, episode_return, state.returned_episode_return),
            returned_episode_length=jnp.where(done, episode_length, state.returned_episode_length),
        )
        info = {
            **ts.info,
            "episode_return": new_state.returned_episode_return,
            "episode_length": new_state.returned_episode_length,
            "episode_done": done,
        }
        return new_state, ts._replace(info=info)

    def render(self, state: StatisticsState, params: EnvParams | None = None):
        """RGB frame of the wrapped env's state."""
        return self.env.render(state.env_state, params)


class RescaleAction(Wrapper):
    """Exposes a ``[-1, 1]`` Box action space and maps it affinely onto the env's bounds.

    Actions outside ``[-1, 1]`` are mapped linearly too (not clipped): the env applies its own
    clipping exactly as its reference does.
    """

    def __init__(self, env: Environment):
        super().__init__(env)
        space = env.action_space()
        if not isinstance(space, Box) or not space.bounded:
            raise TypeError(f"RescaleAction needs a bounded Box action space, got {space}")
        self._low = np.asarray(space.low, np.float32)
        self._high = np.asarray(space.high, np.float32)

    def action_space(self, params: EnvParams | None = None) -> Space:
        """The box [-1, 1] in every action dimension."""
        shape = self._low.shape
        return Box(-np.ones(shape, np.float32), np.ones(shape, np.float32), shape)

    def to_env_action(self, action: Array) -> Array:
        """Map an action in [-1, 1] linearly onto the wrapped env's ``[low, high]``."""
        # jnp on the left: numpy defers to jax's operators here anyway, so the result is a jax
        # array, and the annotation says so.
        low = jnp.asarray(self._low)
        return low + (jnp.asarray(action, jnp.float32) + 1.0) * 0.5 * (self._high - self._low)

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step the wrapped env with the action mapped from [-1, 1] onto its bounds."""
        return self.env.step(key, state, self.to_env_action(action), params)


class DiscretizeActions(Wrapper):
    """Lets a discrete-action learner drive a continuous env.

    Each action dimension gets ``num_bins`` evenly spaced values from its low to its high bound
    (or the explicit ``values``); the discrete action indexes the Cartesian product of the grids,
    first dimension slowest. Rocket thrust in {-1, 0, +1} is ``DiscretizeActions(rocket, 3)``.
    """

    def __init__(self, env: Environment, num_bins: int = 3, values: Any = None):
        super().__init__(env)
        space = env.action_space()
        if not isinstance(space, Box):
            raise TypeError(f"DiscretizeActions needs a Box action space, got {space}")
        dims = int(np.prod(space.shape)) if space.shape else 1
        if values is None:
            if num_bins < 2:
                raise ValueError(f"num_bins must be >= 2, got {num_bins}")
            low, high = space.low.reshape(-1), space.high.reshape(-1)
            grids = [np.linspace(low[d], high[d], num_bins, dtype=np.float32) for d in range(dims)]
        else:
            grids = [np.asarray(values, np.float32)] * dims
        mesh = np.meshgrid(*grids, indexing="ij")
        table = np.stack([m.reshape(-1) for m in mesh], axis=-1)  # [n_actions, dims]
        self._table: np.ndarray = table.reshape((table.shape[0],) + tuple(space.shape))
        self._space_shape = space.shape

    @property
    def action_values(self) -> np.ndarray:
        """``[n, *action_shape]``: the continuous action each index stands for."""
        return self._table

    def action_space(self, params: EnvParams | None = None) -> Space:
        """A ``Discrete`` space with one action per row of the action table."""
        return Discrete(self._table.shape[0])

    def to_env_action(self, action: Array) -> Array:
        """The continuous action (row of the table) that a discrete action index stands for."""
        return jnp.asarray(self._table)[jnp.asarray(action, jnp.int32)]

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step the wrapped env with the continuous action the discrete index stands for."""
        return self.env.step(key, state, self.to_env_action(action), params)


class FlattenObservation(Wrapper):
    """Reshapes observations (and ``info["final_obs"]`` if present) to one dimension."""

    def observation_space(self, params: EnvParams | None = None) -> Space:
        """The wrapped env's observation box flattened to one dimension."""
        space = self.env.observation_space(params)
        if not isinstance(space, Box):
            raise TypeError(f"FlattenObservation needs a Box observation space, got {space}")
        return Box(space.low.reshape(-1), space.high.reshape(-1), (int(np.prod(space.shape)),))

    def _flatten(self, ts: TimeStep) -> TimeStep:
        info = dict(ts.info)
        if "final_obs" in info:
            info["final_obs"] = info["final_obs"].reshape(-1)
        return ts._replace(obs=ts.obs.reshape(-1), info=info)

    def empty_info(self) -> dict[str, Array]:
        """The wrapped env's reset info, with ``final_obs`` (if any) flattened too."""
        info = dict(self.env.empty_info())
        if "final_obs" in info:
            info["final_obs"] = info["final_obs"].reshape(-1)
        return info

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset with a flattened observation."""
        state, ts = self.env.reset(key, params)
        return state, self._flatten(ts)

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start from an exact state, with a flattened observation."""
        state, ts = self.env.reset_to(vector, params)
        return state, self._flatten(ts)

    def reset_after(
        self, key: PRNGKey, state: object, timestep: TimeStep, params: EnvParams | None = None
    ):
        """The wrapped env's ``reset_after`` (given the observation in its shape), flattened."""
        shape = self.env.observation_space(params).shape
        inner = timestep._replace(obs=timestep.obs.reshape(shape))
        state, ts = reset_after(self.env, key, state, inner, params)
        return state, self._flatten(ts)

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step with a flattened observation (and ``final_obs``)."""
        state, ts = self.env.step(key, state, action, params)
        return state, self._flatten(ts)


class SameLimit(Wrapper):
    """A wrapper whose episode limit is its env's: setting it sets the env's, which truncates."""

    @property
    def max_episode_steps(self) -> int:
        """The wrapped env's episode limit."""
        return self.env.max_episode_steps

    @max_episode_steps.setter
    def max_episode_steps(self, value: int) -> None:
        self.env.max_episode_steps = value


class MaskObservation(SameLimit):
    """Shows the learner only the entries ``keep`` of a one-dimensional Box observation, making
    the env partially observed (velocities hidden, for instance).

    By default the other entries are dropped: the observation, its space (bounds included) and
    ``info["final_obs"]`` (where an ``AutoReset`` below keeps one) hold the kept entries in the
    order given. With ``zero_others=True`` they are set to zero instead and the observation and
    its space keep their shape, as RL Zoo's ``MaskVelocityWrapper`` does (``CartPoleNoVel-v1``).
    Rewards, both flags, the rest of ``info``, the state and the episode limit are the wrapped
    env's; setting ``max_episode_steps`` sets the wrapped env's, which decides truncation.
    """

    def __init__(self, env: Environment, keep: Iterable[int], zero_others: bool = False):
        super().__init__(env)
        space = env.observation_space()
        if not isinstance(space, Box) or len(space.shape) != 1:
            raise TypeError(f"MaskObservation needs a one-dimensional Box observation, got {space}")
        size = space.shape[0]
        self.keep = tuple(int(i) for i in keep)
        if not self.keep or len(set(self.keep)) != len(self.keep):
            raise ValueError(f"keep must name distinct observation entries, got {self.keep}")
        if not all(0 <= i < size for i in self.keep):
            raise ValueError(f"keep {self.keep} must index an observation of {size} entries")
        self.zero_others = zero_others
        self._kept = np.zeros(size, np.bool_)
        self._kept[list(self.keep)] = True

    def observation_space(self, params: EnvParams | None = None) -> Space:
        """The kept entries' bounds (or, with ``zero_others``, the wrapped env's space)."""
        space = self.env.observation_space(params)
        if self.zero_others or not isinstance(space, Box):
            return space
        keep = list(self.keep)
        return Box(space.low[keep], space.high[keep], (len(keep),), space.dtype)

    def mask(self, obs: Array) -> Array:
        """The observation the learner sees of ``obs`` (``[..., size]``: leading axes kept)."""
        if self.zero_others:
            kept = jnp.broadcast_to(jnp.asarray(self._kept), obs.shape)
            return jnp.where(kept, obs, jnp.zeros_like(obs))
        return obs[..., np.asarray(self.keep)]

    def _mask_info(self, info: dict[str, Array]) -> dict[str, Array]:
        if "final_obs" not in info:
            return info
        return {**info, "final_obs": self.mask(info["final_obs"])}

    def _masked(self, state: object, ts: TimeStep):
        return state, ts._replace(obs=self.mask(ts.obs), info=self._mask_info(ts.info))

    def empty_info(self) -> dict[str, Array]:
        """The wrapped env's reset info, with ``final_obs`` (if any) masked too."""
        return self._mask_info(dict(self.env.empty_info()))

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset; the learner sees the masked first observation."""
        return self._masked(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start from an exact state of the wrapped env; the observation is masked."""
        return self._masked(*self.env.reset_to(vector, params))

    def reset_after(
        self, key: PRNGKey, state: object, timestep: TimeStep, params: EnvParams | None = None
    ):
        """The wrapped env's ``reset_after``, masked. It gets the observation in its own shape
        with the kept entries in place and zeros for the others (which the mask drops again)."""
        size = self._kept.shape[0]
        if self.zero_others:
            obs = timestep.obs
        else:
            zeros = jnp.zeros((*timestep.obs.shape[:-1], size), timestep.obs.dtype)
            obs = zeros.at[..., np.asarray(self.keep)].set(timestep.obs)
        inner = timestep._replace(obs=obs)
        return self._masked(*reset_after(self.env, key, state, inner, params))

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step the wrapped env; the observation (and ``final_obs``) is masked."""
        return self._masked(*self.env.step(key, state, action, params))

    def step_active(
        self,
        key: PRNGKey,
        state: object,
        action: Array,
        active: Array,
        params: EnvParams | None = None,
    ):
        """The wrapped env's ``step_active`` (which may skip the inactive envs' work), masked."""
        return self._masked(*self.env.step_active(key, state, action, active, params))
