"""Every device busy: 5 seeds, which divide over neither 2 nor 4 devices, spread over all of them
padded with copies of seed 0 that are computed and dropped, and give bit for bit what 5 seeds on
one device give: the same metrics rows and the same checkpoints. The copies never reach a saved
file, so a run resumes on another device count. Plus the layout and shape-sharing maths.

Bit for bit holds because each device runs the same vmapped program on its block, and a batch
of 3 runs and a batch of 5 compute each run with the same kernels (checked here at the tests' XLA
flags, and by the slow test for TD3 at XLA's defaults). That holds for the locked jaxlib; another
XLA may fuse the two batch sizes differently (jax 0.12 does: a loss 1 ulp apart), and there the
runs are compared to a float tolerance, their steps, seeds and counts still exactly. A block of
one seed need not compile to the same kernels even on the lock: see tests/test_sweep.py.
"""

import dataclasses
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import compile_level
import jax
import numpy as np
import pytest
from child_env import python_path
from run_helpers import ON_THE_LOCKED_JAX, leaf_arrays, leaves_bytes
from uneven_specs import SEEDS, spec_for

from rl_jax.errors import RunError
from rl_jax.run import plan, processes
from rl_jax.run.best import BEST_DIR, BestPolicies, policy_fields
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.metrics import read_rows
from rl_jax.run.plan import make_plan
from rl_jax.run.runner import run
from rl_jax.run.sweep_shapes import owners, run_own
from rl_jax.training.device_layout import plan_layout
from rl_jax.training.split_program import Block, Group, split_layout

ROOT = Path(__file__).resolve().parents[2]
CHILD = Path(__file__).with_name("uneven_child.py")
FAKE_CHUNK = 20  # the fake learner's env steps per chunk (4 envs x 5 iterations)
FAKE_TOTAL = 4 * FAKE_CHUNK
TD3_TOTAL = 150  # 3 chunks of 50 env steps, updates from step 50

cpu_only = pytest.mark.skipif(
    jax.default_backend() != "cpu", reason="compares runs on forced CPU devices"
)


def start(devices: int, jobs: list[dict], env: dict | None = None) -> subprocess.Popen:
    """The child on ``devices`` CPU devices, running ``jobs`` one after another."""
    env = {
        **os.environ,
        "PYTHONPATH": python_path(ROOT, ROOT / "tests"),
        "XLA_FLAGS": compile_level.subprocess_flags(),
        "JAX_PLATFORMS": "cpu",
        **(env or {}),
    }
    command = [sys.executable, str(CHILD), str(devices), json.dumps(jobs)]
    return subprocess.Popen(
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def finish(process: subprocess.Popen) -> list:
    out, err = process.communicate(timeout=900)
    assert process.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def run_here(jobs: list[dict]) -> list:
    """What the child does, in this process on its one device."""
    assert len(jax.devices()) == 1
    layouts = []
    for each in jobs:
        spec = spec_for(each["learner"], Path(each["out"]), each["total"], each["resume"])
        spec = dataclasses.replace(spec, layout=each["layout"])
        layout = plan.program_for(spec).layout
        layouts.append([layout.devices, layout.padded_seeds])
        run(spec, notify=lambda message: None)
    return layouts


def job(
    out: Path, total: int, learner: str = "fake", resume: bool = False, layout: str = "auto"
) -> dict:
    return {"out": str(out), "total": total, "resume": resume, "learner": learner, "layout": layout}


def rows(out: Path) -> list[dict]:
    return [
        {k: v for k, v in row.items() if k != "wall_time"}
        for row in read_rows(out / "metrics.jsonl")
    ]


def checkpoint(out: Path, learner: str, total: int):
    """The latest checkpoint, restored into the template of the real 5 runs (a checkpoint with
    padding copies would not match it)."""
    plan = make_plan(spec_for(learner, out, total))
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        state, meta = checkpointer.restore(plan.template)
    assert meta["step"] == total
    return state


def assert_close_rows(got: list[dict], want: list[dict]) -> None:
    """The same rows, their floats to a tolerance (``ON_THE_LOCKED_JAX`` says when)."""
    assert [sorted(row) for row in got] == [sorted(row) for row in want]
    for row, expected in zip(got, want, strict=True):
        for key, value in expected.items():
            if isinstance(value, float):
                np.testing.assert_allclose(row[key], value, rtol=1e-4, atol=1e-5, err_msg=key)
            else:
                assert row[key] == value, key


def assert_same_runs(outs: list[Path], learner: str, total: int, exact: bool = True) -> None:
    """The runs of ``outs`` equal those of ``outs[0]``: bit for bit when ``exact`` on the locked
    jaxlib, else their floats to a tolerance."""
    expected_rows, expected_state = rows(outs[0]), checkpoint(outs[0], learner, total)
    chunks = total // (FAKE_CHUNK if learner == "fake" else 50)
    assert len(expected_rows) == chunks * SEEDS
    assert sorted({row["seed"] for row in expected_rows}) == list(range(SEEDS))  # no copies
    for out in outs[1:]:
        state = checkpoint(out, learner, total)
        if exact and ON_THE_LOCKED_JAX:
            assert rows(out) == expected_rows, out
            assert leaves_bytes(state) == leaves_bytes(expected_state), out
            continue
        assert_close_rows(rows(out), expected_rows)
        for got, want in zip(leaf_arrays(state), leaf_arrays(expected_state), strict=True):
            if np.issubdtype(want.dtype, np.floating):
                np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
            else:
                np.testing.assert_array_equal(got, want)


@cpu_only
def test_five_seeds_on_two_devices_equal_one_device_and_resume_on_one(tmp_path):
    """5 seeds to the end on 2 devices, padded (3 + 3) and split unevenly (3 + 2), and on 1;
    and 5 seeds stopped halfway on 2 devices, resumed on 1 (from either layout) or in the other
    layout. All are the same runs, bit for bit on the locked jaxlib. (The other way, 1 device
    resumed on 2: the slow TD3 test.)"""
    total = 2 * FAKE_CHUNK  # two chunks: a stop halfway and a resume
    half = total // 2
    two = start(
        2,
        [
            job(tmp_path / "two", total),  # auto: 2 chunks are too few to split
            job(tmp_path / "half", half),
            job(tmp_path / "split", total, layout="split"),
            job(tmp_path / "split_half", half, layout="split"),
            job(tmp_path / "pad_then_split", half, layout="pad"),
            job(tmp_path / "pad_then_split", total, resume=True, layout="split"),
        ],
    )
    # One device is this process's own: the same runs here, with no child to start, the
    # unstopped one while the child runs.
    one = run_here([job(tmp_path / "one", total)])
    assert finish(two) == [[2, 6]] * 2 + [[2, 5]] * 2 + [[2, 6], [2, 5]]
    one += run_here(
        [
            job(tmp_path / "half", total, resume=True),
            job(tmp_path / "split_half", total, resume=True, layout="split"),
        ]
    )
    assert one == [[1, 5]] * 3  # one device: nothing to split
    names = ("one", "two", "half", "split", "split_half", "pad_then_split")
    assert_same_runs([tmp_path / name for name in names], "fake", total)
    # Nothing saved is padded: the metrics hold 5 seeds per chunk, every checkpoint restores
    # into the real runs' shapes (above), and so do the best policies, kept in every layout.
    first = best_policies(tmp_path / names[0], "fake", total)
    assert first.returns.shape == (1, SEEDS) and (first.steps >= 0).all()
    for name in names[1:]:
        best = best_policies(tmp_path / name, "fake", total)
        np.testing.assert_array_equal(best.steps, first.steps, err_msg=name)
        np.testing.assert_allclose(best.returns, first.returns, rtol=1e-6, err_msg=name)


def best_policies(out: Path, learner: str, total: int) -> BestPolicies:
    spec = spec_for(learner, out, total)
    template = make_plan(spec).template
    fields = policy_fields(spec.algorithm, template)
    return BestPolicies.restore(out / BEST_DIR, fields, template, at_most=total, expect={})


@pytest.mark.slow
@cpu_only
def test_td3_on_two_devices_equals_one_device_at_default_flags(tmp_path):
    """The same for TD3 (matmuls, Adam, replay) at XLA's default flags, padded and split (3 + 2,
    and a run of 1 device resumed split on 2): bit for bit."""
    env = {"XLA_FLAGS": "", "TEST_XLA_OPT": "default"}
    one = start(
        1, [job(tmp_path / "one", TD3_TOTAL, "td3"), job(tmp_path / "half", 100, "td3")], env
    )
    two = start(
        2,
        [
            job(tmp_path / "two", TD3_TOTAL, "td3"),
            job(tmp_path / "split", TD3_TOTAL, "td3", layout="split"),
        ],
        env,
    )
    assert finish(one) == [[1, 5], [1, 5]] and finish(two) == [[2, 6], [2, 5]]
    resumed = start(2, [job(tmp_path / "half", TD3_TOTAL, "td3", resume=True, layout="split")], env)
    assert finish(resumed) == [[2, 5]]
    names = ("one", "two", "split", "half")
    assert_same_runs([tmp_path / name for name in names], "td3", TD3_TOTAL)


@pytest.mark.slow
@cpu_only
def test_sac_on_a_mujoco_env_trains_the_same_in_every_layout(tmp_path):
    """SAC on half cheetah, stepped by the MuJoCo C op inside the program, at XLA's default
    flags: 5 seeds on one device, split 3 + 2 and padded 3 + 3 over two. The training (every
    metric but the evaluation, and the checkpointed state) is bit for bit the same in all three,
    and so is the split's evaluation; the padded program's evaluations may differ in the last
    bits (measured in RESULTS.md, "SAC's three met rows rerun"), so they are held to a float
    tolerance."""
    env = {"XLA_FLAGS": "", "TEST_XLA_OPT": "default"}
    one = start(1, [job(tmp_path / "one", TD3_TOTAL, "sac")], env)
    two = start(
        2,
        [
            job(tmp_path / "split", TD3_TOTAL, "sac", layout="split"),
            job(tmp_path / "pad", TD3_TOTAL, "sac", layout="pad"),
        ],
        env,
    )
    assert finish(one) == [[1, 5]] and finish(two) == [[2, 5], [2, 6]]

    def training(out: Path) -> list[dict]:
        return [{k: v for k, v in row.items() if k != "eval_return"} for row in rows(out)]

    def evaluations(out: Path) -> np.ndarray:
        return np.array([row["eval_return"] for row in rows(out)])

    expected_state = checkpoint(tmp_path / "one", "sac", TD3_TOTAL)
    assert len(rows(tmp_path / "one")) == 3 * SEEDS
    for name in ("split", "pad"):
        state = checkpoint(tmp_path / name, "sac", TD3_TOTAL)
        if ON_THE_LOCKED_JAX:
            assert training(tmp_path / name) == training(tmp_path / "one"), name
            assert leaves_bytes(state) == leaves_bytes(expected_state), name
        else:
            assert_close_rows(training(tmp_path / name), training(tmp_path / "one"))
    if ON_THE_LOCKED_JAX:
        np.testing.assert_array_equal(
            evaluations(tmp_path / "split"), evaluations(tmp_path / "one")
        )
    np.testing.assert_allclose(
        evaluations(tmp_path / "pad"), evaluations(tmp_path / "one"), rtol=1e-3, atol=1e-2
    )


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


@pytest.mark.slow
@cpu_only
def test_four_processes_with_five_seeds_equal_one_process(tmp_path):
    """4 processes of one device each (jax.distributed on localhost): 5 seeds padded to 2 per
    device, every process holding a block; the lead alone writes, and the run equals the
    one-process one."""
    port = free_port()
    workers = [
        start(
            1,
            [job(tmp_path / "four", FAKE_TOTAL)],
            {"COORDINATOR": f"localhost:{port}", "NUM_PROCESSES": "4", "PROCESS_ID": str(i)},
        )
        for i in range(4)
    ]
    alone = start(1, [job(tmp_path / "one", FAKE_TOTAL)])
    assert [finish(worker) for worker in workers] == [[[4, 8]]] * 4
    assert finish(alone) == [[1, 5]]
    assert_same_runs([tmp_path / "one", tmp_path / "four"], "fake", FAKE_TOTAL)


def test_layout_pads_onto_every_device_it_needs():
    five = plan_layout(1, SEEDS, num_devices=2)
    assert (five.devices, five.padded_seeds, five.runs_per_device, five.padding) == (2, 6, 3, 1)
    # On 4 devices: 2 + 2 + 2 on three is as fast as 2 x 4 and pads one copy, not three.
    four = plan_layout(1, SEEDS, num_devices=4)
    assert (four.devices, four.runs_per_device, four.padding) == (3, 2, 1)
    # Over 4 processes every device holds a block.
    spread = plan_layout(1, SEEDS, num_devices=4, min_devices=4)
    assert (spread.devices, spread.padded_seeds, spread.runs_per_device) == (4, 8, 2)
    assert plan_layout(1, 1, num_devices=2).devices == 1  # one run stays whole
    # No block of one seed: 2 seeds stay together, 3 over 4 processes' devices pad to 2 each.
    assert plan_layout(1, 2, num_devices=2).devices == 1
    three = plan_layout(1, 3, num_devices=4, min_devices=4)
    assert (three.devices, three.padded_seeds // three.seed_split, three.runs_per_device) == (
        4,
        2,
        2,
    )
    assert plan_layout(1, 1, num_devices=2, min_devices=2).padded_seeds == 2
    grid = plan_layout(3, SEEDS, num_devices=2)  # 15 runs: seeds split, 3 x 3 per device
    assert (grid.seed_split, grid.runs_per_device, grid.padding) == (2, 9, 3)
    assert plan_layout(2, 3, num_devices=2).padding == 0  # divides: configs split


@pytest.mark.slow
@cpu_only
def test_five_seeds_split_over_four_devices_equal_one_device(tmp_path):
    """--layout split on 4 CPU devices: 3 + 2 on two of them, as no block may hold a lone seed
    (2 + 1 + 1 + 1 would: XLA compiles a block of one seed to other kernels, the eval return 1
    ulp apart), and the same runs as on one device, bit for bit."""
    four = start(4, [job(tmp_path / "four", FAKE_TOTAL, layout="split")])
    one = start(1, [job(tmp_path / "one", FAKE_TOTAL)])
    assert finish(four) == [[2, 5]] and finish(one) == [[1, 5]]
    assert_same_runs([tmp_path / "one", tmp_path / "four"], "fake", FAKE_TOTAL)


@dataclasses.dataclass(frozen=True)
class FakeDevice:
    platform: str = "cpu"
    process_index: int = 0


def test_split_layout_and_when_auto_splits():
    five = split_layout(1, SEEDS, 2)
    assert (five.axis, five.sizes, five.runs_per_device, five.shapes) == (1, (3, 2), 3, 2)
    assert [(b.hparams, b.seeds) for b in five.blocks] == [
        (range(1), range(3)),
        (range(1), range(3, 5)),
    ]
    # no block of one seed (a lone seed rounds otherwise): 5 seeds on 4 devices as 3 + 2
    assert split_layout(1, SEEDS, 4).sizes == (3, 2)
    seven = split_layout(1, 7, 4)
    assert seven.sizes == (3, 2, 2)
    # one program per block size: 3 seeds on device 0, 4 seeds sharded over devices 1-2
    assert seven.shapes == 2 and seven.groups == (
        Group(Block(range(1), range(3)), range(1)),
        Group(Block(range(1), range(3, 7)), range(1, 3)),
    )
    assert split_layout(1, 2, 4).sizes == (2,)  # never a lone seed, nor an empty block
    assert split_layout(1, 3, 2).sizes == (3,)
    assert split_layout(1, 1, 2).sizes == (1,)
    sets = split_layout(5, 1, 2).groups  # configs split 3 + 2: a group per size
    assert [(g.runs.hparams, g.devices) for g in sets] == [
        (range(3), range(1)),
        (range(3, 5), range(1, 2)),
    ]
    grid = split_layout(3, 2, 2)  # 2 seeds stay together: the configs split, 2 + 1
    assert (grid.axis, grid.sizes, grid.runs_per_device) == (0, (2, 1), 4)
    configs = split_layout(3, 1, 2)  # one seed: the configs split, 2 + 1
    assert (configs.axis, configs.sizes, configs.runs_per_device) == (0, (2, 1), 2)
    cpus, gpus = [FakeDevice()] * 2, [FakeDevice("gpu")] * 2
    enough = plan.SPLIT_MIN_CHUNKS
    assert plan.choose_split("auto", 1, SEEDS, cpus, enough)
    assert not plan.choose_split("auto", 1, SEEDS, cpus, enough - 1)  # compiles not paid back
    assert not plan.choose_split("auto", 1, SEEDS, cpus, None)
    assert not plan.choose_split("auto", 1, 6, cpus, enough)  # divides evenly
    assert not plan.choose_split("auto", 1, SEEDS, gpus, enough)  # devices of their own
    assert not plan.choose_split("auto", 1, 1, cpus, enough)  # one run stays whole
    # 6 on 4: 2 + 2 + 2 either way (a fourth block would hold a lone seed)
    assert not plan.choose_split("auto", 1, 6, [FakeDevice()] * 4, enough)
    assert not plan.choose_split("auto", 1, 3, cpus, enough)  # 2 + 2 padded, not 3 on one
    assert plan.choose_split("split", 1, SEEDS, gpus, 1) and not plan.choose_split(
        "pad", 1, 5, cpus, enough
    )
    other = [FakeDevice(), FakeDevice(process_index=1)]
    assert not plan.choose_split("auto", 1, SEEDS, other, enough)  # a mesh over processes
    with pytest.raises(RunError, match="--layout split needs the devices of one process"):
        plan.choose_split("split", 1, SEEDS, other, enough)
    with pytest.raises(RunError, match="--layout must be one of auto, pad, split"):
        plan.choose_split("even", 1, SEEDS, cpus, enough)


@cpu_only
def test_the_plan_says_a_run_is_split(tmp_path, monkeypatch):
    """10 chunks of 5 seeds on 2 CPU devices: auto splits them, and the plan says so (the test
    process has one device: both blocks go on it, which the plan's arithmetic does not mind)."""
    monkeypatch.setattr(plan.processes, "devices", lambda: [jax.devices()[0]] * 2)
    long = spec_for("fake", tmp_path / "long", plan.SPLIT_MIN_CHUNKS * FAKE_CHUNK)
    made = make_plan(long)
    assert made.chunks == plan.SPLIT_MIN_CHUNKS
    described = plan.format_plan(long, made)
    assert "(3 + 2 runs, split unevenly: 2 programs)" in described
    assert described.splitlines()[0].endswith(", 2 compiled programs")
    assert made.template == make_plan(dataclasses.replace(long, layout="split")).template


def test_shapes_go_to_processes_where_that_is_faster():
    assert owners(4, 1, SEEDS, num_processes=1, local_devices=2) is None  # one process
    assert owners(1, 1, SEEDS, num_processes=2, local_devices=1) is None  # one shape
    # 2 shapes x 5 seeds on 2 processes: 5 runs per device each alone against 2 x 3 together.
    assert owners(2, 1, SEEDS, num_processes=2, local_devices=1) == [0, 1]
    # 3 shapes: 2 x 5 alone against 3 x 3 together.
    assert owners(3, 1, SEEDS, num_processes=2, local_devices=1) is None
    assert owners(4, 2, 2, num_processes=2, local_devices=1) == [0, 1, 0, 1]  # a tie: alone
    assert owners(3, 1, 4, num_processes=4, local_devices=2) == [0, 1, 2]


def test_a_process_alone_runs_on_its_own_devices_and_writes_itself():
    assert processes.devices() == jax.devices()
    with processes.alone():
        assert processes.count() == 1 and processes.is_lead()
        assert processes.devices() == jax.local_devices()
        assert processes.agree(True, False) == (True, False)
    assert processes.count() == jax.process_count()
    processes.wait_for_all("nothing to wait for on one process")


def test_own_shapes_run_alone_and_an_error_in_one_is_one_line(tmp_path):
    """``run_own`` on one process: its shapes run in turn, each writing its own directory; a
    user error in one still comes after the wait for the others, as the error it was."""
    specs = [spec_for("fake", tmp_path / name, FAKE_CHUNK) for name in ("a", "b")]
    assert run_own(specs, ["a", "b"], [0, 0], notify=lambda message: None) is False
    assert all((spec.out / "checkpoints").is_dir() for spec in specs)
    # Another run into a's directory: refused, a untouched.
    refused = dataclasses.replace(spec_for("fake", tmp_path / "a", FAKE_CHUNK), seeds=3)
    with pytest.raises(RunError, match="already holds a different run"):
        run_own([refused], ["a"], [0], notify=lambda message: None)
