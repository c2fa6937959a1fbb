"""Preprocessing wrappers for image and game envs: frame stack, frame skip with max-pooling,
sticky actions, reward transforms, episodic life, and the legal-action mask an env may expose.

Each wrapper is a pure transform of ``reset``/``step`` (jit-, vmap- and scan-friendly); those
that remember something between steps keep it in their own state pytree around the env's.
They go *inside* ``AutoReset`` (``AutoReset(FrameStack(env, 4))``), which then resets them
with the env; the stateful ones refuse an ``AutoReset`` below them, which would mix two
episodes into one stack or one skipped step. An Atari stack (ALE v5's sticky actions, then
DQN's skip, lives, reward sign and stack), innermost first::

    env = StickyActions(game, 0.25, reset_action=0)  # inside the skip: sticky per frame
    env = FrameSkip(EpisodicLife(env), 4)  # the skip stops at a lost life
    env = FrameStack(SignReward(env), 4, axis=-1)  # [84, 84] frames -> [84, 84, 4]

Two entries of the timestep ``info`` are part of the env contract here:

* ``info["lives"]`` (int32 ``[]``): an env with lives reports how many are left on every
  timestep, its reset's included (as ALE's gymnasium envs do). ``EpisodicLife`` reads it.
* ``info["action_mask"]`` (bool ``[n]`` for a ``Discrete(n)`` action space): the legal actions
  of the state the timestep's ``obs`` shows, on every timestep, its reset's included (an env
  reports its first state's mask through ``first_info``; ``empty_info`` holds all True). A
  learner acts, and bootstraps, only over legal actions (``rl_jax.agents.q_learning``'s
  ``masked_argmax``/``masked_max``, ``rl_jax.agents.policy_gradient``'s masked categorical);
  ``action_mask`` reads it, all True for an env without one.

Continuing after a lost life. A learner's episode ends at a life lost, but the game goes on:
the autoreset that follows must continue from the current state instead of starting a new game.
``reset_after(env, key, state, timestep)`` is that reset: the state to go on from after an
episode ended in ``state``. Envs and wrappers that define a ``reset_after`` method continue
(``EpisodicLife`` where the game is not over; the wrappers here pass it down); for every other
env it is ``env.reset(key)``. An autoreset that calls ``env.reset`` instead starts a new game at
every lost life, as gymnasium's ``AtariPreprocessing(terminal_on_life_loss=True)`` does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from rl_jax.envs.core.core import Array, Environment, EnvParams, PRNGKey, TimeStep
from rl_jax.envs.core.spaces import Box, Discrete, Space
from rl_jax.envs.core.wrappers import (
    ACTION_MASK,
    AutoReset,
    SameLimit,
    Wrapper,
    _select,
    reset_after,
)

LIVES = "lives"  # info key: int32 [], the lives left


# ---- the contract: lives, legal actions, continuing resets --------------------------------------
def has_action_mask(env: Environment) -> bool:
    """Whether ``env`` reports ``info["action_mask"]``; raises ``TypeError`` where the mask
    does not fit its action space (a ``Discrete(n)`` space and a bool ``[n]`` mask)."""
    mask = env.empty_info().get(ACTION_MASK)
    if mask is None:
        return False
    space = env.action_space()
    if not isinstance(space, Discrete) or space.shape != ():
        raise TypeError(f"{env.name}: an action mask needs a Discrete action space, got {space}")
    if mask.shape != (space.n,) or mask.dtype != jnp.bool_:
        raise TypeError(
            f"{env.name}: info['action_mask'] must be bool [{space.n}], "
            f"got {mask.dtype} {list(mask.shape)}"
        )
    return True


def action_mask(
    info: dict[str, Array], num_actions: int, batch_shape: tuple[int, ...] = ()
) -> Array:
    """``info["action_mask"]``, or all True (``batch_shape + (num_actions,)``) for an env that
    gives none: the legal actions as a learner reads them."""
    if ACTION_MASK in info:
        return info[ACTION_MASK]
    return jnp.ones((*batch_shape, num_actions), jnp.bool_)


def _refuse_autoreset_below(env: Environment, wrapper: str) -> None:
    inner: Environment = env
    while isinstance(inner, Wrapper):
        if isinstance(inner, AutoReset):
            raise TypeError(
                f"{wrapper} goes inside AutoReset (AutoReset({wrapper}(env))): an autoreset "
                "below it would join two episodes into one of its steps"
            )
        inner = inner.env


# ---- frame stack --------------------------------------------------------------------------------
@struct.dataclass
class FrameStackState:
    """``FrameStack``'s state: the env's and its latest observations."""

    env_state: Any
    frames: Array  # [stack_size, *obs_shape], the newest last

    @property
    def time(self) -> Array:
        """Steps since the wrapped env's last reset."""
        return self.env_state.time


class FrameStack(SameLimit):
    """The last ``stack_size`` observations as one, as gymnasium's ``FrameStackObservation``.

    ``obs`` is ``[stack_size, *obs_shape]``, the newest last (``axis=0``, gymnasium's layout), or
    ``[*obs_shape, stack_size]`` with ``axis=-1`` (84x84 frames as 4 channels of a conv torso).
    After a reset the stack is padded as gymnasium pads it: ``padding="reset"`` (its default)
    repeats the first observation, ``"zero"`` puts zeros before it, and an array of one
    observation's shape puts that value before it.
    """

    def __init__(
        self, env: Environment, stack_size: int, padding: str | Any = "reset", axis: int = 0
    ):
        super().__init__(env)
        _refuse_autoreset_below(env, "FrameStack")
        if int(stack_size) != stack_size or stack_size < 1:
            raise ValueError(f"stack_size must be an integer >= 1, got {stack_size}")
        if axis not in (0, -1):
            raise ValueError(f"axis must be 0 (leading) or -1 (trailing), got {axis}")
        space = env.observation_space()
        if not isinstance(space, Box):
            raise TypeError(f"FrameStack needs a Box observation space, got {space}")
        if isinstance(padding, str) and padding not in ("reset", "zero"):
            raise ValueError(f"padding must be 'reset', 'zero' or an observation, got {padding!r}")
        if not isinstance(padding, str):
            padding = np.asarray(padding, space.dtype)
            if padding.shape != space.shape:
                raise ValueError(f"a padding observation has shape {space.shape}, got {padding}")
        self.stack_size = int(stack_size)
        self.padding = padding
        self.axis = axis
        self._space = space

    def observation_space(self, params: EnvParams | None = None) -> Space:
        """The wrapped env's box, ``stack_size`` times along ``axis``."""
        low = np.stack([self._space.low] * self.stack_size, axis=self.axis)
        high = np.stack([self._space.high] * self.stack_size, axis=self.axis)
        return Box(low, high, low.shape, self._space.dtype)

    def _stacked(self, frames: Array) -> Array:
        return frames if self.axis == 0 else jnp.moveaxis(frames, 0, -1)

    def _start(self, env_state: Any, ts: TimeStep) -> tuple[FrameStackState, TimeStep]:
        if isinstance(self.padding, str):
            fill = ts.obs if self.padding == "reset" else jnp.zeros_like(ts.obs)
        else:
            fill = jnp.asarray(self.padding)
        before = jnp.broadcast_to(fill, (self.stack_size - 1, *ts.obs.shape)).astype(ts.obs.dtype)
        frames = jnp.concatenate([before, ts.obs[None]], axis=0)
        return FrameStackState(env_state, frames), ts._replace(obs=self._stacked(frames))

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset the env; the stack is its first observation after the padding."""
        return self._start(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start the env from an exact state, padded as a reset is."""
        return self._start(*self.env.reset_to(vector, params))

    def reset_after(
        self,
        key: PRNGKey,
        state: FrameStackState,
        timestep: TimeStep,
        params: EnvParams | None = None,
    ):
        """The env's ``reset_after``, with the stack padded as after a reset."""
        inner = timestep._replace(obs=state.frames[-1])
        return self._start(*reset_after(self.env, key, state.env_state, inner, params))

    def step(
        self, key: PRNGKey, state: FrameStackState, action: Array, params: EnvParams | None = None
    ):
        """Step the env; the oldest observation leaves the stack and the new one joins it."""
        env_state, ts = self.env.step(key, state.env_state, action, params)
        frames = jnp.concatenate([state.frames[1:], ts.obs[None]], axis=0)
        return FrameStackState(env_state, frames), ts._replace(obs=self._stacked(frames))

    def render(self, state: FrameStackState, params: EnvParams | None = None):
        """RGB frame of the wrapped env's state."""
        return self.env.render(state.env_state, params)


# ---- frame skip ---------------------------------------------------------------------------------
class FrameSkip(Wrapper):
    """Each action held for ``skip`` env steps (frames), as gymnasium's ``AtariPreprocessing``
    and SB3's ``MaxAndSkipEnv`` do.

    The reward is the sum over the frames played, and the step stops at the first frame that
    terminates or truncates (its flags and ``info`` are the step's). ``obs`` is the elementwise
    maximum of the step's last two frames (``max_pool=True``: Atari sprites that flicker between
    frames stay seen), or its last frame. One difference from gymnasium: on a step that ends
    the episode, gymnasium's ``AtariPreprocessing`` stops before it keeps the ending frame and
    pools frames kept earlier (some from the step before, where the episode ended before the
    step's last frame); here the pool is always of the last two frames played in the step (the
    last alone where only one was), the ending frame included, so that a truncated episode
    bootstraps from its true last observation. The state is the env's, so the time limit
    counts frames: ``max_episode_steps`` is the env's divided by ``skip``, rounded up.
    """

    def __init__(self, env: Environment, skip: int = 4, max_pool: bool = True):
        super().__init__(env)
        _refuse_autoreset_below(env, "FrameSkip")
        if int(skip) != skip or skip < 1:
            raise ValueError(f"skip must be an integer >= 1, got {skip}")
        self.skip = int(skip)
        self.max_pool = max_pool

    @property
    def max_episode_steps(self) -> int:
        """The env's episode limit in agent steps: its frames divided by ``skip``, rounded up."""
        return -(-self.env.max_episode_steps // self.skip)

    @max_episode_steps.setter
    def max_episode_steps(self, value: int) -> None:
        # Wrapper.__init__ copies the env's limit here before ``skip`` is set: the env keeps it.
        if "skip" in self.__dict__:
            self.env.max_episode_steps = value * self.skip

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Play ``action`` for up to ``skip`` frames; returns the step's state and timestep."""
        keys = jax.random.split(key, self.skip)
        state, ts = self.env.step(keys[0], state, action, params)
        first = (state, ts.obs, ts.obs, ts.reward, ts.terminated, ts.truncated, ts.info)

        def frame(
            carry: tuple[object, Array, Array, Array, Array, Array, dict[str, Array]],
            frame_key: PRNGKey,
        ):
            state, last, before_last, reward, terminated, truncated, info = carry
            active = ~(terminated | truncated)
            state, ts = self.env.step_active(frame_key, state, action, active, params)
            new = (ts.obs, last, reward + ts.reward, ts.terminated, ts.truncated, ts.info)
            kept = (last, before_last, reward, terminated, truncated, info)
            return (state, *_select(active, new, kept)), None

        carry = jax.lax.scan(frame, first, keys[1:])[0] if self.skip > 1 else first
        state, last, before_last, reward, terminated, truncated, info = carry
        obs = jnp.maximum(last, before_last) if self.max_pool else last
        return state, TimeStep(obs, reward, terminated, truncated, info)


# ---- sticky actions -----------------------------------------------------------------------------
@struct.dataclass
class StickyState:
    """``StickyActions``'s state: the env's, and the action it last executed."""

    env_state: Any
    last_action: Array  # [*action_shape], the action the env last executed
    has_last: Array  # [] bool; False after a gymnasium-style reset: the next action is kept

    @property
    def time(self) -> Array:
        """Steps since the wrapped env's last reset."""
        return self.env_state.time


class StickyActions(SameLimit):
    """With probability ``repeat_action_probability`` the env executes its previous action
    instead of the agent's (Machado et al. 2018, as gymnasium's ``StickyAction`` with its
    default duration of one step): ALE's v5 envs use 0.25, MinAtar 0.1.

    The previous action is the one executed, stuck or not. After a reset there is none by
    default (gymnasium's convention: the first action is always the agent's); ``reset_action``
    sets one instead, as the ALE (NOOP, action 0) and MinAtar do. Each step splits its key in
    two and draws one uniform from the first. Inside ``FrameSkip`` the draw is made for every
    frame, as in the ALE; outside, once per agent step.
    """

    def __init__(
        self,
        env: Environment,
        repeat_action_probability: float = 0.25,
        reset_action: Any = None,
    ):
        super().__init__(env)
        _refuse_autoreset_below(env, "StickyActions")
        if not 0.0 <= repeat_action_probability < 1.0:
            raise ValueError(
                f"repeat_action_probability must be in [0, 1), got {repeat_action_probability}"
            )
        self.repeat_action_probability = float(repeat_action_probability)
        space = env.action_space()
        self._action_shape, self._action_dtype = tuple(space.shape), space.dtype
        self.reset_action = reset_action
        if reset_action is not None and not bool(space.contains(jnp.asarray(reset_action))):
            raise ValueError(f"reset_action {reset_action!r} is not in the action space {space}")

    def _start(self, env_state: Any, ts: TimeStep) -> tuple[StickyState, TimeStep]:
        if self.reset_action is None:
            last = jnp.zeros(self._action_shape, self._action_dtype)
        else:
            last = jnp.asarray(self.reset_action, self._action_dtype).reshape(self._action_shape)
        has_last = jnp.asarray(self.reset_action is not None)
        return StickyState(env_state, last, has_last), ts

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset the env; the previous action is ``reset_action`` (by default none)."""
        return self._start(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start the env from an exact state, with the previous action as after a reset."""
        return self._start(*self.env.reset_to(vector, params))

    def reset_after(
        self, key: PRNGKey, state: StickyState, timestep: TimeStep, params: EnvParams | None = None
    ):
        """The env's ``reset_after``, with the previous action as after a reset."""
        return self._start(*reset_after(self.env, key, state.env_state, timestep, params))

    def step(
        self, key: PRNGKey, state: StickyState, action: Array, params: EnvParams | None = None
    ):
        """Execute the previous action with the sticky probability, else ``action``."""
        stick_key, env_key = jax.random.split(key)
        stuck = state.has_last & (jax.random.uniform(stick_key) < self.repeat_action_probability)
        action = jnp.asarray(action, self._action_dtype).reshape(self._action_shape)
        executed = jnp.where(stuck, state.last_action, action)
        env_state, ts = self.env.step(env_key, state.env_state, executed, params)
        return StickyState(env_state, executed, jnp.asarray(True)), ts

    def render(self, state: StickyState, params: EnvParams | None = None):
        """RGB frame of the wrapped env's state."""
        return self.env.render(state.env_state, params)


# ---- rewards ------------------------------------------------------------------------------------
class TransformReward(SameLimit):
    """``reward = func(reward)`` on every step (gymnasium's ``TransformReward``); ``func`` maps
    a float32 ``[]`` array to one, in JAX."""

    def __init__(self, env: Environment, func: Callable[[Array], Array]):
        super().__init__(env)
        self.func = func

    def step(self, key: PRNGKey, state: object, action: Array, params: EnvParams | None = None):
        """Step the env and transform its reward."""
        state, ts = self.env.step(key, state, action, params)
        return state, ts._replace(reward=jnp.asarray(self.func(ts.reward), jnp.float32))


class ClipReward(TransformReward):
    """The reward clipped to ``[min_reward, max_reward]`` (gymnasium's ``ClipReward``); DQN's
    Atari setting is the default ``[-1, 1]``."""

    def __init__(self, env: Environment, min_reward: float = -1.0, max_reward: float = 1.0):
        if min_reward > max_reward:
            raise ValueError(f"min_reward {min_reward} is above max_reward {max_reward}")
        super().__init__(env, lambda reward: jnp.clip(reward, min_reward, max_reward))
        self.min_reward, self.max_reward = min_reward, max_reward


class SignReward(TransformReward):
    """The reward's sign, -1, 0 or 1 (CleanRL's and SB3's ``ClipRewardEnv`` for Atari: equal to
    clipping to ``[-1, 1]`` for integer game scores, and coarser for fractional rewards)."""

    def __init__(self, env: Environment):
        super().__init__(env, jnp.sign)


# ---- episodic life ------------------------------------------------------------------------------
@struct.dataclass
class EpisodicLifeState:
    """``EpisodicLife``'s state: the env's, its lives, and whether its game is over."""

    env_state: Any
    lives: Array  # [] int32, the env's lives after its last step
    game_over: Array  # [] bool; the env itself terminated or truncated

    @property
    def time(self) -> Array:
        """Steps since the wrapped env's last reset (of the game, not of a life)."""
        return self.env_state.time


class EpisodicLife(SameLimit):
    """A lost life ends the learner's episode as terminated, while the game goes on (DQN's
    Atari setting; SB3's ``EpisodicLifeEnv``). For envs that report ``info["lives"]``.

    ``terminated`` is the env's or a life lost (fewer lives than after the previous step); the
    game is over where the env itself terminated or truncated. ``reset_after`` then continues
    from the current state, the learner's new episode starting where the life was lost, until
    the game is over; then it resets the env. SB3's wrapper plays one NOOP first, unseen by the
    learner; this one hands the learner the state as the life was lost.
    """

    def __init__(self, env: Environment):
        super().__init__(env)
        _refuse_autoreset_below(env, "EpisodicLife")
        if LIVES not in env.empty_info():
            raise TypeError(
                f"EpisodicLife needs an env whose timestep info reports '{LIVES}'; "
                f"{env.name}'s holds {sorted(env.empty_info())}"
            )

    def _start(self, env_state: Any, ts: TimeStep) -> tuple[EpisodicLifeState, TimeStep]:
        lives = jnp.asarray(ts.info[LIVES], jnp.int32)
        return EpisodicLifeState(env_state, lives, jnp.asarray(False)), ts

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Reset the env: a new game."""
        return self._start(*self.env.reset(key, params))

    def reset_to(self, vector: Array, params: EnvParams | None = None):
        """Start a new game from an exact state."""
        return self._start(*self.env.reset_to(vector, params))

    def reset_after(
        self,
        key: PRNGKey,
        state: EpisodicLifeState,
        timestep: TimeStep,
        params: EnvParams | None = None,
    ):
        """Go on from ``state`` after a lost life (``timestep``'s obs and info, reward 0, both
        flags False); after the game's end, the env's own ``reset_after``: a new game."""
        zero = jnp.zeros((), jnp.bool_)
        going_on = timestep._replace(
            reward=jnp.zeros((), jnp.float32), terminated=zero, truncated=zero
        )
        new_game = self._start(*reset_after(self.env, key, state.env_state, timestep, params))
        return _select(state.game_over, new_game, (state, going_on))

    def step(
        self, key: PRNGKey, state: EpisodicLifeState, action: Array, params: EnvParams | None = None
    ):
        """Step the env; a life lost terminates the learner's episode, not the game."""
        env_state, ts = self.env.step(key, state.env_state, action, params)
        lives = jnp.asarray(ts.info[LIVES], jnp.int32)
        game_over = ts.terminated | ts.truncated
        terminated = ts.terminated | (lives < state.lives)
        return EpisodicLifeState(env_state, lives, game_over), ts._replace(terminated=terminated)

    def render(self, state: EpisodicLifeState, params: EnvParams | None = None):
        """RGB frame of the wrapped env's state."""
        return self.env.render(state.env_state, params)
