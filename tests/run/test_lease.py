"""One live owner per run directory (``rl_jax.run.lease``): a second live copy refuses with one
line naming the owner and leaves the run as it was; a lease whose owner is gone (a dead process
on this host, a heartbeat that stopped on another) is taken over, so a requeue continues."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from child_env import python_path
from run_helpers import fake_run

import rl_jax
from rl_jax.errors import RunError
from rl_jax.run import lease

ROOT = Path(__file__).resolve().parents[2]
OLD_RUN = ROOT / "tests" / "data" / "old_run_td3"


@pytest.fixture(autouse=True)
def quick_heartbeat(monkeypatch):
    monkeypatch.setattr(lease, "HEARTBEAT_SECONDS", 0.2)
    monkeypatch.setattr(lease, "STALE_SECONDS", 1.5)
    monkeypatch.setattr(lease, "POLL_SECONDS", 0.05)


def _write_lease(run_dir: Path, host: str, pid: int, heartbeat: float) -> None:
    owner = {"host": host, "pid": pid, "token": f"{host}:{pid}", "heartbeat": heartbeat}
    (run_dir / lease.LEASE_FILE).write_text(json.dumps({**owner, "started": "earlier"}))


def test_a_held_lease_refuses_a_second_owner_naming_the_first(tmp_path):
    with lease.acquire(tmp_path / "run", "first") as held:
        record = json.loads(held.path.read_text())
        assert record["host"] == socket.gethostname() and record["pid"] == os.getpid()
        started = time.time()
        with pytest.raises(RunError) as refused:
            lease.acquire(tmp_path / "run", "second")
        assert time.time() - started < lease.STALE_SECONDS + 1  # a fresh heartbeat was seen
        line = str(refused.value)
        assert "is in use by a live run" in line and f"pid {os.getpid()}" in line
        assert "\n" not in line
    assert not (tmp_path / "run" / lease.LEASE_FILE).exists()  # released


def test_a_lease_of_a_dead_process_here_is_taken_over_at_once(tmp_path):
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)  # fmt: skip
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_lease(run_dir, socket.gethostname(), int(finished.stdout), time.time())
    started = time.time()
    with lease.acquire(run_dir) as held:
        assert time.time() - started < 0.5
        assert json.loads(held.path.read_text())["pid"] == os.getpid()


def test_another_hosts_lease_is_taken_once_its_heartbeat_stops(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_lease(run_dir, "lost-node", 4242, time.time())
    started = time.time()
    with lease.acquire(run_dir) as held:
        waited = time.time() - started
        assert 1.0 < waited < lease.STALE_SECONDS + 1
        assert json.loads(held.path.read_text())["host"] == socket.gethostname()


def test_another_hosts_live_heartbeat_is_refused(tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    stop = threading.Event()

    def beat() -> None:
        while not stop.wait(0.2):
            _write_lease(run_dir, "busy-node", 4242, time.time())

    _write_lease(run_dir, "busy-node", 4242, time.time())
    beating = threading.Thread(target=beat)
    beating.start()
    try:
        with pytest.raises(RunError, match="in use by a live run \\(host busy-node, pid 4242"):
            lease.acquire(run_dir)
    finally:
        stop.set()
        beating.join()


HOLDER = """
import sys, time
from rl_jax.run import lease
held = lease.acquire(sys.argv[1], "the first copy")
print("held", flush=True)
time.sleep(600)
"""


def test_a_second_copy_of_a_run_leaves_it_untouched_and_a_killed_ones_run_continues(tmp_path):
    """The first copy (a child holding the run's lease) is alive: a resume refuses in one line
    and the run's files keep every byte. Killed, its lease is taken over and the run resumes."""
    run_dir = tmp_path / "run"
    shutil.copytree(OLD_RUN, run_dir)
    before = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
    env = {**os.environ, "PYTHONPATH": python_path(ROOT)}
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(run_dir)], env=env, stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(RunError, match=f"in use by a live run .*pid {holder.pid}"):
            rl_jax.resume(run_dir, total_steps=600, quiet=True)
        after = {p.name: p.read_bytes() for p in run_dir.iterdir() if p.is_file()}
        assert {name: after[name] for name in before} == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    resumed = rl_jax.resume(run_dir, total_steps=600, quiet=True)
    assert resumed.results.step == 600
    assert not (run_dir / lease.LEASE_FILE).exists()


def test_a_new_run_killed_before_its_record_left_a_directory_it_can_start_in(tmp_path):
    """A new run killed after taking its lease and before writing config.json leaves the lease
    alone in its directory: the same run started again takes it over and trains, where it was
    refused as a directory that is not empty."""
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)  # fmt: skip
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    _write_lease(run_dir, socket.gethostname(), int(finished.stdout), time.time())
    fake_run(run_dir, total_steps=20)
    assert (run_dir / "config.json").is_file() and (run_dir / "checkpoints").is_dir()
    assert not (run_dir / lease.LEASE_FILE).exists()  # released at the end
