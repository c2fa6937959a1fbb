"""The PYTHONPATH of a child process that a test starts as a user would.

The parent's own entries are kept after the test's: on a machine where packages come by
PYTHONPATH rather than from a venv (the GPU check puts its wheels in /tmp/site), a child given only
the repository root could not import jax or gymnasium at all.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def python_path(*paths: str | Path) -> str:
    """``paths`` first, then the parent's PYTHONPATH entries not among them."""
    first = [str(path) for path in paths]
    inherited = [
        entry
        for entry in os.environ.get("PYTHONPATH", "").split(os.pathsep)
        if entry and entry not in first
    ]
    return os.pathsep.join(first + inherited)


def without_root() -> str | None:
    """The parent's PYTHONPATH less the repository root (None if nothing is left), for a child
    that must find the project as a user's shell does: installed (``make install``), or, where
    it is not installed (the GPU check), through the PYTHONPATH the machine itself set."""
    from importlib import metadata

    entries = [e for e in os.environ.get("PYTHONPATH", "").split(os.pathsep) if e]
    try:
        metadata.distribution("rl_jax")
    except metadata.PackageNotFoundError:
        return os.pathsep.join(entries) or None
    kept = [e for e in entries if Path(e).resolve() != ROOT]
    return os.pathsep.join(kept) or None
