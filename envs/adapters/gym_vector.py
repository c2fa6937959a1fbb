"""``gymnasium.make_vec(id, vectorization_mode="vector_entry_point")`` for the JAX envs: many
copies stepped by one jitted, vmapped call (seeding and time limits: ``envs.adapters.gym_adapter``).
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from rl_jax.envs.adapters.gym_adapter import (
    build,
    check_no_options_left,
    key_from_rng,
    take_reset_params,
    take_state_vector,
)
from rl_jax.envs.core import registry
from rl_jax.envs.core.spaces import Discrete


class GymnasiumVectorEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` copies of a JAX env stepped by one jitted, vmapped call.

    Autoreset is gymnasium 1.x's default ``NEXT_STEP``: the step after an env terminated or
    truncated resets it (that action is ignored; reward 0, flags false, obs and info of the new
    episode). Infos are dicts of ``[num_envs, ...]`` arrays with ``"_key"`` masks, as
    ``SyncVectorEnv`` builds them. Rewards are float64, also as there.

    ``reset(options=...)`` accepts ``reset_mask`` (bool ``[num_envs]``: reset only those),
    ``state`` (``[num_envs, d]`` or ``[d]`` for all), ``qpos``/``qvel`` likewise, and the env's
    gymnasium reset options (e.g. CartPole's ``low``/``high``).
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": 50,
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        env_id: str,
        num_envs: int = 1,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ):
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.env_id = registry.resolve_id(env_id)
        limit = (
            registry.max_episode_steps(self.env_id)
            if max_episode_steps is None
            else max_episode_steps
        )
        self.max_episode_steps = limit
        self._programs, self.params = build(self.env_id, kwargs, limit)
        self.jax_env = self._programs.env
        self.num_envs, self.render_mode = num_envs, render_mode
        self.metadata = {**self.metadata, "render_fps": getattr(self.jax_env, "render_fps", 50)}
        self.single_observation_space = self.jax_env.observation_space(self.params).to_gymnasium()
        self.single_action_space = self.jax_env.action_space(self.params).to_gymnasium()
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._jax_action_space = self.jax_env.action_space(self.params)
        self._keys: jax.Array | None = None
        self._states: Any = None
        self._obs: jax.Array | None = None
        self._pending = jnp.zeros((num_envs,), jnp.bool_)

    @property
    def jax_state(self) -> Any:
        """The batched JAX state pytree (leading axis ``num_envs``)."""
        return self._states

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset every env (or those of ``options["reset_mask"]``), optionally from exact states."""
        seeds = self._seed_list(seed)
        if isinstance(seed, int | np.integer):
            super().reset(seed=int(seed))
        options = dict(options or {})
        mask = self._take_reset_mask(options)
        self._reseed(seeds, mask)
        vector = take_state_vector(options)
        params = take_reset_params(options, self.jax_env, self.params, self.env_id)
        check_no_options_left(options, self.jax_env)
        if self._states is None and not mask.all():
            raise ValueError("the first reset must reset every env (no reset_mask)")
        if vector is None:
            keys, states, timestep = self._programs.vector_reset(self._keys, params)
        else:
            vectors = np.broadcast_to(vector, (self.num_envs, vector.shape[-1]))
            states, timestep = self._reset_to(vectors, params)
            keys = self._keys
        new = (keys, states, timestep.obs)
        if mask.all():
            self._keys, self._states, self._obs = new
        else:
            old = (self._keys, self._states, self._obs)
            self._keys, self._states, self._obs = self._programs.select(mask, new, old)
        self._pending = jnp.logical_and(self._pending, ~jnp.asarray(mask))
        return np.array(self._obs), _batch_info(jax.device_get(timestep.info), mask)

    def _reset_to(self, vectors: np.ndarray, params: Any):
        try:
            return self._programs.vector_reset_to(vectors, params)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.env_id} cannot start from these states: {error}") from error

    def _seed_list(self, seed: Any) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, int | np.integer):
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"got {len(seeds)} seeds for num_envs={self.num_envs}")
        return seeds

    def _take_reset_mask(self, options: dict[str, Any]) -> np.ndarray:
        if "reset_mask" not in options:
            return np.ones((self.num_envs,), np.bool_)
        mask = options.pop("reset_mask")
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_:
            raise TypeError("options['reset_mask'] must be a numpy bool array")
        if mask.shape != (self.num_envs,) or not mask.any():
            raise ValueError(f"options['reset_mask'] must have shape ({self.num_envs},) and a True")
        return mask

    def _reseed(self, seeds: list[int | None], mask: np.ndarray) -> None:
        """Env ``i`` gets the key a lone env reset with seed ``seeds[i]`` would draw."""
        keys = None if self._keys is None else np.asarray(self._keys)
        fresh = []
        for i, env_seed in enumerate(seeds):
            if env_seed is not None and mask[i]:
                fresh.append(key_from_rng(seeding.np_random(env_seed)[0]))
            elif keys is None:
                fresh.append(key_from_rng(self.np_random))
            else:
                fresh.append(keys[i])
        self._keys = jnp.stack([jnp.asarray(k) for k in fresh])

    def step(self, actions: Any):
        """Step every env in one jitted call; envs that ended last step reset first (gymnasium's
        next-step autoreset).
        """
        if self._states is None:
            raise gymnasium.error.ResetNeeded("call reset() before step()")
        actions = self._check_actions(actions)
        self._keys, self._states, timestep = self._programs.vector_step(
            self._keys, self._states, self._pending, actions, self.params
        )
        self._obs = timestep.obs
        self._pending = timestep.terminated | timestep.truncated
        timestep = jax.device_get(timestep)
        return (
            np.array(timestep.obs),
            np.asarray(timestep.reward, np.float64),
            np.array(timestep.terminated),
            np.array(timestep.truncated),
            _batch_info(timestep.info, np.ones((self.num_envs,), np.bool_)),
        )

    def _check_actions(self, actions: Any) -> np.ndarray:
        space = self._jax_action_space
        array = np.asarray(actions)
        expected = (self.num_envs, *space.shape)
        if array.size != int(np.prod(expected)):
            raise ValueError(f"expected actions of shape {expected}, got {array.shape}")
        array = array.reshape(expected)
        if isinstance(space, Discrete) and (
            not np.issubdtype(array.dtype, np.integer) or array.min() < 0 or array.max() >= space.n
        ):
            raise ValueError(f"expected integer actions in [0, {space.n}), got {actions!r}")
        return array.astype(space.dtype)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """One frame per env in ``rgb_array`` mode; None (with a warning) without a render mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() without a render mode; pass render_mode='rgb_array'")
            return None
        if self._states is None:
            return None
        states = jax.device_get(self._states)
        frames = []
        for i in range(self.num_envs):
            state = jax.tree.map(functools.partial(_index, i), states)
            frames.append(np.asarray(self.jax_env.render(state, self.params), np.uint8))
        return tuple(frames)


def _index(i: int, batched: np.ndarray) -> np.ndarray:
    return batched[i]


def _batch_info(info: dict[str, Any], mask: np.ndarray) -> dict[str, Any]:
    """``SyncVectorEnv``'s layout: each key an array over envs plus a ``"_key"`` bool mask."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        if isinstance(value, dict):
            out[key] = _batch_info(value, mask)
        else:
            out[key] = np.array(value)
            out[key][~mask] = 0  # envs that did not report this key hold zeros there
        out[f"_{key}"] = mask.copy()
    return out
