"""An uneven seed count over several devices against the even count, side by side in one run
(``python -m bench uneven_devices``, or ``python -m bench.bench_uneven_devices --size full
--devices 2,4``).

The goal (issue "every device busy"): 5 seeds over 2 (or 4) devices take <= 1.1x the time of 6
(or 8) seeds over the same devices, and their per-device speed-up matches the even count's. The
job is the default half-cheetah TD3 (``td3.default_config("rl_jax/HalfCheetah-v5")``, updates
from the first step). Per device count ``D``, in a child process with ``D`` CPU devices (the
count is fixed before JAX starts), one after another:

* ``1 device``: 5 seeds, then the even count, on one device: the speed-ups' baselines;
* ``even``: the even count (6 or 8 seeds) over the ``D`` devices;
* ``padded``: 5 seeds as the runs of a run are laid out (``rl_jax.run.plan.program_for``:
  padded with copies of seed 0, computed and dropped, one program);
* ``uneven split``: 5 seeds split without padding (3 + 2, or 2 + 1 + 1 + 1), one program per
  device, compiled in threads and dispatched together (``--layout split``,
  ``rl_jax.training.split_program``).

Each is timed over whole training chunks once compiled; its first call (compile and one chunk)
is reported apart. ``--size tiny`` shrinks the job to a smoke test of seconds (its times mean
nothing).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
ENV_ID = "rl_jax/HalfCheetah-v5"
UNEVEN = 5
EVEN = {2: 6, 4: 8}
# size: (config overrides, seconds each layout is timed for at the least)
SIZES = {
    "tiny": (
        {
            "num_envs": 2,
            "iterations_per_chunk": 4,
            "batch_size": 16,
            "buffer_size": 1_000,
            "actor_hidden": (16, 16),
            "critic_hidden": (16, 16),
            "num_eval_envs": 1,
        },
        0.0,
    ),
    "full": ({}, 60.0),
}


# ---- the worker (a child process with D devices) -------------------------------------------
def _config(size: str) -> Any:
    from rl_jax.agents.td3 import td3
    from rl_jax.training import episodes

    overrides, _ = SIZES[size]
    config = dataclasses.replace(td3.default_config(ENV_ID), learning_starts=0, **overrides)
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    return config


def _timed(chunk: Any, size: str) -> tuple[float, float]:
    """``(first call s, s per chunk)``: the first call compiles; then at least 2 chunks."""
    start = time.perf_counter()
    chunk()
    first = time.perf_counter() - start
    chunks, start = 0, time.perf_counter()
    while chunks < 2 or time.perf_counter() - start < SIZES[size][1]:
        chunk()
        chunks += 1
    return first, (time.perf_counter() - start) / chunks


def _one_program(config: Any, seeds: int, devices: list) -> tuple[Any, str]:
    """A chunk of ``seeds`` runs as the run machinery lays them out over ``devices``."""
    import jax

    from rl_jax.agents.td3 import td3
    from rl_jax.training import parallel, params

    hparams = params.stack([td3.default_hyperparams(ENV_ID)])
    program = parallel.Program(td3, config, 1, seeds, devices=devices)
    state = [program.init(parallel.seed_keys(range(seeds)), hparams)]

    def chunk() -> None:
        state[0], metrics = program.train_chunk(state[0], hparams)
        jax.block_until_ready(metrics)

    layout = program.layout
    return chunk, f"{layout.padded_seeds} runs on {layout.devices} device(s)"


def _split_programs(config: Any, seeds: int, devices: list) -> tuple[Any, str]:
    """``seeds`` split over ``devices`` without padding (``training.split_program``, what
    ``--layout split`` runs): a program per block size, sharded over the devices of its
    blocks, compiled in threads, each program's chunk dispatched before any is waited for."""
    import jax

    from rl_jax.agents.td3 import td3
    from rl_jax.training import parallel, params
    from rl_jax.training.split_program import SplitProgram

    hparams = params.stack([td3.default_hyperparams(ENV_ID)])
    program = SplitProgram(td3, config, 1, seeds, devices)
    state = [program.init(parallel.seed_keys(range(seeds)), hparams)]
    compiled: list = []

    def chunk() -> None:
        if not compiled:
            compiled.append(program.compile(state[0], hparams))
        state[0], metrics = compiled[0](state[0], hparams)
        jax.block_until_ready(metrics)

    sizes = " + ".join(str(block.runs) for block in program.layout.blocks)
    return chunk, f"{sizes} on {program.layout.devices} devices"


def worker(devices: int, size: str) -> dict[str, Any]:
    """Every layout of this device count, timed one after another."""
    import jax

    config = _config(size)
    every = jax.devices()[:devices]
    even = EVEN.get(devices, devices * 2)
    layouts = {
        f"{UNEVEN} seeds, 1 device": _one_program(config, UNEVEN, every[:1]),
        f"{even} seeds, 1 device": _one_program(config, even, every[:1]),
        f"{even} seeds, even": _one_program(config, even, every),
        f"{UNEVEN} seeds, padded": _one_program(config, UNEVEN, every),
        f"{UNEVEN} seeds, uneven split": _split_programs(config, UNEVEN, every),
    }
    rows = {}
    for name, (chunk, layout) in layouts.items():
        first, seconds = _timed(chunk, size)
        rows[name] = {"layout": layout, "first_call_s": round(first, 2), "chunk_s": seconds}
        rows[name]["load"] = round(os.getloadavg()[0], 2)
    steps = config.num_envs * config.iterations_per_chunk
    return {"devices": devices, "even": even, "env_steps_per_chunk": steps, "rows": rows}


# ---- the parent ------------------------------------------------------------------------------
def _worker_child(devices: int, size: str) -> dict[str, Any]:
    command = [sys.executable, "-m", "bench.bench_uneven_devices", "--worker", str(devices)]
    command += ["--size", size]
    flags = [f"--xla_force_host_platform_device_count={devices}"]
    if size == "tiny":  # a smoke test: compile fast (LLVM -O0), the times mean nothing anyway
        flags.append("--xla_backend_optimization_level=0")
    return worker_result(
        command, f"the worker on {devices} devices", {"XLA_FLAGS": " ".join(flags)}
    )


def table(result: dict[str, Any]) -> list[str]:
    """One device count's rows, with the goal's two ratios."""
    rows, even, devices = result["rows"], result["even"], result["devices"]
    seconds = {name: row["chunk_s"] for name, row in rows.items()}
    even_time = seconds[f"{even} seeds, even"]
    lines = [
        f"**{devices} devices** ({result['env_steps_per_chunk']} env steps per run per chunk)",
        "",
        "| runs | layout | first call s | s/chunk | / even count's time | speed-up over 1 device "
        "| load |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    for name, row in rows.items():
        runs = int(name.split()[0])
        alone = seconds.get(f"{runs} seeds, 1 device", row["chunk_s"])
        lines.append(
            f"| {name} | {row['layout']} | {row['first_call_s']:.1f} | {row['chunk_s']:.3f} "
            f"| {row['chunk_s'] / even_time:.2f}x | {alone / row['chunk_s']:.2f}x | {row['load']} |"
        )
    even_speedup = seconds[f"{even} seeds, 1 device"] / even_time
    for kind in ("padded", "uneven split"):
        time_ratio = seconds[f"{UNEVEN} seeds, {kind}"] / even_time
        speedup = seconds[f"{UNEVEN} seeds, 1 device"] / seconds[f"{UNEVEN} seeds, {kind}"]
        met = "met" if time_ratio <= 1.1 else "not met"
        lines.append(
            f"\n{UNEVEN} seeds {kind}: {time_ratio:.2f}x the time of {even} seeds (goal <= 1.1x: "
            f"{met}); per-device speed-up {speedup:.2f}x against the even count's "
            f"{even_speedup:.2f}x ({speedup / even_speedup:.2f} of it)."
        )
    return [*lines, ""]


def section(size: str, device_counts: list[int]) -> str:
    from bench.machine import describe

    command = f"python -m bench.bench_uneven_devices --size {size} --devices "
    command += ",".join(map(str, device_counts))
    lines = ["## An uneven seed count over several devices", "", describe(), "", f"`{command}`", ""]
    if size != "full":
        lines += [f"Size {size}: a smoke test, not a measurement.", ""]
    for devices in device_counts:
        lines += table(_worker_child(devices, size))
    lines.append(f"load avg {[round(x, 2) for x in os.getloadavg()]} at end")
    return "\n".join(lines) + "\n"


def run(quick: bool) -> str:
    """``python -m bench uneven_devices``: 2 devices (``--quick``: the tiny size)."""
    return section("tiny" if quick else "full", [2])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--size", choices=sorted(SIZES), default="full", help="tiny: a smoke test")
    parser.add_argument("--devices", default="2", help="device counts, e.g. 2,4")
    parser.add_argument("--worker", type=int, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    from rl_jax.training.jax_setup import configure

    if args.worker:
        configure(cpu_devices=args.worker)
        print("RESULT " + json.dumps(worker(args.worker, args.size)), flush=True)
        return
    configure()
    print(section(args.size, [int(d) for d in args.devices.split(",")]), flush=True)


if __name__ == "__main__":
    main()
