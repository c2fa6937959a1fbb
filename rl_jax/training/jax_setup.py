"""Process-wide JAX settings that must be made before JAX's first operation.

Call ``configure()`` at the top of a script (experiments and tests do), before anything creates
an array: the persistent compilation cache and the number of host CPU devices are fixed once the
backend starts.
"""

from __future__ import annotations

import hashlib
import os
import platform
from pathlib import Path

import jax

CACHE_ROOT = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rl_jax" / "jax"


def cpu_tag() -> str:
    """A short name of this CPU's model and instruction set. XLA compiles for the CPU it runs on
    (AVX-512 where there is one) but does not key its cache by it: an entry written on one CPU
    and loaded on a lesser one (a home directory shared between machines) may die of SIGILL, and
    JAX warns on every load. One cache directory per tag keeps them apart."""
    text = platform.machine() + platform.processor()
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            lines = [line for line in cpuinfo if line.startswith(("model name", "flags"))]
        text += "".join(sorted(set(lines)))
    except OSError:
        pass
    return hashlib.sha256(text.encode()).hexdigest()[:12]


DEFAULT_CACHE_DIR = CACHE_ROOT / cpu_tag()


def configure(cpu_devices: int | None = None, cache_dir: str | os.PathLike | None = None) -> None:
    """Turn on the persistent compilation cache and, optionally, split the CPU into devices.

    ``cpu_devices`` > 1 exposes that many host devices so seeds can be sharded over cores.
    ``JAX_COMPILATION_CACHE_DIR`` in the environment wins over ``cache_dir``; set it to an empty
    string to disable the cache.
    """
    if cpu_devices is not None and cpu_devices > 1:
        flags = os.environ.get("XLA_FLAGS", "")
        if "xla_force_host_platform_device_count" not in flags:
            flag = f"--xla_force_host_platform_device_count={cpu_devices}"
            os.environ["XLA_FLAGS"] = f"{flags} {flag}".strip()

    directory = os.environ.get("JAX_COMPILATION_CACHE_DIR", cache_dir or str(DEFAULT_CACHE_DIR))
    if directory:
        Path(directory).mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(directory))
        # Cache everything that took noticeable time to compile; tiny programs are not worth it.
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


def cpu_count() -> int:
    """CPU cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def configure_jax() -> None:
    """Compilation cache on and one JAX device per CPU core (seeds and configs are sharded over
    them), before anything starts JAX. ``RL_JAX_CPU_DEVICES`` overrides the device count."""
    configure(cpu_devices=wanted_cpu_devices())


def wanted_cpu_devices() -> int:
    """The CPU devices ``configure_jax`` asks for: one per core, or ``RL_JAX_CPU_DEVICES``."""
    return int(os.environ.get("RL_JAX_CPU_DEVICES", cpu_count()))
