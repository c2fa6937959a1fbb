"""One run over several processes through ``jax.distributed``: the flags every entry point takes,
the checks that turn a bad cluster set-up into one line, and a time limit on every wait for the
other processes.

Every entry point (the experiment scripts, ``experiments/sweep.py``, ``rl-jax train|sweep``,
``rl_jax.train(distributed=...)``) starts the same way::

    argv = distributed.start(argv)   # takes the flags below out of argv, joins the processes

- ``--distributed``: under SLURM (``srun``) or Open MPI (``mpirun``) each process learns its rank,
  the process count and the coordinator from the scheduler, as ``jax.distributed.initialize()``
  reads them (jax's own cluster detection).
- ``--coordinator HOST:PORT --num-processes N --process-id I``: anywhere else (or to override
  the scheduler's coordinator address).
- ``--collective-timeout SECONDS``: the longest any process waits for the others: to join at
  the start, at each exchange between chunks, and at exit. A process that waited longer ends
  with one line, and so does one whose peer was killed (its connection drops at the next
  exchange): no process hangs on a dead one.

Every process computes its devices' share of the runs; process 0 alone writes the run
directory, prints and renders (``rl_jax.run.processes``). The run directory must be on a file
system every process sees (resuming reads its checkpoints in every process).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import socket
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import numpy as np
from jax.experimental import multihost_utils

from rl_jax.errors import (
    OneLineParser,
    UsageError,
    guard,
    parse_float,
    parse_int,
    positive_int,
)
from rl_jax.run import aborts, join, processes
from rl_jax.training.jax_setup import configure_jax

#: Seconds a process waits for the others by default (joining, each exchange, exit).
DEFAULT_TIMEOUT = 600.0
#: The flags of this module that take a value, and the one that takes none.
VALUE_FLAGS = ("--coordinator", "--num-processes", "--process-id", "--collective-timeout")
SWITCH_FLAGS = ("--distributed",)
#: What a collective's error says when a peer's connection dropped (gloo on CPU, the
#: coordination service, NCCL on GPU).
LOST_PEER_SIGNS = (
    *("gloo", "connection reset", "connection closed", "connection refused", "socket closed"),
    *("unavailable", "heartbeat", "nccl"),
)


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where this process stands: the coordinator, how many processes, which one this is, and
    who said so (``"slurm"``, ``"ompi"`` or ``"flags"``)."""

    coordinator: str | None  # None: the scheduler's own (jax derives it)
    num_processes: int
    process_id: int
    source: str


def resume_hint(command: str) -> str:
    """``command`` (a run's resume command) as the processes of this run would give it: with
    the flags that place each process, on every process."""
    if not _joined or jax.process_count() == 1:
        return command
    cluster = _joined[0]
    if command.startswith("rl_jax."):  # the Python API
        return f"{command} in every process, with the same distributed or coordinator arguments"
    if cluster.source != "flags":
        return f"{command} --distributed in every {cluster.source} task (or the same command again)"
    flags = f"--coordinator {cluster.coordinator} --num-processes {cluster.num_processes}"
    last = cluster.num_processes - 1
    return (
        f"{command} {flags} --process-id I on every process, I = 0 .. {last} (or the same "
        "command again on every process)"
    )


_joined: list[Cluster] = []  # the cluster this process joined


@dataclasses.dataclass(frozen=True)
class Options:
    """The distribution flags as given (``None``: not given)."""

    distributed: bool = False
    coordinator: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    timeout: float = DEFAULT_TIMEOUT


def positive_seconds(text: str) -> float:
    """A number of seconds > 0 (``--collective-timeout``)."""
    value = parse_float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def add_flags(parser: argparse.ArgumentParser) -> None:
    """The distribution flags, in their own ``--help`` group."""
    group = parser.add_argument_group("several processes (jax.distributed; docs/cluster.md)")
    group.add_argument(
        "--distributed",
        action="store_true",
        help="one run over the processes that SLURM (srun) or Open MPI (mpirun) started: rank, "
        "process count and coordinator come from the scheduler",
    )
    group.add_argument(
        "--coordinator",
        metavar="HOST:PORT",
        help="process 0's address and a free port, the same on every process",
    )
    group.add_argument(
        "--num-processes", type=positive_int, metavar="N", help="processes in the run"
    )
    group.add_argument("--process-id", type=parse_int, metavar="I", help="this one: 0 .. N-1")
    group.add_argument(
        "--collective-timeout",
        type=positive_seconds,
        default=DEFAULT_TIMEOUT,
        metavar="SECONDS",
        help="the longest a process waits for the others (to join, between chunks, at exit) "
        f"before it stops with an error (default: {DEFAULT_TIMEOUT:.0f})",
    )


def take(argv: list[str]) -> tuple[Options, list[str]]:
    """The distribution flags of ``argv``, and ``argv`` without them."""
    parser = OneLineParser(add_help=False)
    add_flags(parser)
    known, rest = parser.parse_known_args(argv)
    return options_from(known), rest


def options_from(known: argparse.Namespace) -> Options:
    """The distribution flags of a namespace that ``add_flags``'s parser filled."""
    return Options(
        known.distributed,
        known.coordinator,
        known.num_processes,
        known.process_id,
        known.collective_timeout,
    )


def without_flags(argv: list[str]) -> list[str]:
    """``argv`` less the distribution flags (with their values): two launches of one run may
    differ in them (another port, another rank) and still be the same command."""
    kept, skip = [], False
    for arg in argv:
        if skip:
            skip = False
        elif arg in VALUE_FLAGS:
            skip = True
        elif arg not in SWITCH_FLAGS and arg.split("=")[0] not in VALUE_FLAGS:
            kept.append(arg)
    return kept


# ---- who is who -----------------------------------------------------------------------------


def scheduler(environ: Mapping[str, str]) -> tuple[str, int, int] | None:
    """``(name, process count, this rank)`` from SLURM's or Open MPI's variables, as jax's own
    detection (``jax._src.clusters``) reads them; None outside both."""
    slurm = ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_NTASKS", "SLURM_PROCID")
    if all(name in environ for name in slurm):
        return "slurm", int(environ["SLURM_NTASKS"]), int(environ["SLURM_PROCID"])
    if "OMPI_MCA_orte_hnp_uri" in environ:
        size = environ.get("OMPI_COMM_WORLD_SIZE", "1")
        return "ompi", int(size), int(environ.get("OMPI_COMM_WORLD_RANK", "0"))
    return None


def resolve(options: Options, environ: Mapping[str, str] = os.environ) -> Cluster | None:
    """The cluster the flags (and the scheduler, with ``--distributed``) describe; None for one
    process. ``UsageError`` for flags that contradict each other or the scheduler."""
    if options.distributed:
        found = scheduler(environ)
        if found is None:
            if "SLURM_JOB_ID" in environ and options.coordinator is None:
                raise UsageError(
                    "--distributed inside a SLURM job but outside a job step: start the "
                    "processes with srun (srun python ... --distributed)"
                )
            if options.coordinator is None or options.num_processes is None:
                raise UsageError(
                    "--distributed found no SLURM or Open MPI job here (no SLURM_PROCID or "
                    "OMPI_MCA_orte_hnp_uri); start it with srun or mpirun, or give "
                    "--coordinator HOST:PORT --num-processes N --process-id I"
                )
            return _from_flags(options)
        name, count, rank = found
        if options.num_processes is not None and options.num_processes != count:
            raise UsageError(
                f"--num-processes {options.num_processes} does not match the {name} job's "
                f"{count} processes; leave it out under --distributed"
            )
        if options.process_id is not None and options.process_id != rank:
            raise UsageError(
                f"--process-id {options.process_id} does not match this process's {name} rank "
                f"{rank}; leave it out under --distributed"
            )
        return None if count == 1 else Cluster(options.coordinator, count, rank, name)
    if options.coordinator is None and options.num_processes in (None, 1):
        if options.process_id not in (None, 0):
            raise UsageError(f"--process-id {options.process_id} needs --num-processes > it")
        return None
    return _from_flags(options)


def _from_flags(options: Options) -> Cluster | None:
    count, rank = options.num_processes, options.process_id
    if options.coordinator is None or count is None or rank is None:
        raise UsageError(
            "several processes need all of --coordinator HOST:PORT, --num-processes N and "
            "--process-id I (or --distributed under SLURM or Open MPI)"
        )
    host, colon, port = options.coordinator.rpartition(":")
    if not colon or not host or not port.isdigit():
        raise UsageError(f"--coordinator {options.coordinator}: expected HOST:PORT")
    if not 0 <= rank < count:
        raise UsageError(f"--process-id {rank} must be in 0 .. {count - 1} (--num-processes)")
    return None if count == 1 else Cluster(options.coordinator, count, rank, "flags")


# ---- joining --------------------------------------------------------------------------------


def start(argv: list[str]) -> list[str]:
    """Take the distribution flags out of ``argv`` and, if they ask for several processes, join
    them (before JAX starts: device count and compilation cache first). Returns the rest."""
    given, rest = take(argv)
    begin(given, rest)
    return rest


def begin(given: Options, argv: Sequence[str]) -> None:
    """JAX's settings and, if ``given`` asks for several processes, the processes joined
    (before JAX starts: device count and compilation cache first). ``argv``: the command line,
    which every process must share (its distribution flags aside)."""
    cluster = resolve(given)
    configure_jax()
    if cluster is not None:
        initialize(cluster, given.timeout, join.fingerprint(without_flags(list(argv))))


def initialize(
    cluster: Cluster, timeout: float = DEFAULT_TIMEOUT, agreed: join.Fingerprint | None = None
) -> None:
    """``jax.distributed.initialize`` for ``cluster``, given ``timeout`` seconds for every
    process to join, once the processes agreed on ``agreed`` (``rl_jax.run.join``; None, as
    from ``rl_jax.train``: on the rank, the count and the job alone; a
    disagreement, a duplicate rank or a port held by another job is one line, ``UsageError``).
    jax ends a process that cannot join with a fatal log and a stack trace; a watchdog ends it
    a little earlier with one line instead."""
    if jax.distributed.is_initialized():
        return
    limit = int(timeout)
    address = coordinator_address(cluster)
    if address is not None:
        agreed = agreed or join.Fingerprint(job=join.job_key())
        address = handshake(cluster, address, timeout, agreed)
    _joined[:] = [cluster]
    watchdog = processes.Watchdog(timeout, lambda: _join_failed(cluster, timeout))
    aborts.quiet_runtime_log()
    with watchdog:
        jax.distributed.initialize(
            coordinator_address=address,
            num_processes=cluster.num_processes,
            process_id=cluster.process_id,
            # jax's own limits come after ours, so that ours speak first
            initialization_timeout=limit + 30,
            heartbeat_timeout_seconds=limit + 60,
            shutdown_timeout_seconds=limit + 30,
        )
    aborts.install(cluster.process_id, address or _jax_coordinator())
    processes.set_wait_limit(timeout)
    connect_quietly()


def _jax_coordinator() -> str | None:
    """The coordinator's ``HOST:PORT`` as jax found it itself (Open MPI), if it says."""
    from jax._src import distributed as jax_distributed

    address = getattr(getattr(jax_distributed, "global_state", None), "coordinator_address", None)
    return address if isinstance(address, str) else None


def _gather_over_every_device() -> None:
    """One all-gather over every device of every process: the group the runs' own gathers use,
    whose connections Gloo opens (and announces) once."""
    mesh = jax.sharding.Mesh(np.asarray(jax.devices()), ("devices",))
    spread = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("devices"))
    pieces = [jax.device_put(np.zeros(1, np.int32), device) for device in jax.local_devices()]
    local = jax.make_array_from_single_device_arrays((len(jax.devices()),), spread, pieces)
    everywhere = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    jax.jit(lambda values: values, out_shardings=everywhere)(local).block_until_ready()


def connect_quietly() -> None:
    """Open the connections between the processes with one small gather, its output to
    /dev/null: Gloo (the CPU collectives) prints a line on stdout from C++ as it connects
    ("[Gloo] Rank 0 is connected to 1 peer ranks ..."), and no setting of its own turns that
    off."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            with processes.waiting("the first exchange between the processes"):
                _gather_over_every_device()
                multihost_utils.process_allgather(np.zeros(1, np.int32))  # processes.agree's
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def coordinator_address(cluster: Cluster, environ: Mapping[str, str] = os.environ) -> str | None:
    """``HOST:PORT`` of the coordinator: the flag's, or under SLURM the step's first node on a
    port derived from the job and the step (jax's own derivation takes the job alone, so two
    steps of one job would meet on one port; ``JAX_COORDINATOR_PORT`` still sets it), or under
    Open MPI the launcher's host on the port jax derives from the job (``ompi_address``). Found
    here, not by jax, so that the processes' handshake runs under every scheduler."""
    if cluster.coordinator is not None or cluster.source not in ("slurm", "ompi"):
        return cluster.coordinator
    if environ.get("JAX_COORDINATOR_ADDRESS"):  # jax's own override of the whole address
        return environ["JAX_COORDINATOR_ADDRESS"]
    if cluster.source == "ompi":
        return ompi_address(environ)
    port = environ.get("JAX_COORDINATOR_PORT") or str(slurm_port(environ))
    return f"{first_node(environ['SLURM_STEP_NODELIST'])}:{port}"


def ompi_address(environ: Mapping[str, str]) -> str | None:
    """``HOST:PORT`` under Open MPI (4.x, ``OMPI_MCA_orte_hnp_uri`` such as
    ``1531576320.0;tcp://10.96.0.1,10.148.0.1:34911``): the launcher's first address, and as
    jax derives it, a port in 61440 .. 65535 from the job id (a multiple of 4,096), unless
    ``JAX_COORDINATOR_PORT`` sets it. None when the URI cannot be read: jax then finds the
    address itself, without our handshake."""
    uri = environ.get("OMPI_MCA_orte_hnp_uri", "")
    job, _, rest = uri.partition(".")
    found = re.search(r"tcp://([^,:]+)|tcp6://\[([^,\]]+)", rest)
    if not job.isdigit() or found is None:
        return None
    host = found.group(1) or f"[{found.group(2)}]"
    port = environ.get("JAX_COORDINATOR_PORT") or str(61440 + (int(job) // 4096) % 4096)
    return f"{host}:{port}"


def slurm_port(environ: Mapping[str, str]) -> int:
    """A port in jax's range (61440 .. 65535) from the job id and the step id: the steps of one
    job get different ports."""
    job = int(environ["SLURM_JOB_ID"])
    step = environ.get("SLURM_STEP_ID", "0")
    step_id = int(step) if step.isdigit() else 0
    return 61440 + (job * 16 + step_id % 16) % 4096


def first_node(node_list: str) -> str:
    """The first host of a SLURM node list (``node[001-004],gpu7`` -> ``node001``), as jax's
    ``SlurmCluster`` reads it."""
    end = next((i for i, ch in enumerate(node_list) if ch in ",["), len(node_list))
    if end == len(node_list) or node_list[end] == ",":
        return node_list[:end]
    suffix = node_list[end + 1 :]
    stop = next((i for i, ch in enumerate(suffix) if ch in ",-]"), len(suffix))
    return node_list[:end] + suffix[:stop]


def handshake(cluster: Cluster, address: str, timeout: float, agreed: join.Fingerprint) -> str:
    """The processes' agreement before jax joins them (``rl_jax.run.join``): one line
    (``UsageError``) on any disagreement, a duplicate rank or a port held by another job;
    process 0's port is checked before jax binds it. Returns the coordinator's address: under
    SLURM on a derived port, process 0 moves to a free port when it finds its own held and
    tells the others through a file beside the run directory (named by job, step and restart).
    """
    host, _, port_text = address.rpartition(":")
    host, port = host.strip("[]"), int(port_text)
    rank, count = cluster.process_id, cluster.num_processes
    scheduled = cluster.source == "slurm" and cluster.coordinator is None
    fixed = {"JAX_COORDINATOR_PORT", "JAX_COORDINATOR_ADDRESS"} & set(os.environ)
    derived = scheduled and not fixed
    if not scheduled:  # processes placed by hand may sit in different SLURM steps: one job
        agreed = dataclasses.replace(agreed, job="")
    moved_to = join.port_file(agreed.resolved, agreed.job) if derived else None
    try:
        if rank == 0:
            port = _lead(host, port, count, agreed, timeout, moved_to)
        else:
            moved = None if moved_to is None else lambda: join.read_port(moved_to)
            port = join.follow(host, port, rank, count, agreed, timeout, moved)
    except join.JoinError as error:
        raise UsageError(str(error)) from None
    except TimeoutError:
        processes.give_up(_join_failed(cluster, timeout))
    return f"{host}:{port}"


def _lead(
    host: str,
    port: int,
    count: int,
    agreed: join.Fingerprint,
    timeout: float,
    moved_to: Path | None,
) -> int:
    """Process 0's side of the handshake; returns the port it held."""
    try:
        join.lead(port, count, agreed, timeout)
        return port
    except join.PortTaken:
        pass
    try:  # held here: by another process 0 of this run (a duplicate rank), or not ours
        join.follow(host, port, 0, count, agreed, join.SEE_SECONDS)
    except join.JoinError as error:
        if not error.held or moved_to is None:
            raise
    except TimeoutError:
        if moved_to is None:
            raise join.JoinError(
                f"the coordinator port {port} is held on this host ({socket.gethostname()}) by "
                "another job or program; choose another port for this run"
            ) from None
    assert moved_to is not None
    try:
        elsewhere = join.move_port(moved_to)
        join.lead(elsewhere, count, agreed, timeout)
    finally:
        moved_to.unlink(missing_ok=True)
    return elsewhere


def _join_failed(cluster: Cluster, timeout: float) -> str:
    address = cluster.coordinator or os.environ.get("JAX_COORDINATOR_ADDRESS", "")
    how = f"--process-id 0 .. {cluster.num_processes - 1} with the same --coordinator"
    if cluster.source != "flags":
        how = f"the {cluster.source} job's tasks"
    if cluster.process_id != 0 and address and not aborts.answers(address):
        return (
            f"cannot reach the coordinator {address} within {timeout:g} s (process 0 must be "
            "running there, and the port open)"
        )
    return (
        f"the {cluster.num_processes} processes did not all join within {timeout:g} s "
        f"(coordinator {address or 'of the scheduler'}); start all of them: {how}"
    )


# ---- running --------------------------------------------------------------------------------


def is_lost_peer(error: BaseException) -> bool:
    """Whether ``error`` is a collective that failed because another process went away."""
    text = str(error).lower()
    return any(sign in text for sign in LOST_PEER_SIGNS)


def guarded(function: Callable[[], int]) -> int:
    """``rl_jax.errors.guard(function)``, and in a run over several processes a collective that
    failed because another process stopped is one line and status 1 too (every process stops;
    the run's latest checkpoint is kept, and the same command continues it)."""
    try:
        return guard(function)
    except Exception as error:
        if not (jax.distributed.is_initialized() and is_lost_peer(error)):
            raise
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        print(aborts.lost_contact_line(jax.process_index(), first), file=sys.stderr, flush=True)
        return 1


def slurm_requeue(notify: Callable[[str], None] = print) -> None:
    """Put this SLURM job back in the queue (``scontrol requeue``): its command then continues
    the run when it starts again. Not under submitit, which requeues its own jobs."""

    job = os.environ.get("SLURM_JOB_ID")
    if not job or os.environ.get("SUBMITIT_EXECUTOR"):
        return
    try:
        subprocess.run(["scontrol", "requeue", job], check=True, capture_output=True, timeout=60)
    except (OSError, subprocess.SubprocessError) as error:
        print(f"warning: could not requeue SLURM job {job}: {error}", file=sys.stderr, flush=True)
        return
    notify(f"requeued SLURM job {job}: the same command continues this run when it starts again")
