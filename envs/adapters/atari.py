"""Atari 2600 games through the Arcade Learning Environment (ale-py), with the preprocessing of
DQN's Atari runs, as one of our envs::

    from rl_jax import envs

    env = envs.from_atari("Pong")  # any ALE game; or envs.make("rl_jax/Pong-Atari")
    state, ts = jax.vmap(env.reset)(jax.random.split(key, 8))  # ts.obs: [8, 84, 84, 4] uint8
    state, ts = jax.vmap(env.step)(jax.random.split(key, 8), state, actions)

    python experiments/train.py --algo dqn --env rl_jax/Pong-Atari \\
        --conv-layers 32,8,4,64,4,2,64,3,1 --hidden 512

What runs where. The emulator is a C++ library, so the games run on the host, stepped through
``jax.pure_callback`` by the gymnasium adapter (``envs.adapters.gymnasium_host``: lazy start,
one host env per episode under any vmap, the batch stepped in one callback, resume). Each host
env is ALE's gymnasium env (``ALE/<Game>-v5`` with ``frameskip=1``) inside gymnasium's own
``AtariPreprocessing``, which does the per-frame work where the frames are:

- no-op starts: after a reset, 1 to ``noop_max`` (30) NOOP frames, their number drawn from the
  episode's seed (0: none);
- sticky actions: ALE v5's, each frame repeating the previous action with probability
  ``repeat_action_probability`` (0.25; 0 turns them off), inside the skip;
- frame skip: each action is repeated for ``frame_skip`` (4) frames, the rewards summed, and the
  observation is the pixel-wise maximum of the last two frames' grayscale screens;
- 84x84 grayscale: that maximum resized with OpenCV's area interpolation;
- the minimal action set (``full_action_space=False``): Pong has 6 actions, Breakout 4.

Only the frame and the lives left cross the callback (as one float32 row). The rest is done in
JAX by our own wrappers (``envs.core.preprocessing``), inside the compiled step:

- ``FrameStack(axis=-1)``: the last ``frame_stack`` (4) frames as channels, ``[84, 84, 4]``
  uint8, the newest last, the layout of ``rl_jax/CartPolePixels-v1`` that the conv torsos take;
  after a reset the first frame is repeated, as gymnasium's ``FrameStackObservation`` does;
- ``episodic_life=True``: ``EpisodicLife``, a lost life ends the learner's episode (terminated)
  while the game goes on from where the life was lost (off by default, as in ALE v5);
- ``clip_rewards=True``: ``SignReward``, the reward's sign (off by default).

The same seed gives the same episode as gymnasium's ``AtariPreprocessing`` +
``FrameStackObservation`` reset with that seed: the no-op count and the sticky actions are
drawn from the generators that ``reset(seed=...)`` seeds (tests/envs/test_atari.py).

Resets. ``AutoReset`` computes a reset on every step for every env and keeps it where an episode
ended. Here a reset's start observation costs a real reset of a host game (up to 30 no-op
frames), so this env's ``reset_after`` (the reset an autoreset calls) computes starts only for
the envs whose game ended and hands the others zeros, which the autoreset discards.

Why not ale-py's ``AtariVectorEnv`` or envpool, which preprocess in C++ threads: on a 2-core
machine they stepped Pong little faster than the gymnasium envs one after another
(BENCHMARKS.md, "Atari through the ALE", has the numbers), and neither resets each lane
from a seed of its own, which the adapter's seeding, lazy start and vmaps over seeds rest on.
envpool also needs asset packages of its own (its import fails without them).

ale-py and OpenCV are imported when the first Atari env is made, not with ``rl_jax.envs``:
``make install`` installs them (the ``atari`` extra).
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.envs.adapters.gymnasium_host import LOST_KEY, HostEnvState, HostGymnasiumEnv
from rl_jax.envs.core.core import Array, Environment, EnvParams, PRNGKey, TimeStep
from rl_jax.envs.core.preprocessing import LIVES, EpisodicLife, FrameStack, SignReward
from rl_jax.envs.core.registry import UnsupportedEnvError
from rl_jax.envs.core.spaces import Box
from rl_jax.envs.core.wrappers import Wrapper

#: ALE v5's episode cap, 108,000 frames (30 minutes of play), in agent steps of 4 frames.
MAX_EPISODE_STEPS = 108_000 // 4


def _import_ale() -> None:
    """Imports ale-py and registers its envs with gymnasium (a one-line error where it is not
    installed)."""
    try:
        import ale_py
    except ModuleNotFoundError:
        raise UnsupportedEnvError(
            "ale-py is not installed: `make install` installs it, or "
            "`pip install 'ale-py>=0.12.1,<0.13' opencv-python-headless` beside rl_jax"
        ) from None
    gymnasium.register_envs(ale_py)


class _FrameAndLives(gymnasium.ObservationWrapper):
    """Host side: the preprocessed frame and the lives left as one flat float32 row, so that
    both cross the callback in the observation, the reset's included."""

    def __init__(self, env: gymnasium.Env, size: int):
        super().__init__(env)
        self.observation_space = gymnasium.spaces.Box(0.0, 255.0, (size * size + 1,), np.float32)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        lives = self.env.unwrapped.ale.lives()  # type: ignore[attr-defined]
        frame = np.asarray(observation, np.float32).reshape(-1)
        return np.append(frame, np.float32(lives))


def host_env(
    game: str,
    *,
    noop_max: int = 30,
    frame_skip: int = 4,
    frame_size: int = 84,
    repeat_action_probability: float = 0.25,
    full_action_space: bool = False,
    frame_and_lives: bool = True,
) -> gymnasium.Env:
    """One host env: ALE's ``ALE/<game>-v5`` (frames one at a time) in gymnasium's
    ``AtariPreprocessing``; observed as ``_FrameAndLives`` rows unless ``frame_and_lives`` is
    False (then gymnasium's own ``[frame_size, frame_size]`` uint8 frames)."""
    _import_ale()
    try:
        env = gymnasium.make(
            f"ALE/{game}-v5",
            frameskip=1,
            repeat_action_probability=repeat_action_probability,
            full_action_space=full_action_space,
            max_num_frames_per_episode=MAX_EPISODE_STEPS * frame_skip,
        )
    except gymnasium.error.Error as error:
        message = " ".join(str(error).split())
        raise UnsupportedEnvError(f"no ALE game {game!r}: {message}") from None
    try:
        env = gymnasium.wrappers.AtariPreprocessing(
            env, noop_max=noop_max, frame_skip=frame_skip, screen_size=frame_size
        )
    except gymnasium.error.DependencyNotInstalled:
        raise UnsupportedEnvError(
            "OpenCV is not installed (gymnasium's AtariPreprocessing resizes with it): "
            "`make install` installs it, or `pip install opencv-python-headless`"
        ) from None
    return _FrameAndLives(env, frame_size) if frame_and_lives else env


class AtariHost(HostGymnasiumEnv):
    """The host games behind the functional API: one ``[frame_size, frame_size]`` uint8 frame
    per step, ``info["lives"]`` on every timestep (see the module docstring)."""

    def __init__(self, game: str, frame_size: int, max_episode_steps: int, **host: Any):
        make = functools.partial(host_env, game, frame_size=frame_size, **host)
        super().__init__(make, f"rl_jax/{game}-Atari", max_episode_steps)
        self.game, self.frame_size = game, frame_size

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """One grayscale frame, uint8."""
        shape = (self.frame_size, self.frame_size)
        return Box(0, 255, shape, np.dtype(np.uint8))

    def empty_info(self) -> dict[str, Array]:
        """``host_state_lost`` and ``lives`` (int32)."""
        return {**super().empty_info(), LIVES: jnp.zeros((), jnp.int32)}

    def _split(self, row: Array) -> tuple[Array, Array]:
        """A host row's frame (uint8) and lives (int32)."""
        frame = row[:-1].reshape(self.frame_size, self.frame_size).astype(jnp.uint8)
        return frame, row[-1].astype(jnp.int32)

    def _first(self, state: HostEnvState) -> tuple[HostEnvState, TimeStep]:
        frame, lives = self._split(state.obs)
        false = jnp.zeros((), jnp.bool_)
        info = {LOST_KEY: false, LIVES: lives}
        return state, TimeStep(frame, jnp.zeros((), jnp.float32), false, false, info)

    def reset(self, key: PRNGKey, params: EnvParams | None = None):
        """Draw the episode's seed; its start frame and lives come from a host reset."""
        state, _ = self.reset_env(key, self.default_params)
        return self._first(state)

    def reset_after(
        self, key: PRNGKey, state: HostEnvState, timestep: TimeStep, params: EnvParams | None = None
    ):
        """``reset(key)`` where the episode ended, zeros elsewhere (where an autoreset keeps
        the running episode): only the ended episodes pay a host reset. Ended is the host's
        flags or the timestep's, so that a wrapper above that ends episodes of its own still
        gets real starts (under ``EpisodicLife`` a lost life pays one that is not used)."""
        ended = state.terminated | state.truncated | timestep.terminated | timestep.truncated
        seed = jax.random.bits(key, (), jnp.uint32)
        shape = jax.ShapeDtypeStruct(self._observation_space.shape, jnp.float32)
        obs = jax.pure_callback(
            self.pool.start_observations, shape, seed, ended, vmap_method="broadcast_all"
        )
        false = jnp.zeros((), jnp.bool_)
        handle = jnp.array([0, 0], jnp.uint32)  # not started (gymnasium_pool.NOT_STARTED)
        return self._first(HostEnvState(jnp.int32(0), handle, seed, obs, false, false))

    def step(
        self, key: PRNGKey, state: HostEnvState, action: Array, params: EnvParams | None = None
    ) -> tuple[HostEnvState, TimeStep]:
        """One agent step (``frame_skip`` frames) of the host game."""
        state, ts = self._host_step(state, action)
        frame, lives = self._split(ts.obs)
        return state, ts._replace(obs=frame, info={**ts.info, LIVES: lives})

    def step_env(self, key: PRNGKey, state: HostEnvState, action: Array, params: EnvParams):
        """``step``'s results in ``step_env``'s order."""
        state, ts = self.step(key, state, action, params)
        return state, ts.obs, ts.reward, ts.terminated, ts.info

    def render(self, state: HostEnvState, params: EnvParams | None = None) -> np.ndarray:
        """The state's latest grayscale frame as RGB (the host games' screens are not kept)."""
        frame, _ = self._split(jnp.asarray(state.obs))
        return np.repeat(np.asarray(frame)[..., None], 3, axis=-1)


def from_atari(
    game: str,
    *,
    noop_max: int = 30,
    frame_skip: int = 4,
    frame_size: int = 84,
    frame_stack: int = 4,
    repeat_action_probability: float = 0.25,
    full_action_space: bool = False,
    episodic_life: bool = False,
    clip_rewards: bool = False,
    max_episode_steps: int = MAX_EPISODE_STEPS,
) -> Wrapper:
    """The ALE game ``game`` (``"Pong"``, ``"Breakout"``, ... as in ``ALE/<game>-v5``) with the
    preprocessing of the module docstring; observations ``[frame_size, frame_size,
    frame_stack]`` uint8, the newest frame last."""
    if noop_max < 0 or frame_skip < 1 or frame_stack < 1 or frame_size < 1:
        raise ValueError("noop_max must be >= 0; frame_skip, frame_stack and frame_size >= 1")
    if not 0.0 <= repeat_action_probability <= 1.0:
        raise ValueError(
            f"repeat_action_probability must be in [0, 1], got {repeat_action_probability}"
        )
    env: Environment = AtariHost(
        game,
        frame_size,
        max_episode_steps,
        noop_max=noop_max,
        frame_skip=frame_skip,
        repeat_action_probability=repeat_action_probability,
        full_action_space=full_action_space,
    )
    if episodic_life:
        env = EpisodicLife(env)
    if clip_rewards:
        env = SignReward(env)
    return FrameStack(env, frame_stack, axis=-1)


def pong(**kwargs: Any) -> Wrapper:
    """``ALE/Pong-v5`` with DQN's preprocessing (registered as ``rl_jax/Pong-Atari``)."""
    return from_atari("Pong", **kwargs)


def breakout(**kwargs: Any) -> Wrapper:
    """``ALE/Breakout-v5`` with DQN's preprocessing (registered as ``rl_jax/Breakout-Atari``)."""
    return from_atari("Breakout", **kwargs)


def space_invaders(**kwargs: Any) -> Wrapper:
    """``ALE/SpaceInvaders-v5`` with DQN's preprocessing (``rl_jax/SpaceInvaders-Atari``)."""
    return from_atari("SpaceInvaders", **kwargs)


def seaquest(**kwargs: Any) -> Wrapper:
    """``ALE/Seaquest-v5`` with DQN's preprocessing (registered as ``rl_jax/Seaquest-Atari``)."""
    return from_atari("Seaquest", **kwargs)
