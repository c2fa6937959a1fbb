"""Test-wide JAX settings: fail on silent rank promotion, share the compilation cache, and
compute float32 matmuls in float32 on accelerators too."""

import gc
import os
import sys
from pathlib import Path

# numpy's OpenBLAS starts a thread per core in every test process and in every child it spawns;
# with two test processes on two cores (and XLA's own threads) those threads contend, and a small
# numpy matmul (the gymnasium frame references' resizing) takes tens of times longer. One BLAS
# thread per process: `make test` sets it before Python starts (a pytest plugin imports numpy
# before this file runs); here it reaches the child processes that the tests start.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402

# The tests live in folders that mirror the package (agents/, training/, run/, envs/); the helpers
# they share (fake_algorithm, fake_experiment, probe_runs, run_helpers) stay here, importable from
# every folder.
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))

import compile_level  # noqa: E402

from rl_jax.training.jax_setup import configure  # noqa: E402

configure()
jax.config.update("jax_numpy_rank_promotion", "raise")
# Cache every compiled program, not only those that took 0.5 s (configure's choice for scripts):
# the suite compiles hundreds of small programs, eager ops and test-only jits, and a warm cache
# makes a rerun of such files several times faster.
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)

# Python's cyclic garbage collector, at its default thresholds, runs every 700 allocations and
# walks every live object in its older generations: tracing a program allocates millions of small
# objects, and a test process holds many. Collecting less often, with what exists after collection
# frozen out of the walks, makes tracing and lowering faster. Garbage is still collected, later.
gc.set_threshold(50_000, 20, 20)


def pytest_configure(config):
    """LLVM -O0 for the tests' programs (compile_level.py says why), set before JAX starts its
    backend; a run that selects the slow tests keeps XLA's defaults."""
    compile_level.apply(config.getoption("markexpr", "") or "")
    # On a GPU, float32 matmuls default to TF32-like precision (about 3 decimal digits), and the
    # tests compare against float32 references (gymnasium, hand-computed losses); CPUs compute
    # float32 matmuls in full precision already, so their programs (and fingerprints) stay as they
    # are. (This starts JAX's backend: after the flags.)
    if jax.default_backend() != "cpu":
        jax.config.update("jax_default_matmul_precision", "highest")


def pytest_collection_finish(session):
    """The modules, tests and fixtures collected live for the whole run: out of every GC walk."""
    gc.collect()
    gc.freeze()


# ---- spreading the files over the test processes (`make test`: -n 2 --dist loadfile) -----------
# Each file runs whole in one process, so that its tests share their compiled programs. Two
# changes to xdist's file scheduling, both for a cold run: files that share costly work run as
# one unit (SHARED_UNITS), and the heaviest units go first.
# - the MJX env files compile the same MJX step programs (test_mujoco_env imports
#   test_mujoco_parity's engine and BATCH): one unit, so that the second file finds them in the
#   compilation cache instead of both processes compiling them at once;
# - the board-game run files share tests/run/conftest.py's `trained` run, made once per test
#   process, and test_td3_state shares probe_runs.train's cached run with test_td3_probes: one
#   unit each, so that each run is trained (and its chunk traced) once;
# - the heaviest units go first, longest first, so that no process is left with a long file at
#   the end while the other idles. xdist's own order is by number of tests, which can put a long
#   file of few tests near the end. The rest follow in xdist's order.
SHARED_UNITS = {
    "tests/envs/test_mujoco_env.py": "tests/envs/test_mujoco_parity.py",
    "tests/run/test_match_command.py": "tests/run/test_board_game_runs.py",
    "tests/agents/test_td3_state.py": "tests/agents/test_td3_probes.py",
}
# the slowest units of a cold run (`--durations=0` at the tests' flags), the slowest first; their
# times are in docs/testing.md
HEAVIEST_FIRST = (
    "tests/envs/test_mujoco_parity.py",  # with test_mujoco_env.py
    "tests/agents/test_dqn_pixels.py",
    "tests/envs/test_mujoco_ffi.py",
    "tests/training/test_parallel.py",
    "tests/agents/test_td3_reference.py",
    "tests/agents/test_td3_network_options.py",
    "tests/run/test_cli.py",
    "tests/agents/test_td3_probes.py",
    "tests/agents/test_td7.py",
)


def pytest_xdist_make_scheduler(config, log):
    if config.getoption("dist", None) != "loadfile":
        return None
    from xdist.scheduler import LoadFileScheduling

    class Scheduling(LoadFileScheduling):
        def __init__(self, config, log=None):
            super().__init__(config, log)
            self._ordered = False

        def _split_scope(self, nodeid: str) -> str:
            scope = super()._split_scope(nodeid)
            return SHARED_UNITS.get(scope, scope)

        def _assign_work_unit(self, node) -> None:
            if not self._ordered:  # the queue is complete before its first unit goes out
                self._ordered = True
                rank = {unit: i for i, unit in enumerate(HEAVIEST_FIRST)}.get
                units = sorted(self.workqueue.items(), key=lambda item: rank(item[0], 99))
                self.workqueue.clear()
                self.workqueue.update(units)
            super()._assign_work_unit(node)

    return Scheduling(config, log)
