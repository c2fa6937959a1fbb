"""Replay for frame-stacked observations: each env step's new frame is stored once, and the stacks
of ``obs`` and ``next_obs`` are rebuilt when a batch is sampled.

Why: a stack of 4 frames shares 3 of them with the previous step's, and ``next_obs`` shares 3
with ``obs``, so storing both stacks keeps every frame 8 times. Here a step keeps two frames:
the newest frame of ``obs`` (in ``frames``, a ring over env steps) and the newest frame of the
true ``next_obs`` (in the transition rows). Both are needed: at an episode's end ``next_obs`` is
the final observation, which the next step's ``obs`` (a reset) does not hold, and a truncated
episode bootstraps from it. 84x84 frames: 14,112 bytes per transition instead of 56,448 for two
uint8 stacks (225,792 as float32).

Layout. The transition rows are an ordinary ``rl_jax.training.replay.ReplayBuffer`` (or
``rl_jax.training.prioritized.PrioritizedBuffer``) of ``FrameRow`` with ``R`` rows of ``width``
envs, so uniform and prioritized sampling and n-step windows work on it unchanged. ``frames`` and
``ended`` have ``R + stack - 1`` slots indexed by global step modulo their length: the ``stack -
1`` extra slots keep the history of the oldest stored transition until the transition itself is
overwritten.

Rebuilding the stack of step ``g``: frame ``j`` steps back is ``frames[g - j]`` unless an episode
ended at a step in ``g - j .. g - 1``; then the episode started later, and a reset repeats its
first frame, so the stack repeats the oldest frame that is still in the episode. This needs the
env's stacking convention: the newest frame last, shifted in by one per step, a reset filling
the stack with its first frame (``envs.classic.cartpole_pixels`` follows it; the tests check the
rebuilt stacks against the env's own).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from rl_jax.training import replay
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import ReplayBuffer, Transition


class FrameRow(NamedTuple):
    """What a transition keeps besides the newest frame of its ``obs``."""

    action: jax.Array  # [*action_shape]
    reward: jax.Array  # [] float32
    next_frame: jax.Array  # [H, W] uint8, the newest frame of the true next observation
    terminated: jax.Array  # [] bool
    truncated: jax.Array  # [] bool
    next_legal: jax.Array | None = None  # [A] bool, next obs's legal actions (masked envs only)


@struct.dataclass
class FrameReplay:
    rows: ReplayBuffer | PrioritizedBuffer  # of FrameRow, leaves [R, width, ...]
    frames: jax.Array  # [R + stack - 1, width, H, W] uint8, newest frame of obs by global step
    ended: jax.Array  # [R + stack - 1, width] bool, the step ended its episode
    written: jax.Array  # [] int32, env steps (rows) written so far

    @property
    def stack(self) -> int:
        return self.frames.shape[0] - self.storage.rows + 1

    @property
    def storage(self) -> replay.ReplayBuffer:
        """The plain ``ReplayBuffer`` under the rows (prioritized or not)."""
        return storage_of(self.rows)


def storage_of(rows: ReplayBuffer | PrioritizedBuffer) -> ReplayBuffer:
    """The plain ``ReplayBuffer`` under transition rows, prioritized or not."""
    return rows.buffer if isinstance(rows, PrioritizedBuffer) else rows


def _row(transition: Transition) -> FrameRow:
    return FrameRow(
        transition.action,
        transition.reward,
        transition.next_obs[..., -1],
        transition.terminated,
        transition.truncated,
        transition.next_legal,
    )


def init(
    example: Transition, init_rows: Callable[[FrameRow], ReplayBuffer | PrioritizedBuffer]
) -> FrameReplay:
    """An empty buffer for transitions shaped like ``example`` (obs ``[H, W, stack]``);
    ``init_rows(example_row)`` makes the transition rows (``replay.init`` or
    ``prioritized.init`` with the capacity and width)."""
    rows = init_rows(_row(example))
    storage = storage_of(rows)
    slots = storage.rows + example.obs.shape[-1] - 1
    frames = jnp.zeros((slots, storage.width, *example.obs.shape[:-1]), example.obs.dtype)
    # Before the first step every step "ended": no history reaches back past it.
    ended = jnp.ones((slots, storage.width), jnp.bool_)
    return FrameReplay(rows=rows, frames=frames, ended=ended, written=jnp.int32(0))


def add(
    buffer: FrameReplay,
    batch: Transition,
    add_rows: Callable[
        [ReplayBuffer | PrioritizedBuffer, FrameRow], ReplayBuffer | PrioritizedBuffer
    ],
) -> FrameReplay:
    """Write one env step of all envs (``batch`` leaves ``[width, ...]``); ``add_rows`` writes
    the transition rows (``replay.add`` or ``prioritized.add``)."""
    slot = buffer.written % buffer.frames.shape[0]
    ended = jnp.logical_or(batch.terminated, batch.truncated)
    return FrameReplay(
        rows=add_rows(buffer.rows, _row(batch)),
        frames=jax.lax.dynamic_update_index_in_dim(buffer.frames, batch.obs[..., -1], slot, 0),
        ended=jax.lax.dynamic_update_index_in_dim(buffer.ended, ended, slot, 0),
        written=buffer.written + 1,
    )


def global_steps(buffer: FrameReplay, rows: jax.Array) -> jax.Array:
    """The global step each storage row holds (the newest row is ``written - 1``)."""
    count = buffer.storage.rows
    return buffer.written - 1 - (buffer.written - 1 - rows) % count


def stacks(buffer: FrameReplay, steps: jax.Array, columns: jax.Array) -> jax.Array:
    """``obs`` of global ``steps`` in env ``columns`` (same shape ``[...]``):
    ``[..., H, W, stack]``, rebuilt from the frames as the module docstring says."""
    slots = buffer.frames.shape[0]
    frame = buffer.frames[steps % slots, columns]
    in_episode = jnp.ones(steps.shape, jnp.bool_)
    newest_first = [frame]
    for back in range(1, buffer.stack):
        in_episode = in_episode & ~buffer.ended[(steps - back) % slots, columns]
        older = buffer.frames[(steps - back) % slots, columns]
        frame = jnp.where(in_episode[..., None, None], older, frame)
        newest_first.append(frame)
    return jnp.stack(newest_first[::-1], axis=-1)


def transitions(
    buffer: FrameReplay, window: FrameRow, rows: jax.Array, columns: jax.Array
) -> Transition:
    """Full ``Transition`` windows from ``replay.gather_windows`` on ``buffer.storage``:
    ``window`` leaves ``[B, L, ...]`` start at storage ``rows`` [B] in env ``columns`` [B].
    Steps of a window past the newest row get whatever is there, as ``gather_windows`` says."""
    length = window.reward.shape[1]
    steps = global_steps(buffer, rows)[:, None] + jnp.arange(length, dtype=jnp.int32)[None, :]
    env_columns = jnp.broadcast_to(columns[:, None], steps.shape)
    obs = stacks(buffer, steps, env_columns)
    next_obs = jnp.concatenate([obs[..., 1:], window.next_frame[..., None]], axis=-1)
    return Transition(
        obs,
        window.action,
        window.reward,
        next_obs,
        window.terminated,
        window.truncated,
        window.next_legal,
    )
