"""The processes' agreement before ``jax.distributed`` joins them: a small handshake of our own on
the coordinator's port.

jax's coordination service cannot tell a second job from its own processes: a process that
connects with a rank already taken counts as that rank restarted, and the service then aborts
the job that was running (a C++ fatal log, nothing saved). Two processes given one rank, or
another program on the port, abort or wait the whole join timeout. So before jax joins, process
0 binds the coordinator's port itself (a port already held: one line, and jax is never started
there), and every other process connects to it and says who it is: its rank, the process count,
its job, and a fingerprint of its command (the command without the flags that only place
processes, ``--seeds``, ``--out`` as given and resolved). Process 0 checks them all and answers
each with ``ok`` or the one line that names what differs; only then does it let the port go, and
jax binds it. A process that finds the port answered by anything but process 0's handshake (a
running job's coordination service) says so and stops without ever speaking to it.

Process 0 also writes a file with a fresh name beside the run directory (in its nearest existing
folder) and tells the others its name: a process that cannot see it is on a host that does not
share the run directory.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import secrets
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path

#: The longest a process waits to see process 0's file, or for one line of the handshake.
SEE_SECONDS = 5.0
#: How long process 0 still answers latecomers with the error once the handshake failed.
LINGER_SECONDS = 5.0
#: The prefix of the file that tells whether the run directory is shared.
NONCE_PREFIX = ".rl_jax-join-"
#: The prefix of the file with the port process 0 moved to, and how long the others wait for it.
PORT_PREFIX = ".rl_jax-port-"
MOVE_SECONDS = 20.0


class JoinError(Exception):
    """One line on why the processes cannot run together; ``held``: the port answered, but not
    as this run's process 0."""

    def __init__(self, message: str, held: bool = False):
        super().__init__(message)
        self.held = held


@dataclasses.dataclass(frozen=True)
class Fingerprint:
    """What every process of one run must agree on; ``job`` tells two jobs apart (SLURM's job,
    step and restart; empty where nothing does)."""

    command: str = ""
    seeds: str | None = None
    out: str | None = None
    resolved: str = ""
    job: str = ""


def fingerprint(argv: list[str], environ: Mapping[str, str] = os.environ) -> Fingerprint:
    """The fingerprint of ``argv`` (without the process flags) as this process sees it."""
    out = _value(argv, "--out") or _value(argv, "--resume")
    seeds = _value(argv, "--seeds")
    command = hashlib.sha256("\0".join(argv).encode()).hexdigest()[:16]
    resolved = str(Path(out).resolve()) if out else str(Path.cwd().resolve())
    return Fingerprint(command, seeds, out, resolved, job_key(environ))


def job_key(environ: Mapping[str, str] = os.environ) -> str:
    """SLURM's job, step and restart count, or empty outside SLURM."""
    if "SLURM_JOB_ID" not in environ:
        return ""
    parts = ("SLURM_JOB_ID", "SLURM_STEP_ID", "SLURM_RESTART_COUNT")
    return ".".join(environ.get(name, "0") for name in parts)


def _value(argv: list[str], flag: str) -> str | None:
    """The last value of ``flag`` in ``argv`` (``--flag V`` or ``--flag=V``)."""
    found = None
    for index, arg in enumerate(argv):
        if arg == flag and index + 1 < len(argv):
            found = argv[index + 1]
        elif arg.startswith(flag + "="):
            found = arg[len(flag) + 1 :]
    return found


def port_is_free(port: int) -> bool:
    """Whether nothing holds ``port`` on this host (jax's service listens on every address)."""
    try:
        _listen(port).close()
        return True
    except OSError:
        return False


def _listen(port: int) -> socket.socket:
    if socket.has_dualstack_ipv6():
        return socket.create_server(("", port), family=socket.AF_INET6, dualstack_ipv6=True)
    return socket.create_server(("", port))


# ---- the checks -----------------------------------------------------------------------------


def disagreement(rank: int, count: int, mine: Fingerprint, hello: Mapping[str, object]) -> str:
    """What differs between process 0 (``mine``, ``count``) and one other's ``hello``; empty
    when nothing does."""
    other = int(str(hello["rank"]))
    if int(str(hello["count"])) != count:
        return (
            f"--num-processes differs between the processes: {count} on process {rank}, "
            f"{hello['count']} on process {other}; give every process the same"
        )
    theirs = _fingerprint_of(hello)
    if theirs.seeds != mine.seeds:
        return (
            f"--seeds differs between the processes: {mine.seeds} on process {rank}, "
            f"{theirs.seeds} on process {other}; start every process with the same command"
        )
    if theirs.out != mine.out:
        return (
            f"--out differs between the processes: {mine.out} on process {rank}, {theirs.out} on "
            f"process {other}; start every process with the same command"
        )
    if theirs.resolved != mine.resolved:
        return (
            f"the run directory {mine.out or '(the working directory)'} is {mine.resolved} on "
            f"process {rank} but {theirs.resolved} on process {other}: start every process in "
            "the same working directory, or give --out as an absolute path"
        )
    if theirs.command != mine.command:
        return (
            f"process {other} runs another command than process {rank} (beyond --coordinator, "
            "--num-processes and --process-id): start every process with the same command"
        )
    if hello.get("sees") is False:
        return (
            f"the run directory is not shared between the processes' hosts: process {other} "
            f"does not see the file process {rank} wrote in {nearest(mine.resolved)}; "
            "put --out on a file system that every process sees"
        )
    return ""


def _fingerprint_of(hello: Mapping[str, object]) -> Fingerprint:
    given = hello.get("fingerprint")
    fields: Mapping[str, object] = given if isinstance(given, dict) else {}

    def text(name: str) -> str | None:
        value = fields.get(name)
        return None if value is None else str(value)

    return Fingerprint(
        text("command") or "", text("seeds"), text("out"), text("resolved") or "", text("job") or ""
    )


def nearest(path: str) -> Path:
    """The nearest folder of ``path`` (itself or an ancestor) that exists here."""
    folder = Path(path)
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    return folder


# ---- the handshake --------------------------------------------------------------------------


def _send(connection: socket.socket, message: Mapping[str, object]) -> None:
    with contextlib.suppress(OSError):  # a process that went away hears nothing
        connection.sendall((json.dumps(message) + "\n").encode())


def _read_line(connection: socket.socket, seconds: float) -> dict[str, object] | None:
    """One JSON line from ``connection`` within ``seconds``; None for anything else (silence,
    a closed connection, bytes of another protocol)."""
    connection.settimeout(seconds)
    data = b""
    try:
        while not data.endswith(b"\n"):
            chunk = connection.recv(4096)
            data += chunk
            if not chunk or data[:1] != b"{" or len(data) > 65536:
                return None
        message = json.loads(data)
    except (OSError, ValueError):
        return None
    return message if isinstance(message, dict) else None


def lead(port: int, count: int, mine: Fingerprint, timeout: float) -> None:
    """Process 0's side: hold ``port`` until the other ``count - 1`` processes said who they
    are, and answer them. ``JoinError`` (after telling every connected process) for a port
    already held or any disagreement; ``TimeoutError`` when not all came within ``timeout``."""
    try:
        server = _listen(port)
    except OSError:
        raise PortTaken(port) from None
    folder, nonce = _write_nonce(mine.resolved)
    try:
        with server:
            _serve(server, count, mine, timeout, (folder, nonce))
    finally:
        if nonce:
            (folder / (NONCE_PREFIX + nonce)).unlink(missing_ok=True)


class PortTaken(OSError):
    """Process 0 found the coordinator's port held on its host."""

    def __init__(self, port: int):
        super().__init__(port)
        self.port = port


def _write_nonce(resolved: str) -> tuple[Path, str]:
    folder, nonce = nearest(resolved), secrets.token_hex(8)
    if not resolved:
        return folder, ""  # no run directory to check (the Python API)
    try:
        (folder / (NONCE_PREFIX + nonce)).write_text("")
    except OSError:
        return folder, ""  # a folder process 0 cannot write: the run itself says so
    return folder, nonce


def _serve(
    server: socket.socket, count: int, mine: Fingerprint, timeout: float, seen: tuple[Path, str]
) -> None:
    deadline = time.monotonic() + timeout
    joined: dict[int, socket.socket] = {}
    error = ""
    try:
        while len(joined) < count - 1 and not error:
            connection = _accept(server, deadline)
            if connection is None:
                raise TimeoutError(sorted(joined))
            error = _admit(connection, count, mine, seen, joined)
        if error:
            _refuse_all(server, joined, error, count)
            raise JoinError(error)
        for connection in joined.values():
            _send(connection, {"ok": True})
    finally:
        for connection in joined.values():
            connection.close()


def _accept(server: socket.socket, deadline: float) -> socket.socket | None:
    left = deadline - time.monotonic()
    if left <= 0:
        return None
    server.settimeout(left)
    try:
        return server.accept()[0]
    except TimeoutError:
        return None


def _admit(
    connection: socket.socket,
    count: int,
    mine: Fingerprint,
    seen: tuple[Path, str],
    joined: dict[int, socket.socket],
) -> str:
    """Read one process's hello; keep its connection in ``joined`` under its rank. Returns the
    disagreement, if any (an empty string: none)."""
    folder, nonce = seen
    _send(connection, {"rl_jax": 1, "folder": str(folder), "nonce": nonce})
    hello = _read_line(connection, SEE_SECONDS * 2)
    if hello is None or "rank" not in hello:
        connection.close()  # not one of ours (a port scan, a process that went away)
        return ""
    if _fingerprint_of(hello).job != mine.job:
        _send(connection, {"other_job": mine.job})
        connection.close()
        return ""
    rank = int(str(hello["rank"]))
    duplicate = rank == 0 or rank in joined
    joined[rank if not duplicate else -len(joined) - 1] = connection
    if duplicate:
        return (
            f"duplicate --process-id {rank}: two processes of the run were given it; give each "
            f"process its own rank, 0 .. {count - 1}"
        )
    return disagreement(0, count, mine, hello)


def _refuse_all(
    server: socket.socket, joined: dict[int, socket.socket], error: str, count: int
) -> None:
    """Tell every process the error, and for a while those still coming."""
    for connection in joined.values():
        _send(connection, {"error": error})
    deadline = time.monotonic() + LINGER_SECONDS
    while len(joined) < count - 1:
        connection = _accept(server, deadline)
        if connection is None:
            return
        _send(connection, {"rl_jax": 1, "folder": "", "nonce": ""})
        _read_line(connection, SEE_SECONDS)
        _send(connection, {"error": error})
        joined[-len(joined) - 100] = connection


def follow(
    host: str,
    port: int,
    rank: int,
    count: int,
    mine: Fingerprint,
    timeout: float,
    moved: Callable[[], int | None] | None = None,
) -> int:
    """Any other process's side (and a process 0 that found its port held): say who it is to
    process 0 at ``host:port`` and wait for its answer; returns the port it joined at.
    ``moved`` tells the port process 0 moved to when it found its own held (None: not moved).
    ``JoinError`` with the line to print; ``TimeoutError`` when process 0 did not answer
    within ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        port = (moved and moved()) or port
        try:
            connection = socket.create_connection((host, port), timeout=SEE_SECONDS)
        except OSError:
            if time.monotonic() > deadline:
                raise TimeoutError() from None
            time.sleep(0.25)
            continue
        try:
            _greet(connection, host, port, rank, count, mine, deadline)
            return port
        except JoinError as error:
            if not error.held or moved is None:
                raise
            port = _moved_from(port, moved, error)


def _moved_from(port: int, moved: Callable[[], int | None], error: JoinError) -> int:
    """The port process 0 moved to from ``port``, once it says so (within ``MOVE_SECONDS``);
    ``error`` if it does not."""
    deadline = time.monotonic() + MOVE_SECONDS
    while time.monotonic() < deadline:
        elsewhere = moved()
        if elsewhere is not None and elsewhere != port:
            return elsewhere
        time.sleep(0.25)
    raise error


def _greet(
    connection: socket.socket,
    host: str,
    port: int,
    rank: int,
    count: int,
    mine: Fingerprint,
    deadline: float,
) -> None:
    with connection:
        greeting = _read_line(connection, SEE_SECONDS)
        if greeting is None or greeting.get("rl_jax") != 1:
            raise JoinError(_held(host, port), held=True)
        sees = _sees(str(greeting["folder"]), str(greeting["nonce"]))
        hello = {"rank": rank, "count": count, "fingerprint": dataclasses.asdict(mine)}
        _send(connection, {**hello, "sees": sees})
        answer = _read_line(connection, max(deadline - time.monotonic(), SEE_SECONDS))
    if answer is None:
        raise JoinError("process 0 stopped while the processes joined (its output says why)")
    if "other_job" in answer:
        who = f" (process 0 of SLURM job step {answer['other_job']})"
        raise JoinError(_held(host, port, who), held=True)
    if "error" in answer:
        raise JoinError(str(answer["error"]))


# ---- a port moved: process 0 found its own held (SLURM) --------------------------------------


def port_file(resolved: str, job: str) -> Path:
    """Where process 0 writes the port it moved to: beside the run directory, named by job."""
    return nearest(resolved) / f"{PORT_PREFIX}{job}"


def read_port(path: Path) -> int | None:
    """The port in ``path``; None while there is none."""
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def move_port(path: Path) -> int:
    """A free port, written to ``path`` for the other processes."""
    with socket.socket() as probe:
        probe.bind(("", 0))
        port = probe.getsockname()[1]
    path.write_text(f"{port}\n")
    return port


def _held(host: str, port: int, who: str = "") -> str:
    return (
        f"the coordinator port {host}:{port} is held by another job or program{who}, not by this "
        "run's process 0; choose another port (--coordinator) for this run"
    )


def _sees(folder: str, nonce: str) -> bool:
    """Whether the file process 0 wrote is here (within a few seconds: a network file system
    may show it late). True when process 0 wrote none."""
    if not nonce:
        return True
    path = Path(folder) / (NONCE_PREFIX + nonce)
    deadline = time.monotonic() + SEE_SECONDS
    while not path.exists():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.2)
    return True
