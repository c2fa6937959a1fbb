"""R2D2's pure parts: the invertible value rescaling, n-step targets over a sequence with episode
ends inside it, sequence priorities, and the sequence replay with stored states.

Nothing here builds a network or reads ``rl_jax.agents.r2d2``'s settings; sequences are time
first (``[T, B]``) in the maths and batch first (``[B, L, ...]``) in the replay.

The replay (``SequenceReplay``) keeps each env's last ``length`` steps, oldest first, and every
``period`` steps (once ``length`` have been seen) writes them as one sequence per env, with the
recurrent state the policy had before acting on the sequence's first step (the stored-state
strategy of Kapturowski et al. 2019). Sequences overlap by ``length - period`` steps and run on
through episode ends: the flags of the steps say where the state is reset inside a sequence
(``episode_starts``). The sequences are rows of an ``rl_jax.training.replay.ReplayBuffer``, or
of an ``rl_jax.training.prioritized.PrioritizedBuffer`` for prioritised sequences.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple, cast

import jax
import jax.numpy as jnp
from flax import struct
from jax.typing import ArrayLike

from rl_jax.training import prioritized, replay
from rl_jax.training.prioritized import PrioritizedBuffer
from rl_jax.training.replay import ReplayBuffer, Transition


# ---- value rescaling (Pohlen et al. 2018) ------------------------------------------------------
def value_rescale(x: jax.Array, eps: ArrayLike = 1e-3) -> jax.Array:
    """``h(x) = sign(x) (sqrt(|x| + 1) - 1) + eps x``: squashes large returns, keeps their sign
    and order, and is invertible (``inverse_value_rescale``). ``sqrt(s + 1) - 1`` is computed
    as ``s / (sqrt(s + 1) + 1)``, the same without the cancellation near 0."""
    size = jnp.abs(x)
    return jnp.sign(x) * size / (jnp.sqrt(size + 1.0) + 1.0) + eps * x


def inverse_value_rescale(x: jax.Array, eps: ArrayLike = 1e-3) -> jax.Array:
    """``h^-1(x) = sign(x) (((sqrt(1 + 4 eps (|x| + 1 + eps)) - 1) / (2 eps))^2 - 1)``, the exact
    inverse of ``value_rescale`` for ``eps > 0`` (Pohlen et al. 2018, Proposition A.2).

    Computed as ``sign(x) (u - 1)(u + 1)`` with ``u = (root - 1) / (2 eps)`` written without
    its cancellations (``root`` the square root above, ``s = |x|``, ``a = s + 1 + eps``):
    ``u = 2 a / (root + 1)`` and ``u - 1 = 4 s a / ((2 a - 1 + root)(root + 1))``. The formula
    as printed loses about ``1e-7 / eps`` of relative precision in float32 near 0."""
    size = jnp.abs(x)
    a = size + 1.0 + eps
    root = jnp.sqrt(1.0 + 4.0 * eps * a)
    u_minus_1 = 4.0 * size * a / ((2.0 * a - 1.0 + root) * (root + 1.0))
    return jnp.sign(x) * u_minus_1 * (u_minus_1 + 2.0)


# ---- targets and priorities --------------------------------------------------------------------
def episode_starts(terminated: jax.Array, truncated: jax.Array) -> jax.Array:
    """``[T, B]`` bool, true where a step's observation begins an episode inside the sequence
    (the step before it ended one). The first step is never marked: its stored state is already
    the one the policy acted with, reset or not."""
    ended = jnp.logical_or(terminated, truncated)
    return jnp.concatenate([jnp.zeros_like(ended[:1]), ended[:-1]], axis=0)


def n_step_targets(
    r_t: jax.Array, discount_t: jax.Array, v_t: jax.Array, ended: jax.Array, n: int
) -> jax.Array:
    """n-step returns of every step of a sequence, time first ``[T, B]``.

    From step ``t`` the rewards of steps ``t .. m`` are summed, discounted by ``discount_t``
    (``gamma``, 0 at a termination), and step ``m`` bootstraps from ``v_t[m]``, the value of its
    true next observation. ``m`` is the first of ``t + n - 1``, the first step at or after ``t``
    that ``ended`` an episode (terminated or truncated), and the sequence's last step.
    """
    last = (jnp.arange(r_t.shape[0]) == r_t.shape[0] - 1)[:, None]
    stop = jnp.logical_or(ended, last)
    target = r_t + discount_t * v_t
    for _ in range(n - 1):
        following = jnp.concatenate([target[1:], target[-1:]], axis=0)  # the last row: stop
        target = r_t + discount_t * jnp.where(stop, v_t, following)
    return target


def rescaled_n_step_targets(
    r_t: jax.Array,
    discount_t: jax.Array,
    v_t: jax.Array,
    ended: jax.Array,
    n: int,
    eps: ArrayLike,
) -> jax.Array:
    """R2D2's targets ``h(n-step return with h^-1(v_t))``, no gradient: ``v_t`` and the
    targets are in the rescaled units the Q-network learns (``n_step_targets`` for the rest)."""
    returns = n_step_targets(r_t, discount_t, inverse_value_rescale(v_t, eps), ended, n)
    return jax.lax.stop_gradient(value_rescale(returns, eps))


def sequence_priorities(td_error: jax.Array, eta: ArrayLike) -> jax.Array:
    """``eta max_t |delta| + (1 - eta) mean_t |delta|`` per sequence: ``[T, B] -> [B]``."""
    size, eta = jnp.abs(td_error), jnp.asarray(eta)
    return eta * jnp.max(size, axis=0) + (1.0 - eta) * jnp.mean(size, axis=0)


# ---- the sequence replay -----------------------------------------------------------------------
class Sequence(NamedTuple):
    """One stored sequence (leaves ``[L, ...]``; sampled, ``[B, L, ...]``)."""

    steps: Transition  # its steps, oldest first, without their policy states
    start_state: object  # the policy's state before acting on steps.obs[0] (a pytree)


#: The sequences, uniform or prioritised.
Sequences = ReplayBuffer[Sequence] | PrioritizedBuffer[Sequence]


@struct.dataclass
class SequenceReplay:
    """Each env's recent steps and the sequences written so far."""

    recent: Transition  # leaves [num_envs, length, ...], oldest first, with policy_state
    steps: jax.Array  # [] int32, steps of every env added so far
    sequences: Sequences  # rows of num_envs sequences
    period: int = struct.field(pytree_node=False, default=1)  # steps between sequence starts

    @property
    def length(self) -> int:
        """Steps per sequence."""
        return int(self.recent.obs.shape[1])


def _sequence(recent: Transition) -> Sequence:
    start_state = jax.tree.map(lambda x: x[:, 0], recent.policy_state)
    return Sequence(steps=recent._replace(policy_state=None), start_state=start_state)


def init(
    example: Transition,
    num_envs: int,
    length: int,
    period: int,
    capacity: int,
    prioritize: bool,
) -> SequenceReplay:
    """An empty replay for ``capacity`` sequences (rounded up to rows of ``num_envs``) of
    ``length`` steps shaped like ``example`` (one step, with its ``policy_state``), one
    written every ``period`` steps."""
    if not 1 <= period <= length:
        raise ValueError(f"the period must be in 1..{length}, got {period}")
    recent = jax.tree.map(
        lambda x: jnp.zeros((num_envs, length, *jnp.shape(x)), jnp.asarray(x).dtype), example
    )
    item = jax.tree.map(lambda x: x[0], _sequence(recent))
    store = prioritized.init if prioritize else replay.init
    sequences = store(item, capacity, num_envs)
    return SequenceReplay(recent, jnp.int32(0), sequences, period)


def _write_row_if(buffer: ReplayBuffer, row: Sequence, ready: jax.Array) -> ReplayBuffer:
    """``replay.add`` where ``ready``, else ``buffer`` as it was. A select on the one row, not
    a ``lax.cond``: under a seed vmap a cond would run both sides over the whole buffer."""
    old = jax.tree.map(lambda stored: stored[buffer.position], buffer.data)
    row = jax.tree.map(lambda new, kept: jnp.where(ready, new.astype(kept.dtype), kept), row, old)
    written = replay.add(buffer, row)
    return ReplayBuffer(
        data=written.data,
        position=jnp.where(ready, written.position, buffer.position),
        rows_filled=jnp.where(ready, written.rows_filled, buffer.rows_filled),
    )


def _add_prioritized_if(
    rows: PrioritizedBuffer, row: Sequence, ready: jax.Array, alpha: ArrayLike
) -> PrioritizedBuffer:
    """``prioritized.add`` (the new sequences get the largest priority so far) where ``ready``."""
    slots = rows.buffer.position * rows.buffer.width + jnp.arange(rows.buffer.width)
    powered = jnp.full(slots.shape, rows.max_priority**alpha, jnp.float32)
    sums = jnp.where(ready, powered, rows.sums[rows.leaves + slots])
    mins = jnp.where(ready, powered, rows.mins[rows.leaves + slots])
    return dataclasses.replace(
        rows,
        buffer=_write_row_if(rows.buffer, row, ready),
        sums=prioritized.tree_set(rows.sums, slots, sums, jnp.add),
        mins=prioritized.tree_set(rows.mins, slots, mins, jnp.minimum),
    )


def add(memory: SequenceReplay, step: Transition, alpha: ArrayLike) -> SequenceReplay:
    """One step of every env (leaves ``[num_envs, ...]``, with ``policy_state``); every
    ``period`` steps from the ``length``-th on, each env's last ``length`` steps become a
    sequence (prioritised: with ``alpha``, the priority exponent)."""
    recent = jax.tree.map(
        lambda kept, new: jnp.concatenate([kept[:, 1:], new[:, None].astype(kept.dtype)], axis=1),
        memory.recent,
        step,
    )
    steps = memory.steps + 1
    ready = jnp.logical_and(steps >= memory.length, (steps - memory.length) % memory.period == 0)
    row = _sequence(recent)
    if isinstance(memory.sequences, PrioritizedBuffer):
        sequences: Sequences = _add_prioritized_if(memory.sequences, row, ready, alpha)
    else:
        sequences = _write_row_if(memory.sequences, row, ready)
    return dataclasses.replace(memory, recent=recent, steps=steps, sequences=sequences)


def sample(
    memory: SequenceReplay, key: jax.Array, batch_size: int, beta: ArrayLike
) -> tuple[Sequence, jax.Array, tuple[jax.Array, jax.Array]]:
    """``(sequences [B, L, ...], importance weights [B], (rows, columns))``: uniform (weights
    1), or proportional to priority^alpha with weights of exponent ``beta``."""
    if isinstance(memory.sequences, PrioritizedBuffer):
        rows, columns, weights = prioritized.sample_indices(
            memory.sequences, key, batch_size, jnp.asarray(beta)
        )
        buffer = memory.sequences.buffer
    else:
        buffer = cast(ReplayBuffer, memory.sequences)
        rows, columns = replay.sample_indices(buffer, key, batch_size)
        weights = jnp.ones(batch_size, jnp.float32)
    return replay.gather(buffer, rows, columns), weights, (rows, columns)


def write_priorities(
    memory: SequenceReplay,
    indices: tuple[jax.Array, jax.Array],
    priorities: jax.Array,
    alpha: ArrayLike,
) -> SequenceReplay:
    """The sampled sequences' new priorities (> 0); uniform replay is returned as it was."""
    if not isinstance(memory.sequences, PrioritizedBuffer):
        return memory
    sequences = prioritized.update_priorities(memory.sequences, *indices, priorities, alpha)
    return dataclasses.replace(memory, sequences=sequences)


def capacity(buffer_size: int, period: int) -> int:
    """Sequences kept for a replay of ``buffer_size`` env steps: each sequence brings
    ``period`` new steps."""
    return max(1, buffer_size // period)
