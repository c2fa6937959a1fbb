"""The processes' agreement before jax joins them (``rl_jax.run.join``): in process over
threads, and with two processes started by hand, each case one line on every process."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from unittest import mock

import pytest
from test_distributed import ENV, SCRIPT

from rl_jax.run import distributed, join, launch

TINY = ["--total-steps", "100", "--iterations-per-chunk", "5", "--log-interval", "0"]
TINY += ["--checkpoint-interval", "0"]


def test_slurm_coordinator_is_the_first_node_on_a_port_of_the_job_and_step():
    slurm = {"SLURM_JOB_ID": "4242", "SLURM_STEP_NODELIST": "node[007-009],gpu1"}
    cluster = distributed.Cluster(None, 2, 1, "slurm")
    first = distributed.coordinator_address(cluster, {**slurm, "SLURM_STEP_ID": "0"})
    second = distributed.coordinator_address(cluster, {**slurm, "SLURM_STEP_ID": "1"})
    assert first is not None and first.startswith("node007:") and second.startswith("node007:")
    assert first != second  # two steps of one job: two ports
    assert all(61440 <= int(address.split(":")[1]) <= 65535 for address in (first, second))
    given = {**slurm, "JAX_COORDINATOR_PORT": "1234"}
    assert distributed.coordinator_address(cluster, given) == "node007:1234"
    given = {**slurm, "JAX_COORDINATOR_ADDRESS": "head:99"}
    assert distributed.coordinator_address(cluster, given) == "head:99"
    assert distributed.first_node("a1,b2") == "a1" and distributed.first_node("solo") == "solo"
    assert distributed.first_node("n[1,3-4]") == "n1"
    ompi = distributed.Cluster(None, 2, 1, "ompi")
    assert distributed.coordinator_address(ompi, {}) is None  # jax's own


def test_the_fingerprint_leaves_out_the_process_flags_and_reads_seeds_and_out(tmp_path):
    argv = ["--seeds", "3", "--out=runs/x", "--gamma", "0.9"]
    mine = join.fingerprint(argv, {"SLURM_JOB_ID": "7", "SLURM_STEP_ID": "2"})
    assert mine.seeds == "3" and mine.out == "runs/x" and mine.job == "7.2.0"
    assert mine.resolved == str(Path("runs/x").resolve())
    placed = distributed.without_flags([*argv, "--coordinator", "h:1", "--process-id", "1"])
    assert join.fingerprint(placed, {}).command == join.fingerprint(argv, {}).command
    assert join.fingerprint([*argv, "--gif"], {}).command != mine.command


def handshake(
    tmp_path: Path, others: list[tuple[int, int, join.Fingerprint]], count: int = 2
) -> list[str]:
    """Process 0 (``count`` processes, fingerprint of ``tmp_path``) and ``others`` (rank,
    count, fingerprint), each in a thread: what each one ended with ("ok" or its line)."""
    port = launch.free_port()
    mine = join.Fingerprint("c", "2", "run", str(tmp_path / "run"))
    results = ["" for _ in range(len(others) + 1)]

    def side(index: int, call) -> None:
        try:
            call()
            results[index] = "ok"
        except (join.JoinError, TimeoutError) as error:
            results[index] = str(error) or type(error).__name__

    threads = [threading.Thread(target=side, args=(0, lambda: join.lead(port, count, mine, 20)))]
    for index, (rank, their_count, theirs) in enumerate(others, start=1):
        call = lambda r=rank, c=their_count, f=theirs: join.follow("localhost", port, r, c, f, 20)  # noqa: E731
        threads.append(threading.Thread(target=side, args=(index, call)))
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    return results


def test_processes_that_agree_join_and_leave_no_file_behind(tmp_path):
    same = join.Fingerprint("c", "2", "run", str(tmp_path / "run"))
    assert handshake(tmp_path, [(1, 3, same), (2, 3, same)], count=3) == ["ok", "ok", "ok"]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("rank", "count", "changes", "expected"),
    [
        (1, 2, {"seeds": "3"}, "--seeds differs between the processes: 2 on process 0, 3 on"),
        (1, 2, {"out": "other"}, "--out differs between the processes: run on process 0, other"),
        (1, 2, {"command": "d"}, "process 1 runs another command than process 0"),
        (1, 3, {}, "--num-processes differs between the processes: 2 on process 0, 3 on"),
        (0, 2, {}, "duplicate --process-id 0: two processes of the run were given it"),
    ],
)
def test_a_disagreement_is_the_same_line_on_every_process(tmp_path, rank, count, changes, expected):
    theirs = join.Fingerprint(**{"command": "c", "seeds": "2", "out": "run", **changes})
    theirs = join.Fingerprint(**{**theirs.__dict__, "resolved": str(tmp_path / "run")})
    results = handshake(tmp_path, [(rank, count, theirs)])
    assert results[0] == results[1] and results[0].startswith(expected), results


def test_a_run_directory_one_host_cannot_see_is_named(monkeypatch, tmp_path):
    """Another host's view, played here: process 0's file is not where the other looks."""
    monkeypatch.setattr(join, "_write_nonce", lambda resolved: (tmp_path, "0123456789abcdef"))
    monkeypatch.setattr(join, "SEE_SECONDS", 0.5)
    same = join.Fingerprint("c", "2", "run", str(tmp_path / "run"))
    results = handshake(tmp_path, [(1, 2, same)])
    assert results[0] == results[1], results
    assert results[0].startswith("the run directory is not shared between the processes' hosts")


def test_a_process_of_another_slurm_step_is_turned_away_and_the_job_goes_on(tmp_path):
    """Two steps (or jobs) that meet on one port: process 0 answers the stranger "not this job"
    and keeps waiting for its own processes."""
    port = launch.free_port()
    mine = join.Fingerprint("c", "2", "run", str(tmp_path / "run"), "7.0.0")
    stranger = join.Fingerprint("d", "3", "other", str(tmp_path / "other"), "7.1.0")
    ended: list[BaseException] = []

    def lead() -> None:
        try:
            join.lead(port, 2, mine, 3)
        except (join.JoinError, TimeoutError) as error:
            ended.append(error)

    thread = threading.Thread(target=lead)
    thread.start()
    with pytest.raises(join.JoinError, match=r"process 0 of SLURM job step 7\.0\.0") as caught:
        join.follow("localhost", port, 1, 2, stranger, 10)
    assert caught.value.held
    thread.join(timeout=30)
    assert len(ended) == 1 and isinstance(ended[0], TimeoutError)  # not refused by the stranger


def test_another_job_on_the_port_is_left_alone(tmp_path, monkeypatch):
    """A port answered by something else (here a silent listener, as jax's service is to us):
    the process says so, and sends it nothing."""
    monkeypatch.setattr(join, "SEE_SECONDS", 0.5)  # the wait for a greeting that never comes
    port = launch.free_port()
    received: list[bytes] = []
    with socket.create_server(("", port)) as holder:

        def serve() -> None:
            connection, _ = holder.accept()
            with connection:
                connection.settimeout(10)
                received.append(connection.recv(100))

        thread = threading.Thread(target=serve)
        thread.start()
        assert not join.port_is_free(port)
        with pytest.raises(join.JoinError, match="is held by another job or program"):
            join.follow("localhost", port, 1, 2, join.Fingerprint(), 10)
        thread.join(timeout=30)
    assert received == [b""]


# ---- two processes started by hand ---------------------------------------------------------


def by_hand(cwd: Path, *commands: list[str]) -> list[subprocess.CompletedProcess]:
    """Each of ``commands`` as a process of the fake script, started at once; their ends."""
    started = [
        subprocess.Popen(
            [sys.executable, str(SCRIPT), *TINY, *command],
            cwd=cwd,
            env={**ENV, "RL_JAX_CPU_DEVICES": "1"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for command in commands
    ]
    ended = []
    for process in started:
        out, err = process.communicate(timeout=120)
        ended.append(subprocess.CompletedProcess(process.args, process.returncode, out, err))
    return ended


def places(port: int, rank: int, count: int = 2) -> list[str]:
    return ["--coordinator", f"localhost:{port}", "--num-processes", str(count)] + [
        "--process-id",
        str(rank),
    ]


def assert_one_line_each(ended: list[subprocess.CompletedProcess], expected: str) -> None:
    for done in ended:
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, done.stderr
        assert lines[0].startswith(f"error: {expected}"), done.stderr


@pytest.mark.parametrize(
    ("second", "expected"),
    [
        (["--seeds", "3", "--out", "run", "--process-id", "1"], "--seeds differs"),
        (["--seeds", "2", "--out", "other", "--process-id", "1"], "--out differs"),
        (["--seeds", "2", "--out", "run", "--process-id", "0"], "duplicate --process-id 0"),
    ],
)
def test_processes_started_by_hand_that_disagree_stop_with_one_line(tmp_path, second, expected):
    port = launch.free_port()
    first = ["--seeds", "2", "--out", "run", *places(port, 0)]
    started = time.monotonic()
    ended = by_hand(tmp_path, first, [*second[:-2], *places(port, int(second[-1]))])
    assert time.monotonic() - started < 30
    assert_one_line_each(ended, expected)
    assert list(tmp_path.iterdir()) == []  # nothing written, not even the check's file


def test_open_mpi_addresses_are_jaxs_and_its_processes_that_disagree_stop_with_one_line(
    tmp_path,
):
    """Under Open MPI the address comes from the launcher's URI as jax derives it (so that our
    handshake runs there too), and two ranks given different ``--seeds`` stop with one line."""
    from jax._src.clusters.ompi_cluster import OmpiCluster

    for uri in (
        "1531576320.0;tcp://10.96.0.1,10.148.0.1,10.108.0.1:34911",
        "1314521088.0;tcp6://[fe80::b9b:ac5d:9cf0:b858,2620:10d:c083:150e::3000:2]:43370",
    ):
        with mock.patch.dict(os.environ, {"OMPI_MCA_orte_hnp_uri": uri}):
            theirs = OmpiCluster.get_coordinator_address(None, None)
        host, port = theirs.rsplit(":", 1)
        ours = distributed.ompi_address({"OMPI_MCA_orte_hnp_uri": uri})
        assert ours in (theirs, f"[{host}]:{port}")
    assert distributed.ompi_address({"OMPI_MCA_orte_hnp_uri": "garbled"}) is None
    port = str(launch.free_port())

    def rank(index: int, seeds: str) -> subprocess.Popen:
        ompi = {
            "OMPI_MCA_orte_hnp_uri": "1531576320.0;tcp://127.0.0.1:1",
            "OMPI_COMM_WORLD_SIZE": "2",
            "OMPI_COMM_WORLD_RANK": str(index),
            "OMPI_COMM_WORLD_LOCAL_RANK": str(index),
            "JAX_COORDINATOR_PORT": port,
        }
        return subprocess.Popen(
            [sys.executable, str(SCRIPT), *TINY, "--seeds", seeds, "--out", "run", "--distributed"],
            cwd=tmp_path,
            env={**ENV, "RL_JAX_CPU_DEVICES": "1", **ompi},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    started = time.monotonic()
    ranks = [rank(0, "2"), rank(1, "3")]
    ended = []
    for process in ranks:
        out, err = process.communicate(timeout=120)
        ended.append(subprocess.CompletedProcess(process.args, process.returncode, out, err))
    assert time.monotonic() - started < 30
    assert_one_line_each(ended, "--seeds differs")


@pytest.mark.slow
def test_a_count_mismatch_by_hand_stops_both_with_one_line(tmp_path):
    port = launch.free_port()
    started = time.monotonic()
    ended = by_hand(
        tmp_path, ["--seeds", "2", *places(port, 0, 3)], ["--seeds", "2", *places(port, 1, 2)]
    )
    assert time.monotonic() - started < 30
    assert_one_line_each(ended, "--num-processes differs between the processes: 3 on process 0")


@pytest.mark.slow
def test_a_port_held_by_another_program_is_one_line_on_every_rank(tmp_path):
    port = launch.free_port()
    with socket.create_server(("", port)):
        started = time.monotonic()
        ended = by_hand(
            tmp_path, ["--seeds", "2", *places(port, 0)], ["--seeds", "2", *places(port, 1)]
        )
    assert time.monotonic() - started < 30
    assert_one_line_each(ended, f"the coordinator port localhost:{port} is held by another job")


@pytest.mark.slow
def test_a_second_job_on_the_port_stops_and_the_first_finishes(tmp_path):
    port = launch.free_port()
    first = [
        subprocess.Popen(
            [sys.executable, str(SCRIPT), *TINY, "--total-steps", "2000", "--seeds", "2"]
            + ["--out", "first", *places(port, rank)],
            cwd=tmp_path,
            env={**ENV, "RL_JAX_CPU_DEVICES": "1"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for rank in (0, 1)
    ]
    for line in first[0].stdout:  # training has started: jax's service holds the port
        if line.startswith("step "):
            break
    second = by_hand(
        tmp_path,
        ["--seeds", "2", "--out", "second", *places(port, 0)],
        ["--seeds", "2", "--out", "second", *places(port, 1)],
    )
    assert_one_line_each(second, f"the coordinator port localhost:{port} is held by another job")
    for process in first:
        out, err = process.communicate(timeout=300)
        assert process.returncode == 0, err
    assert (tmp_path / "first" / "results.txt").exists() and not (tmp_path / "second").exists()


def slurm_task(job: str, rank: int) -> dict[str, str]:
    """The variables of one task of a two-task SLURM step on this host."""
    return {
        "SLURM_JOB_ID": job,
        "SLURM_STEP_ID": "0",
        "SLURM_STEP_NODELIST": "localhost",
        "SLURM_NTASKS": "2",
        "SLURM_PROCID": str(rank),
        "SLURM_LOCALID": str(rank),
    }


@pytest.mark.slow
def test_under_slurm_a_held_port_moves_and_the_others_follow_through_the_run_directory(tmp_path):
    """The port derived from the job and step is held (another job's step, say): process 0
    takes a free one and writes it beside the run directory; the other reads it and joins."""
    job = next(
        str(job)
        for job in range(1000, 5000)
        if join.port_is_free(distributed.slurm_port({"SLURM_JOB_ID": str(job)}))
    )
    port = distributed.slurm_port({"SLURM_JOB_ID": job})
    with socket.create_server(("", port)):
        started = [
            subprocess.Popen(
                [sys.executable, str(SCRIPT), *TINY, "--seeds", "2", "--out", "run"]
                + ["--distributed"],
                cwd=tmp_path,
                env={**ENV, "RL_JAX_CPU_DEVICES": "1", **slurm_task(job, rank)},
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for rank in (0, 1)
        ]
        ended = [process.communicate(timeout=300) for process in started]
    for process, (_out, err) in zip(started, ended, strict=True):
        assert process.returncode == 0, err
    assert (tmp_path / "run" / "results.txt").exists()
    assert not list(tmp_path.glob(".rl_jax-*"))  # the port's file is gone with the handshake


# ---- what the lead says of the other processes ------------------------------------------------


def test_the_resume_hint_gives_the_process_flags(monkeypatch):
    monkeypatch.setattr(distributed.jax, "process_count", lambda: 2)
    monkeypatch.setattr(distributed, "_joined", [distributed.Cluster("h:1", 2, 0, "flags")])
    assert distributed.resume_hint("x.py --resume run") == (
        "x.py --resume run --coordinator h:1 --num-processes 2 --process-id I on every process, "
        "I = 0 .. 1 (or the same command again on every process)"
    )
    monkeypatch.setattr(distributed, "_joined", [distributed.Cluster(None, 2, 0, "slurm")])
    assert distributed.resume_hint("x.py --resume run") == (
        "x.py --resume run --distributed in every slurm task (or the same command again)"
    )
    assert distributed.resume_hint("rl_jax.resume('run')").endswith(
        "in every process, with the same distributed or coordinator arguments"
    )
    monkeypatch.setattr(distributed, "_joined", [])
    assert distributed.resume_hint("x.py --resume run") == "x.py --resume run"


def test_the_lead_names_the_process_whose_signal_stops_the_run(monkeypatch):
    import numpy as np

    from rl_jax.run import processes

    # columns as the runner's agree gives them: checkpoint due, stop asked, requeue
    monkeypatch.setattr(processes, "_last_agreed", [np.array([[0, 0, 0], [1, 1, 0]])])
    assert processes.stopped_by(asked=1, requeue=2) == "SIGTERM or SIGINT on process 1"
    monkeypatch.setattr(processes, "_last_agreed", [np.array([[0, 0, 0], [0, 1, 1], [0, 1, 1]])])
    assert processes.stopped_by(asked=1, requeue=2) == "SIGUSR1 on processes 1, 2"


def can_hide_folders() -> bool:
    """Whether this process may mount over a folder in a namespace of its own (root, or user
    namespaces): how a host that does not share a folder is played here."""
    try:
        done = subprocess.run(
            ["unshare", "-m", "--map-root-user", "true"], capture_output=True, timeout=30
        )
    except (OSError, subprocess.SubprocessError):
        return False
    return done.returncode == 0


@pytest.mark.slow
@pytest.mark.skipif(not can_hide_folders(), reason="needs unshare -m (a mount namespace)")
def test_a_run_directory_another_process_cannot_see_stops_both_with_one_line(tmp_path):
    """Process 1 runs in a mount namespace where an empty tmpfs covers the folder that holds
    the run directory: the same path, another file system, as on a host that does not share
    it."""
    port = launch.free_port()
    out = ["--seeds", "2", "--out", str(tmp_path / "run")]
    hidden = f'mount -t tmpfs none "{tmp_path}" && exec "$@"'  # the same path, an empty folder
    command = [sys.executable, str(SCRIPT), *TINY, *out, *places(port, 1)]
    started = time.monotonic()
    processes = [
        subprocess.Popen(
            [sys.executable, str(SCRIPT), *TINY, *out, *places(port, 0)],
            cwd=tmp_path,
            env={**ENV, "RL_JAX_CPU_DEVICES": "1"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        ),
        subprocess.Popen(
            ["unshare", "-m", "--map-root-user", "sh", "-c", hidden, "sh", *command],
            cwd="/",
            env={**ENV, "RL_JAX_CPU_DEVICES": "1"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        ),
    ]
    ended = []
    for process in processes:
        stdout, stderr = process.communicate(timeout=120)
        ended.append(subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr))
    assert time.monotonic() - started < 30
    assert_one_line_each(ended, "the run directory is not shared between the processes' hosts")
    assert list(tmp_path.iterdir()) == []
