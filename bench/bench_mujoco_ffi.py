"""MuJoCo C inside the compiled program: the FFI op against the pure_callback path and raw C.

Two parts (``python -m bench mujoco_ffi`` runs both; ``python -m bench.bench_mujoco_ffi --part
steps|warm`` one of them):

``steps``
    Env steps/s (agent steps, frame skip included) at 1, 4, 64 and 1,024 envs of each MuJoCo env:
    raw ``mujoco.rollout`` (threaded batched C from Python, nothing around it), and our jitted
    ``lax.scan`` of ``vmap(env.step)`` on ``backend="mujoco_ffi"`` and ``"mujoco_callback"``
    (the programs of ``bench_mujoco.ours``). Timed in turn, best of 3 rounds.
``warm``
    The start of ``experiments/td3_cheetah.py`` (its default 5 seeds, one 5,000-step chunk), run as
    a fresh process twice with one new, empty ``JAX_COMPILATION_CACHE_DIR`` (cold, then warm),
    per C backend: seconds from launch to the first chunk's metrics row, and the "compiled in"
    time the script prints. The FFI library itself is built before (a once-per-machine cost).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.bench_mujoco import ENV_IDS, _cores, _format, measure_batch
from bench.machine import describe

BATCH_SIZES = (1, 4, 64, 1024)
C_BACKENDS = ("mujoco_ffi", "mujoco_callback")
ROUNDS = 3
SCRIPT = Path(__file__).resolve().parents[1] / "experiments" / "td3_cheetah.py"
CHUNK_STEPS = 5000  # env steps per seed of the script's first chunk
WARM_GOAL_SECONDS = 5.0


def steps_section(quick: bool) -> list[str]:
    min_time, rounds = (0.3, 1) if quick else (1.0, ROUNDS)
    env_ids, sizes = (["HalfCheetah-v5"], (64,)) if quick else (ENV_IDS, BATCH_SIZES)
    lines = [
        "### Env steps/s: FFI op vs pure_callback vs raw C",
        "",
        f"{_cores()} cores; every batched C path uses {_cores()} threads; timed in turn, best of "
        f"{rounds} round(s) of >= {min_time} s.",
        "",
    ]
    for env_id in env_ids:
        lines += [
            f"#### {env_id}",
            "",
            "| envs | raw C rollout | FFI op | callback | FFI/raw | callback/raw | FFI/callback |"
            " compile s FFI / callback |",
            "|---:|---:|---:|---:|---:|---:|---:|---:|",
        ]
        for n_envs in sizes:
            result = measure_batch(env_id, n_envs, min_time, rounds, backends=C_BACKENDS)
            raw, ffi, callback = (result["rates"][k] for k in ("raw", *C_BACKENDS))
            compile_ffi, compile_callback = (result["compile"][k] for k in C_BACKENDS)
            lines.append(
                f"| {n_envs} | {_format(raw)} | {_format(ffi)} | {_format(callback)} | "
                f"{ffi / raw:.2f} | {callback / raw:.2f} | {ffi / callback:.2f} | "
                f"{compile_ffi:.1f} / {compile_callback:.1f} |"
            )
        lines.append("")
    return lines


def start_script(backend: str, cache: str, out: Path, seeds: int) -> dict[str, float]:
    """One fresh ``td3_cheetah.py`` process: seconds to its first metrics row, its compile time."""
    environment = {**os.environ, "JAX_COMPILATION_CACHE_DIR": cache}
    environment["RL_JAX_MUJOCO_BACKEND"] = backend
    environment["PYTHONPATH"] = str(SCRIPT.parents[1])
    command = [sys.executable, str(SCRIPT), "--seeds", str(seeds)]
    command += ["--total-steps", str(CHUNK_STEPS), "--out", str(out)]
    metrics = out / "metrics.jsonl"
    started = time.perf_counter()
    with tempfile.TemporaryFile("w+") as log:
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=environment)
        first_chunk = None
        while process.poll() is None:
            if first_chunk is None and metrics.exists() and metrics.stat().st_size:
                first_chunk = time.perf_counter() - started
            time.sleep(0.02)
        log.seek(0)
        output = log.read()
    if process.returncode != 0:
        raise RuntimeError(f"{SCRIPT.name} failed ({backend}):\n{output[-2000:]}")
    compiled = re.search(r"compiled in ([0-9.]+) s", output)
    return {
        "first_chunk_s": float("nan") if first_chunk is None else first_chunk,
        "compile_s": float(compiled.group(1)) if compiled else float("nan"),
        "load": os.getloadavg()[0],
    }


def warm_section(quick: bool) -> list[str]:
    from rl_jax.envs.mujoco import mujoco_ffi_build

    mujoco_ffi_build.build()  # a once-per-machine cost, not part of a start
    seeds = 1 if quick else 5
    lines = [
        "### Start of td3_cheetah.py: cold and warm compilation cache",
        "",
        f"`td3_cheetah.py --seeds {seeds} --total-steps {CHUNK_STEPS}` as a fresh process, twice "
        "with one new cache dir. First chunk s: launch to the first metrics row (imports, env "
        "build, compile or cache load, one 5,000-step chunk). Goal: warm < "
        f"{WARM_GOAL_SECONDS:.0f} s.",
        "",
        "| backend | cache | first chunk s | compiled in s | load |",
        "|---|---|---:|---:|---:|",
    ]
    for backend in C_BACKENDS:
        with tempfile.TemporaryDirectory() as directory:
            for cache_state in ("cold", "warm"):
                out = Path(directory) / f"run_{cache_state}"
                result = start_script(backend, str(Path(directory) / "cache"), out, seeds)
                lines.append(
                    f"| {backend} | {cache_state} | {result['first_chunk_s']:.1f} | "
                    f"{result['compile_s']:.1f} | {result['load']:.1f} |"
                )
    return lines + [""]


PARTS = {"steps": steps_section, "warm": warm_section}


def run(quick: bool = False, parts: tuple[str, ...] = tuple(PARTS)) -> str:
    lines = [
        "## MuJoCo C: FFI op vs pure_callback (`python -m bench mujoco_ffi`)",
        "",
        describe(),
        "",
    ]
    for part in parts:
        lines += PARTS[part](quick)
    lines.append(f"Load average (1 min) at end: {os.getloadavg()[0]:.2f}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=sorted(PARTS), action="append", help="default: all")
    parser.add_argument("--quick", action="store_true", help="one size, one env: a smoke run")
    args = parser.parse_args(argv)
    from rl_jax.training.jax_setup import configure

    configure()
    print(run(args.quick, tuple(args.part or PARTS)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
