"""One line describing the machine and its load, printed above every benchmark table; and the
child-process worker every benchmark that needs its own JAX (device count, flags) runs."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


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


def _json_result(
    command: list[str], what: str, prefix: str, environment: dict[str, str]
) -> dict[str, Any]:
    """Run ``command`` from the repository root and return the JSON of the last stdout line that
    starts with ``prefix`` (a worker's ``RESULT {json}``, or a peer's bare ``{json}``): the line
    from its first brace on. A failed run raises ``RuntimeError`` naming ``what``, with the end
    of its stderr."""
    done = subprocess.run(command, cwd=ROOT, env=environment, capture_output=True, text=True)
    lines = [x for x in done.stdout.splitlines() if x.startswith(prefix)]
    if done.returncode or not lines:
        raise RuntimeError(f"{what} failed:\n{done.stderr[-3000:]}")
    return json.loads(lines[-1][lines[-1].index("{") :])


def _environment(base: dict[str, str], env: dict[str, str | None] | None) -> dict[str, str]:
    """``base`` over this process's environment, then ``env``'s variables set (or, given as
    None, removed)."""
    environment = {**os.environ, "TF_CPP_MIN_LOG_LEVEL": "3", **base}
    for name, value in (env or {}).items():
        if value is None:
            environment.pop(name, None)
        else:
            environment[name] = value
    return environment


def worker_result(
    command: list[str], what: str, env: dict[str, str | None] | None = None
) -> dict[str, Any]:
    """Run a benchmark's worker (``python -m bench.NAME --worker ...``, which prints its result
    as a ``RESULT {json}`` line) from the repository root and return that JSON. ``env`` sets
    variables of the child's environment, or removes those given as None. A failed worker
    raises ``RuntimeError`` naming ``what``, with the end of its stderr."""
    environment = _environment({"PYTHONPATH": str(ROOT)}, env)
    return _json_result(command, what, "RESULT ", environment)


def peer_result(
    command: list[str], what: str, env: dict[str, str | None] | None = None
) -> dict[str, Any]:
    """The JSON line that a peer's script (run in the peers' venv) prints last, its other
    variables as for ``worker_result``; a failed script raises ``RuntimeError`` naming ``what``,
    with the end of its stderr."""
    return _json_result(command, what, "{", _environment({}, env))


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


def rates_section(
    title: str,
    command: str,
    explanation: str,
    columns: tuple[str, str],
    rates: dict[tuple[str, int], float],
    digits: int = 2,
) -> str:
    """A Markdown section of rates per (implementation, envs): title, machine line, command,
    ``explanation``, then one row per entry of ``rates`` with its ratio over the first entry
    (the baseline), and the load at the end. ``columns``: the rate's and the ratio's headers."""
    baseline = next(iter(rates.values()))
    rate_header, ratio_header = columns
    lines = [f"## {title}", "", describe(), "", f"`{command}`", "", explanation, ""]
    lines += [f"| implementation | envs | {rate_header} | {ratio_header} |", "|---|---:|---:|---:|"]
    for (label, num_envs), rate in rates.items():
        ratio = f"{rate / baseline:,.{digits}f}x"
        lines.append(f"| {label} | {num_envs:,} | {rate:,.0f} | {ratio} |")
    load = f"load avg {[round(x, 2) for x in os.getloadavg()]} at end"
    return "\n".join([*lines, "", load, ""])
