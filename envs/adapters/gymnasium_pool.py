"""The host side of ``envs.adapters.gymnasium_host``: the pool of gymnasium envs one adapter
steps, and the uint32 row each env's inputs and outputs cross the callback as (see that module's
docstring for the lazy start, batching and resume)."""

from __future__ import annotations

import secrets
import threading
import warnings
from collections.abc import Callable
from typing import Any

import gymnasium
import numpy as np

NOT_STARTED = 0  # the serial of a handle whose episode has not taken a host env yet

# One uint32 row per env crosses the callback each way: every array that crosses costs tens of
# microseconds here, more than a classic gymnasium step. Floats travel as their bits, so nothing
# is rounded, and integers never pass through float arithmetic.
HANDLE, SEED, TIME, TERMINATED, TRUNCATED, OBS = slice(0, 2), 2, 3, 4, 5, 6  # then action
OUT_TERMINATED, OUT_TRUNCATED, OUT_LOST, OUT_REWARD, OUT_OBS = 2, 3, 4, 5, 6  # 0-1: handle


class _Episode:
    """A host env running one episode, and the steps it has taken."""

    __slots__ = ("env", "time")

    def __init__(self, env: gymnasium.Env):
        self.env, self.time = env, 0


class HostPool:
    """The gymnasium envs of one adapter: idle ones, and running episodes by serial.

    Every method takes a whole batch (any leading shape, flattened into lanes) and holds the
    lock, since XLA may run a reset and a step callback, or two devices' shards, at once.
    """

    def __init__(
        self,
        make_env: Callable[[], gymnasium.Env],
        action_space: gymnasium.Space,
        obs_shape: tuple[int, ...],
        max_episode_steps: int,
    ):
        self.make_env = make_env
        self.action_space = action_space
        self.obs_shape = obs_shape
        self.max_episode_steps = max_episode_steps
        discrete = isinstance(action_space, gymnasium.spaces.Discrete)
        self._action_dtype = np.int32 if discrete else np.float32  # as the JAX side packs it
        self.pool_id = secrets.randbits(32) or 1  # handles of another process are not ours
        self.idle: list[gymnasium.Env] = []
        self.running: dict[int, _Episode] = {}
        self.cut_episodes = 0  # episodes cut because the pool did not hold them (see Resume)
        self._next_serial = 1
        self._scratch: gymnasium.Env | None = None
        self._lock = threading.Lock()
        self._warned_reset = False

    def _take_env(self) -> gymnasium.Env:
        return self.idle.pop() if self.idle else self.make_env()

    def _reset(self, env: gymnasium.Env, seed: Any) -> np.ndarray:
        obs, _ = env.reset(seed=int(seed))
        return np.asarray(obs, np.float32).reshape(self.obs_shape)

    def start_observations(self, seeds: np.ndarray, needed: np.ndarray | None = None) -> np.ndarray:
        """Each seed's start observation, from a scratch env (no episode is started). With
        ``needed`` (a bool per seed), only those seeds' starts are computed, zeros elsewhere:
        an autoreset keeps a start only where an episode ended, and an env whose reset is
        expensive (an Atari game's no-op start) should not pay for the others."""
        seeds = np.asarray(seeds)
        flat = seeds.reshape(-1)
        wanted = np.ones(flat.shape, bool) if needed is None else np.asarray(needed).reshape(-1)
        starts = np.zeros(flat.shape + self.obs_shape, np.float32)
        with self._lock:
            for lane in np.flatnonzero(wanted):
                if self._scratch is None:
                    self._scratch = self._take_env()
                starts[lane] = self._reset(self._scratch, flat[lane])
        return starts.reshape(seeds.shape + self.obs_shape)

    def step(self, rows: np.ndarray) -> np.ndarray:
        """One step of every env: ``rows`` [..., IN_WIDTH] -> [..., OUT_WIDTH] (see ``_pack``
        in ``envs.adapters.gymnasium_host``)."""
        rows = np.asarray(rows)
        batch_shape, width = rows.shape[:-1], rows.shape[-1]
        obs_size = int(np.prod(self.obs_shape, dtype=np.int64))
        outputs = np.zeros(
            (int(np.prod(batch_shape, dtype=np.int64)), OUT_OBS + obs_size), np.uint32
        )
        with self._lock:
            for lane, row in enumerate(rows.reshape(-1, width)):
                outputs[lane] = self._step_row(row, obs_size)
        return outputs.reshape(batch_shape + outputs.shape[1:])

    def _step_row(self, row: np.ndarray, obs_size: int) -> np.ndarray:
        """One env's output row from its input row."""
        output = np.zeros(OUT_OBS + obs_size, np.uint32)
        handle, obs_bits = row[HANDLE].copy(), row[OBS : OBS + obs_size]
        output[OUT_TERMINATED], output[OUT_TRUNCATED] = row[TERMINATED], row[TRUNCATED]
        output[OUT_OBS:] = obs_bits  # an ended or lost episode reports its last obs again
        if row[TERMINATED] or row[TRUNCATED]:
            output[HANDLE] = handle  # an ended episode stays where it ended (reward 0)
            return output
        obs = obs_bits.view(np.float32).reshape(self.obs_shape)
        episode = self._episode_of(handle, row[SEED], int(row[TIME]), obs)
        output[HANDLE] = handle
        if episode is None:
            output[OUT_TRUNCATED] = output[OUT_LOST] = 1  # cut: see "Resume" above
            self.cut_episodes += 1
            return output
        action = row[OBS + obs_size :].view(self._action_dtype)
        obs, reward, terminated, truncated = self._step_episode(int(handle[1]), episode, action)
        output[OUT_TERMINATED], output[OUT_TRUNCATED] = terminated, truncated
        output[OUT_REWARD] = np.asarray(reward, np.float32).reshape(()).view(np.uint32)
        output[OUT_OBS:] = obs.reshape(-1).view(np.uint32)
        return output

    def _episode_of(
        self, handle: np.ndarray, seed: int | np.integer, time: int, obs: np.ndarray
    ) -> _Episode | None:
        """The episode ``handle`` names, running at step ``time`` (started now if it has not
        been, and ``handle`` filled in); None when this pool does not hold it at that step."""
        if handle[1] == NOT_STARTED and time == 0:
            handle[:] = self.pool_id, self._start(seed, obs)
            return self.running[int(handle[1])]
        episode = self.running.get(int(handle[1])) if handle[0] == self.pool_id else None
        return episode if episode is not None and episode.time == time else None

    def _start(self, seed: Any, reported_obs: np.ndarray) -> int:
        """Start an episode on an idle env with the seed ``reset`` used; its serial."""
        episode = _Episode(self._take_env())
        start = self._reset(episode.env, seed)
        if not self._warned_reset and not np.array_equal(start, reported_obs, equal_nan=True):
            self._warned_reset = True
            warnings.warn(
                "this gymnasium env's reset(seed=s) does not always give the same start: runs "
                "on it are not reproducible from their seed",
                RuntimeWarning,
                stacklevel=1,
            )
        serial = self._next_serial
        self._next_serial = self._next_serial % (2**32 - 1) + 1  # never NOT_STARTED
        self.running[serial] = episode
        return serial

    def _action(self, action: np.ndarray) -> Any:
        space = self.action_space
        if isinstance(space, gymnasium.spaces.Discrete):
            return int(action[0]) + int(space.start)
        return np.asarray(action, space.dtype).reshape(space.shape)

    def _step_episode(self, serial: int, episode: _Episode, action: np.ndarray) -> tuple:
        obs, reward, terminated, truncated, _ = episode.env.step(self._action(action))
        episode.time += 1
        truncated = bool(truncated) or episode.time >= self.max_episode_steps
        if terminated or truncated:  # the env is free for the next episode at once
            del self.running[serial]
            self.idle.append(episode.env)
        return np.asarray(obs, np.float32), reward, terminated, truncated
