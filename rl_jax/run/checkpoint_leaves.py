"""How a train state's leaves are kept in a checkpoint: the arrays orbax saves, keyed by their
position in the flattened tree (``leaf_00000``...), and one JSON record per leaf (the ``leaves`` of
the checkpoint's metadata). The records work around orbax's quirks, as ``rl_jax.run.checkpoint``
lists them: zero-size arrays are rebuilt as zeros, typed PRNG keys are saved as their key data
and re-wrapped, non-array leaves go into the JSON, and a template that does not match the saved
layout is described in one line instead of being cast to.
"""

from __future__ import annotations

import json
from typing import Any, TypeGuard

import jax
import numpy as np

from rl_jax.errors import CheckpointError


def is_key(leaf: object) -> TypeGuard[jax.Array]:
    """Whether ``leaf`` is a typed PRNG key array (saved as its key data)."""
    return hasattr(leaf, "dtype") and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key)


def leaf_record(path: str, leaf: object) -> dict[str, Any]:
    """How a leaf is stored: ``kind`` is array, key, empty (zero-size) or json."""
    if is_key(leaf):
        data = jax.random.key_data(leaf)
        impl = str(jax.random.key_impl(leaf))
        return {
            "path": path,
            "kind": "key",
            "shape": list(data.shape),
            "dtype": str(data.dtype),
            "impl": impl,
        }
    if isinstance(leaf, (np.ndarray, jax.Array, np.generic)):
        kind = "empty" if leaf.size == 0 else "array"
        return {"path": path, "kind": kind, "shape": list(leaf.shape), "dtype": str(leaf.dtype)}
    return {"path": path, "kind": "json", "value": leaf}


def split_state(
    state: object,
) -> tuple[dict[str, jax.Array | np.ndarray], list[dict[str, Any]]]:
    """The saveable arrays (keyed ``leaf_00000``...) and the per-leaf records."""
    arrays, records = {}, []
    for index, (path, leaf) in enumerate(jax.tree_util.tree_flatten_with_path(state)[0]):
        record = leaf_record(jax.tree_util.keystr(path), leaf)
        if record["kind"] == "json":
            try:
                json.dumps(record["value"])
            except TypeError as error:
                message = f"state leaf {record['path']} cannot be saved: {error}"
                raise CheckpointError(message) from None
        elif record["kind"] == "key":
            data = jax.random.key_data(leaf)
            # Under jax.distributed orbax refuses a process-local jax.Array; host data it takes.
            arrays[leaf_name(index)] = np.asarray(data) if jax.process_count() > 1 else data
        elif record["kind"] == "array":
            arrays[leaf_name(index)] = leaf
        records.append(record)
    return arrays, records


def leaf_name(index: int) -> str:
    """The name under which the ``index``-th leaf's array is saved."""
    return f"leaf_{index:05d}"


def template_records(template: object) -> list[dict[str, Any]]:
    """Records describing what the caller expects (arrays or ``jax.ShapeDtypeStruct``s)."""
    records = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(template)[0]:
        name = jax.tree_util.keystr(path)
        if is_key(leaf):
            data = jax.eval_shape(jax.random.key_data, leaf)
            records.append(
                {"path": name, "kind": "key", "shape": list(data.shape), "dtype": str(data.dtype)}
            )
        elif hasattr(leaf, "shape") and hasattr(leaf, "dtype"):
            kind = "empty" if int(np.prod(leaf.shape)) == 0 else "array"
            records.append(
                {
                    "path": name,
                    "kind": kind,
                    "shape": list(leaf.shape),
                    "dtype": str(np.dtype(leaf.dtype)),
                }
            )
        else:
            records.append({"path": name, "kind": "json"})
    return records


def first_mismatch(saved: list[dict], expected: list[dict]) -> str | None:
    """A one-line description of the first difference, or None if the layouts agree."""
    if len(saved) != len(expected):
        return f"it holds {len(saved)} state leaves, this run's state has {len(expected)}"
    for have, want in zip(saved, expected, strict=True):
        for field in ("path", "kind", "shape", "dtype"):
            if field in want and have.get(field) != want[field]:
                return (
                    f"state leaf {want['path']} has {field} {have.get(field)} in the checkpoint, "
                    f"{want[field]} in this run"
                )
    return None


def rebuild_leaf(
    record: dict, arrays: dict[str, jax.Array], index: int, sharding: jax.sharding.Sharding | None
) -> object:
    """The ``index``-th leaf from its record and the restored arrays: JSON values as saved,
    zero-size arrays as zeros (placed by ``sharding``), keys re-wrapped from their data.
    """
    kind = record["kind"]
    if kind == "json":
        return record["value"]
    if kind == "empty":
        zeros = np.zeros(record["shape"], record["dtype"])
        return jax.device_put(zeros, sharding) if sharding is not None else jax.numpy.asarray(zeros)
    array = arrays[leaf_name(index)]
    if kind == "key":
        return jax.random.wrap_key_data(array, impl=record["impl"])
    return array
