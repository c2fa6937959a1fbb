"""One line, ours, when jax's runtime aborts a process of a run over several processes.

Process 0 hosts jax's coordination service. When it dies while no collective of ours is under
way to fail first (while the processes compile, say), jax's distributed client in every other
process notices that the service stopped answering and ends its process itself: a fatal log of
several lines, a C++ stack trace, then ``abort()`` (SIGABRT, status 134). jax gives no way to
replace that (its client takes a ``missed_heartbeat_callback``, but one written in Python cannot
receive the status it is called with), so a process of a run over several processes:

- turns jax's C++ log off (``quiet_runtime_log``), as ``TF_CPP_MIN_LOG_LEVEL=4`` would (rl_jax's
  own default is 3, fatal lines only), unless the user set ``TF_CPP_MIN_LOG_LEVEL`` themselves:
  then their level holds, and jax's log comes before our line;
- answers SIGABRT with one line and status 1 (``install``): that another process of the run
  stopped, when the coordination service no longer answers, else that jax's runtime aborted. The
  run's latest checkpoint is kept either way, and the same command continues it.

Linux only (the handler is installed through libc's ``sigaction``); elsewhere jax's default
stays.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import socket
import sys

#: Set by the user, jax's C++ log level wins over ours.
LOG_LEVEL_VARIABLE = "TF_CPP_MIN_LOG_LEVEL"
#: absl's minimum log level above FATAL: nothing is printed.
SILENT = 4
#: The resume advice every stopped process gives.
CONTINUE = (
    "The latest checkpoint is kept: start all processes again with the same command to continue"
)

_HANDLER_TYPE = ctypes.CFUNCTYPE(None, ctypes.c_int)


class _Sigaction(ctypes.Structure):
    """glibc's ``struct sigaction``: the handler, a 1,024-bit signal mask, flags, restorer."""

    _fields_ = (
        ("sa_handler", _HANDLER_TYPE),
        ("sa_mask", ctypes.c_ulong * (1024 // (8 * ctypes.sizeof(ctypes.c_ulong)))),
        ("sa_flags", ctypes.c_int),
        ("sa_restorer", ctypes.c_void_p),
    )


#: The handler installed, kept alive for as long as the process (libc holds only its address).
_installed: list[object] = []


def lost_contact_line(process_id: int, details: str = "") -> str:
    """The line a process prints when another process of its run went away."""
    said = f" ({details[:160]})" if details else ""
    return (
        f"error: process {process_id} lost contact with another process of the run{said}; "
        f"stopping. {CONTINUE}"
    )


def abort_line(process_id: int, coordinator: str | None) -> str:
    """What process ``process_id`` says when jax's runtime aborts it: lost contact when the
    coordination service at ``coordinator`` (``HOST:PORT``) no longer answers, else an abort
    inside jax, most likely because another process stopped."""
    if process_id != 0 and coordinator is not None and not answers(coordinator):
        return lost_contact_line(
            process_id, "process 0, which hosts jax's coordination service, stopped answering"
        )
    return (
        f"error: process {process_id} stopped: jax's runtime aborted it, most likely because "
        "another process of the run stopped (see that process's output; "
        f"{LOG_LEVEL_VARIABLE}=0 shows jax's own log). {CONTINUE}"
    )


def answers(address: str, timeout: float = 2.0) -> bool:
    """Whether something accepts a connection at ``HOST:PORT``."""
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout):
            return True
    except (OSError, ValueError):
        return False


def quiet_runtime_log() -> None:
    """Turn jax's C++ log (absl's) off for this process, unless ``TF_CPP_MIN_LOG_LEVEL`` is
    set. Its lines would otherwise come before ours when the runtime aborts."""
    import rl_jax  # which records whether the user chose the level before it set its own

    if getattr(rl_jax, "_cpp_log_level_chosen", LOG_LEVEL_VARIABLE in os.environ):
        return
    with contextlib.suppress(ImportError, AttributeError):
        from jax._src.lib import utils  # absl's setter, as jax's own logging config uses it

        utils.absl_set_min_log_level(SILENT)


def install(process_id: int, coordinator: str | None) -> bool:
    """Answer SIGABRT in this process with ``abort_line`` on stderr and status 1; whether it
    could (Linux with glibc's ``sigaction``)."""
    if not sys.platform.startswith("linux") or _installed:
        return bool(_installed)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
    except OSError:
        return False

    def on_abort(_signal_number: int) -> None:
        line = abort_line(process_id, coordinator)
        with contextlib.suppress(OSError):
            os.write(2, (line + "\n").encode())
        os._exit(1)

    handler = _HANDLER_TYPE(on_abort)
    action = _Sigaction()
    action.sa_handler = handler
    if libc.sigaction(signal.SIGABRT, ctypes.byref(action), None) != 0:
        return False
    _installed.append(handler)
    return True
