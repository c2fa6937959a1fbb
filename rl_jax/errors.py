"""User errors: the exception types that mean bad input rather than a bug, and the helpers that
report them as one line on stderr (``error: <message>``, exit status 2) instead of a traceback.

They are raised in every layer (``rl_jax.training.validation``'s range check is a ``RunError``;
the run tools raise the others), so they live beside the public face and import nothing of the
package. The envs' own user errors (unknown id, unknown MuJoCo backend, unsupported external env)
stay in ``envs`` and are looked up when an error is reported. Every module, tests included,
imports these types from here.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable
from typing import NoReturn


class UsageError(Exception):
    """Bad command-line input (reported as one line, exit status 2)."""


class RunError(Exception):
    """A user-facing problem with a run (bad directory, foreign resume, not enough memory)."""


class CheckpointError(Exception):
    """A checkpoint is missing, unreadable, or does not match the state it should restore."""


class PolicyError(Exception):
    """The policy cannot be loaded (no run, no checkpoint, a seed the run does not have)."""


class RenderError(Exception):
    """The policy cannot be rendered (no OpenGL, no renderer for the env, no checkpoint)."""


# ---- value parsing --------------------------------------------------------------------------


def parse_int(text: str) -> int:
    """An integer; ``1e6`` and ``1_000_000`` are accepted when they are whole numbers."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid integer value: {text!r}") from None
    if not value.is_integer():
        raise argparse.ArgumentTypeError(f"invalid integer value: {text!r}")
    return int(value)


def parse_float(text: str) -> float:
    """A finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid numeric value: {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"invalid numeric value: {text!r} (must be finite)")
    return value


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1, else one clear usage error."""
    value = parse_int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


# ---- one-line reports -----------------------------------------------------------------------


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad flag in one line (no usage block) and exits with 2."""

    def error(self, message: str) -> NoReturn:
        """Exit with status 2 and one line naming the problem, instead of argparse's usage block."""
        self.exit(2, f"error: {message} (see --help)\n")


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that mean bad input, not a bug: reported in one line."""
    errors = (UsageError, RunError, CheckpointError, RenderError, PolicyError)
    # The envs' own too, once the envs are loaded (none of them is raised before): this module
    # imports nothing of the package, and envs would pull in JAX and gymnasium.
    registry = sys.modules.get("rl_jax.envs.core.registry")
    if registry is None:
        return errors
    return (*errors, registry.UnknownEnvError, registry.BackendError, registry.UnsupportedEnvError)


def guard(function: Callable[[], int]) -> int:
    """Run ``function``; a user error becomes ``error: <one line>`` on stderr and status 2."""
    try:
        return function()
    except user_errors() as error:
        message = " ".join(str(error).split("\n")).strip() or type(error).__name__
        print(f"error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: aborted (the latest checkpoint is kept)", file=sys.stderr)
        return 130


def exit_now(status: int) -> NoReturn:
    """Exit with ``status``. After an error, skip interpreter shutdown: a failed checkpoint
    read can leave tensorstore callbacks pending, and run during shutdown they print tracebacks
    under our one-line error. Everything of ours is closed by then."""
    if status == 0:
        sys.exit(0)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
