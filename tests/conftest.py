"""Test-wide JAX settings: fail on silent rank promotion, share the compilation cache, and
compute float32 matmuls in float32 on accelerators too."""

import sys
from pathlib import Path

import jax

# The tests live in folders that mirror the package (agents/, training/, run/, envs/); the helpers
# they share (fake_algorithm, fake_experiment, probe_runs, run_helpers) stay here, importable from
# every folder.
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))

# LLVM -O0 for the tests' programs, set before JAX starts its backend (compile_level.py says why).
import compile_level  # noqa: E402

compile_level.apply()

from rl_jax.training.jax_setup import configure  # noqa: E402

configure()
jax.config.update("jax_numpy_rank_promotion", "raise")
# Cache every compiled program, not only those that took 0.5 s (configure's choice for scripts):
# the suite compiles hundreds of small programs, eager ops and test-only jits, and a warm cache
# makes a rerun of such files 2-3x faster here (test_dqn_losses 22 s -> 8 s, test_vmap 9 s -> 3 s).
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
# On a GPU, float32 matmuls default to TF32-like precision (about 3 decimal digits), and the tests
# compare against float32 references (gymnasium, hand-computed losses); CPUs compute float32
# matmuls in full precision already, so their programs (and fingerprints) stay as they are.
if jax.default_backend() != "cpu":
    jax.config.update("jax_default_matmul_precision", "highest")
