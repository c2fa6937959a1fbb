"""Hyperparameters and configs as data: their conversion to arrays and JSON, stacking several
into one ``[H]`` pytree, and product grids over their fields.

Every place that turns hyperparameters into arrays (the learners' ``Hyperparams.as_arrays``, the
run's identity, the stacked ``[H]`` input of the compiled program) converts through ``as_arrays``
here, so a value has one dtype wherever it is seen; grids (``parallel``-style stacked grids, the
CLI's ``--grid``, the sweep script's axes) expand through ``product``.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeAlias, TypeVar, runtime_checkable

import jax
import numpy as np
import numpy.typing as npt

from rl_jax.errors import RunError

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

# ---- arrays ---------------------------------------------------------------------------------

_DTYPES = {"f": np.float32, "i": np.int32, "u": np.int32, "b": np.bool_}

T = TypeVar("T")  # hyperparameters, a pytree of them or a dataclass: what goes in comes out
D = TypeVar("D", bound="DataclassInstance")


@runtime_checkable
class RetiresFields(Protocol):
    """A ``Config`` or ``Hyperparams`` class that lists fields it no longer has: ``RETIRED`` maps
    each to the value that meant "off" and what became of the setting."""

    RETIRED: ClassVar[Mapping[str, tuple[object, str]]]


#: A hyperparameter's value: a Python number, or an array leaf (stacked: ``[H]``).
Scalar: TypeAlias = float | jax.Array


def _as_array(value: npt.ArrayLike, like: npt.ArrayLike | None = None) -> np.ndarray:
    """``value`` as an array of the kind of ``like`` (else its own): float32, int32 or bool."""
    array = np.asarray(value)
    kind = np.asarray(like).dtype.kind if like is not None else array.dtype.kind
    dtype = _DTYPES.get(kind)
    return array if dtype is None else array.astype(dtype)


def as_arrays(hparams: T) -> T:
    """Every hyperparameter as a numpy array (0-d, or ``[H]`` from a stack's JSON).

    The dtype follows the field's default where the field has one (a float default makes 3 and
    3.0 the same float32), else the value: float32 for numbers with a fraction, int32 for
    integers, bool for flags. A pytree that is not a dataclass converts leaf by leaf."""
    if not dataclasses.is_dataclass(hparams):
        return jax.tree.map(_as_array, hparams)
    values = {}
    for field in dataclasses.fields(hparams):
        default = None if field.default is dataclasses.MISSING else field.default
        values[field.name] = _as_array(getattr(hparams, field.name), default)
    return dataclasses.replace(hparams, **values)


def stack(hparams_list: Sequence[T]) -> T:
    """``[H]``-stacked hyperparameters (each through ``as_arrays``), the leading axis a grid's
    configs: the ``hparams`` input of ``rl_jax.training.parallel.Program``."""
    arrays = [as_arrays(h) for h in hparams_list]
    return jax.tree.map(lambda *leaves: np.stack(leaves), *arrays)


# ---- grids ----------------------------------------------------------------------------------


def product(values: Mapping[str, Sequence[Any]]) -> list[dict[str, Any]]:
    """Every combination of the named values, ``{name: value}`` each, first name slowest."""
    names = list(values)
    return [
        dict(zip(names, combo, strict=True))
        for combo in itertools.product(*(values[name] for name in names))
    ]


def expand(base: D, values: Mapping[str, Sequence[Any]]) -> list[D]:
    """``base`` (a dataclass) with each combination of ``product(values)`` replaced in it."""
    return [dataclasses.replace(base, **point) for point in product(values)]


def grid(base: D, **values: Sequence[float]) -> tuple[D, list[dict[str, Any]]]:
    """The product grid on top of ``base``: ``(stacked pytree [H], [{field: value}, ...])``,
    first field varying slowest."""
    return stack(expand(base, values)), product(values)


# ---- JSON -----------------------------------------------------------------------------------


def _json_value(value: object) -> object:
    """Plain JSON for config and hyperparameter values (tuples become lists)."""
    if isinstance(value, (tuple, list)):
        return [_json_value(v) for v in value]
    if isinstance(value, (np.ndarray, jax.Array, np.generic)):
        array = np.asarray(value)
        if array.dtype == np.float32:
            # The shortest decimal that round-trips the float32 (0.01, not 0.009999999776).
            shortest = [float(str(x)) for x in array.reshape(-1)]
            return np.array(shortest, dtype=object).reshape(array.shape).tolist()
        return array.tolist()
    return value


def dataclass_to_dict(instance: DataclassInstance) -> dict[str, Any]:
    """Fields of a (frozen or flax struct) dataclass as JSON-ready values."""
    return {f.name: _json_value(getattr(instance, f.name)) for f in dataclasses.fields(instance)}


def dataclass_from_dict(template: D, values: dict[str, Any]) -> D:
    """``template`` with ``values`` replaced, each converted to the template field's type.

    A field the dataclass no longer has is dropped where a run recorded it at the value that
    meant "off" (its class's ``RETIRED``: name -> (that value, what became of it)), so that runs
    recorded before it went still load; at another value it is an error that says where the
    setting went."""
    values = dict(values)
    retired: Mapping[str, tuple[object, str]] = (
        template.RETIRED if isinstance(template, RetiresFields) else {}
    )
    for name, (off, moved) in retired.items():
        if name in values and not _same(values.pop(name), off):
            raise RunError(f"this run set {name}, which {moved}: it cannot be continued here")
    names = {f.name for f in dataclasses.fields(template)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise RunError(f"unknown {type(template).__name__} field(s): {', '.join(unknown)}")
    converted = {
        name: _like(getattr(template, name), value, name) for name, value in values.items()
    }
    try:
        return dataclasses.replace(template, **converted)
    except (TypeError, ValueError) as error:  # the dataclass's own validation
        raise RunError(f"invalid {type(template).__name__}: {error}") from None


def _same(recorded: Any, value: Any) -> bool:
    """Whether a recorded setting is ``value`` (numbers as the float32 a run stores them in)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        numeric = isinstance(recorded, (int, float)) and not isinstance(recorded, bool)
        return numeric and np.float32(recorded) == np.float32(value)
    return recorded == value


def _like(default: object, value: object, name: str) -> object:
    """``value`` converted to the type of ``default`` (bool, int, float, str, tuple, array)."""
    if isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise RunError(f"{name} must be a list, got {value!r}")
        element = default[0] if default else value[0] if value else 0
        return tuple(_like(element, v, name) for v in value)
    if isinstance(default, (np.ndarray, jax.Array, np.generic)):
        return np.asarray(value, dtype=np.asarray(default).dtype)
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise RunError(f"{name} must be true or false, got {value!r}")
        return value
    if isinstance(default, int) and not isinstance(value, bool):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, int):
            raise RunError(f"{name} must be an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RunError(f"{name} must be a number, got {value!r}")
        return float(value)
    return value


class HyperparamsMethods:
    """Conversions for a learner's ``Hyperparams`` (a ``flax.struct`` dataclass of scalars)."""

    def as_arrays(self):
        """Every field as an array, as ``as_arrays`` (lists, e.g. a stack's JSON, become [H])."""
        return as_arrays(self)

    def to_dict(self) -> dict[str, Any]:
        """Fields as plain Python values (JSON-ready)."""
        return dataclass_to_dict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]):
        """Inverse of ``to_dict``: the hyperparameters with every field as an array."""
        return cls(**values).as_arrays()
