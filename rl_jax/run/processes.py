"""One run across the processes of ``jax.distributed``: every process computes its devices' share
of the runs and takes part in each gather, and the lead (process 0) alone writes the run
directory and speaks to the terminal.

Every decision that starts a collective (saving a checkpoint gathers the state) must be the same
in every process, or they wait on each other forever. Such decisions are taken from the clocks
and signals of all processes by ``agree``; everything else the processes decide from gathered
metrics, which are equal everywhere. On one process these are no-ops.

Every wait for the other processes runs under ``waiting``: past the limit that
``rl_jax.run.distributed`` sets (``--collective-timeout``), the process ends with one line
rather than hang on a peer that stopped.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import jax
import numpy as np
from jax.experimental import multihost_utils

_WAIT_LIMIT: list[float] = []  # seconds; empty: no limit (one process, or set by no one)


def count() -> int:
    """Number of processes in the ``jax.distributed`` job (1 when not distributed)."""
    return jax.process_count()


def is_lead() -> bool:
    """Whether this process writes the run directory (always so without ``jax.distributed``)."""
    return jax.process_index() == 0


def set_wait_limit(seconds: float) -> None:
    """The longest ``waiting`` waits for the other processes from now on."""
    _WAIT_LIMIT[:] = [seconds]


@contextlib.contextmanager
def waiting(what: str) -> Iterator[None]:
    """A wait for the other processes at ``what``: one line and exit status 1 past the limit
    (nothing on one process)."""
    if count() == 1 or not _WAIT_LIMIT:
        yield
        return
    from rl_jax.run.distributed import Watchdog

    limit = _WAIT_LIMIT[0]
    message = (
        f"process {jax.process_index()} waited over {limit:g} s for the other processes at "
        f"{what}: one of them stopped or hangs; stopping (the latest checkpoint is kept; "
        "--collective-timeout sets the limit)"
    )
    with Watchdog(limit, lambda: message):
        yield


def agree(*flags: bool) -> tuple[bool, ...]:
    """Each flag ORed over all processes (one small gather; the flags as they are on one)."""
    if count() == 1:
        return tuple(bool(flag) for flag in flags)

    local = np.asarray(flags, dtype=np.int32)
    with waiting("the end of a chunk"):
        gathered = np.asarray(multihost_utils.process_allgather(local))
    return tuple(bool(value) for value in gathered.reshape(-1, len(flags)).max(axis=0))


def barrier(name: str) -> None:
    """Wait until every process reaches ``name`` (nothing on one process)."""
    if count() > 1:
        with waiting(name):
            multihost_utils.sync_global_devices(name)
