"""The best evaluated policy of every run, kept next to the latest checkpoint.

A learner's last policy is not always its best: DQN on CartPole reaches 500 and can then fall
away. After every chunk the runner compares each (config, seed)'s eval return with the best so
far and, where it improved, keeps a host copy of that run's *policy part* of the train state:
the fields ``algorithm.policy`` reads (``algorithm.policy_fields``, default ``("agent",)``). That
is parameters and optimizer state, not the replay buffer, so it costs little to keep.

On disk it is an ordinary checkpoint in ``RUN_DIR/best/``, written at the same step as (and just
before) each checkpoint of ``RUN_DIR/checkpoints/``, with the per-run best returns and steps in
its metadata. A resume restores the best from the step of the checkpoint it resumes, so a run
that stopped and resumed keeps the same best as one that never stopped.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import jax
import numpy as np

from rl_jax.run.checkpoint import Checkpointer, DamagedCheckpointError
from rl_jax.training.algorithm import Algorithm, HoldsAgent, TrainState, hooks

BEST_DIR = "best"


def policy_fields(algorithm: Algorithm, state: TrainState) -> tuple[str, ...]:
    """The train-state fields the deterministic policy reads (empty: no best tracking)."""
    fields = hooks(algorithm).policy_fields
    if fields is None:
        fields = ("agent",) if isinstance(state, HoldsAgent) else ()
    return tuple(fields)


def policy_part(state: TrainState, fields: tuple[str, ...]) -> dict[str, object]:
    """The fields of the train state the policy reads, by name."""
    return {name: getattr(state, name) for name in fields}


def with_policy_part(state: TrainState, part: dict[str, object]) -> TrainState:
    """``state`` with the fields of ``part`` replaced (NamedTuple or dataclass states)."""
    if isinstance(state, _NamedTuple):
        return state._replace(**part)
    assert not isinstance(state, tuple)  # a NamedTuple has _replace
    return dataclasses.replace(state, **part)


@runtime_checkable
class _NamedTuple(Protocol):
    """A NamedTuple state: fields replaced by ``_replace``."""

    def _replace(self, **fields: object) -> TrainState: ...


class BestPolicies:
    """Per run of an ``[H, S]`` program: the best eval return, its step and its policy part."""

    def __init__(self, fields: tuple[str, ...], runs: tuple[int, int]):
        self.fields = fields
        self.returns = np.full(runs, -np.inf)
        self.steps = np.full(runs, -1, dtype=np.int64)
        self.part: dict[str, object] | None = None  # host arrays with leading [H, S]
        self.changed = False  # since the last save

    @property
    def enabled(self) -> bool:
        """Whether the learner names policy fields, so that best policies are tracked at all."""
        return bool(self.fields)

    def observe(
        self,
        eval_return: np.ndarray,
        env_steps: np.ndarray,
        fetch: Callable[[], dict[str, object]],
    ) -> np.ndarray:
        """Take the runs whose finite eval return beats their best; ``fetch()`` gives the
        ``[H, S]`` host copy of the policy part, called only when one improved. Returns the
        ``[H, S]`` mask of improved runs."""
        eval_return = np.asarray(eval_return, np.float64)
        improved = np.isfinite(eval_return) & (eval_return > self.returns)
        if not self.enabled or not improved.any():
            return improved
        current = jax.tree.map(np.asarray, fetch())
        if self.part is None:
            self.part = jax.tree.map(np.copy, current)
        else:
            self.part = jax.tree.map(
                lambda old, new: np.where(_expand(improved, old.ndim), new, old),
                self.part,
                current,
            )
        self.returns = np.where(improved, eval_return, self.returns)
        self.steps = np.where(improved, np.asarray(env_steps, np.int64), self.steps)
        self.changed = True
        return improved

    def metadata(self) -> dict[str, Any]:
        """Best eval return and its env step per run, as JSON-ready nested lists ``[H][S]``."""
        return {
            "best_returns": [[_json_float(r) for r in row] for row in self.returns.tolist()],
            "best_steps": self.steps.tolist(),
        }

    def save(self, checkpointer: Checkpointer, step: int, meta: dict[str, Any]) -> None:
        """Write the best policies as checkpoint ``step`` (if there are any yet)."""
        if self.part is None:
            return
        checkpointer.save(step, self.part, {**meta, **self.metadata()})
        self.changed = False

    @classmethod
    def restore(
        cls,
        directory: Path,
        fields: tuple[str, ...],
        template: TrainState,
        at_most: int,
        expect: dict[str, Any],
    ) -> BestPolicies:
        """The best policies saved at the latest readable step <= ``at_most`` (none: a fresh
        tracker). ``template``: the ``[H, S]`` abstract train state. A damaged one is passed over
        with one line on stderr, never stopping the resume: the best policies are a record of
        the run, not its state, so the resume goes on from an older record, or a fresh one."""
        best = cls(fields, _runs(template, fields))
        if not best.enabled or not Path(directory).is_dir():
            return best
        with Checkpointer(directory, read_only=True) as checkpointer:
            for step in reversed([s for s in checkpointer.steps() if s <= at_most]):
                try:
                    part, meta = checkpointer.restore(
                        policy_part(template, fields), step=step, expect=expect
                    )
                except DamagedCheckpointError as error:
                    print(
                        f"warning: the best policies' checkpoint step {step} {error.problem}; "
                        "passed over",
                        file=sys.stderr,
                        flush=True,
                    )
                    continue
                break
            else:
                return best
        best.part = jax.tree.map(np.asarray, part)
        best.returns = np.array(
            [[-np.inf if r is None else r for r in row] for row in meta["best_returns"]]
        )
        best.steps = np.array(meta["best_steps"], dtype=np.int64)
        return best


def load_part(
    directory: Path, fields: tuple[str, ...], template: TrainState, expect: dict[str, Any]
) -> tuple[dict[str, object], dict[str, Any]] | None:
    """``(part, metadata)`` of the latest best-policy checkpoint, or None if there is none."""
    if not Path(directory).is_dir():
        return None
    with Checkpointer(directory, read_only=True) as checkpointer:
        if checkpointer.latest_step() is None:
            return None
        return checkpointer.restore(policy_part(template, fields), expect=expect)


def _runs(template: TrainState, fields: tuple[str, ...]) -> tuple[int, int]:
    leaves = jax.tree.leaves(policy_part(template, fields))
    return tuple(leaves[0].shape[:2]) if leaves else (0, 0)


def _expand(mask: np.ndarray, ndim: int) -> np.ndarray:
    return mask.reshape(mask.shape + (1,) * (ndim - mask.ndim))


def _json_float(value: float) -> float | None:
    return value if math.isfinite(value) else None
