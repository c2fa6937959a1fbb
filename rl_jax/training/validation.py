"""Valid ranges of the hyperparameters and config counts, checked before anything compiles.

One table by field name serves every learner (the names mean the same thing wherever they
appear); an algorithm may refine it with a ``ranges`` attribute (``{name: Range}``). A value out
of range is refused with one line naming the flag and its range, e.g.
``--gamma must be in [0, 1], got 2``.

Some limits depend on another field: the replay buffer must hold a batch and the random warm-up
(``buffer_too_small``, which asks the learner's hooks for all three); ``check_ranges`` reports
them after the config's own ranges.

``check_ranges`` applies the table to a run's config and every hyperparameter config of a grid;
``runner.prepare`` calls it, so scripts, ``--grid`` sweeps and the Python API are all checked
before anything is written or compiled.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from rl_jax.errors import RunError
from rl_jax.training.algorithm import Algorithm, hooks

if TYPE_CHECKING:
    from _typeshed import DataclassInstance


class RangeError(RunError):
    """A hyperparameter or config value outside its valid range (bad input, one line)."""


class Range(NamedTuple):
    """An allowed interval of a setting, closed or open at either end, for one-line error
    messages.
    """

    low: float
    high: float = math.inf
    low_open: bool = False  # True: low itself is not allowed
    high_open: bool = False

    def holds(self, value: float) -> bool:
        """Whether ``value`` lies inside the interval."""
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def __str__(self) -> str:
        if self.high == math.inf:
            return f"{'>' if self.low_open else '>='} {_number(self.low)}"
        left, right = "(" if self.low_open else "[", ")" if self.high_open else "]"
        return f"in {left}{_number(self.low)}, {_number(self.high)}{right}"


UNIT = Range(0.0, 1.0)
POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
AT_LEAST_ONE = Range(1.0)

#: Field name -> range, for names that are the same everywhere.
BY_NAME: dict[str, Range] = {
    "gamma": UNIT,
    "tau": Range(0.0, 1.0, low_open=True),
    "exploration_correlation": Range(0.0, 1.0, high_open=True),
    "epsilon_start": UNIT,
    "epsilon_end": UNIT,
    "priority_alpha": UNIT,
    "priority_beta_start": UNIT,
    "priority_eps": POSITIVE,
    "huber_delta": POSITIVE,
    "initial_std": POSITIVE,
    # Config counts that must be at least one.
    "num_envs": AT_LEAST_ONE,
    "num_eval_envs": AT_LEAST_ONE,
    "batch_size": AT_LEAST_ONE,
    "buffer_size": AT_LEAST_ONE,
    "iterations_per_chunk": AT_LEAST_ONE,
    "policy_delay": AT_LEAST_ONE,
    "target_update_period": AT_LEAST_ONE,
    "n_step": AT_LEAST_ONE,
    "num_critics": AT_LEAST_ONE,
}


def range_of(name: str, algorithm: Algorithm | None = None) -> Range | None:
    """The valid range of field ``name`` (None: no numeric range to check)."""
    own = hooks(algorithm).ranges if algorithm is not None else {}
    if name in own:
        return own[name]
    if name in BY_NAME:
        return BY_NAME[name]
    if name == "lr" or name.endswith("_lr") or name.endswith("learning_rate"):
        return POSITIVE
    if name.endswith("hidden"):  # layer widths (each one; an empty tuple is no hidden layer)
        return AT_LEAST_ONE
    if "noise" in name or name.endswith(("_steps", "_updates", "_coef", "_decay", "_norm")):
        return NON_NEGATIVE
    return None


def out_of_range(instance: DataclassInstance, algorithm: Algorithm | None = None) -> str | None:
    """The first field of a ``Config``/``Hyperparams`` dataclass outside its range, as the
    one-line message (flag, range, value); None when all hold."""
    for field in dataclasses.fields(instance):
        rule = range_of(field.name, algorithm)
        value = getattr(instance, field.name)
        flag = "--" + field.name.replace("_", "-")
        if rule is not None and isinstance(value, tuple):
            numbers = [v for v in value if isinstance(v, (int, float)) and not isinstance(v, bool)]
            if any(not math.isfinite(v) or not rule.holds(v) for v in numbers):
                shown = ",".join(_number(v) for v in value)
                return f"{flag} must have every value {rule}, got {shown}"
            continue
        if rule is None or isinstance(value, (bool, np.bool_, str)) or value is None:
            continue
        array = np.asarray(value)
        if array.dtype.kind not in "iuf" or array.size != 1:
            continue
        number = float(array)
        if not math.isfinite(number) or not rule.holds(number):
            return f"{flag} must be {rule}, got {_number(number)}"
    return None


def buffer_too_small(config: DataclassInstance, algorithm: Algorithm) -> str | None:
    """The one-line message when a config's replay buffer (the ``replay_capacity`` hook) is smaller
    than a batch (``replay_batch``) or than the random warm-up (``warm_up_steps``); None otherwise.

    A buffer smaller than a batch makes every update draw repeats of the same few transitions;
    one smaller than the warm-up overwrites the warm-up's random transitions before the first
    update learns from them, so the warm-up was run for nothing. Neither trains as the user
    meant. All three fields count transitions of one seed over all its ``num_envs`` envs together
    (each env step of the batch adds ``num_envs``), so they compare directly, whatever
    ``num_envs`` is; the size asked for is checked, not the multiple of ``num_envs`` the buffer
    rounds it up to, so that the rule is the one the message states.
    """
    book = hooks(algorithm)
    size = book.replay_capacity(config)
    if size is None:
        return None
    batch = book.replay_batch(config) or 0
    warm_up = book.warm_up_steps(config)
    if size >= max(batch, warm_up):
        return None
    if warm_up > batch:
        envs = book.envs_per_seed(config)
        together = f", of all {envs} envs together," if envs and envs > 1 else ""
        why = (
            f"--learning-starts: the random warm-up's transitions{together} would be "
            "overwritten before the first update"
        )
        return f"--buffer-size must be >= {warm_up} ({why}), got {size}"
    why = "--batch-size: every update draws a batch from it"
    return f"--buffer-size must be >= {batch} ({why}), got {size}"


def check_ranges(
    algorithm: Algorithm, config: DataclassInstance, hparams_list: Iterable[DataclassInstance]
) -> None:
    """``RangeError`` naming the first value of ``config`` or of any hyperparameter config (a
    grid has several) outside its range."""
    hparams_list = list(hparams_list)
    problem = out_of_range(config, algorithm) or buffer_too_small(config, algorithm)
    if problem:
        raise RangeError(problem)
    for index, hparams in enumerate(hparams_list):
        problem = out_of_range(hparams, algorithm)
        if problem:
            where = f" (config {index} of {len(hparams_list)})" if len(hparams_list) > 1 else ""
            raise RangeError(problem + where)


def _number(value: float) -> str:
    return f"{value:g}"
