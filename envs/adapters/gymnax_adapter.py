"""gymnax envs as ours: ``envs.from_gymnax("Breakout-MinAtar")`` runs any gymnax env inside the
compiled program, exactly as our own envs run (jit, vmap, scan, our wrappers and learners)::

    from rl_jax import envs

    env = envs.from_gymnax("SpaceInvaders-MinAtar")  # or envs.make("rl_jax/SpaceInvaders-MinAtar")
    state, ts = env.reset(jax.random.key(0))
    state, ts = env.step(jax.random.key(1), state, jnp.int32(2))

Conventions bridged:

- gymnax's ``step`` merges its two episode ends into ``done`` and resets inside the step. The
  adapter calls gymnax's ``step_env`` and ``reset_env`` instead: ``terminated`` is ``step_env``'s
  own (in gymnax 1.0 a natural end only, never the time limit), ``truncated`` our static
  ``max_episode_steps`` (gymnax's ``max_steps_in_episode``), and nothing resets: ``AutoReset`` does.
- The step key is split as gymnax's ``step`` splits it, and the reset key is passed as it is, so
  the same keys give gymnax's own episodes, step for step (tests/envs/test_gymnax.py).
- Observations are float32 arrays (MinAtar's HxWxC grids of 0/1, channels last); gymnax's Box and
  Discrete spaces become ours. gymnax's info (a ``discount``) is dropped.
- The params pytree is gymnax's own ``EnvParams``. Its ``max_steps_in_episode`` is the static
  limit given to ``from_gymnax`` (default: gymnax's), which the adapter reads once; a params
  pytree with another value passed to ``step`` does not move the limit.

gymnax is imported on the first ``from_gymnax``, not with ``rl_jax.envs``.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvState, PRNGKey
from rl_jax.envs.core.preprocessing import StickyActions
from rl_jax.envs.core.registry import UnsupportedEnvError
from rl_jax.envs.core.spaces import Box, Discrete, Space

#: gymnax's field for the episode limit, which becomes our static ``max_episode_steps``.
LIMIT_FIELD = "max_steps_in_episode"


class GymnaxEnv(Protocol):
    """What the adapter calls of a gymnax ``Environment`` (gymnax ships no type information)."""

    @property
    def name(self) -> str: ...

    def reset_env(self, key: PRNGKey, params: object) -> tuple[Array, object]: ...

    def step_env(
        self, key: PRNGKey, state: object, action: Array, params: object
    ) -> tuple[Array, object, Array, Array, dict[str, Array]]: ...

    def get_obs(self, state: object, params: object) -> Array: ...

    def observation_space(self, params: object) -> object: ...

    def action_space(self, params: object) -> object: ...


@struct.dataclass
class GymnaxState(EnvState):
    """Our env state around gymnax's: ``time`` counts steps since our reset."""

    inner: object  # gymnax's env state (a flax struct dataclass)


def _space(gymnax_space: object, what: str, name: str) -> Space:
    kind = type(gymnax_space).__name__
    attributes = vars(gymnax_space)  # gymnax's spaces are plain objects without type information
    if kind == "Discrete":
        return Discrete(int(attributes["n"]))
    if kind == "Box":
        shape = tuple(int(n) for n in attributes["shape"])
        low = np.broadcast_to(np.asarray(attributes["low"], np.float32), shape)
        high = np.broadcast_to(np.asarray(attributes["high"], np.float32), shape)
        return Box(low, high, shape)
    raise UnsupportedEnvError(
        f"gymnax env {name!r} has a {kind} {what} space; from_gymnax translates Box and Discrete"
    )


class FromGymnax(Environment):
    """A gymnax env as an rl_jax ``Environment`` (see the module docstring)."""

    def __init__(
        self, gymnax_env: GymnaxEnv, params: object, max_episode_steps: int, env_id: str = ""
    ) -> None:
        self.gymnax_env = gymnax_env
        self._params = params
        self.max_episode_steps = max_episode_steps
        self.id = env_id or f"gymnax/{gymnax_env.name}"
        self._observation_space = _space(
            gymnax_env.observation_space(params), "observation", self.id
        )
        if isinstance(self._observation_space, Discrete):  # observed as a float32 scalar
            n = self._observation_space.n
            self._observation_space = Box(
                np.zeros((), np.float32), np.full((), n - 1, np.float32), ()
            )
        self._action_space = _space(gymnax_env.action_space(params), "action", self.id)

    @property
    def default_params(self):
        """gymnax's params, ``max_steps_in_episode`` set to this env's limit."""
        return self._params

    def observation_space(self, params: object | None = None) -> Space:
        """gymnax's observation space as a float32 Box."""
        return self._observation_space

    def action_space(self, params: object | None = None) -> Space:
        """gymnax's action space: a Discrete or a Box."""
        return self._action_space

    def reset_env(self, key: PRNGKey, params: object) -> tuple[GymnaxState, Array]:
        """gymnax's ``reset_env`` with the key as gymnax's ``reset`` passes it."""
        obs, inner = self.gymnax_env.reset_env(key, params)
        state = GymnaxState(time=jnp.zeros((), jnp.int32), inner=inner)
        return state, jnp.asarray(obs, jnp.float32)

    def step_env(self, key: PRNGKey, state: GymnaxState, action: Array, params: object):
        """gymnax's ``step_env`` with the key gymnax's ``step`` gives it; no reset inside."""
        key_step, _ = jax.random.split(key)  # gymnax's step: (key_step, key_reset)
        obs, inner, reward, done, _ = self.gymnax_env.step_env(
            key_step, state.inner, action, params
        )
        next_state = GymnaxState(time=state.time + 1, inner=inner)
        return next_state, jnp.asarray(obs, jnp.float32), reward, done, {}

    def render(self, state: GymnaxState, params: object | None = None) -> np.ndarray:
        """A grid observation (H x W x C, as MinAtar's) drawn as MinAtar's own display draws it:
        each cell in the colour of its highest set channel, black where none is; 16 px a cell."""
        params = self.default_params if params is None else params
        obs = np.asarray(self.gymnax_env.get_obs(state.inner, params))
        if obs.ndim != 3:
            raise NotImplementedError(f"{self.id} has no renderer (its observation is not a grid)")
        channels = obs.shape[-1]
        colours = _cubehelix(channels)
        index = np.max((obs > 0) * np.arange(1, channels + 1), axis=-1)
        frame = colours[index]
        return np.repeat(np.repeat(frame, 16, axis=0), 16, axis=1)


def _cubehelix(channels: int) -> np.ndarray:
    """Black, then ``channels`` colours of matplotlib's cubehelix map, as MinAtar's display picks
    them (seaborn samples the map away from its black and white ends)."""
    from matplotlib import colormaps

    points = np.linspace(0.0, 1.0, channels + 2)[1:-1]
    rgb = colormaps["cubehelix"](points)[:, :3]
    return (np.concatenate([np.zeros((1, 3)), rgb]) * 255).round().astype(np.uint8)


def from_gymnax(
    name: str, *, max_steps_in_episode: int | None = None, **kwargs: object
) -> FromGymnax:
    """The gymnax env ``name`` (``"Breakout-MinAtar"``, ``"CartPole-v1"``, ...) as one of ours.

    Keyword arguments that name a field of the env's gymnax params set it (``ramping=False`` for
    Asterix); the others go to gymnax's constructor (``use_minimal_action_set=False``).
    ``max_steps_in_episode`` is the static episode limit (default: gymnax's).
    """
    try:
        import gymnax
    except ModuleNotFoundError:
        raise UnsupportedEnvError(
            "gymnax is not installed: `make install` installs it (requirements-nodeps.lock), "
            "or `pip install --no-deps gymnax==1.0.1 seaborn six` beside rl_jax"
        ) from None
    if name not in gymnax.registered_envs:
        raise UnsupportedEnvError(
            f"unknown gymnax env {name!r}; gymnax has {gymnax.registered_envs}"
        )
    gymnax_env, params = gymnax.make(name)
    fields = {field.name for field in dataclasses.fields(params)}
    overrides = {key: value for key, value in kwargs.items() if key in fields}
    constructor = {key: value for key, value in kwargs.items() if key not in fields}
    if constructor:  # built again only where a keyword is the constructor's
        gymnax_env, params = gymnax.make(name, **constructor)
    if overrides:
        params = params.replace(**overrides)
    limit = (
        int(getattr(params, LIMIT_FIELD)) if max_steps_in_episode is None else max_steps_in_episode
    )
    if hasattr(params, LIMIT_FIELD):
        params = params.replace(**{LIMIT_FIELD: limit})
    return FromGymnax(gymnax_env, params, limit)


def _minatar(game: str, sticky_actions: float = 0.0, **kwargs: object) -> Environment:
    """gymnax's ``game`` (which has no sticky actions); with ``sticky_actions`` p > 0, the
    original MinAtar's: each step executes the previous action with probability p (MinAtar's
    default 0.1, as the MinAtar paper's runs), the previous action after a reset being 0."""
    env = from_gymnax(f"{game}-MinAtar", **kwargs)  # type: ignore[arg-type]  # checked there
    if not sticky_actions:
        return env
    return StickyActions(env, sticky_actions, reset_action=0)


def breakout_minatar(sticky_actions: float = 0.0, **kwargs: object) -> Environment:
    """gymnax's ``Breakout-MinAtar`` (registered as ``rl_jax/Breakout-MinAtar``);
    ``sticky_actions=p`` as in the original MinAtar (``_minatar``)."""
    return _minatar("Breakout", sticky_actions, **kwargs)


def space_invaders_minatar(sticky_actions: float = 0.0, **kwargs: object) -> Environment:
    """gymnax's ``SpaceInvaders-MinAtar`` (registered as ``rl_jax/SpaceInvaders-MinAtar``);
    ``sticky_actions=p`` as in the original MinAtar (``_minatar``)."""
    return _minatar("SpaceInvaders", sticky_actions, **kwargs)


def asterix_minatar(sticky_actions: float = 0.0, **kwargs: object) -> Environment:
    """gymnax's ``Asterix-MinAtar`` (registered as ``rl_jax/Asterix-MinAtar``);
    ``sticky_actions=p`` as in the original MinAtar (``_minatar``)."""
    return _minatar("Asterix", sticky_actions, **kwargs)


def freeway_minatar(sticky_actions: float = 0.0, **kwargs: object) -> Environment:
    """gymnax's ``Freeway-MinAtar`` (registered as ``rl_jax/Freeway-MinAtar``);
    ``sticky_actions=p`` as in the original MinAtar (``_minatar``)."""
    return _minatar("Freeway", sticky_actions, **kwargs)
