"""The env-throughput benchmark's smoke run and its MJX time limit (``bench/bench_env_throughput``).

The full benchmark takes tens of minutes; these check, in seconds, that its table is made and
that an MJX phase which runs too long, or fails, becomes a "skipped" cell instead of a hang.
"""

import pytest

from bench import bench_env_throughput
from rl_jax.envs.mujoco import mujoco_ffi_build


def test_mjx_phase_over_its_limit_is_skipped_not_waited_for():
    # Importing JAX alone takes longer than 0.2 s: the worker is killed while building its env.
    results = bench_env_throughput.mjx_rates("InvertedPendulum-v5", (2, 4), 0.2, 0.01, 1)
    assert results[2] == {"skipped": "build > 0.2 s"}
    assert results[4] == {"skipped": "build > 0.2 s"}


def test_failing_mjx_worker_reports_its_error():
    results = bench_env_throughput.mjx_rates("NoSuchEnv-v5", (2,), 60.0, 0.01, 1)
    assert results[2]["skipped"].startswith("build failed: "), results


def test_quick_run_makes_the_side_by_side_table():
    if not mujoco_ffi_build.available():
        pytest.skip("the MuJoCo FFI op is not built here")
    section = bench_env_throughput.run(quick=True, env_ids=("InvertedPendulum-v5",), mjx_limit=0.2)
    row = next(line for line in section.splitlines() if line.startswith("| InvertedPendulum"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    # env, gymnasium, raw C 2, ours 2, MJX 2, ours/raw, MJX compile s
    assert len(cells) == 7, row
    assert all(float(cell.replace(",", "")) > 0 for cell in cells[1:4]), row
    assert cells[4] == "skipped (build > 0.2 s)", row
    assert float(cells[5]) > 0, row
    assert "ours >= 0.9 x raw C at 2 envs" in section


def test_interrupt_keeps_the_sizes_measured_and_says_where_it_stopped(monkeypatch, capsys):
    # A time limit's SIGINT arrives as KeyboardInterrupt while the parent waits on its worker:
    # here after one size's compile and run, during the second size's compile.
    events = iter([{"phase": "build"}, {"phase": "compile", "seconds": 3.0},
                   {"phase": "run", "rate": 1234.0}])  # fmt: skip

    def next_event(process, selector, limit):
        event = next(events, None)
        if event is None:
            raise KeyboardInterrupt
        return event

    monkeypatch.setattr(bench_env_throughput, "_next_event", next_event)
    section = bench_env_throughput.run(
        env_ids=("InvertedPendulum-v5", "Hopper-v5"), sizes=(2, 4), backend="mjx", mjx_limit=60.0
    )
    row = next(line for line in section.splitlines() if line.startswith("| InvertedPendulum"))
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[1:] == ["1,234", "skipped (compile interrupted)", "3 / -"], row
    assert "Hopper-v5 |" not in section
    assert "Interrupted during InvertedPendulum-v5; not run: Hopper-v5." in section
    err = capsys.readouterr().err
    assert "InvertedPendulum-v5 MJX: 2 envs compiled in 3.0 s" in err
    assert "InvertedPendulum-v5 MJX: 2 envs: 1,234 env steps/s" in err
