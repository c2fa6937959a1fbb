"""One line describing the machine and its load, printed above every benchmark table."""

from __future__ import annotations

import os
import platform
import time


def describe() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    import jax

    return (
        f"{time.strftime('%Y-%m-%d')} · {cpu} · {os.cpu_count()} cores · "
        f"load avg {load:.2f} at start · jax {jax.__version__} · {platform.python_version()}"
    )


def timeit(fn, *, min_time: float = 1.0, warmup: int = 1) -> float:
    """Seconds per call of ``fn`` (which must block until done), repeated for ``min_time``."""
    for _ in range(warmup):
        fn()
    calls, start = 0, time.perf_counter()
    while True:
        fn()
        calls += 1
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            return elapsed / calls
