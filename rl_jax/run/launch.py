"""Start an experiment script's command over several processes: on this machine, or as a SLURM job
through submitit. Each process runs the same command and they join through ``jax.distributed``
(``rl_jax.run.distributed``): one run whose process 0 writes the run directory.

  python -m rl_jax.run.launch --local 2 experiments/td3_pendulum.py --seeds 4 --out runs/p
  python -m rl_jax.run.launch --slurm --nodes 2 --tasks-per-node 4 --gpus-per-node 4 \\
      --time 240 --partition gpu experiments/td3_cheetah.py --seeds 16 --out runs/cheetah

``--local N`` starts N processes here with ``--coordinator``, ``--num-processes`` and
``--process-id`` added, each making its share of the cores into CPU devices
(``RL_JAX_CPU_DEVICES``, unless it is set). ``--pin`` keeps each process to its own block of
the cores, as SLURM's ``--cpu-bind`` does, so that their XLA thread pools do not compete; a
pinned process runs a smaller thread pool, whose matmuls sum in another order, so its results
are not bit for bit those of one process over the same devices (unpinned, they are). Nothing is
pinned with fewer cores than processes or where the system cannot pin (macOS). The launcher
shows process 0's output, passes Ctrl-C, SIGTERM and SIGUSR1 on to all of them, and
stops them all when one fails. ``--slurm`` submits the command with ``--distributed`` added:
each task learns its rank from SLURM. SLURM sends SIGUSR1 90 s before the time limit; the run
checkpoints and submitit requeues the job, whose same command then continues the run, after
every time limit (``--max-requeues N`` caps that; submitit's own cap of 3 is not used). submitit
is an optional dependency: ``pip install 'rl_jax[cluster]'``. docs/cluster.md has the details
and sbatch templates for the same jobs without submitit.

A COMMAND that starts with a ``.py`` file runs under this Python.
"""

from __future__ import annotations

import argparse
import importlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import IO

from rl_jax.errors import OneLineParser, UsageError, exit_now, guard, positive_int

#: What the runs print to stderr that says what went wrong (one line each).
ERROR_PREFIX = "error: "
FORWARDED = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1)


#: ``--max-requeues``'s default: more time limits than any run meets, so that the run, not a
#: count, decides when the job ends.
UNLIMITED_REQUEUES = 10_000


def parse(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """The launcher's flags, and the command after them."""
    parser = OneLineParser(
        prog="python -m rl_jax.run.launch",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--local", type=positive_int, metavar="N", help="N processes here")
    where.add_argument("--slurm", action="store_true", help="a SLURM job through submitit")
    parser.add_argument(
        "--pin",
        action="store_true",
        help="--local: keep each process to its own block of the cores (faster where the "
        "processes share a machine; other floating-point sums than one process makes)",
    )
    slurm = parser.add_argument_group("SLURM (--slurm)")
    slurm.add_argument("--nodes", type=positive_int, default=1, metavar="N", help="default: 1")
    slurm.add_argument(
        "--tasks-per-node", type=positive_int, default=1, metavar="N", help="processes per node"
    )
    slurm.add_argument("--cpus-per-task", type=positive_int, default=None, metavar="N")
    slurm.add_argument("--gpus-per-node", type=positive_int, default=None, metavar="N")
    slurm.add_argument(
        "--time", type=positive_int, default=60, metavar="MINUTES", help="time limit (60)"
    )
    slurm.add_argument("--partition", default=None)
    slurm.add_argument("--job-name", default="rl_jax")
    slurm.add_argument(
        "--logs", type=Path, default=Path("slurm_logs"), metavar="DIR", help="submitit's folder"
    )
    slurm.add_argument(
        "--max-requeues",
        type=positive_int,
        default=UNLIMITED_REQUEUES,
        metavar="N",
        help="requeues after the time limit before the job is left stopped (default: as many as "
        "the run needs; a preemption always requeues); submitit's own default is 3",
    )
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the script and its flags")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        raise UsageError("give the command to run: python -m rl_jax.run.launch --local 2 SCRIPT")
    if command[0].endswith(".py"):
        command = [sys.executable, *command]
    return args, command


def free_port() -> int:
    """A TCP port nothing listens on now (the coordinator's)."""
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


# ---- local processes ------------------------------------------------------------------------


def core_blocks(count: int, cores: Iterable[int] | None = None) -> list[set[int]] | None:
    """Disjoint blocks of ``cores`` (default: those this process may use), one per process:
    rank r gets the r-th run of ``len(cores) // count`` of them in order, the rest stay unused.
    None when they cannot be pinned: fewer cores than processes, or a system without
    ``os.sched_setaffinity`` (macOS)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    ordered = sorted(os.sched_getaffinity(0) if cores is None else cores)
    size = len(ordered) // count
    if size == 0:
        return None
    return [set(ordered[rank * size : (rank + 1) * size]) for rank in range(count)]


def _pin_to(cores: set[int]) -> Callable[[], None]:
    """What the child runs between fork and exec: keep to ``cores``, so that the processes'
    XLA CPU thread pools, which spin before they sleep, do not compete for the same cores. It
    makes one system call and takes no lock the launcher's reader threads could hold."""
    return lambda: os.sched_setaffinity(0, cores)


class LocalJob:
    """N processes of one command on this machine, joined through ``--coordinator``."""

    def __init__(self, command: list[str], count: int, port: int | None = None, pin: bool = False):
        self.command, self.count = command, count
        self.port = port or free_port()
        self.blocks = core_blocks(count) if pin else None
        self.processes: list[subprocess.Popen] = []
        self.errors: list[list[str]] = [[] for _ in range(count)]
        self._readers: list[threading.Thread] = []

    def environment(self) -> dict[str, str]:
        """Ours, with the CPU devices each process makes of its share of the cores (a pinned
        block has that many cores: ``core_blocks`` cuts the same share)."""
        env = dict(os.environ)
        if "RL_JAX_CPU_DEVICES" not in env:  # the cores shared out, one device each at least
            from rl_jax.training.jax_setup import cpu_count

            env["RL_JAX_CPU_DEVICES"] = str(max(1, cpu_count() // self.count))
        return env

    def start(self) -> None:
        """Start every process, with its rank's flags added to the command."""
        coordinator = f"localhost:{self.port}"
        for rank in range(self.count):
            flags = ["--coordinator", coordinator, "--num-processes", str(self.count)]
            process = subprocess.Popen(
                [*self.command, *flags, "--process-id", str(rank)],
                env=self.environment(),
                preexec_fn=None if self.blocks is None else _pin_to(self.blocks[rank]),
                # process 0's output is the run's; the others' stdout holds library chatter
                stdout=None if rank == 0 else subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
                start_new_session=True,  # Ctrl-C reaches them once, through forward()
            )
            self.processes.append(process)
            reader = threading.Thread(target=self._read, args=(rank, process.stderr), daemon=True)
            reader.start()
            self._readers.append(reader)

    def _read(self, rank: int, stream: IO[str] | None) -> None:
        """Process 0's stderr goes on to ours as it comes; every process's error lines are kept."""
        for line in stream or ():
            if rank == 0:
                sys.stderr.write(line)
                sys.stderr.flush()
            if line.startswith(ERROR_PREFIX):
                self.errors[rank].append(line.rstrip("\n"))

    def forward(self, signum: int, frame: types.FrameType | None = None) -> None:
        """Pass a signal on to every process still running."""
        for process in self.processes:
            if process.poll() is None:
                process.send_signal(signum)

    def wait(self, grace: float = 30.0) -> int:
        """Until all have ended; once one fails, the others are stopped (SIGTERM, then SIGKILL
        after ``grace`` seconds). The exit status: the first failure's, else 0."""
        failed: int | None = None
        deadline = None
        while any(process.poll() is None for process in self.processes):
            for rank, process in enumerate(self.processes):
                if failed is None and process.poll() not in (None, 0):
                    failed, deadline = rank, time.monotonic() + grace
                    self.forward(signal.SIGTERM)
            if deadline is not None and time.monotonic() > deadline:
                self.forward(signal.SIGKILL)
            time.sleep(0.1)
        for reader in self._readers:
            reader.join(timeout=5)
        if failed is None:
            failed = next((r for r, p in enumerate(self.processes) if p.returncode), None)
        if failed is None:
            return 0
        self._explain(failed)
        return _status(self.processes[failed].returncode)

    def _explain(self, failed: int) -> None:
        """One line on what failed, unless process 0 already said it."""
        if self.errors[0]:
            return
        said = self.errors[failed] or next((lines for lines in self.errors if lines), [])
        if said:
            print(said[-1], file=sys.stderr)
            return
        status = self.processes[failed].returncode
        how = f"was killed by {signal.Signals(-status).name}" if status < 0 else f"exited {status}"
        print(f"error: process {failed} of {self.count} {how}; stopped the others", file=sys.stderr)


def _status(returncode: int) -> int:
    return returncode if returncode > 0 else 128 - returncode


def run_local(command: list[str], count: int, pin: bool = False) -> int:
    """``command`` as ``count`` processes here, each on its own cores with ``pin``; returns the
    job's exit status."""
    job = LocalJob(command, count, pin=pin)
    previous = {signum: signal.signal(signum, job.forward) for signum in FORWARDED}
    try:
        job.start()
        return job.wait()
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


# ---- SLURM through submitit -----------------------------------------------------------------


class ClusterCommand:
    """What submitit runs in every task of the job: the command as a child process. On SLURM's
    warning signal (``checkpoint``, rank 0) it passes SIGUSR1 on to the run, waits for its
    checkpoint, and hands submitit the same command to requeue."""

    def __init__(self, command: list[str]):
        self.command = command
        self._child: subprocess.Popen | None = None

    def __call__(self) -> int:
        self._child = subprocess.Popen(self.command)
        while self._child.poll() is None:  # not wait(): checkpoint() may run meanwhile
            time.sleep(1.0)
        if self._child.returncode != 0:
            raise RuntimeError(f"{self.command[0]} exited with status {self._child.returncode}")
        return 0

    def checkpoint(self, *args: object, **kwargs: object) -> object:
        """Stop the run after its chunk (it checkpoints), then requeue the same command."""
        submitit = importlib.import_module("submitit")
        child = self._child
        if child is not None and child.poll() is None:
            child.send_signal(signal.SIGUSR1)
            while child.poll() is None:
                time.sleep(1.0)
        return submitit.helpers.DelayedSubmission(ClusterCommand(self.command))

    def __getstate__(self) -> dict[str, object]:
        return {"command": self.command, "_child": None}


def submit(command: list[str], args: argparse.Namespace) -> int:
    """Submit ``command --distributed`` as a SLURM job of ``args.nodes`` x
    ``args.tasks_per_node`` tasks; prints the job id and where its logs go."""
    # submitit's warning signal: the one the run checkpoints on (read when submitit is imported)
    os.environ.setdefault("SUBMITIT_PREEMPT_SIGNAL", "USR1")
    try:
        submitit = importlib.import_module("submitit")  # optional: the cluster extra
    except ImportError:
        raise UsageError(
            "--slurm needs submitit, which is not installed: pip install 'rl_jax[cluster]'"
        ) from None
    # submitit requeues a job preempted by SLURM as often as it happens, one that hit its time
    # limit only max_num_timeout times (3 unless told): a long run needs many of those
    executor = submitit.AutoExecutor(folder=str(args.logs), slurm_max_num_timeout=args.max_requeues)
    parameters: dict[str, int | str] = {
        "nodes": args.nodes,
        "tasks_per_node": args.tasks_per_node,
        "timeout_min": args.time,
        "name": args.job_name,
        "slurm_signal_delay_s": 90,
    }
    if args.cpus_per_task:
        parameters["cpus_per_task"] = args.cpus_per_task
    if args.gpus_per_node:
        parameters["gpus_per_node"] = args.gpus_per_node
    if args.partition:
        parameters["slurm_partition"] = args.partition
    executor.update_parameters(**parameters)
    job = executor.submit(ClusterCommand([*command, "--distributed"]))
    print(
        f"submitted SLURM job {job.job_id}: {args.nodes * args.tasks_per_node} processes; "
        f"logs in {args.logs}/"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m rl_jax.run.launch``: parse, then run here or submit."""
    args, command = parse(list(sys.argv[1:] if argv is None else argv))
    if args.slurm:
        return submit(command, args)
    return run_local(command, args.local, pin=args.pin)


if __name__ == "__main__":
    exit_now(guard(main))
