"""The LLVM optimisation level the tests compile at.

A cold run of the suite is mostly XLA compiling hundreds of small training programs, and most of
that is LLVM optimising machine code that then runs for a few hundred steps. The tests compile at
LLVM -O0 (``--xla_backend_optimization_level=0``): the same HLO programs, with the same results
up to rounding in the last bits, in about half the compile time (``test_td3_options.py`` cold:
172 s of compiling at the default level, 76 s at -O0, 2-core AMD EPYC). Scripts and users keep
XLA's default level; the persistent compilation cache keys entries by their XLA flags, so the two
levels never share an entry.

On a machine with an accelerator plugin (a GPU) nothing changes. ``apply()`` must run before JAX
starts its backend (conftest does); subprocesses inherit the flag.
A test that checks results bit for bit against a record made at the default level runs its
program in a subprocess with ``default_level_env()``. ``TEST_XLA_OPT=default`` keeps the
default level for the whole suite.
"""

import os
import pkgutil

FLAG = "--xla_backend_optimization_level=0"
# XLA's older elemental emitters compile a fusion faster than its newer MLIR fusion emitters
# (half cheetah's MJX step at -O0: 8.1 s -> 5.3 s). The flag is XLA's own and may go away: an
# unknown flag aborts the process, so it is only given to the jaxlib it was measured on.
EMITTER_FLAG = "--xla_cpu_use_fusion_emitters=false"
EMITTER_FLAG_JAXLIB = ("0.9.",)


def _accelerator_plugin() -> bool:
    """A PJRT plugin (CUDA) is installed and may be used: its kernels keep their own level."""
    if os.environ.get("JAX_PLATFORMS", "").strip() == "cpu":
        return False
    try:
        import jax_plugins
    except ImportError:
        return False
    return any(True for _ in pkgutil.iter_modules(jax_plugins.__path__))


def apply() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if os.environ.get("TEST_XLA_OPT") == "default" or "xla_backend_optimization_level" in flags:
        return
    if _accelerator_plugin():
        return
    os.environ["XLA_FLAGS"] = " ".join([*flags.split(), *_flags()])


def _flags() -> list[str]:
    from importlib.metadata import version

    emitters = version("jaxlib").startswith(EMITTER_FLAG_JAXLIB)
    return [FLAG, EMITTER_FLAG] if emitters else [FLAG]


def active() -> bool:
    """This process compiles with the tests' flags rather than XLA's defaults."""
    return FLAG in os.environ.get("XLA_FLAGS", "").split()


def default_emitters() -> dict[str, bool]:
    """``compiler_options`` for a ``jax.jit`` whose programs must fuse as at XLA's defaults: the
    newer emitters where this process turned them off, else nothing."""
    on = EMITTER_FLAG in os.environ.get("XLA_FLAGS", "").split()
    return {"xla_cpu_use_fusion_emitters": True} if on else {}


def subprocess_flags() -> str:
    """XLA_FLAGS for a subprocess that must not inherit other flags (a device count): this
    process's compile flags only."""
    ours = (FLAG, EMITTER_FLAG)
    return " ".join(flag for flag in os.environ.get("XLA_FLAGS", "").split() if flag in ours)


def default_level_env() -> dict[str, str]:
    """This process's environment with XLA's default compile flags."""
    ours = (FLAG, EMITTER_FLAG)
    flags = [flag for flag in os.environ.get("XLA_FLAGS", "").split() if flag not in ours]
    return {**os.environ, "XLA_FLAGS": " ".join(flags), "TEST_XLA_OPT": "default"}
