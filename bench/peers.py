"""The peers' venv: SBX (``sbx-rl``, which needs jax 0.10), PyTorch, and what pgx's AlphaZero
example needs (dm-haiku, omegaconf, pydantic, pgx, mctx), pinned, apart from ours.

    python -m bench.peers            # create .venv-peers from bench/peers-requirements.txt
    python -m bench.peers --check    # say whether it is there and complete

``bench_peers`` calls ``ensure()`` before it measures, so ``python -m bench peers`` builds the
venv on first use (it needs PyPI; ~1.5 GB). Our own venv stays on jax 0.9.2 (pyproject.toml says
why), so SBX cannot share it.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv-peers"
REQUIREMENTS = Path(__file__).resolve().parent / "peers-requirements.txt"
PYTHON = VENV / "bin" / "python"
STAMP = VENV / ".installed"


class PeersUnavailable(RuntimeError):
    """The peers' venv could not be built (no network, no python3.11)."""


def ready() -> bool:
    """The venv exists and was installed from the current requirements file."""
    return STAMP.is_file() and STAMP.read_text() == REQUIREMENTS.read_text()


def ensure(quiet: bool = True) -> Path:
    """The peers' python, building the venv first when it is missing or out of date."""
    if ready():
        return PYTHON
    if not PYTHON.is_file():
        _run([sys.executable, "-m", "venv", str(VENV)], "create the venv")
    pip = [str(PYTHON), "-m", "pip", "install", "--disable-pip-version-check"]
    pip += ["--quiet"] if quiet else []
    _run([*pip, "-r", str(REQUIREMENTS)], f"install {REQUIREMENTS.name} (needs PyPI)")
    STAMP.write_text(REQUIREMENTS.read_text())
    return PYTHON


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise PeersUnavailable(f"could not {what}: " + " | ".join(tail))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.peers", description=__doc__)
    parser.add_argument("--check", action="store_true", help="only report the venv's state")
    args = parser.parse_args(argv)
    if args.check:
        print(f"{VENV}: {'ready' if ready() else 'missing or out of date'}")
        return 0 if ready() else 1
    try:
        print(f"peers' python: {ensure(quiet=False)}")
    except PeersUnavailable as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
