"""sweep.py: a grid over a hyperparameter and a shape, ranked; and the same sweep run by two
processes of one device each through jax.distributed (each training one shape of its own, on its
device), stopped and resumed from its checkpoints, equals the one-process run on one device.

One device, not two: the 2 configs x 2 seeds of a shape then run as one block of 4 in both
sweeps. Over 2 devices they run as blocks of 2 configs x 1 seed, whose TD3 updates rounded
differently here from the first update on (a vmap over one seed is compiled to other kernels than
over two); 5 seeds as 3 + 3 against 5 do agree bit for bit (tests/run/test_uneven_devices.py)."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from child_env import python_path

# Three sweeps compile in three processes, each a program of its own: slow.
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "experiments" / "sweep.py"
# Tiny: 2 envs x 25 iterations = 50 env steps per chunk, updates from step 50.
TINY = [
    "--algo", "td3", "--env", "rl_jax/Pendulum-v1", "--seeds", "2", "--total-steps", "100",
    "--num-envs", "2", "--iterations-per-chunk", "25", "--learning-starts", "50",
    "--batch-size", "16", "--buffer-size", "200", "--num-eval-envs", "1",
    "--actor-hidden", "8,8", "--critic-hidden", "8,8", "--log-interval", "0",
]  # fmt: skip
GRID = ["--grid", "lr=1e-4,1e-3"]
LONGER = ["--total-steps", "150"]  # one chunk more than TINY's


def sweep(args: list[str], cwd: Path, devices: int) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": python_path(ROOT), "RL_JAX_CPU_DEVICES": str(devices)}
    env.pop("XLA_FLAGS", None)
    env.pop("TF_CPP_MIN_LOG_LEVEL", None)  # set to 1 by importing jax here; rl_jax sets 3
    return subprocess.Popen(
        [sys.executable, str(SCRIPT), *TINY, *args],
        cwd=cwd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(process: subprocess.Popen) -> str:
    out, err = process.communicate(timeout=900)
    assert process.returncode == 0, err[-3000:]
    return out


def rows(run_dir: Path) -> list[dict]:
    """Metrics rows without the wall-clock time."""
    lines = (run_dir / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if k != "wall_time"} for line in lines]


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


def distributed(args: list[str], root: Path) -> list[str]:
    """The sweep on 2 processes of 1 device each, through jax.distributed."""
    port = free_port()
    processes = [
        sweep(
            [*args, "--coordinator", f"localhost:{port}", "--num-processes", "2"]
            + ["--process-id", str(i)],
            root,
            devices=1,
        )
        for i in range(2)
    ]
    return [finish(p) for p in processes]


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """One process on 1 device to 150 steps; 2 processes of 1 device each to 100 steps, then
    resumed from their checkpoint to 150."""
    root = tmp_path_factory.mktemp("sweep")
    single = sweep([*GRID, "--grid", "batch=8,16", "--out", "single", *LONGER], root, devices=1)
    first = distributed([*GRID, "--grid", "batch=8,16", "--out", "distributed"], root)
    resumed = distributed(["--resume", "distributed", *LONGER], root)
    return root, finish(single), first, resumed


def test_sweep_ranks_every_config_of_every_shape(sweeps):
    root, out, *_ = sweeps
    table = (root / "single" / "results.txt").read_text()
    ranked = [line.split()[1:3] for line in table.splitlines() if line.strip()[:1].isdigit()]
    assert len(ranked) == 4  # 2 batch sizes (one program each) x 2 learning rates (vmapped)
    labels = {" ".join(parts) for parts in ranked}
    # labelled by the grid's names: lr (which sets actor_lr and critic_lr) and batch
    assert labels == {f"batch={b}, lr={lr}" for b in (8, 16) for lr in ("0.0001", "0.001")}, labels
    means = [float(line.split()[3]) for line in table.splitlines() if line.strip()[:1].isdigit()]
    assert means == sorted(means, reverse=True)
    assert "95% CI" in table and (root / "single" / "curves.png").stat().st_size > 0
    assert out.count("compiled in") == 2  # once per shape
    assert "2 seeds x 2 configs (lr)" in out
    for batch in (8, 16):
        record = json.loads((root / "single" / f"batch={batch}" / "config.json").read_text())
        assert record["identity"]["config"]["batch_size"] == batch


def test_two_processes_equal_one_process(sweeps):
    """With a stop and resume in between: the distributed sweep checkpoints as any run."""
    root, _, first, (lead, other) = sweeps
    for batch in (8, 16):
        single = rows(root / "single" / f"batch={batch}")
        assert rows(root / "distributed" / f"batch={batch}") == single
        assert len(single) == 3 * 2 * 2  # chunks x configs x seeds
        assert (root / "distributed" / f"batch={batch}" / "checkpoints").is_dir()
    assert "sweep directory: distributed" in first[0] and "sweep directory" not in first[1]
    # Each process trained one shape of its own (rl_jax.run.sweep_shapes), compiling only it.
    assert "== shape 2/2: batch=16 (process 1)" in first[0] and first[0].count("compiled in") == 1
    assert "resuming from the checkpoint at step 100" in lead
    # Only the lead prints (the other's stdout holds the collectives library's own lines).
    assert "== shape" in lead and "plan:" in lead and "step 150" in lead
    assert not any(text in other for text in ("== shape", "plan:", "step ", "sweep directory"))
    tables = [(root / name / "results.txt").read_text() for name in ("single", "distributed")]
    ranked = [[line for line in t.splitlines() if line.strip()[:1].isdigit()] for t in tables]
    assert ranked[0] == ranked[1] and len(ranked[0]) == 4
