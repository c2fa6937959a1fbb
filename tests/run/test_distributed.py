"""One run over several processes (``rl_jax.run.distributed``, ``rl_jax.run.launch``): the
set-up checks, a same command that continues its run, and, through the launcher's local mode,
two processes of one CPU device each against one process with two devices, a requeue, and a
killed process."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import fake_algorithm as fake
import psutil
import pytest
from child_env import python_path
from run_helpers import leaves_bytes

from rl_jax.errors import RunError, UsageError
from rl_jax.run import distributed, launch
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec
from rl_jax.run.start import GracefulStop

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tests" / "fake_experiment.py"
ENV = {
    **{key: value for key, value in os.environ.items() if key not in ("TF_CPP_MIN_LOG_LEVEL",)},
    "PYTHONPATH": python_path(ROOT),
}
ENV.pop("XLA_FLAGS", None)  # the device count is the launcher's (RL_JAX_CPU_DEVICES)
SLURM = {
    "SLURM_JOB_ID": "4242",
    "SLURM_STEP_NODELIST": "node[001-002]",
    "SLURM_NTASKS": "2",
    "SLURM_PROCID": "1",
    "SLURM_LOCALID": "0",
}


# ---- the set-up, in process ------------------------------------------------------------------


def options(**given) -> distributed.Options:
    return distributed.Options(**given)


def test_one_process_needs_no_flags_and_several_need_all_three():
    assert distributed.resolve(options(), {}) is None
    assert distributed.resolve(options(num_processes=1), {}) is None
    cluster = distributed.resolve(
        options(coordinator="host:1234", num_processes=2, process_id=1), {}
    )
    assert cluster == distributed.Cluster("host:1234", 2, 1, "flags")
    with pytest.raises(UsageError, match="need all of --coordinator"):
        distributed.resolve(options(num_processes=2, process_id=0), {})
    with pytest.raises(UsageError, match="expected HOST:PORT"):
        distributed.resolve(options(coordinator="host", num_processes=2, process_id=0), {})
    with pytest.raises(UsageError, match=r"--process-id 2 must be in 0 \.\. 1"):
        distributed.resolve(options(coordinator="h:1", num_processes=2, process_id=2), {})


def test_distributed_reads_the_scheduler_and_refuses_what_contradicts_it():
    with pytest.raises(UsageError, match="--distributed found no SLURM or Open MPI job here"):
        distributed.resolve(options(distributed=True), {})
    assert distributed.resolve(options(distributed=True), SLURM) == distributed.Cluster(
        None, 2, 1, "slurm"
    )
    with pytest.raises(UsageError, match="--num-processes 4 does not match the slurm job's 2"):
        distributed.resolve(options(distributed=True, num_processes=4), SLURM)
    with pytest.raises(UsageError, match="--process-id 0 does not match"):
        distributed.resolve(options(distributed=True, process_id=0), SLURM)
    ompi = {"OMPI_MCA_orte_hnp_uri": "1;tcp://10.0.0.1:1", "OMPI_COMM_WORLD_SIZE": "3"}
    assert distributed.resolve(options(distributed=True), ompi).num_processes == 3


def test_train_from_python_checks_its_cluster_arguments_first(monkeypatch, tmp_path):
    import rl_jax

    for name in ("SLURM_JOB_ID", "SLURM_PROCID", "OMPI_MCA_orte_hnp_uri"):
        monkeypatch.delenv(name, raising=False)
    with pytest.raises(UsageError, match="--distributed found no SLURM or Open MPI job"):
        rl_jax.train("td3", "rl_jax/Pendulum-v1", out=tmp_path / "run", distributed=True)
    with pytest.raises(UsageError, match="need all of --coordinator"):
        rl_jax.train("td3", "rl_jax/Pendulum-v1", out=tmp_path / "run", num_processes=2)
    assert not (tmp_path / "run").exists()


def test_flags_are_taken_out_and_left_out_of_the_compared_command():
    argv = ["--seeds", "2", "--distributed", "--coordinator", "h:1", "--process-id=1", "--gif"]
    taken, rest = distributed.take(argv)
    assert taken.distributed and taken.coordinator == "h:1" and taken.process_id == 1
    assert rest == ["--seeds", "2", "--gif"]
    assert distributed.without_flags(argv) == ["--seeds", "2", "--gif"]


def test_sigusr1_asks_to_stop_after_the_chunk():
    said = []
    with GracefulStop(said.append) as stop:
        os.kill(os.getpid(), signal.SIGUSR1)
        time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGTERM)  # asked already: no second line
        time.sleep(0.1)
    assert stop.requested == "SIGUSR1" and len(said) == 1 and said[0].startswith("SIGUSR1: stop")


def test_a_stop_agreed_with_another_process_leaves_the_first_ctrl_c_a_first_one():
    """Another process's signal stops this one too; a Ctrl-C here then asks again (nothing to
    add), and only a second one aborts, as it would without the other process's signal."""
    said = []
    with GracefulStop(said.append) as stop:
        stop.requested = "another process"
        stop.relay("SIGUSR1 on process 1")
        os.kill(os.getpid(), signal.SIGINT)  # the first Ctrl-C here: no abort
        time.sleep(0.1)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)
    assert said == ["SIGUSR1 on process 1: stopping after this chunk (a checkpoint follows)"]


def test_a_stop_inside_another_passes_on_what_it_was_asked():
    """A sweep's stop around a run's: the run's signal reaches the sweep's, and a Ctrl-C after
    the run's stop has closed is the second one, as it would be in the run."""
    said = []
    with GracefulStop(said.append, when="before the next shape (x") as outer:
        with GracefulStop(said.append) as inner:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)
        assert inner.requested == outer.requested == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)
    assert said == ["SIGINT: stopping after this chunk (a checkpoint follows; Ctrl-C again aborts)"]


def test_the_launcher_needs_a_command_and_says_when_submitit_is_missing(monkeypatch):
    with pytest.raises(UsageError, match="give the command to run"):
        launch.parse(["--local", "2"])
    args, command = launch.parse(["--local", "2", "x.py", "--seeds", "3"])
    assert args.local == 2 and command == [sys.executable, "x.py", "--seeds", "3"]
    monkeypatch.setitem(sys.modules, "submitit", None)  # import fails, as when not installed
    args, command = launch.parse(["--slurm", "x.py"])
    with pytest.raises(UsageError, match=r"pip install 'rl_jax\[cluster\]'"):
        launch.submit(command, args)


def test_slurm_jobs_requeue_after_every_time_limit_unless_capped(monkeypatch):
    """submitit stops requeueing after 3 time limits unless told: the launcher tells it
    ``--max-requeues`` (default: more than any run meets). submitit itself is faked here."""
    made: list[dict] = []

    class Executor:
        def __init__(self, **kwargs):
            made.append(kwargs)

        def update_parameters(self, **kwargs):
            pass

        def submit(self, command):
            return type("job", (), {"job_id": "1"})()

    monkeypatch.setitem(sys.modules, "submitit", type("submitit", (), {"AutoExecutor": Executor}))
    for flags, expected in [([], launch.UNLIMITED_REQUEUES), (["--max-requeues", "5"], 5)]:
        args, command = launch.parse(["--slurm", *flags, "x.py"])
        assert launch.submit(command, args) == 0
        assert made[-1]["slurm_max_num_timeout"] == expected


def test_cores_are_split_into_disjoint_blocks_when_there_are_enough():
    blocks = launch.core_blocks(2, [7, 0, 3, 5, 1])
    if blocks is None:
        pytest.skip("this system cannot pin processes to cores")
    assert blocks == [{0, 1}, {3, 5}]  # in order; the odd core stays unused
    assert launch.core_blocks(3, [0, 1]) is None  # fewer cores than processes: no pinning
    assert not launch.parse(["--local", "2", "x.py"])[0].pin
    args, command = launch.parse(["--local", "2", "--pin", "x.py", "--pin"])
    assert args.pin and command == [sys.executable, "x.py", "--pin"]


#: Writes, per rank, the cores it may use and its device count; ignores the launcher's flags.
AFFINITY_SCRIPT = """
import json, os, sys
rank = sys.argv[sys.argv.index("--process-id") + 1]
seen = {"cores": sorted(os.sched_getaffinity(0)), "devices": os.environ["RL_JAX_CPU_DEVICES"]}
with open(f"rank{rank}.json", "w") as out:
    json.dump(seen, out)
"""


def launched_affinities(tmp_path: Path, *flags: str) -> list[dict]:
    script = tmp_path / "affinity.py"
    script.write_text(AFFINITY_SCRIPT)
    done = subprocess.run(
        [sys.executable, "-m", "rl_jax.run.launch", "--local", "2", *flags, str(script)],
        cwd=tmp_path,
        env={k: v for k, v in ENV.items() if k != "RL_JAX_CPU_DEVICES"},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    return [json.loads((tmp_path / f"rank{rank}.json").read_text()) for rank in range(2)]


needs_two_cores = pytest.mark.skipif(
    not hasattr(os, "sched_setaffinity") or len(os.sched_getaffinity(0)) < 2,
    reason="pinning needs os.sched_setaffinity and at least 2 cores",
)


@needs_two_cores
def test_local_processes_are_pinned_to_disjoint_blocks_of_cores(tmp_path):
    cores = os.sched_getaffinity(0)
    size = len(cores) // 2
    first, second = launched_affinities(tmp_path, "--pin")
    assert len(first["cores"]) == len(second["cores"]) == size
    assert not set(first["cores"]) & set(second["cores"])
    assert set(first["cores"]) | set(second["cores"]) <= cores
    assert first["devices"] == second["devices"] == str(size)  # one device per core of its block


@needs_two_cores
def test_unpinned_local_processes_share_all_cores(tmp_path):
    cores = sorted(os.sched_getaffinity(0))
    first, second = launched_affinities(tmp_path)
    assert first["cores"] == second["cores"] == cores
    assert first["devices"] == second["devices"] == str(max(1, len(cores) // 2))


def spec_for(out: Path, command: str, **changes) -> RunSpec:
    config = dataclasses.replace(fake.default_config(), iterations_per_chunk=5)
    spec = RunSpec(
        fake,
        fake.ENV_ID,
        config,
        (fake.default_hyperparams(),),
        out,
        seeds=2,
        total_steps=40,
        log_interval=1e9,
        command=command,
    )
    return dataclasses.replace(spec, **changes)


def test_the_same_command_continues_its_run_and_another_is_refused(tmp_path):
    command = "python run.py --seeds 2 --out run --coordinator h:1 --process-id 0"
    said: list[str] = []
    run(spec_for(tmp_path / "run", command, total_steps=20), notify=said.append)
    assert not any("continuing" in line for line in said)
    # a requeued job: the same command (another port, another Python name), a longer budget
    # written in the same flags would be another command: refused below
    again = "python3 run.py --seeds 2 --out run --coordinator h:2 --process-id 0"
    said.clear()
    result = run(spec_for(tmp_path / "run", again, total_steps=20), notify=said.append)
    continuing = f"{tmp_path / 'run'} holds this run, started by this same command: continuing it"
    assert said[0] == continuing
    assert result.step == 20 and "resuming from the checkpoint at step 20 (chunk 1)" in said
    with pytest.raises(RunError, match="already holds this run; continue it with --resume"):
        run(spec_for(tmp_path / "run", command + " --total-steps 40"), notify=said.append)
    record = json.loads((tmp_path / "run" / "config.json").read_text())
    assert len(record["sessions"]) == 2


def test_only_the_lead_probes_a_fresh_out_and_the_others_take_its_verdict(monkeypatch, tmp_path):
    """Every process of a run starts at once: were each to probe ``--out`` (create it and a file
    in it, then remove them), one would find another's probe there and refuse a directory nobody
    used. Another process leaves ``--out`` alone and takes the lead's verdict."""
    from rl_jax.run import processes, run_dir

    verdicts: list[bool] = []
    lead_refused = [False]

    def agree(*flags, at):
        assert at == "the check of --out"
        verdicts.extend(flags)
        return (lead_refused[0],)

    monkeypatch.setattr(processes, "is_lead", lambda: False)
    monkeypatch.setattr(processes, "agree", agree)
    out = tmp_path / "fresh" / "run"
    run_dir.check_out_dir(out, spec_for(out, "python run.py").identity)
    assert not (tmp_path / "fresh").exists() and verdicts == [False]
    # the lead's probe, caught in the act, is not this process's business
    out.mkdir(parents=True)
    (out / ".probe").write_text("")
    run_dir.check_out_dir(out, spec_for(out, "python run.py").identity)
    lead_refused[0] = True
    with pytest.raises(RunError, match=r"^process 0 refused --out .* \(its output says why\)$"):
        run_dir.check_out_dir(out, spec_for(out, "python run.py").identity)
    # the lead itself checks, and says why it refuses
    monkeypatch.setattr(processes, "is_lead", lambda: True)
    verdicts.clear()
    with pytest.raises(RunError, match="is not empty; choose another --out"):
        run_dir.check_out_dir(out, spec_for(out, "python run.py").identity)
    assert verdicts == [True]


def test_an_unreachable_coordinator_is_one_line_within_the_time_limit(tmp_path):
    port = launch.free_port()
    flags = ["--coordinator", f"localhost:{port}", "--num-processes", "2", "--process-id", "1"]
    started = time.monotonic()
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *flags, "--collective-timeout", "1"],
        cwd=tmp_path,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 1
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0] == f"error: cannot reach the coordinator localhost:{port} within 1 s (" + (
        "process 0 must be running there, and the port open)"
    )
    assert time.monotonic() - started < 120
    assert not any(tmp_path.iterdir())


# ---- several processes, through the launcher ---------------------------------------------------

TINY = ["--seeds", "2", "--total-steps", "300", "--iterations-per-chunk", "5"]
TINY += ["--log-interval", "0", "--checkpoint-interval", "0"]


def launched(args: list[str], cwd: Path, processes: int = 2) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "rl_jax.run.launch", "--local", str(processes), str(SCRIPT), *args],
        cwd=cwd,
        env={**ENV, "RL_JAX_CPU_DEVICES": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def one_process(args: list[str], cwd: Path) -> None:
    """The reference: one process with two CPU devices."""
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *args],
        cwd=cwd,
        env={**ENV, "RL_JAX_CPU_DEVICES": "2"},
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr


def rows(run_dir: Path) -> list[dict]:
    """Metrics rows without the wall-clock time."""
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if k != "wall_time"} for line in lines]


def final_state(run_dir: Path, step: int, seeds: int = 2) -> list[bytes]:
    config = dataclasses.replace(fake.default_config(), iterations_per_chunk=5)
    spec = RunSpec(fake, fake.ENV_ID, config, (fake.default_hyperparams(),), run_dir, seeds=seeds)
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        assert checkpointer.latest_step() == step
        return leaves_bytes(checkpointer.restore(make_plan(spec).template)[0])


def wait_for_training(process: subprocess.Popen) -> list[str]:
    """Process 0's lines up to its first progress line (training has started)."""
    seen = []
    for line in process.stdout:
        seen.append(line)
        if line.startswith("step "):
            return seen
    raise AssertionError("the run ended before training: " + "".join(seen))


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("distributed")
    one_process([*TINY, "--out", "single"], root)
    return root


@pytest.mark.slow
def test_two_processes_stopped_and_requeued_equal_one_process_on_two_devices(reference):
    """Bit for bit: each run's seeds compute on their own device in both layouts (no
    communication inside a chunk), and the gathers only copy."""
    root = reference
    args = [*TINY, "--out", "requeued"]
    first = launched(args, root)
    wait_for_training(first)
    first.send_signal(signal.SIGTERM)  # the launcher passes it on to both processes
    out, err = first.communicate(timeout=900)
    assert first.returncode == 0, err
    assert "SIGTERM: stopping after this chunk" in out and "stopped at step" in out
    again = launched(args, root)  # the requeued job: the same command
    out, err = again.communicate(timeout=900)
    assert again.returncode == 0, err
    assert "requeued holds this run, started by this same command: continuing it" in out
    assert "resuming from the checkpoint at step" in out
    assert "devices: TFRT_CPU_0, TFRT_CPU_" in out  # one device of each process
    assert rows(root / "requeued") == rows(root / "single")
    assert final_state(root / "requeued", 300) == final_state(root / "single", 300)


@pytest.mark.slow
def test_three_seeds_give_the_same_numbers_in_every_layout(tmp_path):
    """3 seeds of one command on 1 device, on 2 padded (2 + 2) or split (one block of 3), on 2
    processes of one device, and on 2 processes started by hand that each take their default
    devices (one per core, no ``RL_JAX_CPU_DEVICES``): every seed's metrics and the final
    checkpoint are the same bit for bit, as no device ever holds a lone seed of the run
    (``device_layout.MIN_BLOCK_SEEDS``), and the plan says so."""
    from test_join import places

    args = ["--seeds", "3", *TINY[2:]]

    def alone(out: str, devices: str, *flags: str) -> str:
        done = subprocess.run(
            [sys.executable, str(SCRIPT), *args, "--out", out, *flags],
            cwd=tmp_path,
            env={**ENV, "RL_JAX_CPU_DEVICES": devices},
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert done.returncode == 0, done.stderr
        return done.stdout

    def by_hand(out: str, env: dict) -> str:
        port = launch.free_port()
        ranks = [
            subprocess.Popen(
                [sys.executable, str(SCRIPT), *args, "--out", out, *places(port, rank)],
                cwd=tmp_path,
                env=env,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            )
            for rank in (0, 1)
        ]
        outputs = [rank.communicate(timeout=900) for rank in ranks]
        for rank, (_out, err) in zip(ranks, outputs, strict=True):
            assert rank.returncode == 0, err
        return outputs[0][0]

    plans = {
        "one": alone("one", "1"),
        "padded": alone("padded", "2"),
        "split": alone("split", "2", "--layout", "split"),
        "processes": by_hand("processes", {**ENV, "RL_JAX_CPU_DEVICES": "1"}),
        "defaults": by_hand(
            "defaults", {k: v for k, v in ENV.items() if k != "RL_JAX_CPU_DEVICES"}
        ),
    }
    assert "(2 runs each; 1 padding copy of a run computed and dropped)" in plans["padded"]
    assert "(3 runs, split unevenly: one program)" in plans["split"]
    for name, printed in plans.items():
        assert "  seeds: 2 or more per block: each seed's numbers are the same in every layout" in (
            printed
        ), name
    expected = rows(tmp_path / "one")
    assert sorted({row["seed"] for row in expected}) == [0, 1, 2]
    state = final_state(tmp_path / "one", 300, seeds=3)
    for name in list(plans)[1:]:
        assert rows(tmp_path / name) == expected, name
        assert final_state(tmp_path / name, 300, seeds=3) == state, name


@pytest.mark.slow
def test_a_killed_process_stops_the_other_with_one_line_and_the_run_continues(reference):
    root = reference
    args = [*TINY, "--out", "killed"]
    job = launched(args, root)
    wait_for_training(job)
    children = psutil.Process(job.pid).children()
    victim = next(c for c in children if c.cmdline()[-2:] == ["--process-id", "1"])
    started = time.monotonic()
    victim.kill()
    out, err = job.communicate(timeout=300)
    assert time.monotonic() - started < 120
    assert job.returncode in (1, 137), err  # process 0's error, or the kill, whichever came first
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("error: process 0 lost contact with another process of the run")
    # SIGKILL kept the last checkpoint: the same command continues from it to the same end
    again = launched(args, root)
    out, err = again.communicate(timeout=900)
    assert again.returncode == 0, err
    assert "killed holds this run, started by this same command: continuing it" in out
    assert rows(root / "killed") == rows(root / "single")
    assert final_state(root / "killed", 300) == final_state(root / "single", 300)


def test_submitit_warning_stops_the_run_and_requeues_the_same_command(monkeypatch, tmp_path):
    """``ClusterCommand.checkpoint``, as submitit calls it on SLURM's warning signal: SIGUSR1 to
    the run, its end awaited, the same command handed back (submitit itself is faked here)."""
    requeued = []
    helpers = type("helpers", (), {"DelayedSubmission": staticmethod(requeued.append)})
    monkeypatch.setitem(sys.modules, "submitit", type("submitit", (), {"helpers": helpers}))
    ready = tmp_path / "ready"
    child = (
        "import signal, sys, time, pathlib\n"
        "signal.signal(signal.SIGUSR1, lambda *a: sys.exit(0))\n"
        f"pathlib.Path({str(ready)!r}).touch()\n"
        "time.sleep(120)\n"
    )
    command = launch.ClusterCommand([sys.executable, "-c", child])
    done = []
    thread = threading.Thread(target=lambda: done.append(command()))
    thread.start()
    deadline = time.monotonic() + 60
    while not ready.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    command.checkpoint()
    thread.join(timeout=30)
    assert done == [0]  # the run ended by itself, with status 0
    assert [again.command for again in requeued] == [command.command]


def test_sigusr1_under_slurm_requeues_the_job_once_checkpointed(monkeypatch, tmp_path):
    """What the lead does after a SIGUSR1 stop: ``scontrol requeue JOB`` (a stand-in here), and
    nothing under submitit, which requeues its own jobs."""
    calls = tmp_path / "calls"
    scontrol = tmp_path / "scontrol"
    scontrol.write_text(f'#!/bin/sh\necho "$@" >> {calls}\n')
    scontrol.chmod(0o755)
    monkeypatch.setenv("PATH", f"{tmp_path}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("SLURM_JOB_ID", "77")
    monkeypatch.delenv("SUBMITIT_EXECUTOR", raising=False)
    said: list[str] = []
    distributed.slurm_requeue(said.append)
    assert calls.read_text() == "requeue 77\n"
    assert said == [
        "requeued SLURM job 77: the same command continues this run when it starts again"
    ]
    monkeypatch.setenv("SUBMITIT_EXECUTOR", "slurm")
    distributed.slurm_requeue(said.append)
    assert calls.read_text() == "requeue 77\n" and len(said) == 1


@pytest.mark.slow
def test_a_hung_process_stops_the_other_at_the_time_limit(reference):
    """A process that stops answering (SIGSTOP) without closing its connections: the other
    waits no longer than --collective-timeout, then ends with one line."""
    job = launched([*TINY, "--out", "hung", "--collective-timeout", "60"], reference)
    wait_for_training(job)
    children = psutil.Process(job.pid).children()
    victim = next(c for c in children if c.cmdline()[-2:] == ["--process-id", "1"])
    started = time.monotonic()
    victim.suspend()
    out, err = job.communicate(timeout=300)
    assert 60 <= time.monotonic() - started < 200
    assert job.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: process 0 waited over 60 s for the other processes at ")


@pytest.mark.slow
def test_a_signal_to_another_process_is_named_by_the_lead_with_a_full_resume_hint(reference):
    """SIGTERM to process 1 alone: the lead says whose signal stopped the run, and the resume
    hint carries the process flags. Gloo's connection lines stay out of the output."""
    job = launched([*TINY, "--out", "signalled"], reference)
    seen = "".join(wait_for_training(job))
    children = psutil.Process(job.pid).children()
    victim = next(c for c in children if c.cmdline()[-2:] == ["--process-id", "1"])
    victim.send_signal(signal.SIGTERM)
    out, err = job.communicate(timeout=300)
    assert job.returncode == 0, err
    assert "SIGTERM or SIGINT on process 1: stopping after this chunk" in out
    hint = next(line for line in out.splitlines() if line.startswith("resume with: "))
    assert "--num-processes 2 --process-id I on every process, I = 0 .. 1" in hint
    assert "[Gloo]" not in seen + out + err
