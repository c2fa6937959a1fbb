"""One run across the processes of ``jax.distributed``: every process computes its devices' share
of the runs and takes part in each gather, and the lead (process 0) alone writes the run
directory and speaks to the terminal.

Every decision that starts a collective (saving a checkpoint gathers the state) must be the same
in every process, or they wait on each other forever. Such decisions are taken from the clocks
and signals of all processes by ``agree``; everything else the processes decide from gathered
metrics, which are equal everywhere. On one process these are no-ops.
"""

from __future__ import annotations

import jax
import numpy as np
from jax.experimental import multihost_utils


def count() -> int:
    """Number of processes in the ``jax.distributed`` job (1 when not distributed)."""
    return jax.process_count()


def is_lead() -> bool:
    """Whether this process writes the run directory (always so without ``jax.distributed``)."""
    return jax.process_index() == 0


def agree(*flags: bool) -> tuple[bool, ...]:
    """Each flag ORed over all processes (one small gather; the flags as they are on one)."""
    if count() == 1:
        return tuple(bool(flag) for flag in flags)

    local = np.asarray(flags, dtype=np.int32)
    gathered = np.asarray(multihost_utils.process_allgather(local))
    return tuple(bool(value) for value in gathered.reshape(-1, len(flags)).max(axis=0))


def barrier(name: str) -> None:
    """Wait until every process reaches ``name`` (nothing on one process)."""
    if count() > 1:
        multihost_utils.sync_global_devices(name)
