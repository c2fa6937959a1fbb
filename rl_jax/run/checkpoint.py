"""Checkpoints of a whole train state (every seed and config) with orbax, plus JSON metadata.

A checkpoint is one orbax step directory holding two items: ``arrays`` (every array leaf of the
state, keyed by its position in the flattened tree) and ``meta`` (a JSON dict: the step, whatever
the caller adds — config hash, algorithm, env id — the library versions, and one record per
leaf, ``rl_jax.run.checkpoint_leaves``). The record is what lets us work around orbax's quirks:

* zero-size arrays cannot be saved (google/orbax#2587): they are kept as a shape/dtype record and
  rebuilt as zeros;
* typed PRNG keys are saved as their key data and re-wrapped with the recorded implementation;
* non-array leaves (Python scalars, strings) go into the JSON;
* restore would silently cast to the template's dtype: we compare shapes and dtypes ourselves and
  refuse a mismatch instead;
* ``save(step)`` silently skips a step that is not newer than the latest: we raise instead.

orbax writes each step into a temporary directory and renames it when complete, so a crash during
a write leaves the previous checkpoints intact; leftover temporary directories are ignored when
reading and removed (synchronously) when a writable ``Checkpointer`` opens the directory.

A checkpoint damaged later (files overwritten, truncated or missing, a state that no longer fits)
is a ``DamagedCheckpointError``. ``restore_newest_readable`` then falls back to the next older
one, and ``set_aside`` renames a damaged step directory to ``damaged-<step>-<time>``, which orbax
no longer lists, so nothing is deleted and the step can be saved again.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from importlib.metadata import version
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import flax
import jax
import jaxlib
import numpy as np
import optax

import rl_jax
from rl_jax.errors import CheckpointError
from rl_jax.run.checkpoint_leaves import (
    first_mismatch,
    leaf_name,
    rebuild_leaf,
    split_state,
    template_records,
)

#: a pytree restored into the structure of its template
Tree = TypeVar("Tree")

_TMP_MARKER = ".orbax-checkpoint-tmp"
#: Name prefix of a damaged step directory set aside (``damaged-<step>-<time>``).
DAMAGED_PREFIX = "damaged-"


class DamagedCheckpointError(CheckpointError):
    """A checkpoint that cannot be restored: unreadable or damaged files, or a state that does not
    fit this run's. Unlike a checkpoint of another run, an older checkpoint may stand in for it.
    ``problem`` says what is wrong (``is unreadable (...)``), after ``checkpoint step N in DIR``.
    """

    def __init__(self, message: str, step: int, problem: str):
        super().__init__(message)
        self.step = step
        self.problem = problem


class Skipped(NamedTuple):
    """A damaged checkpoint that ``restore_newest_readable`` passed over."""

    step: int
    problem: str  # what ``DamagedCheckpointError.problem`` says


def library_versions() -> dict[str, str]:
    """Versions of the libraries a checkpoint's content depends on."""
    return {
        "rl_jax": rl_jax.__version__,
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        # from the package's metadata: importing orbax to ask is left to the first checkpoint
        "orbax-checkpoint": version("orbax-checkpoint"),
        "numpy": np.__version__,
    }


# ---- the checkpointer -----------------------------------------------------------------------


class Checkpointer:
    """Save and restore a train state pytree in ``directory``, keeping the ``keep`` latest steps.

    ``read_only=True`` opens an existing directory without creating or cleaning anything (used
    to validate a ``--resume`` before touching the run).
    """

    def __init__(self, directory: str | Path, keep: int = 3, read_only: bool = False):
        self.directory = Path(directory).absolute()
        if read_only and not self.directory.is_dir():
            raise CheckpointError(f"no checkpoint directory at {self.directory}")
        # orbax reports routine decisions as absl warnings; a user only needs our errors.
        logging.getLogger("absl").setLevel(logging.ERROR)
        import orbax.checkpoint as ocp  # heavy: imported on first use

        self._ocp = ocp
        if not read_only:
            # orbax's own clean-up runs in a background thread and races with the next save.
            _remove_leftover_temporaries(self.directory)
        multiprocess = {}
        if jax.process_count() > 1:
            # Each process reads and writes on its own: under jax.distributed only the lead
            # writes (rl_jax.run.processes), so orbax must not wait for the others. (orbax then
            # leaves creating the directory to us.)
            me = _orbax_multihost().process_index()  # 0 within ``writing_alone``
            multiprocess["multiprocessing_options"] = ocp.options.MultiprocessingOptions(
                primary_host=me, active_processes={me}
            )
            if not read_only:
                self.directory.mkdir(parents=True, exist_ok=True)
        options = ocp.CheckpointManagerOptions(
            preservation_policy=ocp.checkpoint_managers.LatestN(n=max(1, keep)),
            enable_async_checkpointing=False,
            create=not read_only and not multiprocess,
            read_only=read_only,
            **multiprocess,
        )
        with _quiet_orbax():  # it lists the steps
            self._manager = ocp.CheckpointManager(
                self.directory, options=options, item_names=("arrays", "meta")
            )

    def steps(self) -> list[int]:
        """Completed checkpoints, oldest first."""
        with _quiet_orbax():
            self._manager.reload()
            return sorted(self._manager.all_steps())

    def latest_step(self) -> int | None:
        """The newest saved step, or None when nothing is saved yet."""
        steps = self.steps()
        return steps[-1] if steps else None

    def discard_after(self, step: int) -> list[int]:
        """Delete the checkpoints newer than ``step`` (left by a session that crashed between
        two related saves); returns the steps deleted."""
        newer = [s for s in self.steps() if s > step]
        for s in newer:
            self._manager.delete(s)
        return newer

    def save(self, step: int, state: object, metadata: dict[str, Any] | None = None) -> None:
        """Write ``state`` as checkpoint ``step`` (must be newer than the latest)."""
        latest = self.latest_step()
        if latest is not None and step <= latest:
            raise CheckpointError(
                f"cannot save checkpoint step {step}: {self.directory} already holds step {latest}"
            )
        arrays, records = split_state(state)
        meta = {
            **(metadata or {}),
            "step": int(step),
            "versions": library_versions(),
            "leaves": records,
        }
        args = self._ocp.args.Composite(
            arrays=self._ocp.args.StandardSave(arrays), meta=self._ocp.args.JsonSave(meta)
        )
        if not self._manager.save(int(step), args=args, force=True):
            raise CheckpointError(f"orbax declined to save checkpoint step {step}")
        self._manager.wait_until_finished()

    def metadata(self, step: int | None = None) -> dict[str, Any]:
        """The JSON metadata of ``step`` (default: the latest)."""
        step = self._resolve_step(step)
        try:
            with _quiet_orbax():
                restored = self._manager.restore(
                    step, args=self._ocp.args.Composite(meta=self._ocp.args.JsonRestore())
                )
            meta = restored["meta"]
        except Exception as error:  # orbax raises many types for damaged files
            raise self._unreadable(step, error) from None
        if not isinstance(meta, dict) or not isinstance(meta.get("leaves"), list):
            raise self._unreadable(step, ValueError("metadata has no leaf records"))
        return meta

    def restore(
        self,
        template: Tree,
        step: int | None = None,
        expect: dict[str, Any] | None = None,
        sharding: jax.sharding.Sharding | None = None,
    ) -> tuple[Tree, dict[str, Any]]:
        """Restore ``step`` (default: latest) into the structure of ``template``.

        ``template`` is a pytree of arrays or ``jax.ShapeDtypeStruct`` with the run's exact
        shapes and dtypes (``jax.eval_shape`` of the init). ``expect`` holds metadata entries
        that must match (e.g. the config hash). ``sharding`` places every restored array.
        Returns ``(state, metadata)``; raises ``CheckpointError`` on any mismatch or damage.
        """
        step = self._resolve_step(step)
        meta = self.metadata(step)
        self._check_expected(step, meta, expect or {})
        mismatch = first_mismatch(meta["leaves"], template_records(template))
        if mismatch:
            problem = f"does not match this run: {mismatch}"
            raise DamagedCheckpointError(
                f"checkpoint step {step} in {self.directory} {problem}", step, problem
            )
        arrays = self._restore_arrays(step, meta["leaves"], sharding)
        leaves = [
            rebuild_leaf(record, arrays, index, sharding)
            for index, record in enumerate(meta["leaves"])
        ]
        treedef = jax.tree_util.tree_structure(template)
        return jax.tree_util.tree_unflatten(treedef, leaves), meta

    def _restore_arrays(
        self, step: int, records: list[dict], sharding: jax.sharding.Sharding | None
    ) -> dict[str, jax.Array]:
        if sharding is None:
            sharding = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
        targets = {
            leaf_name(index): jax.ShapeDtypeStruct(
                tuple(record["shape"]), np.dtype(record["dtype"]), sharding=sharding
            )
            for index, record in enumerate(records)
            if record["kind"] in ("array", "key")
        }
        if not targets:
            return {}
        _ignore_closed_loop_reports()  # before: some reports come while the read fails
        try:
            args = self._ocp.args.Composite(arrays=self._ocp.args.StandardRestore(targets))
            with _quiet_orbax():
                return dict(self._manager.restore(step, args=args)["arrays"])
        except Exception as error:
            raise self._unreadable(step, error) from None

    def restore_newest_readable(
        self,
        template: Tree,
        expect: dict[str, Any] | None = None,
        sharding: jax.sharding.Sharding | None = None,
    ) -> tuple[Tree, dict[str, Any], list[Skipped]]:
        """``restore`` of the newest checkpoint that can be restored, with the newer ones that
        cannot (damaged: ``Skipped``, newest first). A checkpoint of another run (``expect``) is
        refused at once, never passed over: it is no damage, and an older one would not be this
        run's either. If none can be restored, a ``DamagedCheckpointError`` names the newest and
        how many older ones failed too. Writes nothing: see ``set_aside``."""
        skipped: list[Skipped] = []
        for step in reversed(self.steps()):
            try:
                state, meta = self.restore(template, step, expect, sharding)
            except DamagedCheckpointError as error:
                skipped.append(Skipped(step, error.problem))
                continue
            return state, meta, skipped
        if not skipped:
            raise CheckpointError(f"no checkpoint in {self.directory}")
        newest, older = skipped[0], [str(s.step) for s in skipped[1:]]
        tail = (
            f"; the older checkpoints ({', '.join(older)}) cannot be restored either"
            if older
            else "; there is no older checkpoint to resume from"
        )
        message = f"checkpoint step {newest.step} in {self.directory} {newest.problem}{tail}"
        raise DamagedCheckpointError(message, newest.step, newest.problem)

    def _check_expected(self, step: int, meta: dict, expect: dict[str, Any]) -> None:
        """Each ``expect`` value must match; a ``frozenset`` value lists the accepted ones."""
        for key, value in expect.items():
            accepted = value if isinstance(value, frozenset) else frozenset([value])
            if meta.get(key) not in accepted:
                wanted = " or ".join(repr(v) for v in sorted(accepted, key=str))
                raise CheckpointError(
                    f"checkpoint step {step} in {self.directory} is from another run: "
                    f"its {key} is {meta.get(key)!r}, this run's is {wanted}"
                )

    def _resolve_step(self, step: int | None) -> int:
        steps = self.steps()
        if step is None:
            if not steps:
                raise CheckpointError(f"no checkpoint in {self.directory}")
            return steps[-1]
        if step not in steps:
            raise CheckpointError(f"no checkpoint step {step} in {self.directory} (has {steps})")
        return step

    def _unreadable(self, step: int, error: BaseException) -> DamagedCheckpointError:
        reason = (str(error).strip().splitlines() or [type(error).__name__])[0]
        reason = reason if len(reason) <= 160 else reason[:160] + "..."
        problem = f"is unreadable ({reason})"
        older = [s for s in self.steps() if s < step]
        # For the tools that read the latest checkpoint (render, evaluate, load_policy): a
        # resume repairs the run without anyone deleting anything.
        hint = (
            f"; older checkpoints: {older} (--resume continues from the newest readable one)"
            if older
            else ""
        )
        message = f"checkpoint step {step} in {self.directory} {problem}{hint}"
        return DamagedCheckpointError(message, step, problem)

    def close(self) -> None:
        """Wait for pending writes and release the checkpoint manager."""
        self._manager.close()

    def __enter__(self) -> Checkpointer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def _orbax_multihost() -> Any:
    # orbax's private module (no public handle on the process index it writes as), imported
    # only where a process writes alone, so that a change to it fails there and nowhere else
    from orbax.checkpoint._src.multihost import multihost

    return multihost


@contextlib.contextmanager
def writing_alone() -> Iterator[None]:
    """Within: this process writes and reads the checkpoints of runs of its own (a sweep's
    shape, ``rl_jax.run.processes.alone``) as the process 0 of a job of one, whatever its index
    under ``jax.distributed``. orbax writes arrays and JSON only from the process it takes for
    process 0 (its handlers test ``multihost.process_index() == 0``): process 1 would otherwise
    save checkpoints without their data. Nothing changes on process 0."""
    if jax.process_index() == 0:
        yield
        return
    multihost = _orbax_multihost()
    original = multihost.process_index
    multihost.process_index = lambda: 0
    try:
        yield
    finally:
        multihost.process_index = original


@contextlib.contextmanager
def _quiet_orbax() -> Iterator[None]:
    """orbax logs an absl ERROR for each damaged file it meets while listing or reading steps
    ("Failed to read Metadata file ..."): lines on stderr beside the one we report, which says
    the same. Silence them while it reads."""
    logger = logging.getLogger("absl")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(level)


class _ClosedLoopFilter:
    """An unraisable hook that drops ``RuntimeError('Event loop is closed')`` reports and
    hands every other report to the hook installed before it."""

    def __init__(self, previous: Callable[[sys.UnraisableHookArgs], object]) -> None:
        self.previous = previous

    def __call__(self, unraisable: sys.UnraisableHookArgs) -> None:
        error = unraisable.exc_value
        if isinstance(error, RuntimeError) and str(error) == "Event loop is closed":
            return
        self.previous(unraisable)


def _ignore_closed_loop_reports() -> None:
    """When a read fails, orbax closes its event loop while tensorstore callbacks of the other
    reads are pending; each then reports an unraisable ``RuntimeError('Event loop is closed')``
    on stderr, during the failure and after it. They say nothing beyond the error we raise:
    drop just those reports."""
    if not isinstance(sys.unraisablehook, _ClosedLoopFilter):
        sys.unraisablehook = _ClosedLoopFilter(sys.unraisablehook)


def set_aside(directory: str | Path, step: int) -> Path:
    """Rename checkpoint ``step`` of ``directory`` to ``damaged-<step>-<time>`` beside it and
    return the new path. Kept, never deleted: a damaged checkpoint may still be worth a look.
    orbax lists only directories named by a bare integer (or ending in ``_<integer>``, hence the
    hyphens), so it neither restores nor prunes the renamed one, and the step number is free: a
    resumed run saves that step again (orbax would skip a step that is not newer than the latest
    one it lists)."""
    directory = Path(directory)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    target = directory / f"{DAMAGED_PREFIX}{step}-{stamp}"
    suffix = 1
    while target.exists():  # set aside twice within a second
        suffix += 1
        target = directory / f"{DAMAGED_PREFIX}{step}-{stamp}-{suffix}"
    os.rename(directory / str(step), target)
    return target


def leftover_temporaries(directory: str | Path) -> list[Path]:
    """Unfinished step directories (a write was interrupted)."""
    directory = Path(directory)
    return sorted(p for p in directory.glob(f"*{_TMP_MARKER}*")) if directory.is_dir() else []


def _remove_leftover_temporaries(directory: str | Path) -> None:
    for path in leftover_temporaries(directory):
        shutil.rmtree(path, ignore_errors=True)
