"""Half cheetah on a GPU: candidate recipes by return against wall-clock (scripts/gpu_check.sh).

The goal (issue text): 5 seeds to a mean eval return of 5,000 in <= 60 s of training, compile
excluded, on one H100/H200, with many envs, large batches and as many updates per env step as
learning needs. Each candidate is ``experiments/td3_cheetah.py --seeds 5`` with its loop flags::

    python -m bench.gpu_recipe warm  --workdir /tmp/recipes    # compile all, in parallel
    python -m bench.gpu_recipe run   --workdir /tmp/recipes --budget 60 --deadline EPOCH
    python -m bench.gpu_recipe table --workdir /tmp/recipes    # Markdown table

``warm`` starts every candidate at once, one process each, and ends each once its program is
compiled, and so in the persistent compilation cache (compiling is CPU work, and the GPU machine
has 16 cores); ``run`` then trains them one at a time, so that no two share the GPU while timed, and
ends each (SIGKILL: only metrics.jsonl is wanted, and it is flushed per chunk) once the seed mean
reaches the goal, or after the chunk that ends past ``--budget`` seconds of training, or at the
``--deadline``. Training seconds are counted from the script's "compiled in" line, as this process
sees it (polled every 0.2 s). ``--dry`` swaps in tiny versions (2 seeds, small networks) for a CPU
rehearsal.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "td3_cheetah.py"
GOAL = 5000.0
# Env steps per seed between evaluations. An evaluation is 1,000 sequential MJX steps (seconds
# on a GPU, as long as a few hundred loop iterations), so evaluating often costs much of the
# budget; more seldom blurs the time at which the goal was reached.
CHUNK_STEPS = 24_576
#: name: (num_envs, batch_size, updates_per_iteration), in the order ``run`` tries them.
#: Updates per env step = updates_per_iteration / num_envs; the CPU recipe makes 1 at batch 128.
#: The first reached the goal on one H100 (BENCHMARKS.md has its run) and is
#: ``td3_cheetah.py --recipe gpu`` (td3's recipe "gpu"); the others were not timed.
CANDIDATES = {
    "e64-b1024-u32": (64, 1024, 32),  # 0.5 update per env step
    "e64-b4096-u16": (64, 4096, 16),  # 0.25, 4x the batch
    "e256-b4096-u64": (256, 4096, 64),  # 0.25 with 4x the envs
    "e64-b1024-u64": (64, 1024, 64),  # 1.0, the paper's ratio
}
DRY_CANDIDATES = {"dry-e2-b32-u2": (2, 32, 2), "dry-e4-b64-u2": (4, 64, 2)}
COMPILED = re.compile(r"compiled in ([0-9.]+) s")


def flags(name: str, dry: bool, base_seed: int = 0) -> list[str]:
    """td3_cheetah.py's arguments for a candidate (no --out, no --total-steps); a nonzero
    ``base_seed`` runs another seed set (seeds base_seed .. base_seed + 4)."""
    num_envs, batch, updates = {**CANDIDATES, **DRY_CANDIDATES}[name]
    chunk = 256 if dry else CHUNK_STEPS
    args = ["--seeds", "2" if dry else "5", "--num-envs", str(num_envs)]
    if base_seed:
        args += ["--base-seed", str(base_seed)]
    args += ["--batch-size", str(batch), "--updates-per-iteration", str(updates)]
    args += ["--iterations-per-chunk", str(max(1, chunk // num_envs))]
    args += ["--actor-lr", "1e-3", "--critic-lr", "1e-3"]
    # A smaller buffer than the CPU recipe's 1M: 60 s make fewer steps per seed than this, and
    # the buffer's memory is allocated (and copied into every checkpoint) whole.
    args += ["--buffer-size", "20000" if dry else "500000", "--checkpoint-interval", "100000"]
    if dry:
        args += ["--learning-starts", "256", "--actor-hidden", "32,32", "--critic-hidden", "32,32"]
        args += ["--num-eval-envs", "2"]
    return args


def _launch(
    name: str, dry: bool, out: Path, total_steps: int, log: Path, base_seed: int = 0
) -> subprocess.Popen:
    command = [sys.executable, str(SCRIPT), *flags(name, dry, base_seed), "--out", str(out)]
    command += ["--total-steps", str(total_steps), "--log-interval", "5"]
    environment = dict(os.environ)
    environment["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p
    )
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "w") as file:
        return subprocess.Popen(
            command, stdout=file, stderr=subprocess.STDOUT, cwd=ROOT, env=environment
        )


def warm(workdir: Path, names: list[str], dry: bool, timeout: float, base_seed: int = 0) -> None:
    """Every candidate at once, each killed as soon as its train chunk is compiled (JAX has then
    written the program to the persistent cache), or at ``timeout``."""
    # Several processes share the GPU: none may take 75% of its memory up front.
    os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    logs = {name: workdir / "logs" / f"warm-{name}.log" for name in names}
    processes = {
        name: _launch(name, dry, workdir / "warm" / name, 10_000_000, logs[name], base_seed)
        for name in names
    }
    deadline = time.monotonic() + timeout
    while processes:
        time.sleep(0.5)
        for name, process in list(processes.items()):
            found = COMPILED.search(logs[name].read_text())
            if found or process.poll() is not None or time.monotonic() > deadline:
                process.kill()
                process.wait()
                state = f"compiled in {found.group(1)} s" if found else "not compiled"
                print(f"warm {name}: {state} (exit {process.returncode})", flush=True)
                del processes[name]


def _mean_rows(metrics: Path) -> list[tuple[int, float, float]]:
    """(step, mean eval return over seeds, wall_time) per evaluation, in step order."""
    from rl_jax.run.metrics import read_rows

    by_step: dict[int, list] = {}
    for row in read_rows(metrics):
        by_step.setdefault(row["step"], []).append(row)
    return [
        (step, float(np.mean([r["eval_return"] for r in rows])), rows[0]["wall_time"])
        for step, rows in sorted(by_step.items())
    ]


def train_one(
    name: str,
    workdir: Path,
    dry: bool,
    goal: float,
    budget: float,
    deadline: float,
    base_seed: int = 0,
):
    """Train one candidate until the goal, the budget or the deadline; writes ``stop.json``."""
    out = workdir / "runs" / name
    launched = time.monotonic()
    process = _launch(name, dry, out, 10_000_000, workdir / "logs" / f"{name}.log", base_seed)
    compiled_at, compile_seconds, curve, reason = None, None, [], "exit"
    budget_passed_rows = None
    while process.poll() is None:
        time.sleep(0.2)
        now = time.monotonic()
        if compiled_at is None:
            found = COMPILED.search((workdir / "logs" / f"{name}.log").read_text())
            if found:
                compiled_at, compile_seconds = now, float(found.group(1))
        rows = _mean_rows(out / "metrics.jsonl")
        while len(curve) < len(rows):  # training seconds as this process saw each row
            step, mean, wall_time = rows[len(curve)]
            train_s = None if compiled_at is None else now - compiled_at
            curve.append({"step": step, "mean": mean, "wall_time": wall_time, "train_s": train_s})
        if curve and curve[-1]["mean"] >= goal:
            reason = "goal"
        elif time.time() > deadline:
            reason = "deadline"
        elif compiled_at is not None and now - compiled_at > budget:
            # Let the chunk in flight end (its row is the first past the budget), within reason.
            budget_passed_rows = len(curve) if budget_passed_rows is None else budget_passed_rows
            if len(curve) > budget_passed_rows or now - compiled_at > 1.5 * budget + 10:
                reason = "budget"
        if reason != "exit":
            process.kill()
            break
    process.wait()
    record = {
        "name": name,
        "flags": flags(name, dry, base_seed),
        "stopped_by": reason,
        "exit": process.returncode,
        "compile_s": compile_seconds,
        "launch_to_compiled_s": None if compiled_at is None else compiled_at - launched,
        "curve": curve,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "stop.json").write_text(json.dumps(record))
    print(f"{name}: stopped by {reason} after {len(curve)} evaluations", flush=True)


def table(workdir: Path, goal: float) -> str:
    """One row per candidate run: when the mean first reached the goal, and the loop's rates."""
    header = (
        "| candidate | envs | batch | updates/iter | updates per env step | compile s | "
        f"mean >= {goal:,.0f} at step | training s | wall_time s | last mean (step, training s) "
        "| env steps/s per seed | updates/s per seed | stopped by |"
    )
    lines = [header, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---|"]
    for record_path in sorted((workdir / "runs").glob("*/stop.json")):
        record = json.loads(record_path.read_text())
        num_envs, batch, updates = {**CANDIDATES, **DRY_CANDIDATES}[record["name"]]
        curve = record["curve"]
        first = next((point for point in curve if point["mean"] >= goal), None)
        reached = ["-", "-", "-"]
        if first:
            train_s = "?" if first["train_s"] is None else f"{first['train_s']:.0f}"
            reached = [f"{first['step']:,}", train_s, f"{first['wall_time']:.0f}"]
        last = "-"
        if curve:
            seconds = curve[-1]["train_s"]
            last = f"{curve[-1]['mean']:,.0f} ({curve[-1]['step']:,}, {seconds or 0:.0f})"
        rates = _rates(record_path.parent / "metrics.jsonl")
        compile_s = "-" if record["compile_s"] is None else f"{record['compile_s']:.0f}"
        cells = [record["name"], f"{num_envs:,}", f"{batch:,}", str(updates)]
        cells += [f"{updates / num_envs:g}", compile_s, *reached, last, *rates]
        lines.append("| " + " | ".join([*cells, record["stopped_by"]]) + " |")
    return "\n".join(lines) + "\n"


def _rates(metrics: Path) -> list[str]:
    """Env steps/s and updates/s per seed between the first and the last evaluation (the first
    chunk, which may include the warm-up without updates, is the baseline)."""
    from rl_jax.run.metrics import read_rows

    rows = read_rows(metrics)
    rows = [row for row in rows if row["seed"] == rows[0]["seed"]]  # one row per evaluation
    if len(rows) < 2 or rows[-1]["wall_time"] <= rows[0]["wall_time"]:
        return ["-", "-"]
    seconds = rows[-1]["wall_time"] - rows[0]["wall_time"]
    steps = (rows[-1]["step"] - rows[0]["step"]) / seconds
    updates = (rows[-1]["updates"] - rows[0]["updates"]) / seconds
    return [f"{steps:,.0f}", f"{updates:,.0f}"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("action", choices=("warm", "run", "table"))
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--candidates", default=None, help="comma-separated (default: all)")
    parser.add_argument("--dry", action="store_true", help="tiny candidates, for a CPU rehearsal")
    parser.add_argument("--goal", type=float, default=GOAL)
    parser.add_argument("--budget", type=float, default=60.0, help="training seconds each")
    parser.add_argument("--deadline", type=float, default=float("inf"), help="epoch seconds")
    parser.add_argument("--timeout", type=float, default=150.0, help="warm: seconds in all")
    parser.add_argument("--base-seed", type=int, default=0, help="first seed of the 5 (or 2)")
    args = parser.parse_args(argv)
    names = list(DRY_CANDIDATES if args.dry else CANDIDATES)
    if args.candidates:
        names = args.candidates.split(",")
    if args.action == "warm":
        warm(args.workdir, names, args.dry, args.timeout, args.base_seed)
    elif args.action == "run":
        for name in names:
            if args.deadline - time.time() < 30:  # too little left for startup and one chunk
                print(f"{name}: not run, the deadline is near", flush=True)
                continue
            train_one(
                name, args.workdir, args.dry, args.goal, args.budget, args.deadline, args.base_seed
            )
    else:
        print(table(args.workdir, args.goal), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
