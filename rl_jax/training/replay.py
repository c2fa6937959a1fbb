"""A pure-functional circular replay buffer.

Storage is time-major: every leaf is ``[rows, width, ...]`` where one row holds the transitions
that ``width`` parallel envs produced in the same env step. ``add`` writes one row (the batch of
all envs) at ``position`` and wraps around, overwriting the oldest row. Keeping rows intact means
that consecutive steps of one env stay in one column, which n-step returns and sequence sampling
can read later; uniform sampling just draws a flat index over the filled part.

The buffer is generic over the stored pytree; off-policy learners store a ``Transition``.
"""

from __future__ import annotations

import math
from typing import Generic, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
from flax import struct
from jax.typing import ArrayLike


class Transition(NamedTuple):
    """One env step. ``next_obs`` is the *true* next observation: at the end of an episode it is
    the final one (``info["final_obs"]`` of ``AutoReset``), not the next episode's first."""

    obs: jax.Array  # [*obs_shape]
    action: jax.Array  # [*action_shape]
    reward: jax.Array  # [] float32
    next_obs: jax.Array  # [*obs_shape]
    terminated: jax.Array  # [] bool: next_obs is terminal, its value is 0
    truncated: jax.Array  # [] bool: the time limit cut the episode; next_obs still has a value
    # [A] bool, the legal actions of next_obs, kept only for an env with an action mask (None:
    # no leaf, so the rows of other envs stay as they were)
    next_legal: jax.Array | None = None
    # the policy state the action was chosen with, kept only by a recurrent learner's replay
    # (offpolicy.Learner.policy_state; None: no leaf)
    policy_state: object = None


#: the stored pytree (one item, no batch axis): a ``Transition`` for the off-policy learners
Item = TypeVar("Item")


@struct.dataclass
class ReplayBuffer(Generic[Item]):
    data: Item  # leaves [rows, width, ...]
    position: jax.Array  # [] int32, the row ``add`` writes next
    rows_filled: jax.Array  # [] int32, rows holding data (stops growing at ``rows``)

    @property
    def rows(self) -> int:
        """Rows of the ring buffer; each holds one transition per env."""
        return jax.tree.leaves(self.data)[0].shape[0]

    @property
    def width(self) -> int:
        """Transitions per row: the number of envs that write together."""
        return jax.tree.leaves(self.data)[0].shape[1]

    @property
    def capacity(self) -> int:
        """Transitions the buffer holds when full (rows x width)."""
        return self.rows * self.width

    def size(self) -> jax.Array:
        """[] int32: number of transitions stored."""
        return self.rows_filled * self.width


def rows_for(capacity: int, width: int) -> int:
    """Rows needed to hold at least ``capacity`` transitions written ``width`` at a time."""
    return max(1, math.ceil(capacity / width))


def init(example: Item, capacity: int, width: int) -> ReplayBuffer[Item]:
    """An empty buffer for at least ``capacity`` items shaped like ``example`` (one item, no batch
    axis), filled ``width`` items at a time."""
    rows = rows_for(capacity, width)
    data = jax.tree.map(
        lambda x: jnp.zeros((rows, width, *jnp.shape(x)), jnp.asarray(x).dtype), example
    )
    return ReplayBuffer(data=data, position=jnp.int32(0), rows_filled=jnp.int32(0))


def nbytes(example: object, capacity: int, width: int) -> int:
    """Memory the buffer's storage takes, computed without allocating it."""
    rows = rows_for(capacity, width)
    per_item = sum(
        jnp.asarray(x).dtype.itemsize * math.prod(jnp.shape(x)) for x in jax.tree.leaves(example)
    )
    return rows * width * per_item


def add(buffer: ReplayBuffer[Item], batch: Item) -> ReplayBuffer[Item]:
    """Write one row: ``batch`` has the stored pytree's structure with leaves ``[width, ...]``."""
    data = jax.tree.map(
        lambda stored, new: jax.lax.dynamic_update_index_in_dim(
            stored, new.astype(stored.dtype), buffer.position, axis=0
        ),
        buffer.data,
        batch,
    )
    return ReplayBuffer(
        data=data,
        position=(buffer.position + 1) % buffer.rows,
        rows_filled=jnp.minimum(buffer.rows_filled + 1, buffer.rows),
    )


def sample_indices(buffer: ReplayBuffer, key: jax.Array, batch_size: int):
    """Uniform (with replacement) over the stored transitions: ``(rows, columns)``, each
    ``[batch_size]`` int32. Sampling an empty buffer returns row 0 (zeros); callers wait until
    data is in."""
    flat = jax.random.randint(key, (batch_size,), 0, jnp.maximum(buffer.size(), 1))
    return flat // buffer.width, flat % buffer.width


def gather(buffer: ReplayBuffer[Item], rows: jax.Array, columns: jax.Array) -> Item:
    """The stored items at ``(rows, columns)``; leaves ``[len(rows), ...]``."""
    return jax.tree.map(lambda stored: stored[rows, columns], buffer.data)


def sample(buffer: ReplayBuffer[Item], key: jax.Array, batch_size: int) -> Item:
    """A uniform batch of ``batch_size`` stored items."""
    return gather(buffer, *sample_indices(buffer, key, batch_size))


def gather_windows(buffer: ReplayBuffer, rows: jax.Array, columns: jax.Array, length: int):
    """``length`` consecutive steps of one env from each ``(row, column)`` on (n-step returns).

    Returns ``(items, stored)``: leaves ``[len(rows), length, ...]`` and ``[len(rows), length]``
    bool, true where the step is in the buffer. A window runs into older or unwritten data past
    the newest row; those steps are marked not stored (their values are whatever is there).
    Episode boundaries are the caller's business (the items carry their own done flags).
    """
    offsets = jnp.arange(length, dtype=jnp.int32)
    window_rows = (rows[:, None] + offsets[None, :]) % buffer.rows
    # Steps from the window's first row to the newest row written, around the circle.
    to_newest = (buffer.position - 1 - rows) % buffer.rows
    stored = offsets[None, :] <= to_newest[:, None]
    items = jax.tree.map(lambda leaf: leaf[window_rows, columns[:, None]], buffer.data)
    return items, stored


# ---- n-step windows (DQN, TD3) -------------------------------------------------------------------
class NStepBatch(NamedTuple):
    """Windows of up to n consecutive steps of one env, cut at episode ends, as n-step targets
    read them: ``r_t[0] + d[0] (r_t[1] + d[1] (... + d[n-1] v(next_obs)))``."""

    obs: jax.Array  # [B, *obs_shape], where each window starts
    action: jax.Array  # [B]
    r_t: jax.Array  # [B, n], 0 after the window's end
    discount_t: jax.Array  # [B, n], gamma (0 at termination), 1 after the window's end
    next_obs: jax.Array  # [B, *obs_shape], the true next obs of the window's last step
    next_legal: jax.Array | None = None  # [B, A] bool, its legal actions (masked envs only)


def n_step_batch(window: Transition, stored: jax.Array, gamma: ArrayLike) -> NStepBatch:
    """Cut each window (leaves [B, n, ...], ``stored`` [B, n]) after its first episode end."""
    ended = jnp.logical_or(window.terminated, window.truncated)
    ended_before = (jnp.cumsum(ended, axis=1) - ended) > 0
    included = jnp.logical_and(stored, ~ended_before)
    not_terminal = 1.0 - window.terminated.astype(jnp.float32)
    last = jnp.sum(included, axis=1) - 1

    def at_last(leaf: jax.Array) -> jax.Array:
        return jnp.take_along_axis(leaf, last.reshape((-1,) + (1,) * (leaf.ndim - 1)), axis=1)[:, 0]

    next_legal = None if window.next_legal is None else at_last(window.next_legal)
    return NStepBatch(
        obs=window.obs[:, 0],
        action=window.action[:, 0],
        r_t=jnp.where(included, window.reward, 0.0),
        discount_t=jnp.where(included, gamma * not_terminal, 1.0),
        next_obs=at_last(window.next_obs),
        next_legal=next_legal,
    )


def sample_n_step(
    buffer: ReplayBuffer, key: jax.Array, batch_size: int, n: int, gamma: ArrayLike
) -> NStepBatch:
    """A uniform batch of ``n``-step windows (``NStepBatch``)."""
    rows, columns = sample_indices(buffer, key, batch_size)
    window, stored = gather_windows(buffer, rows, columns, n)
    return n_step_batch(window, stored, gamma)


def fold_n_step(r_t: jax.Array, discount_t: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The n-step target as an affine map of the bootstrap value ``v``: ``(reward, discount)``
    [B] with ``r_t[0] + d[0] (r_t[1] + ... + d[n-1] v) = reward + discount * v``."""
    reward = jnp.zeros_like(r_t[:, 0])
    discount = jnp.ones_like(discount_t[:, 0])
    for k in reversed(range(r_t.shape[1])):
        reward = r_t[:, k] + discount_t[:, k] * reward
        discount = discount_t[:, k] * discount
    return reward, discount
