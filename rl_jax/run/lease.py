"""One live owner per run directory: a lease file with host, PID and a heartbeat.

A run holds ``RUN_DIR/lease.json`` from before it reads its checkpoints until it ends. A second
copy of the same command on the same directory (a double-submitted job, a requeue while a lost
node still runs the old step) finds the lease and stops with one line naming the owner, before
it reads, truncates or writes anything. A lease whose owner is gone is taken over, so that a
requeued or restarted job continues by itself:

- on the same host, the owner's process no longer exists (while it does, it owns the run);
- on another host, its heartbeat stopped: the owner rewrites the file every
  ``HEARTBEAT_SECONDS``, and a newcomer that sees no new heartbeat for ``STALE_SECONDS`` takes
  the lease (it waits that long at most, and only when the lease's last heartbeat is recent).

The file is published whole with a hard link, which fails where the name exists, and replaced
through a rename, both atomic on local file systems and on NFS (v3 and later) and Lustre, where
``flock`` may not reach other hosts; a lease taken over is read back to check that this process
won.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import threading
import time
from pathlib import Path
from typing import TypedDict, cast

from rl_jax.errors import RunError
from rl_jax.run.run_dir import LEASE_FILE, write_json_atomic


class Holder(TypedDict, total=False):
    """What ``lease.json`` says of its owner (fields may be missing from a damaged file)."""

    host: str
    pid: int
    token: str
    started: str
    command: str
    heartbeat: float


HEARTBEAT_SECONDS = 10.0
STALE_SECONDS = 30.0
POLL_SECONDS = 1.0

#: Tokens of the leases this process holds now.
_HELD: set[str] = set()


class Lease:
    """This process's hold on a run directory; ``release()`` (or ``with``) gives it back."""

    def __init__(self, run_dir: Path, owner: Holder) -> None:
        self.path = Path(run_dir) / LEASE_FILE
        self.owner = owner
        _HELD.add(str(owner["token"]))
        self._stop = threading.Event()
        self._beat = threading.Thread(target=self._heartbeat, name="rl_jax-lease", daemon=True)
        self._beat.start()

    def _heartbeat(self) -> None:
        while not self._stop.wait(HEARTBEAT_SECONDS):
            if _read(self.path).get("token") != self.owner["token"]:
                return  # taken over (this process was thought gone): never write over it
            write_json_atomic(self.path, {**self.owner, "heartbeat": time.time()})

    def release(self) -> None:
        """Stop the heartbeat and remove the lease if it is still this process's."""
        self._stop.set()
        self._beat.join(timeout=5)
        _HELD.discard(str(self.owner["token"]))
        if _read(self.path).get("token") == self.owner["token"]:
            with contextlib.suppress(OSError):
                self.path.unlink()

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def acquire(run_dir: Path, command: str = "") -> Lease:
    """The lease of ``run_dir`` (created if the directory is new), or ``RunError`` naming the
    live owner."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    path = run_dir / LEASE_FILE
    now = time.time()
    owner: Holder = {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "token": f"{socket.gethostname()}:{os.getpid()}:{now:.6f}",
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "command": command,
        "heartbeat": now,
    }
    if _create(path, owner):
        return Lease(run_dir, owner)
    held = _wait_for_stale(path)
    if held is not None:
        raise RunError(_refusal(run_dir, held))
    # the former owner is gone: take over, then check that no one else did
    write_json_atomic(path, owner)
    if _read(path).get("token") != owner["token"]:
        raise RunError(_refusal(run_dir, _read(path)))
    return Lease(run_dir, owner)


def _create(path: Path, owner: Holder) -> bool:
    """Publish the lease file whole, only if none exists; False if one does. The file is
    written under a name of this process's first and then hard-linked into place, which fails
    where the name exists (on NFS too): no one ever reads a lease half written."""
    written = path.with_name(f"{path.name}.{os.getpid()}.new")
    written.write_text(json.dumps(owner))
    try:
        os.link(written, path)
    except FileExistsError:
        return False
    finally:
        written.unlink(missing_ok=True)
    return True


def _wait_for_stale(path: Path) -> Holder | None:
    """The lease's owner while it lives, None once it is gone: at once where that can be seen
    (the same host, an unreadable or missing file), else after watching the heartbeat."""
    held = _read(path)
    if not held or _gone_here(held):
        return None
    if held.get("host") == socket.gethostname():
        return held  # a live process of this host: no heartbeat needs watching
    deadline = float(held.get("heartbeat", 0.0)) + STALE_SECONDS
    while time.time() < deadline:
        time.sleep(POLL_SECONDS)
        now = _read(path)
        if not now or _gone_here(now):
            return None
        if now.get("heartbeat") != held.get("heartbeat") or now.get("token") != held.get("token"):
            return now  # a fresh heartbeat: the owner lives
    return None


def _gone_here(held: Holder) -> bool:
    """Whether the owner ran on this host and its process no longer exists (or is this process,
    which no longer holds that lease)."""
    if held.get("host") != socket.gethostname():
        return False
    pid = held.get("pid")
    if pid == os.getpid():
        return held.get("token") not in _HELD
    if not isinstance(pid, int):
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's live process
        return False
    return False


def _read(path: Path) -> Holder:
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return cast(Holder, value) if isinstance(value, dict) else {}


def _refusal(run_dir: Path, held: Holder) -> str:
    age = max(0.0, time.time() - float(held.get("heartbeat", 0.0)))
    return (
        f"{run_dir} is in use by a live run (host {held.get('host')}, pid {held.get('pid')}, "
        f"started {held.get('started')}, last heartbeat {age:.0f} s ago): stop that run first; "
        f"a run that was killed hands its lease on by itself within {STALE_SECONDS:.0f} s"
    )
