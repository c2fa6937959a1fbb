"""DQN's replay: rows of transitions, uniform or prioritized (``Config.prioritized``:
``rl_jax.training.prioritized``); for a ``PixelConfig`` each frame is kept once beside the rows and
stacks are rebuilt when sampled (``rl_jax.training.frame_replay``). A sample is a batch of
``n_step`` windows (``rl_jax.training.replay``) with its importance weights.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from rl_jax.agents.dqn_config import Config, Hyperparams, PixelConfig
from rl_jax.training import frame_replay, offpolicy, prioritized, replay
from rl_jax.training.frame_replay import FrameReplay, FrameRow
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import NStepBatch, ReplayBuffer, Transition

#: The transition rows: uniform, or prioritized with ``Config.prioritized``.
Rows = ReplayBuffer | PrioritizedBuffer
#: DQN's replay: the rows, or with a ``PixelConfig`` the rows and the frames they point into.
Buffer = Rows | FrameReplay
#: ``(rows, columns)`` of the sampled transitions in the buffer, each ``[B]``.
Indices = tuple[jax.Array, jax.Array]


def init_buffer(example: Transition, config: Config) -> Buffer:
    if isinstance(config, PixelConfig):  # frames kept once, stacks rebuilt when sampled
        return frame_replay.init(example, lambda row: _init_rows(row, config))
    return _init_rows(example, config)


def add_to_buffer(
    buffer: Buffer, transitions: Transition, config: Config, hparams: Hyperparams
) -> Buffer:
    if isinstance(config, PixelConfig):
        add_rows = lambda rows, batch: _add_rows(rows, batch, config, hparams)  # noqa: E731
        return frame_replay.add(buffer, transitions, add_rows)
    return _add_rows(buffer, transitions, config, hparams)


def sample(
    buffer: Buffer, key: jax.Array, config: Config, hparams: Hyperparams, update_index: jax.Array
) -> tuple[NStepBatch, jax.Array, Indices]:
    """``(batch, weights [B], (rows, columns))`` from uniform or prioritized replay."""
    frames, buffer = buffer, _rows_of(buffer, config)
    if config.prioritized:
        env_steps = offpolicy.env_steps_at_update(update_index, config)
        beta = prioritized.annealed_beta(
            hparams.priority_beta_start, env_steps, hparams.priority_beta_steps
        )
        rows, columns, weights = prioritized.sample_indices(buffer, key, config.batch_size, beta)
        storage = buffer.buffer
    else:
        rows, columns = replay.sample_indices(buffer, key, config.batch_size)
        weights, storage = jnp.ones(config.batch_size, jnp.float32), buffer
    window, stored = replay.gather_windows(storage, rows, columns, config.n_step)
    if isinstance(config, PixelConfig):
        window = frame_replay.transitions(frames, window, rows, columns)
    return replay.n_step_batch(window, stored, hparams.gamma), weights, (rows, columns)


def write_priorities(
    buffer: Buffer, indices: Indices, td_error: jax.Array, config: Config, hparams: Hyperparams
) -> Buffer:
    """With ``prioritized``: the sampled transitions' priorities become ``|TD error| + eps``."""
    if not config.prioritized:
        return buffer
    rows, columns = indices
    priorities = jnp.abs(td_error) + hparams.priority_eps
    rows_buffer = prioritized.update_priorities(
        _rows_of(buffer, config), rows, columns, priorities, hparams.priority_alpha
    )
    return _with_rows(buffer, rows_buffer, config)


def _init_rows(example: Transition | FrameRow, config: Config) -> Rows:
    if config.prioritized:
        return prioritized.init(example, config.buffer_size, config.num_envs)
    return offpolicy.uniform_buffer(example, config)


def _add_rows(
    rows: Rows, transitions: Transition | FrameRow, config: Config, hparams: Hyperparams
) -> Rows:
    if config.prioritized:
        return prioritized.add(rows, transitions, hparams.priority_alpha)
    return replay.add(rows, transitions)


def _rows_of(buffer: Buffer, config: Config) -> Rows:
    """The transition rows (uniform or prioritized) whatever the observation layout."""
    return buffer.rows if isinstance(config, PixelConfig) else buffer


def _with_rows(buffer: Buffer, rows: Rows, config: Config) -> Buffer:
    return buffer.replace(rows=rows) if isinstance(config, PixelConfig) else rows
