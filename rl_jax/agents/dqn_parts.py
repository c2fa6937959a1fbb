"""DQN's replay, picked once per config by ``make_replay``: rows of transitions, uniform or
prioritized (``rl_jax.training.prioritized``), laid out flat or beside frames kept once, whose
stacks are rebuilt when sampled (``rl_jax.training.frame_replay``). A sample is a batch of
``n_step`` windows (``rl_jax.training.replay``) with its importance weights.

It reads the loop's settings (``OffPolicyConfig``: batch and buffer sizes, the update clock) and
is told the rest (``n_step``, prioritized or not, frames or not) by ``rl_jax.agents.dqn``, whose
``Config`` it does not import.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple, Protocol, cast

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike

from rl_jax.training import frame_replay, offpolicy, prioritized, replay
from rl_jax.training.frame_replay import FrameReplay, FrameRow
from rl_jax.training.offpolicy import OffPolicyConfig
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import NStepBatch, ReplayBuffer, Transition

#: One stored row: a transition, or with frames its ``FrameRow`` (frames kept apart).
Row = Transition | FrameRow
#: The transition rows: uniform, or prioritized.
Rows = ReplayBuffer | PrioritizedBuffer
#: DQN's replay: the rows, or with frames the rows and the frames they point into.
Buffer = Rows | FrameReplay
#: ``(rows, columns)`` of the sampled transitions in the buffer, each ``[B]``.
Indices = tuple[jax.Array, jax.Array]


class ReplayHparams(Protocol):
    """The hyperparameters the replay reads (DQN's ``Hyperparams`` has them): the discount of
    its n-step returns and prioritized replay's settings."""

    @property
    def gamma(self) -> ArrayLike:
        """The discount of the n-step returns."""
        ...

    @property
    def priority_alpha(self) -> ArrayLike:
        """Prioritized: ``P(i)`` proportional to ``priority_i^alpha``."""
        ...

    @property
    def priority_beta_start(self) -> ArrayLike:
        """Prioritized: the importance-weight exponent at the start."""
        ...

    @property
    def priority_beta_steps(self) -> ArrayLike:
        """Prioritized: the env steps for beta to rise to 1."""
        ...

    @property
    def priority_eps(self) -> ArrayLike:
        """Prioritized: added to ``|TD error|`` to make a priority."""
        ...


# ---- the rows: uniform or prioritized -----------------------------------------------------------
class RowKind(NamedTuple):
    """How the transition rows are kept, drawn from and told the TD errors. Each kind's
    functions take the ``Rows`` union and are only ever given their own kind of rows
    (``make_replay`` pairs them), so they narrow it with ``cast``."""

    init: Callable[[Row, OffPolicyConfig], Rows]  # (example row, config) -> rows
    # (rows, batch of rows [N, ...], hparams) -> rows
    add: Callable[[Rows, Row, ReplayHparams], Rows]
    # (rows, key, config, hparams, update_index) -> (rows [B], columns [B], weights [B])
    draw: Callable[
        [Rows, jax.Array, OffPolicyConfig, ReplayHparams, jax.Array], tuple[jax.Array, ...]
    ]
    storage: Callable[[Rows], ReplayBuffer]  # the plain ReplayBuffer under the rows
    # (rows, indices, td_error [B], hparams) -> rows
    reprioritize: Callable[[Rows, Indices, jax.Array, ReplayHparams], Rows]


def _draw_uniform(
    rows: Rows,
    key: jax.Array,
    config: OffPolicyConfig,
    hparams: ReplayHparams,
    update_index: jax.Array,
) -> tuple[jax.Array, ...]:
    rows_drawn, columns = replay.sample_indices(cast(ReplayBuffer, rows), key, config.batch_size)
    return rows_drawn, columns, jnp.ones(config.batch_size, jnp.float32)


def _draw_prioritized(
    rows: Rows,
    key: jax.Array,
    config: OffPolicyConfig,
    hparams: ReplayHparams,
    update_index: jax.Array,
) -> tuple[jax.Array, ...]:
    env_steps = offpolicy.env_steps_at_update(update_index, config)
    beta = prioritized.annealed_beta(
        hparams.priority_beta_start, env_steps, hparams.priority_beta_steps
    )
    return prioritized.sample_indices(cast(PrioritizedBuffer, rows), key, config.batch_size, beta)


def _reprioritize(
    rows: Rows, indices: Indices, td_error: jax.Array, hparams: ReplayHparams
) -> PrioritizedBuffer:
    """The sampled transitions' priorities become ``|TD error| + eps``."""
    priorities = jnp.abs(td_error) + hparams.priority_eps
    return prioritized.update_priorities(
        cast(PrioritizedBuffer, rows), *indices, priorities, hparams.priority_alpha
    )


UNIFORM = RowKind(
    init=lambda example, config: replay.init(example, config.buffer_size, config.num_envs),
    add=lambda rows, batch, hparams: replay.add(cast(ReplayBuffer, rows), batch),
    draw=_draw_uniform,
    storage=lambda rows: cast(ReplayBuffer, rows),
    reprioritize=lambda rows, indices, td_error, hparams: rows,
)
PRIORITIZED = RowKind(
    init=lambda example, config: prioritized.init(example, config.buffer_size, config.num_envs),
    add=lambda rows, batch, hparams: prioritized.add(
        cast(PrioritizedBuffer, rows), batch, hparams.priority_alpha
    ),
    draw=_draw_prioritized,
    storage=lambda rows: cast(PrioritizedBuffer, rows).buffer,
    reprioritize=_reprioritize,
)


# ---- the layout: observations in the rows, or frames beside them --------------------------------
class Layout(NamedTuple):
    """Where the observations are kept, around rows of some ``RowKind``. As with ``RowKind``,
    each layout's functions take the ``Buffer`` union and are given only their own layout."""

    # (example transition, init_rows(example row) -> rows) -> buffer
    init: Callable[[Transition, Callable[[Row], Rows]], Buffer]
    # (buffer, transitions [N, ...], add_rows(rows, batch of rows) -> rows) -> buffer
    add: Callable[[Buffer, Transition, Callable[[Rows, Row], Rows]], Buffer]
    rows_of: Callable[[Buffer], Rows]  # buffer -> its rows
    with_rows: Callable[[Buffer, Rows], Buffer]  # (buffer, rows) -> the buffer with those rows
    # (buffer, windows of rows [B, L, ...], rows [B], columns [B]) -> Transition windows
    transitions: Callable[[Buffer, Row, jax.Array, jax.Array], Transition]


FLAT = Layout(
    init=lambda example, init_rows: init_rows(example),
    add=lambda buffer, transitions, add_rows: add_rows(cast(Rows, buffer), transitions),
    rows_of=lambda buffer: cast(Rows, buffer),
    with_rows=lambda buffer, rows: rows,
    transitions=lambda buffer, window, rows, columns: cast(Transition, window),
)
FRAMES = Layout(
    init=frame_replay.init,
    add=lambda buffer, transitions, add_rows: frame_replay.add(
        cast(FrameReplay, buffer), transitions, add_rows
    ),
    rows_of=lambda buffer: cast(FrameReplay, buffer).rows,
    with_rows=lambda buffer, rows: dataclasses.replace(cast(FrameReplay, buffer), rows=rows),
    transitions=lambda buffer, window, rows, columns: frame_replay.transitions(
        cast(FrameReplay, buffer), cast(FrameRow, window), rows, columns
    ),
)


# ---- DQN's replay for one config ----------------------------------------------------------------
class Replay(NamedTuple):
    """DQN's buffer functions for one config: rows of one kind in one layout."""

    config: OffPolicyConfig  # the loop's settings: batch and buffer sizes, the update clock
    n_step: int  # rewards summed before bootstrapping
    kind: RowKind
    layout: Layout

    def init(self, example: Transition) -> Buffer:
        """An empty buffer for transitions shaped like ``example``."""
        return self.layout.init(example, lambda row: self.kind.init(row, self.config))

    def add(self, buffer: Buffer, transitions: Transition, hparams: ReplayHparams) -> Buffer:
        """``buffer`` with one env step of all envs (``transitions`` leaves ``[N, ...]``)."""
        add_rows = lambda rows, batch: self.kind.add(rows, batch, hparams)  # noqa: E731
        return self.layout.add(buffer, transitions, add_rows)

    def sample(
        self, buffer: Buffer, key: jax.Array, hparams: ReplayHparams, update_index: jax.Array
    ) -> tuple[NStepBatch, jax.Array, Indices]:
        """``(batch, weights [B], (rows, columns))``."""
        rows_buffer = self.layout.rows_of(buffer)
        rows, columns, weights = self.kind.draw(
            rows_buffer, key, self.config, hparams, update_index
        )
        window, stored = replay.gather_windows(
            self.kind.storage(rows_buffer), rows, columns, self.n_step
        )
        window = self.layout.transitions(buffer, window, rows, columns)
        return replay.n_step_batch(window, stored, hparams.gamma), weights, (rows, columns)

    def write_priorities(
        self, buffer: Buffer, indices: Indices, td_error: jax.Array, hparams: ReplayHparams
    ) -> Buffer:
        """With ``prioritized``: the sampled transitions' priorities from their TD errors."""
        rows = self.kind.reprioritize(self.layout.rows_of(buffer), indices, td_error, hparams)
        return self.layout.with_rows(buffer, rows)


def make_replay(config: OffPolicyConfig, n_step: int, prioritized: bool, frames: bool) -> Replay:
    """The one place where the settings pick DQN's replay: ``n_step`` windows, rows prioritized
    or uniform, with frames kept apart (stacked frames as observations) or not."""
    kind = PRIORITIZED if prioritized else UNIFORM
    layout = FRAMES if frames else FLAT
    return Replay(config, n_step, kind, layout)
