"""Env throughput of every MuJoCo env in one side-by-side table (`python -m bench env_throughput`).

Env steps/s (agent steps, ``frame_skip`` physics substeps each) of the nine MuJoCo envs, measured
with ``bench_mujoco``'s programs:

* gymnasium: ``gymnasium.make(id).unwrapped`` stepped in a Python loop (the MuJoCo env itself, cut
  at the same episode limit), and ``AsyncVectorEnv`` with one env per process, one process per core;
* raw C: ``mujoco.rollout`` of the same model, ``frame_skip`` substeps per call with fresh
  controls, one thread per core (``bench_mujoco.raw_rollout_call``);
* ours: ``jax.jit`` of a ``lax.scan`` over ``vmap(env.step)`` with random actions drawn inside the
  program (``bench_mujoco.ours``) on the FFI op (``backend="mujoco_ffi"``, the CPU default), timed
  in turn with raw C at the same batch size, best of the rounds;
* MJX: the same program on ``backend="mjx"``, in a child process that must finish each phase
  (build the env, compile a batch size, time it) within ``--mjx-limit`` seconds, else the cell says
  ``skipped (compile > N s)``: XLA cannot be interrupted in-process, and Humanoid's MJX step may
  compile and run for many minutes on a 2-core CPU. "compile s" is the compile or, on a rerun,
  the persistent compilation cache's load.

Goal (issue text): ours >= 0.9 of raw C at 64 envs, for every env.

``--backend mjx --sizes 1024,4096,...`` times MJX alone (what a GPU is for; scripts/gpu_check.sh).
``--quick``: batch size 2, one short round, no AsyncVectorEnv, MJX for the first env only.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import selectors
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.bench_mujoco import (
    ENV_IDS as FIRST_ENV_IDS,
)
from bench.bench_mujoco import (
    _cores,
    _format,
    _our_env,
    _rate,
    gymnasium_async_call,
    gymnasium_single_call,
    measure_batch,
    ours,
    release,
)
from bench.machine import describe

ROOT = Path(__file__).resolve().parents[1]
ENV_IDS = (
    *FIRST_ENV_IDS,
    *(f"{name}-v5" for name in ("Hopper", "Walker2d", "Ant", "Reacher", "Swimmer", "Humanoid")),
)
SIZES = (1, 64, 1024)
RATIO_SIZE = 64  # the goal is stated at 64 envs
GOAL = 0.9
ROUNDS = 3
MIN_TIME = 1.0
MJX_LIMIT = 180.0
FFI = "mujoco_ffi"
MARK = "@@bench "  # prefixes the worker's JSON lines: JAX or MuJoCo may print to stdout too


# ---- MJX in a child process with a time limit per phase ----------------------------------------


def _emit(event: dict) -> None:
    print(MARK + json.dumps(event), flush=True)


def worker(env_id: str, sizes: tuple[int, ...], min_time: float, rounds: int) -> None:
    """The child's side: build the MJX env, then compile and time each batch size, one JSON line
    after each phase."""
    _our_env(env_id, "mjx")
    _emit({"phase": "build"})
    for n_envs in sizes:
        call, compile_seconds = ours(env_id, "mjx", n_envs)
        _emit({"phase": "compile", "envs": n_envs, "seconds": compile_seconds})
        rate = max(_rate(call, min_time) for _ in range(rounds))
        _emit({"phase": "run", "envs": n_envs, "rate": rate})


def _next_event(process: subprocess.Popen, selector, limit: float) -> dict | None:
    """The worker's next JSON line within ``limit`` seconds; None if it took longer or ended."""
    deadline = time.monotonic() + limit
    while (remaining := deadline - time.monotonic()) > 0:
        if not selector.select(remaining):
            return None
        line = process.stdout.readline()
        if not line:  # the worker ended: reap it, so that _failure sees its exit code
            with contextlib.suppress(subprocess.TimeoutExpired):
                process.wait(timeout=10)
            return None
        if line.startswith(MARK):
            return json.loads(line[len(MARK) :])
    return None


def mjx_rates(
    env_id: str, sizes: tuple[int, ...], limit: float, min_time: float, rounds: int
) -> dict[int, dict]:
    """Per batch size ``{"rate", "compile"}`` or ``{"skipped": reason}``, from one worker
    process that is killed when a phase takes longer than ``limit`` seconds."""
    command = [sys.executable, "-m", "bench.bench_env_throughput", "--worker", "--envs", env_id]
    command += ["--sizes", ",".join(map(str, sizes)), "--min-time", str(min_time)]
    command += ["--rounds", str(rounds)]
    environment = dict(os.environ)
    environment["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p
    )
    results: dict[int, dict] = {}
    interrupted = False
    phases = [("build", None)] + [(phase, n) for n in sizes for phase in ("compile", "run")]
    reason, failed_at = None, None
    with tempfile.TemporaryFile("w+") as log:
        process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=log, text=True, cwd=ROOT, env=environment
        )
        selector = selectors.DefaultSelector()
        selector.register(process.stdout, selectors.EVENT_READ)
        try:
            for phase, n_envs in phases:
                try:
                    event = _next_event(process, selector, limit)
                except KeyboardInterrupt:  # keep what was measured; the caller stops after us
                    reason, failed_at, interrupted = f"{phase} interrupted", n_envs, True
                    break
                if event is None:
                    reason, failed_at = _failure(process, log, phase, limit), n_envs
                    break
                if phase == "compile":
                    results[n_envs] = {"compile": event["seconds"]}
                elif phase == "run":
                    results[n_envs]["rate"] = event["rate"]
                _progress(env_id, phase, n_envs, event)
        finally:
            if process.poll() is None:
                process.kill()
            process.wait()
            selector.close()
            process.stdout.close()
    for n_envs in sizes:
        if "rate" not in results.get(n_envs, {}):
            own = failed_at is None or n_envs == failed_at
            skipped = reason if own else f"not run after {failed_at:,} envs: {reason}"
            results[n_envs] = {**results.get(n_envs, {}), "skipped": skipped}
    if interrupted:
        raise Interrupted(results)
    return results


class Interrupted(Exception):
    """Ctrl-C (or a time limit's SIGINT) during an MJX measurement, with the sizes measured."""

    def __init__(self, results: dict[int, dict]):
        super().__init__("interrupted")
        self.results = results


def _progress(env_id: str, phase: str, n_envs: int | None, event: dict) -> None:
    """One stderr line per finished phase, so that a run cut short still shows what it
    measured."""
    if phase == "build":
        text = "built"
    elif phase == "compile":
        text = f"{n_envs:,} envs compiled in {event['seconds']:.1f} s"
    else:
        text = f"{n_envs:,} envs: {_format(event['rate'])} env steps/s"
    print(f"{env_id} MJX: {text}", file=sys.stderr, flush=True)


def _failure(process: subprocess.Popen, log, phase: str, limit: float) -> str:
    """Why the worker gave no event: its time ran out, or it failed (its last stderr line)."""
    if process.poll() is None:
        return f"{phase} > {limit:g} s"
    log.seek(0)
    lines = [line for line in log.read().splitlines() if line.strip()]
    return f"{phase} failed: {lines[-1][:120] if lines else f'exit {process.returncode}'}"


# ---- the C side and gymnasium, then the table --------------------------------------------------


def measure_env(
    env_id: str, sizes: tuple[int, ...], min_time: float, rounds: int, gym_vector: bool
) -> dict:
    """gymnasium, and raw C and ours on the FFI op timed in turn at each batch size."""
    single = gymnasium_single_call(env_id, unwrapped=True)
    row: dict = {"gym": max(_rate(single, min_time) for _ in range(rounds))}
    if gym_vector:
        row["gym_vector"] = _rate(gymnasium_async_call(env_id), min_time)
    for n_envs in sizes:
        result = measure_batch(env_id, n_envs, min_time, rounds, backends=(FFI,))
        row[("raw", n_envs)], row[("ours", n_envs)] = (result["rates"][k] for k in ("raw", FFI))
    release()  # the rollout pools and gymnasium's processes would compete with the next env
    return row


def _cell(result: dict) -> str:
    return _format(result["rate"]) if "rate" in result else f"skipped ({result['skipped']})"


def _compile_cell(results: dict[int, dict]) -> str:
    return " / ".join(f"{r['compile']:.0f}" if "compile" in r else "-" for r in results.values())


def full_table(rows: dict[str, dict], sizes: tuple[int, ...], mjx_sizes: tuple[int, ...]) -> list:
    ratio_size = RATIO_SIZE if RATIO_SIZE in sizes else max(sizes)
    header = ["env", "gymnasium 1 env"]
    if any("gym_vector" in row for row in rows.values()):
        header.append(f"gymnasium async ({_cores()} proc)")
    for n_envs in sizes:
        header += [f"raw C {n_envs:,}", f"ours {n_envs:,}"]
    header += [f"MJX {n:,}" for n in mjx_sizes]
    header += [f"ours/raw at {ratio_size:,}", "MJX compile s"]
    lines = ["| " + " | ".join(header) + " |", "|---" + "|---:" * (len(header) - 1) + "|"]
    for env_id, row in rows.items():
        cells = [env_id, _format(row["gym"])]
        if "gym_vector" in row:
            cells.append(_format(row["gym_vector"]))
        for n_envs in sizes:
            cells += [_format(row[("raw", n_envs)]), _format(row[("ours", n_envs)])]
        mjx = row.get("mjx", {})
        cells += [_cell(mjx[n]) if n in mjx else "-" for n in mjx_sizes]
        ratio = row[("ours", ratio_size)] / row[("raw", ratio_size)]
        cells += [f"{ratio:.2f}", _compile_cell(mjx) if mjx else "-"]
        lines.append("| " + " | ".join(cells) + " |")
    met = [e for e, r in rows.items() if r[("ours", ratio_size)] >= GOAL * r[("raw", ratio_size)]]
    lines += ["", f"ours >= {GOAL} x raw C at {ratio_size:,} envs: {len(met)} of {len(rows)} envs."]
    return lines


def mjx_table(rows: dict[str, dict], sizes: tuple[int, ...]) -> list:
    header = ["env", *(f"MJX {n:,}" for n in sizes), "compile s"]
    lines = ["| " + " | ".join(header) + " |", "|---" + "|---:" * (len(header) - 1) + "|"]
    for env_id, row in rows.items():
        cells = [env_id, *(_cell(row["mjx"][n]) for n in sizes), _compile_cell(row["mjx"])]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def run(
    quick: bool = False,
    env_ids: tuple[str, ...] = ENV_IDS,
    sizes: tuple[int, ...] | None = None,
    backend: str = "all",
    mjx_limit: float = MJX_LIMIT,
    min_time: float | None = None,
    rounds: int | None = None,
    command: str | None = None,
) -> str:
    """The Markdown section. ``backend="all"``: gymnasium, raw C and ours (FFI) at ``sizes``, MJX
    at the sizes above 1; ``"mjx"``: MJX alone at ``sizes``."""
    command = command or f"python -m bench env_throughput{' --quick' if quick else ''}"
    sizes = sizes or ((2,) if quick else SIZES)
    min_time = min_time if min_time is not None else (0.05 if quick else MIN_TIME)
    rounds = rounds or (1 if quick else ROUNDS)
    mjx_sizes = sizes if backend == "mjx" else tuple(n for n in sizes if n > 1) or sizes
    load_start = os.getloadavg()[0]
    if backend != "mjx":
        from rl_jax.envs.mujoco import mujoco_ffi_build

        mujoco_ffi_build.build()  # a once-per-machine cost, not part of any measurement
    rows: dict[str, dict] = {}
    stopped = None
    for index, env_id in enumerate(env_ids):
        row = {} if backend == "mjx" else measure_env(env_id, sizes, min_time, rounds, not quick)
        if backend == "mjx" or not quick or index == 0:
            try:
                row["mjx"] = mjx_rates(env_id, mjx_sizes, mjx_limit, min_time, rounds)
            except Interrupted as cut:
                row["mjx"], stopped = cut.results, env_id
        rows[env_id] = row
        print(f"{env_id}: {json.dumps({str(k): v for k, v in row.items()})}", file=sys.stderr)
        if stopped:
            break
    lines = [
        "## Env throughput of every MuJoCo env (env steps/s, frame skip included)",
        "",
        describe(),
        "",
        f"`{command}`; {_cores()} cores, every batched C path uses {_cores()} threads; raw C and "
        f"ours timed in turn, best of {rounds} round(s) of >= {min_time:g} s; MJX in a child "
        f"process, each phase limited to {mjx_limit:g} s.",
        "",
    ]
    lines += mjx_table(rows, sizes) if backend == "mjx" else full_table(rows, sizes, mjx_sizes)
    if stopped:
        rest = env_ids[env_ids.index(stopped) + 1 :]
        lines += [
            "",
            f"Interrupted during {stopped}" + (f"; not run: {', '.join(rest)}." if rest else "."),
        ]
    load_end = os.getloadavg()[0]
    lines += ["", f"Load average (1 min): {load_start:.2f} at start, {load_end:.2f} at end."]
    return "\n".join(lines) + "\n"


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(x) for x in text.split(","))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], epilog="(python -m bench env_throughput: defaults)"
    )
    parser.add_argument("--quick", action="store_true", help="a smoke run (see the module doc)")
    parser.add_argument("--envs", type=lambda t: tuple(t.split(",")), default=ENV_IDS)
    parser.add_argument("--sizes", type=_ints, default=None, help="batch sizes (default 1,64,1024)")
    parser.add_argument("--backend", choices=("all", "mjx"), default="all")
    parser.add_argument("--mjx-limit", type=float, default=MJX_LIMIT, help="seconds per phase")
    parser.add_argument("--min-time", type=float, default=None, help="seconds per round")
    parser.add_argument("--rounds", type=int, default=None)
    parser.add_argument("--out", type=Path, default=None, help="also write the section here")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    from rl_jax.training.jax_setup import configure

    configure()
    if args.worker:
        worker(args.envs[0], args.sizes, args.min_time, args.rounds)
        return 0
    command = " ".join(["python -m bench.bench_env_throughput", *(argv or sys.argv[1:])])
    section = run(
        args.quick, args.envs, args.sizes, args.backend, args.mjx_limit, args.min_time,
        args.rounds, command,
    )  # fmt: skip
    print(section, flush=True)
    if args.out:
        args.out.write_text(section)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
