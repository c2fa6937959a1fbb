"""Proportional prioritized replay (Schaul et al. 2016) as pure functions over arrays.

Transition ``i`` is drawn with probability ``P(i) = p_i^alpha / sum_k p_k^alpha`` and its update is
weighted by ``w_i = (N P(i))^-beta / max_j (N P(j))^-beta`` (``N`` transitions stored), so the
weights only ever scale updates down. New transitions enter with the largest priority seen so far,
so each is replayed at least about once before its own TD error is known.

The transitions stay in an ordinary ``rl_jax.training.replay.ReplayBuffer`` (rows of ``width``
envs); slot ``row * width + column`` of it has leaf ``slot`` in two implicit binary trees over a
power of two ``leaves`` >= capacity (node ``i`` has children ``2i`` and ``2i + 1``, the root is node
1, leaf ``s`` is node ``leaves + s``): ``sums`` holds ``p^alpha`` and subtree sums, ``mins`` subtree
minima (``+inf`` on empty slots) for the weights' normaliser.

Why trees: drawing a batch descends ``log2(leaves)`` levels and writing priorities recomputes
``log2(leaves)`` ancestors, all vectorised over the batch: ``O(B log N)`` per update, where the
flat alternative (a cumulative sum over all priorities plus ``searchsorted``) is ``O(N)`` per
update, which dominates with buffers of 10^5-10^6 transitions.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Generic, cast

import jax
import jax.numpy as jnp
from flax import struct
from jax.typing import ArrayLike

from rl_jax.training import replay
from rl_jax.training.params import Scalar
from rl_jax.training.replay import Item, ReplayBuffer


@struct.dataclass
class PrioritizedBuffer(Generic[Item]):
    """A replay buffer with a sum tree and a min tree over the priorities, for proportional
    prioritized sampling.
    """

    buffer: ReplayBuffer[Item]  # the transitions, leaves [rows, width, ...]
    sums: jax.Array  # [2 * leaves] float32: p^alpha at leaves, subtree sums above (node 0 unused)
    mins: jax.Array  # [2 * leaves] float32: subtree minima of p^alpha, +inf where nothing stored
    max_priority: jax.Array  # [] float32, the largest priority (before ^alpha) given so far

    @property
    def leaves(self) -> int:
        """Leaves of the trees: the buffer's capacity rounded up to a power of two."""
        return self.sums.shape[0] // 2

    @property
    def depth(self) -> int:
        """Levels below the root of the trees."""
        return self.leaves.bit_length() - 1

    def total(self) -> jax.Array:
        """[] float32: sum of p^alpha over the stored transitions."""
        return self.sums[1]


def tree_leaves(capacity: int) -> int:
    """The power of two the trees need for ``capacity`` slots."""
    return 1 << max(0, capacity - 1).bit_length()


def init(example: Item, capacity: int, width: int) -> PrioritizedBuffer[Item]:
    """An empty prioritized buffer (see ``rl_jax.training.replay.init`` for ``example`` and
    ``width``)."""
    buffer = replay.init(example, capacity, width)
    leaves = tree_leaves(buffer.capacity)
    return PrioritizedBuffer(
        buffer=buffer,
        sums=jnp.zeros(2 * leaves, jnp.float32),
        mins=jnp.full(2 * leaves, jnp.inf, jnp.float32),
        max_priority=jnp.float32(1.0),
    )


# ---- the trees ----------------------------------------------------------------------------------
def tree_set(tree: jax.Array, slots: jax.Array, values: jax.Array, combine: Callable) -> jax.Array:
    """Set leaves ``slots`` [B] to ``values`` [B] and recompute their ancestors from their children
    with ``combine`` (``jnp.add`` or ``jnp.minimum``). Recomputing rather than adding differences
    keeps every node exact; a slot repeated in ``slots`` ends with one of its values everywhere."""
    leaves = tree.shape[0] // 2
    node = slots.astype(jnp.int32) + leaves
    tree = tree.at[node].set(values.astype(tree.dtype))

    def level(_: int, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        tree, node = carry
        node = node // 2
        return tree.at[node].set(combine(tree[2 * node], tree[2 * node + 1])), node

    return jax.lax.fori_loop(0, leaves.bit_length() - 1, level, (tree, node))[0]


def tree_find(sums: jax.Array, targets: jax.Array) -> jax.Array:
    """The slot whose prefix-sum interval holds each target in [0, total): ``[B]`` int32.

    At a node the target goes left when below the left subtree's sum, otherwise right with that sum
    subtracted; a right subtree of sum 0 (nothing stored) is never entered, so float rounding at an
    interval's edge cannot land on an empty slot."""
    leaves = sums.shape[0] // 2

    def level(_: int, carry: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        node, target = carry
        left, right = sums[2 * node], sums[2 * node + 1]
        go_right = jnp.logical_and(target >= left, right > 0.0)
        target = jnp.where(go_right, target - left, jnp.minimum(target, left))
        return 2 * node + go_right.astype(jnp.int32), target

    start = jnp.ones(targets.shape, jnp.int32)
    node, _ = jax.lax.fori_loop(0, leaves.bit_length() - 1, level, (start, targets))
    return node - leaves


# ---- the maths ----------------------------------------------------------------------------------
def importance_weights(
    probabilities: jax.Array, min_probability: jax.Array, size: jax.Array, beta: Scalar
) -> jax.Array:
    """``(N P(i))^-beta / (N min_j P(j))^-beta``: the largest possible weight is 1."""
    return (size * probabilities) ** -beta / (size * min_probability) ** -beta


def annealed_beta(
    beta_start: ArrayLike, env_steps: jax.Array, anneal_steps: ArrayLike
) -> jax.Array:
    """``beta`` rises linearly from ``beta_start`` to 1 over ``anneal_steps`` env steps."""
    fraction = jnp.clip(env_steps / jnp.maximum(anneal_steps, 1.0), 0.0, 1.0)
    return cast(jax.Array, beta_start + (1.0 - beta_start) * fraction)


# ---- buffer operations --------------------------------------------------------------------------
def _row_slots(prioritized: PrioritizedBuffer, row: jax.Array) -> jax.Array:
    width = prioritized.buffer.width
    return row * width + jnp.arange(width, dtype=jnp.int32)


def _set_priorities(
    prioritized: PrioritizedBuffer, slots: jax.Array, powered: jax.Array
) -> PrioritizedBuffer:
    return dataclasses.replace(
        prioritized,
        sums=tree_set(prioritized.sums, slots, powered, jnp.add),
        mins=tree_set(prioritized.mins, slots, powered, jnp.minimum),
    )


def add(
    prioritized: PrioritizedBuffer[Item], batch: Item, alpha: ArrayLike
) -> PrioritizedBuffer[Item]:
    """Write one row (``rl_jax.training.replay.add``) with the largest priority so far."""
    slots = _row_slots(prioritized, prioritized.buffer.position)
    prioritized = dataclasses.replace(prioritized, buffer=replay.add(prioritized.buffer, batch))
    powered = jnp.full(slots.shape, prioritized.max_priority**alpha, jnp.float32)
    return _set_priorities(prioritized, slots, powered)


def sample_indices(
    prioritized: PrioritizedBuffer, key: jax.Array, batch_size: int, beta: Scalar
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Stratified proportional draws: the range [0, total) is cut into ``batch_size`` equal
    segments and one target is drawn uniformly in each (lower variance than independent draws,
    same marginal). Returns ``(rows, columns, weights)``, each ``[batch_size]``."""
    total = prioritized.total()
    offsets = jax.random.uniform(key, (batch_size,), jnp.float32)
    targets = (jnp.arange(batch_size, dtype=jnp.float32) + offsets) * (total / batch_size)
    slots = tree_find(prioritized.sums, jnp.minimum(targets, total))
    leaves = prioritized.sums.shape[0] // 2
    probabilities = prioritized.sums[leaves + slots] / total
    weights = importance_weights(
        probabilities,
        prioritized.mins[1] / total,
        prioritized.buffer.size().astype(jnp.float32),
        beta,
    )
    width = prioritized.buffer.width
    return slots // width, slots % width, weights


def update_priorities(
    prioritized: PrioritizedBuffer,
    rows: jax.Array,
    columns: jax.Array,
    priorities: jax.Array,
    alpha: ArrayLike,
) -> PrioritizedBuffer:
    """New priorities (e.g. ``|td error| + eps``, > 0) of the transitions at ``(rows, columns)``."""
    priorities = priorities.astype(jnp.float32)
    slots = rows * prioritized.buffer.width + columns
    prioritized = _set_priorities(prioritized, slots, priorities**alpha)
    return dataclasses.replace(
        prioritized, max_priority=jnp.maximum(prioritized.max_priority, jnp.max(priorities))
    )


def reset_max_priority(prioritized: PrioritizedBuffer, alpha: ArrayLike) -> PrioritizedBuffer:
    """The priority new transitions get becomes the largest one stored now (instead of the
    largest ever given), as TD7 does at each target update: early large errors, long since
    corrected, no longer make every new transition a favourite. Read from the leaves' p^alpha."""
    powered = jnp.max(prioritized.sums[prioritized.leaves :])
    return dataclasses.replace(prioritized, max_priority=powered ** (1.0 / alpha))


def nbytes(example: object, capacity: int, width: int) -> int:
    """Memory of the transitions and both trees, computed without allocating them."""
    leaves = tree_leaves(replay.rows_for(capacity, width) * width)
    return replay.nbytes(example, capacity, width) + 2 * 2 * leaves * 4 + 4
