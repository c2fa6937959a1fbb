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

A process may also run a run of its own, on its local devices only (``alone``: a sweep gives
each process shapes of its own). Within ``alone`` it writes that run's directory itself, takes
no part in other processes' collectives and decides alone; only process 0 still prints.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Callable, Iterator

import jax
import numpy as np
from jax.experimental import multihost_utils

_WAIT_LIMIT: list[float] = []  # seconds; empty: no limit (one process, or set by no one)
_alone = [False]  # inside ``alone()``: this process runs a run of its own
_last_agreed: list[np.ndarray] = []  # the flags of every process at the last ``agree``

#: The longest ``wait_for_all`` waits for the slowest process: one of a sweep's shapes may train
#: for days. A process that dies ends the wait sooner (the coordinator misses its heartbeats).
LONGEST_WAIT_MS = 2**31 - 1


@contextlib.contextmanager
def alone() -> Iterator[None]:
    """Within: this process runs its runs by itself, as if it were the only process (its local
    devices, its own writes and decisions, no collectives)."""
    previous, _alone[0] = _alone[0], True
    try:
        yield
    finally:
        _alone[0] = previous


def is_alone() -> bool:
    """Whether this process is within ``alone``."""
    return _alone[0]


def count() -> int:
    """Number of processes in the ``jax.distributed`` job (1 when not distributed, or inside
    ``alone``)."""
    return 1 if _alone[0] else jax.process_count()


def is_lead() -> bool:
    """Whether this process writes the run directory (always so without ``jax.distributed``, and
    within ``alone``)."""
    return _alone[0] or jax.process_index() == 0


def speaks() -> bool:
    """Whether this process prints: process 0 alone, whatever it runs."""
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
    limit = _WAIT_LIMIT[0]
    message = (
        f"process {jax.process_index()} waited over {limit:g} s for the other processes at "
        f"{what}: one of them stopped or hangs; stopping (the latest checkpoint is kept; "
        "--collective-timeout sets the limit)"
    )
    with Watchdog(limit, lambda: message):
        yield


class Watchdog:
    """A time limit on native code that waits for other processes: after ``seconds`` inside the
    ``with``, ``message()`` as one error line and exit status 1 (a process stuck there could only
    end by aborting)."""

    def __init__(self, seconds: float, message: Callable[[], str]) -> None:
        self._timer = threading.Timer(seconds, self._fire)
        self._timer.daemon = True
        self._message = message

    def _fire(self) -> None:
        give_up(self._message())

    def __enter__(self) -> Watchdog:
        self._timer.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._timer.cancel()


def give_up(message: str) -> None:
    """One error line, then exit status 1 at once (no clean-up: another process is gone, and
    jax's own shutdown would wait for it)."""
    sys.stdout.flush()
    print(f"error: {message}", file=sys.stderr, flush=True)
    os._exit(1)


def devices() -> list[jax.Device]:
    """The devices a run spreads over: every process's, or this process's own within
    ``alone``."""
    return jax.local_devices() if _alone[0] else jax.devices()


def agree(*flags: bool, at: str = "the end of a chunk") -> tuple[bool, ...]:
    """Each flag ORed over all processes (one small gather; the flags as they are on one); ``at``
    names the place in the run for the line of a wait past its limit."""
    if count() == 1:
        return tuple(bool(flag) for flag in flags)

    local = np.asarray(flags, dtype=np.int32)
    with waiting(at):
        gathered = np.asarray(multihost_utils.process_allgather(local))
    _last_agreed[:] = [gathered.reshape(-1, len(flags))]
    return tuple(bool(value) for value in _last_agreed[0].max(axis=0))


def raised_by(index: int) -> list[int]:
    """The processes whose flag ``index`` was set at the last ``agree`` (none on one process)."""
    if not _last_agreed:
        return []
    return [int(rank) for rank in np.flatnonzero(_last_agreed[0][:, index])]


def stopped_by(asked: int, requeue: int) -> str:
    """Who asked the last ``agree`` to stop, for the lead's line: the processes whose flag
    ``asked`` was set, and SIGUSR1 where flag ``requeue`` was (SIGTERM or Ctrl-C otherwise:
    the flags do not say which)."""
    ranks = raised_by(asked)
    which = "SIGUSR1" if raised_by(requeue) else "SIGTERM or SIGINT"
    named = ", ".join(str(rank) for rank in ranks) or "another process"
    return f"{which} on process{'es' if len(ranks) > 1 else ''} {named}"


def barrier(name: str) -> None:
    """Wait until every process reaches ``name`` (nothing on one process)."""
    if count() > 1:
        with waiting(name):
            multihost_utils.sync_global_devices(name)


def wait_for_all(name: str) -> None:
    """Wait until every process reaches ``name``, however long the slowest takes (each process
    of a sweep trains shapes of its own, of different lengths): at the coordinator of
    ``jax.distributed``, with a time limit of our own, rather than in a collective over the
    devices. Nothing on one process."""
    if jax.process_count() == 1:
        return
    from jax._src import distributed  # the coordinator's client: no public handle in jax 0.9

    client = distributed.global_state.client
    if client is None:
        multihost_utils.sync_global_devices(name)
        return
    client.wait_at_barrier(name, LONGEST_WAIT_MS)
