"""``rl_jax.run.aborts``: a process of a run over several processes that jax's runtime aborts
prints one line, ours, and ends with status 1 (the end to end case, process 0 killed while the
processes compile, is ``test_faults.py``)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap

import pytest
from child_env import ROOT, python_path

import rl_jax
from rl_jax.run import aborts

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's sigaction")


def closed_port() -> int:
    """A port that nothing listens on (bound, then released)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_the_line_says_lost_contact_only_when_the_coordinator_is_gone():
    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        alive = f"127.0.0.1:{listening.getsockname()[1]}"
        assert "jax's runtime aborted it" in aborts.abort_line(1, alive)
    gone = f"127.0.0.1:{closed_port()}"
    line = aborts.abort_line(1, gone)
    assert line.startswith("error: process 1 lost contact with another process of the run")
    assert "process 0, which hosts jax's coordination service, stopped answering" in line
    # process 0 hosts the service itself; no address (not joined yet): never "lost contact"
    assert "jax's runtime aborted it" in aborts.abort_line(0, gone)
    assert "jax's runtime aborted it" in aborts.abort_line(1, None)
    for text in (line, aborts.abort_line(0, gone)):
        assert "\n" not in text and text.endswith(aborts.CONTINUE)


@pytest.mark.parametrize("coordinator", ["none", "gone"])
def test_an_abort_is_one_line_and_status_1(coordinator):
    address = None if coordinator == "none" else f"127.0.0.1:{closed_port()}"
    child = textwrap.dedent(
        f"""
        import os
        from rl_jax.run import aborts
        assert aborts.install(1, {address!r})
        print("installed", flush=True)
        os.abort()
        """
    )
    env = {**os.environ, "PYTHONPATH": python_path(ROOT)}
    done = subprocess.run(
        [sys.executable, "-c", child], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 1, done.stderr
    assert done.stdout == "installed\n"
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    expected = "lost contact with another" if address else "jax's runtime aborted it"
    assert expected in lines[0]


def test_the_runtime_log_is_turned_off_unless_the_user_chose_its_level(monkeypatch):
    from jax._src.lib import utils

    levels: list[int] = []
    monkeypatch.setattr(utils, "absl_set_min_log_level", levels.append)
    monkeypatch.setattr(rl_jax, "_cpp_log_level_chosen", True)
    aborts.quiet_runtime_log()
    assert levels == []
    monkeypatch.setattr(rl_jax, "_cpp_log_level_chosen", False)
    aborts.quiet_runtime_log()
    assert levels == [aborts.SILENT]
