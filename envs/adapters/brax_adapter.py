"""Brax interop, both ways.

``FromBrax(brax_env)`` (or ``make_brax("hopper", backend="mjx")``) makes any ``brax.envs.Env``
one of our ``Environment``s, so our learners and wrappers train it::

    from rl_jax import envs
    from rl_jax.envs.adapters.brax_adapter import ToBrax, make_brax

    env = envs.AutoReset(make_brax("ant"))          # brax's MJX ant as an rl_jax env

``ToBrax(env)`` exposes one of our envs as a ``brax.envs.Env``, so brax's wrappers and training code
drive it::

    cheetah = ToBrax(envs.make("rl_jax/HalfCheetah-v5"))
    brax_env = brax.envs.training.wrap(cheetah, episode_length=1000)

Conventions bridged: brax's ``done`` is termination only (brax's ``EpisodeWrapper`` adds the time
limit and reports it in ``info["truncation"]``), so ``FromBrax`` maps ``done`` to ``terminated`` and
applies our own ``max_episode_steps``, while ``ToBrax`` reports our ``terminated`` as ``done`` and
leaves the episode limit to brax's wrappers. Brax steps take no PRNG key; ``ToBrax`` carries one in
``state.info["rng"]``. Brax actions are in [-1, 1] by convention: wrap ours in ``RescaleAction``
first when its bounds differ (``ToBrax(env, rescale_actions=True)`` does it).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvParams, EnvState, PRNGKey
from rl_jax.envs.core.spaces import Box
from rl_jax.envs.core.wrappers import RescaleAction
from rl_jax.envs.mujoco.mujoco_backend import without_warp_lines

with without_warp_lines():  # brax imports MJX, which prints two lines where Warp is not installed
    from brax.envs import base as brax_base


@struct.dataclass
class BraxEnvState(EnvState):
    """Our env state wrapping a brax ``State``."""

    brax_state: Any  # brax.envs.base.State


class FromBrax(Environment[BraxEnvState, EnvParams]):
    """A brax env as an rl_jax ``Environment``: no dynamic params, brax's metrics in ``info``.

    Brax's own code relies on implicit rank promotion, so its calls are traced with it allowed
    even where the caller set ``jax_numpy_rank_promotion="raise"`` (as our tests do).
    """

    def __init__(self, brax_env: brax_base.Env, max_episode_steps: int = 1000, env_id: str = ""):
        self.brax_env = brax_env
        self.max_episode_steps = max_episode_steps
        self.id = env_id or f"brax/{type(brax_env.unwrapped).__name__}"
        with jax.numpy_rank_promotion("allow"):
            first = jax.eval_shape(brax_env.reset, jax.random.PRNGKey(0))
        if not hasattr(first.obs, "shape"):
            raise TypeError("FromBrax supports brax envs with array observations, not dicts")
        self._obs_shape = tuple(first.obs.shape)
        self._metric_names = tuple(sorted(first.metrics))

    @property
    def default_params(self) -> EnvParams:
        """Empty params: a brax env has no dynamic params of ours."""
        return EnvParams()

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """An unbounded box shaped like the brax env's observation."""
        return Box(-np.inf, np.inf, self._obs_shape)

    def action_space(self, params: EnvParams | None = None) -> Box:
        """The box [-1, 1] of the brax env's action size (brax's convention)."""
        size = self.brax_env.action_size
        return Box(-np.ones(size, np.float32), np.ones(size, np.float32), (size,))

    def empty_info(self) -> dict[str, Array]:
        """Zero for each of the brax env's metrics."""
        return {name: jnp.zeros((), jnp.float32) for name in self._metric_names}

    def _info(self, brax_state: brax_base.State) -> dict[str, Array]:
        return {
            name: jnp.asarray(brax_state.metrics[name], jnp.float32) for name in self._metric_names
        }

    def reset_env(self, key: PRNGKey, params: EnvParams) -> tuple[BraxEnvState, Array]:
        """brax's ``reset``; the observation is its ``obs``."""
        with jax.numpy_rank_promotion("allow"):
            brax_state = self.brax_env.reset(key)
        return BraxEnvState(time=jnp.zeros((), jnp.int32), brax_state=brax_state), brax_state.obs

    def step_env(self, key: PRNGKey, state: BraxEnvState, action: Array, params: EnvParams):
        """brax's ``step``: its ``done`` becomes ``terminated`` and its metrics the info."""
        with jax.numpy_rank_promotion("allow"):
            brax_state = self.brax_env.step(state.brax_state, action)
        terminated = brax_state.done > 0.5
        next_state = BraxEnvState(time=state.time + 1, brax_state=brax_state)
        return next_state, brax_state.obs, brax_state.reward, terminated, self._info(brax_state)


def make_brax(
    name: str, backend: str = "mjx", max_episode_steps: int = 1000, **kwargs: object
) -> FromBrax:
    """``brax.envs.get_environment(name, backend=...)`` wrapped as an rl_jax env."""
    from brax import envs as brax_envs  # heavy: loads every brax env; imported on first use

    brax_env = brax_envs.get_environment(name, backend=backend, **kwargs)
    return FromBrax(brax_env, max_episode_steps, env_id=f"brax/{name}")


class ToBrax(brax_base.Env):
    """One of our envs as a ``brax.envs.Env``; our state rides in ``pipeline_state``."""

    def __init__(
        self, env: Environment, params: EnvParams | None = None, rescale_actions: bool = False
    ):
        self.env = RescaleAction(env) if rescale_actions else env
        self.params = env.default_params if params is None else params

    def reset(self, rng: jax.Array) -> brax_base.State:
        """Reset our env; the PRNG key for later steps rides in ``info["rng"]``."""
        key_reset, key_next = jax.random.split(rng)
        state, timestep = self.env.reset(key_reset, self.params)
        return brax_base.State(
            pipeline_state=state,
            obs=timestep.obs,
            reward=jnp.zeros((), jnp.float32),
            done=jnp.zeros((), jnp.float32),
            metrics=self._metrics(timestep.info),
            info={"rng": key_next},
        )

    def step(self, state: brax_base.State, action: jax.Array) -> brax_base.State:
        """Step our env with the key carried in ``info["rng"]``; ``done`` is our ``terminated``."""
        key_step, key_next = jax.random.split(state.info["rng"])
        next_state, timestep = self.env.step(key_step, state.pipeline_state, action, self.params)
        return state.replace(
            pipeline_state=next_state,
            obs=timestep.obs,
            reward=timestep.reward,
            done=timestep.terminated.astype(jnp.float32),
            metrics=self._metrics(timestep.info),
            info={**state.info, "rng": key_next},
        )

    @staticmethod
    def _metrics(info: dict[str, Array]) -> dict[str, Array]:
        return {name: jnp.asarray(value, jnp.float32) for name, value in info.items()}

    @property
    def observation_size(self) -> int:
        """Number of observation values."""
        return int(np.prod(self.env.observation_space().shape))

    @property
    def action_size(self) -> int:
        """Number of action values."""
        return int(np.prod(self.env.action_space().shape))

    @property
    def backend(self) -> str:
        """Our env's physics backend name, or "jax" for a pure-JAX env."""
        return getattr(self.env, "backend", "jax")
