"""TD3 performance: update throughput against the CPU's matmul rate, scaling over seeds and
compile time, all measured in one run on the same cores. (Our loop beside SBX and the PyTorch
script our users ran, at equal work, is ``bench_peers``.)

Every timed program runs in a child process (``python -m bench.bench_td3 --worker PART``): the
CPU must be split into two JAX devices before JAX starts, and a compile-time measurement needs a
fresh process and cache directory anyway. The machine is shared, so absolute rates move with the
load; the ratios are what carry over (each part measures its reference in the same process,
interleaved with the thing it is compared to).

1. ``throughput``: achieved GFLOP/s of TD3 updates at the default sizes (256 x 256, batch 256)
   for 1 seed, 5 seeds vmapped (every layer one batched matmul) and 5 seeds sharded over 2 CPU
   devices, divided by the GFLOP/s of float32 1024-square matmuls (the better of one device and
   one chain per device), in alternating rounds. FLOPs: see ``bench.td3_programs``.
2. ``scaling``: seconds per seed of one fixed training chunk (half cheetah, MuJoCo C backend,
   the default recipe) for 1, 5 and 20 seeds and a 4 x 5 grid of hyperparameter sets x seeds.
3. ``compile``: time to the first chunk minus a steady chunk, for the half-cheetah TD3 program
   with an empty persistent compilation cache (cold) and again from a new process (warm).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
RAW = ROOT / "bench" / "results"  # the measured numbers behind each section, as JSON


# ---- workers (child processes) -----------------------------------------------------------------
def throughput(quick: bool) -> dict[str, Any]:
    from bench import td3_programs as programs
    from rl_jax.agents.td3 import td3

    config = td3.default_config(programs.ENV_ID)  # the paper sizes: 256 x 256, batch 256
    paper = config.__class__(env_id=config.env_id)
    flops = programs.update_flops(paper)
    updates = 10 if quick else 50
    matmuls = {d: programs.matmul_program(d) for d in (1, 2)}
    cases = {"1 seed": (1, 1), "5 seeds, vmap": (5, 1), "5 seeds, vmap, 2 devices": (5, 2)}
    calls = {name: programs.update_program(paper, s, d, updates) for name, (s, d) in cases.items()}
    for call in [*calls.values(), *(c for c, _ in matmuls.values())]:
        call()  # compile (and warm up) outside the timed rounds

    def matmul_rate() -> float:
        return max(f / programs.best_seconds(c, 1) for c, f in matmuls.values()) / 1e9

    # Each program is timed between two matmul timings; its ratio is to their mean, so a load
    # change on the shared machine moves both sides of a ratio alike.
    rounds = {name: [] for name in cases}
    references = {name: [] for name in cases}
    for _ in range(1 if quick else 3):
        for name, (seeds, _) in cases.items():
            before = matmul_rate()
            seconds = programs.best_seconds(calls[name], 1)
            rounds[name].append(seeds * updates * flops["per_update"] / seconds / 1e9)
            references[name].append((before + matmul_rate()) / 2)
    return {
        "flops": flops,
        "updates_per_call": updates,
        "gflops": rounds,
        "matmul_gflops": references,
        "load": programs.load(),
    }


def scaling(quick: bool) -> dict[str, Any]:
    from bench.cheetah_recipe import measure

    recipe = {"iterations_per_chunk": 50 if quick else 250, "num_eval_envs": 1}
    recipe["buffer_size"] = 100_000  # 20 seeds of the default 1M would need ~3.5 GB
    cases = [("1 seed", 1, 1), ("5 seeds", 5, 1), ("20 seeds", 20, 1), ("4 x 5 grid", 5, 4)]
    if quick:
        cases = cases[:2]
    return {name: measure(recipe, seeds, 1, sets) for name, seeds, sets in cases}


def compile_time(quick: bool) -> dict[str, Any]:
    from bench.cheetah_recipe import measure

    result = measure({"iterations_per_chunk": 20, "num_eval_envs": 1}, 5, 1)
    result["compile_s"] = round(result["first_call_s"] - result["chunk_s"], 2)
    return result


WORKERS = {
    "throughput": throughput,
    "scaling": scaling,
    "compile": compile_time,
}


def worker_main(part: str, quick: bool, devices: int) -> None:
    from rl_jax.training.jax_setup import configure

    configure(cpu_devices=devices)
    print("RESULT " + json.dumps(WORKERS[part](quick)), flush=True)


# ---- the driver ---------------------------------------------------------------------------------
def _child(part: str, quick: bool, devices: int = 2, env: dict | None = None) -> dict[str, Any]:
    command = [sys.executable, "-m", "bench.bench_td3", "--worker", part, "--devices", str(devices)]
    command += ["--quick"] if quick else []
    return worker_result(command, f"bench_td3 worker {part}", dict(env or {}))


def run(quick: bool) -> str:
    from bench.machine import describe

    lines = [f"## TD3 performance\n\n{describe()}\n", "Command: `python -m bench td3`\n"]
    started = time.strftime("%H:%M")
    lines += _part(throughput_section, lambda: _child("throughput", quick))
    lines += _part(scaling_section, lambda: _child("scaling", quick))
    lines += _part(compile_section, lambda: _compile_cold_and_warm(quick))
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).\n")
    return "\n".join(lines)


def _part(section: Any, measure: Any) -> list[str]:
    """One section; a failing part is reported in the output instead of losing the others."""
    try:
        result = measure()
    except Exception as error:  # noqa: BLE001 - any failure of a child is reported as is
        return [f"### {section.__name__} failed\n", "```", str(error)[-2000:], "```", ""]
    RAW.mkdir(exist_ok=True)
    (RAW / f"td3_{section.__name__}.json").write_text(json.dumps(result))
    return section(*result) if isinstance(result, tuple) else section(result)


def _compile_cold_and_warm(quick: bool) -> tuple[dict, dict]:
    with tempfile.TemporaryDirectory() as cache:
        cold = _child("compile", quick, env={"JAX_COMPILATION_CACHE_DIR": cache})
        warm = _child("compile", quick, env={"JAX_COMPILATION_CACHE_DIR": cache})
    return cold, warm


def throughput_section(result: dict[str, Any]) -> list[str]:
    flops, rounds, references = result["flops"], result["gflops"], result["matmul_gflops"]
    round_count = len(next(iter(references.values())))
    lines = [
        "### Update throughput vs the CPU's matmul rate\n",
        f"One TD3 update at 256 x 256, batch 256: {flops['critic_step'] / 1e6:.1f} MFLOP critic "
        f"step + {flops['actor_step'] / 1e6:.1f} MFLOP actor step every 2nd update = "
        f"**{flops['per_update'] / 1e6:.1f} MFLOP per update** (matmuls, forward + backward, "
        f"counted from the traced program). {result['updates_per_call']} updates per timed "
        "call. Each program is timed between two timings of the float32 1024x1024 matmul "
        "reference (the better of one device and one chain per device); ratio = program / mean "
        f"of the two, median over {round_count} rounds. Load avg "
        f"{result['load']:.2f} at the end.\n",
        "| program | GFLOP/s (best round) | seed-updates/s (best) | matmul GFLOP/s (same "
        "rounds) | ratio (median) |",
        "|---|---|---|---|---|",
    ]
    for name, values in rounds.items():
        ratio = statistics.median(v / m for v, m in zip(values, references[name], strict=True))
        rate = max(values) * 1e9 / flops["per_update"]
        matmul = ", ".join(f"{m:.0f}" for m in references[name])
        lines.append(
            f"| TD3 update, {name} | {max(values):.1f} | {rate:.0f} | {matmul} | {ratio:.2f} |"
        )
    return lines + [""]


def scaling_section(result: dict[str, Any]) -> list[str]:
    chunk = next(iter(result.values()))["recipe"]["iterations_per_chunk"]
    lines = [
        "### Scaling over seeds and hyperparameter sets\n",
        f"One training chunk ({chunk} iterations of the default recipe: env steps of all envs + "
        "the updates, then a 1-episode evaluation), half cheetah on MuJoCo C, 100k buffer, "
        "updates from the first step. Seconds per run (seed x hyperparameter set) and speed-up "
        "per run over 1 seed. Runs are split over 2 CPU devices where they divide evenly "
        "(`rl_jax.training.parallel.Program`).\n",
        "| runs | devices | s/chunk | s/chunk per run | per-run speed-up vs 1 seed | load |",
        "|---|---|---|---|---|---|",
    ]
    base = result["1 seed"]["chunk_s"]
    for name, one in result.items():
        per_run = one["chunk_s"] / one["runs"]
        lines.append(
            f"| {name} | {one['devices']} | {one['chunk_s']:.2f} | {per_run:.3f} | "
            f"{base / per_run:.1f}x | {one['load']:.1f} |"
        )
    return lines + [""]


def compile_section(cold: dict[str, Any], warm: dict[str, Any]) -> list[str]:
    return [
        "### Compile time of the half-cheetah TD3 program (5 seeds)\n",
        "Time to the first chunk (init + trace + compile + run) minus one steady chunk.\n",
        "| cache | compile s | first call s | load |",
        "|---|---|---|---|",
        f"| cold (empty cache dir) | {cold['compile_s']:.1f} | {cold['first_call_s']:.1f} | "
        f"{cold['load']:.1f} |",
        f"| warm (same dir, new process) | {warm['compile_s']:.1f} | {warm['first_call_s']:.1f} | "
        f"{warm['load']:.1f} |",
        "",
    ]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--worker", choices=sorted(WORKERS), required=True)
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args(argv)
    worker_main(args.worker, args.quick, args.devices)


if __name__ == "__main__":
    main()
