"""Helpers shared by the run-machinery tests."""

from pathlib import Path

import jax
import numpy as np


def leaves_bytes(state) -> list[bytes]:
    """The raw bytes of every leaf (typed keys as their key data): equal means bit-identical."""

    def to_bytes(leaf):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        return np.asarray(leaf).tobytes()

    return [to_bytes(leaf) for leaf in jax.tree.leaves(state)]


def snapshot(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` with its content (to prove nothing changed)."""
    return {
        str(path.relative_to(directory)): path.read_bytes()
        for path in sorted(Path(directory).rglob("*"))
        if path.is_file()
    }
