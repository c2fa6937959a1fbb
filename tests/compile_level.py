"""The XLA compile flags the tests use: faster to compile than XLA's defaults, same programs.

A cold run of the suite is mostly XLA compiling hundreds of small training programs that then run
a few hundred steps, and most of that time is code generation. The tests compile at LLVM -O0
(``--xla_backend_optimization_level=0``) and, on the jaxlib it was measured on, with XLA's older
elemental emitters (``--xla_cpu_use_fusion_emitters=false``): the same HLO programs, whose results
differ from the defaults' only by rounding in the last bits, and that compile several times
faster (docs/testing.md has the measurements). Scripts and users keep XLA's defaults; the
persistent compilation cache keys entries by their XLA flags, so the two never share an entry.

``apply()`` must run before JAX starts its backend (conftest's ``pytest_configure`` does);
subprocesses inherit the flags. A run that selects the slow tests (``-m slow``, ``make test-slow``)
keeps XLA's defaults: those tests train RESULTS.md's rows, whose times and seed paths are the
defaults'. On a machine with an accelerator plugin (a GPU) nothing changes. ``TEST_XLA_OPT=default``
keeps XLA's defaults for the whole suite. Bit-for-bit checks against records made at other
flags, or between two programs that the older emitters fuse differently, use
``default_level_env()`` (a subprocess) or ``default_emitters()`` (one jit's options).
"""

import os
import pkgutil

FLAG = "--xla_backend_optimization_level=0"
# XLA's older elemental emitters compile a fusion faster than its newer MLIR fusion emitters.
# The flag is XLA's own and may go away: an unknown flag aborts the process, so it is only given
# to the jaxlib it was measured on.
EMITTER_FLAG = "--xla_cpu_use_fusion_emitters=false"
EMITTER_FLAG_JAXLIB = ("0.9.",)


def _accelerator_plugin() -> bool:
    """A PJRT plugin (CUDA) is installed and may be used: its kernels keep their own level."""
    if os.environ.get("JAX_PLATFORMS", "").strip() == "cpu":
        return False
    from importlib.metadata import entry_points

    if entry_points(group="jax_plugins"):  # the two ways JAX discovers a plugin
        return True
    try:
        import jax_plugins
    except ImportError:
        return False
    return any(True for _ in pkgutil.iter_modules(jax_plugins.__path__))


def selects_slow(markexpr: str) -> bool:
    """Whether a pytest ``-m`` expression can select tests marked ``slow`` (the suite's own
    ``not slow`` cannot)."""
    return "slow" in markexpr and " ".join(markexpr.split()) != "not slow"


def apply(markexpr: str = "") -> None:
    """The tests' flags into ``XLA_FLAGS``, unless kept at XLA's defaults: by
    ``TEST_XLA_OPT=default``, by a level already given, or because ``markexpr`` selects slow
    tests. Those train RESULTS.md's rows, in this process or in scripts that inherit the flags,
    and the rows' wall-clock goals and seed paths were measured at XLA's defaults: at these flags
    a row runs slower and its seeds take other paths."""
    flags = os.environ.get("XLA_FLAGS", "")
    if os.environ.get("TEST_XLA_OPT") == "default" or "xla_backend_optimization_level" in flags:
        return
    if selects_slow(markexpr):
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
