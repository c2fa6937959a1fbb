"""Where a run starts: fresh, or from the newest readable checkpoint of a resumed run (damaged
newer ones are set aside once the run is known to start); the run record (``config.json``) each
session writes; and stopping on signals (SIGINT, SIGTERM, SIGUSR1) after the current chunk."""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
import time
from collections.abc import Callable
from types import FrameType
from typing import Any, ClassVar

from flax.typing import ArrayPytree

from rl_jax.errors import RunError
from rl_jax.run import learners
from rl_jax.run.best import BEST_DIR, BestPolicies, policy_fields
from rl_jax.run.checkpoint import Checkpointer, Skipped, set_aside
from rl_jax.run.plan import Plan
from rl_jax.run.run_dir import (
    CHECKPOINT_DIR,
    CONFIG_FILE,
    identity_hash,
    new_run_record,
    read_run_record,
    write_json_atomic,
)
from rl_jax.run.spec import RunSpec
from rl_jax.training import parallel, params

#: The signal that asks to stop and come back: SLURM sends it before the time limit when the job
#: asks (``--signal=USR1@90``); the run then checkpoints and, under SLURM, requeues its job.
REQUEUE_SIGNAL = "SIGUSR1"
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1)

# Checkpoints by default: every 120 s, or further apart where one takes longer than a twentieth
# of the time between them (a large replay buffer to copy and compress), so that checkpoints take
# at most ~5% of a run.
DEFAULT_CHECKPOINT_INTERVAL = 120.0
CHECKPOINT_TIME_SHARE = 0.05


def checkpoint_interval(given: float | None, save_seconds: float) -> float:
    """Least seconds from the end of one checkpoint to the next: ``given`` where set, else the
    default spacing after a checkpoint that took ``save_seconds``."""
    if given is not None:
        return given
    spacing = save_seconds * (1 - CHECKPOINT_TIME_SHARE) / CHECKPOINT_TIME_SHARE
    return max(DEFAULT_CHECKPOINT_INTERVAL, spacing)


class GracefulStop:
    """The first SIGINT, SIGTERM or SIGUSR1 asks to stop after the current chunk; a second
    SIGINT aborts.

    One may be opened inside another (a sweep's around each of its shapes' runs): the inner one
    starts with what the outer one was asked already, and passes on what it is asked itself, so
    that a signal is never forgotten when the inner one closes; between the inner ones, the outer
    one's handler catches the signals."""

    #: the stops open now, innermost last
    _open: ClassVar[list[GracefulStop]] = []

    def __init__(
        self,
        notify: Callable[[str], None] = print,
        when: str = "after this chunk (a checkpoint follows",
    ):
        self._requested: str | None = None
        self._signalled = False  # whether this process was sent a stop signal
        self._notify = notify
        self._when = when
        self._outer: GracefulStop | None = None
        self._previous: dict[int, Any] = {}

    @property
    def requested(self) -> str | None:
        """The signal (or who) that asked to stop, or None."""
        return self._requested

    @requested.setter
    def requested(self, value: str | None) -> None:
        self._requested = value
        if value is not None and self._outer is not None and self._outer.requested is None:
            self._outer.requested = value

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        # Only a signal to this process makes a Ctrl-C the second one: a stop agreed with
        # another process (``relay``) still lets this one finish its chunk and save.
        if self._signalled and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stop: GracefulStop | None = self
        while stop is not None:  # a Ctrl-C after the inner stop closes is a second one too
            stop._signalled, stop = True, stop._outer
        if self.requested is not None:
            return  # asked already (a scheduler may signal a step's processes more than once)
        self.requested = name
        self._notify(f"{name}: stopping {self._when}; Ctrl-C again aborts)")

    def relay(self, who: str) -> None:
        """Say that another process's signal (``who``) stops the run after this chunk."""
        self._notify(f"{who}: stopping {self._when})")

    def __enter__(self) -> GracefulStop:
        if GracefulStop._open:
            self._outer = GracefulStop._open[-1]
            self._requested = self._outer.requested
            self._signalled = self._outer._signalled
        GracefulStop._open.append(self)
        for signum in STOP_SIGNALS:
            # Outside the main thread signals cannot be caught: they stay with the caller.
            with contextlib.suppress(ValueError):
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc_info: object) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()
        GracefulStop._open.remove(self)


@dataclasses.dataclass
class Start:
    state: ArrayPytree
    chunk: int  # first chunk to run
    step: int  # env steps per seed already done
    updates: int
    wall_clock: float  # seconds spent by earlier sessions
    checkpoint_step: int | None  # the checkpoint restored, if any
    best: BestPolicies  # the best evaluated policy of every run so far
    # Newer checkpoints that could not be restored (newest first): set aside before the run
    # writes anything else (``set_aside_damaged``).
    skipped: tuple[Skipped, ...] = ()


def checkpoint_expectation(spec: RunSpec) -> dict[str, Any]:
    return {
        "identity_hash": identity_hash(spec.identity),
        "algorithm": spec.algorithm.name,
        "env_id": spec.env_id,
    }


def checkpoint_accepts(spec: RunSpec) -> dict[str, Any]:
    """What a checkpoint of this resumed run must carry: ``checkpoint_expectation``, except that
    the identity hash may also be the one the run was created with (its record's
    ``identity_hash``). A run written before a config field was added lacks that field
    (``run_dir.with_newer_fields`` fills it with its default), and so do the hashes of the
    checkpoints saved then."""
    expect = checkpoint_expectation(spec)
    created = read_run_record(spec.out).get("identity_hash", expect["identity_hash"])
    expect["identity_hash"] = frozenset({expect["identity_hash"], created})
    return expect


def restore_start(spec: RunSpec, plan: Plan) -> Start | None:
    """The newest readable checkpoint of a resumed run (None if it has none yet), with the newer
    damaged ones it passed over. Writes nothing."""
    directory = spec.out / CHECKPOINT_DIR
    if not directory.is_dir():
        return None
    with Checkpointer(directory, read_only=True) as checkpointer:
        if checkpointer.latest_step() is None:
            return None
        state, meta, skipped = checkpointer.restore_newest_readable(
            plan.template, expect=checkpoint_accepts(spec)
        )
    best = BestPolicies.restore(
        spec.out / BEST_DIR,
        policy_fields(spec.algorithm, plan.template),
        plan.template,
        at_most=meta["step"],
        expect=checkpoint_accepts(spec),
    )
    return Start(
        plan.program.place(state, params.stack(list(spec.hparams))),
        meta["chunk"] + 1,
        meta["step"],
        meta.get("updates", 0),
        meta.get("wall_clock", 0.0),
        meta["step"],
        best,
        tuple(skipped),
    )


def set_aside_damaged(spec: RunSpec, start: Start) -> list[dict[str, Any]]:
    """Rename each checkpoint ``start`` passed over to ``damaged-<step>-<time>`` (kept, never
    deleted) and say so in one line on stderr per checkpoint; returns what was moved where, for
    the run record. Called once every check has passed, as the run's first write: a resume that
    is refused moves nothing."""
    directory = spec.out / CHECKPOINT_DIR
    moved = []
    for skipped in start.skipped:
        try:
            kept = set_aside(directory, skipped.step)
        except OSError as error:
            reason = error.strerror or type(error).__name__
            raise RunError(
                f"checkpoint step {skipped.step} in {directory} {skipped.problem}, and it cannot "
                f"be set aside to resume from step {start.step:,}: {reason}"
            ) from None
        print(
            f"warning: checkpoint step {skipped.step} {skipped.problem}; resuming from step "
            f"{start.step:,} instead, the damaged one is kept as {kept}",
            file=sys.stderr,
            flush=True,
        )
        moved.append({"step": skipped.step, "problem": skipped.problem, "kept_as": kept.name})
    return moved


def fresh_start(spec: RunSpec, plan: Plan) -> Start:
    keys = parallel.seed_keys(spec.seed_numbers)
    state = plan.program.init(keys, params.stack(list(spec.hparams)))
    # the fields from the runs' template: a split program's device state is a tuple of blocks
    best = BestPolicies(
        policy_fields(spec.algorithm, plan.template), (len(spec.hparams), spec.seeds)
    )
    return Start(state, 0, 0, 0, 0.0, None, best)


def write_run_record(
    spec: RunSpec, plan: Plan, start: Start, damaged: list[dict[str, Any]] | None = None
) -> None:
    """config.json: created on a fresh run, updated (total steps, sessions) on a resume. A
    session records the ``damaged`` checkpoints it set aside, if any."""
    path = spec.out / CONFIG_FILE
    session = {
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "command": spec.command,
        "from_step": start.step,
    }
    if damaged:
        session["damaged_checkpoints"] = damaged
    if spec.resume:
        record = read_run_record(spec.out)
        record["total_steps"] = spec.total_steps
        record["sessions"] = [*record.get("sessions", []), session]
    else:
        extra = {
            "total_steps": spec.total_steps,
            "steps_per_chunk": plan.steps_per_chunk,
            "grid_fields": list(spec.grid_fields),
            "command": spec.command,
            "sessions": [session],
        }
        learner = learners.record_fields(spec.algorithm)  # where it came from (learners.py)
        module = learner.pop("algorithm_module")
        record = new_run_record(spec.identity, module, {**learner, **extra})
    write_json_atomic(path, record)
