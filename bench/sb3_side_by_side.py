"""The driver shared by the benchmarks that time our PPO beside a Stable-Baselines3 peer at equal
work: ``bench_ppo_sb3`` (SB3's PPO on HalfCheetah), ``bench_recurrent_ppo_sb3`` (sb3-contrib's
RecurrentPPO on CartPoleNoVel) and ``bench_ppo_minatar_sb3`` (SB3's PPO on MinAtar Breakout).
Each of those keeps what differs: its env, its settings and their parity with ours, our side's
worker, its budgets, arguments and labels.

What they share: our side runs as a child process of our venv (``python -m bench.bench_NAME
--worker``: one device whose XLA thread pool spans all cores, no ``XLA_FLAGS`` inherited), the
peer's script in the peers' venv (``bench/peers.py``), one after the other: ours, the peer at
each torch thread count (first probing the counts on a short budget where the bench asks), ours
again. The section is the bench's head, a Markdown table with one row per timed run and the
bench's ratio line; its raw numbers go to ``bench/results/NAME.json``, ``main``'s text to
``bench/results/NAME.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
T = TypeVar("T", bound=Mapping[str, Any])  # one side's timed run, as its JSON line gives it
R = TypeVar("R")  # a bench's results: its runs under its own keys
A = TypeVar("A")  # a bench's settled arguments


def round_up(steps: int, unit: int) -> int:
    """``steps`` rounded up to whole ``unit`` s (rollouts, or our compiled calls' env steps)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    return math.ceil(steps / unit) * unit


def parse_threads(text: str) -> list[int]:
    """``"1,2"`` -> ``[1, 2]``: the peer's torch thread counts, each >= 1, no repeats."""
    try:
        counts = [int(part) for part in text.split(",")]
    except ValueError:
        raise ValueError(f"--sb3-threads takes counts like 1,2; got {text!r}") from None
    if not counts or min(counts) < 1 or len(set(counts)) != len(counts):
        raise ValueError(f"--sb3-threads takes distinct counts >= 1, like 1,2; got {text!r}")
    return counts


def default_threads() -> list[int]:
    """The peer's thread counts to probe: 1 and every core (one count on a 1-core machine)."""
    return sorted({1, os.cpu_count() or 1})


def quick_command(name: str, quick: bool) -> str:
    """``python -m bench NAME [--quick]``, as a section states it."""
    return f"python -m bench {name}" + (" --quick" if quick else "")


# ---- ours (a child process: its own JAX, one device over all cores) ---------------------------
def time_ours(
    program: Callable[[Any, Any], Any],
    state: Any,
    hparams: Any,
    *,
    calls: int,
    steps_per_call: int,
    startup: float,
    warmup: bool,
) -> tuple[Any, dict[str, Any]]:
    """Time ``calls`` calls of our compiled ``program(state, hparams)``, each on the state the
    last one left, after one untimed call (the warm-up) when ``warmup``. Returns the last state
    and the timing: env steps, seconds, env steps/s, ``startup`` (seconds to build and compile,
    timed by the caller), the warm-up's, the cores, JAX's version and the load."""
    import jax

    if warmup:
        start = time.perf_counter()
        state = jax.block_until_ready(program(state, hparams))
        warmup_s = time.perf_counter() - start
    start = time.perf_counter()
    for _ in range(calls):
        state = program(state, hparams)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    timed = calls * steps_per_call
    result: dict[str, Any] = {
        "env_steps": timed,
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(timed / seconds, 1),
        "startup_s": round(startup, 3),
    }
    if warmup:
        result |= {"warmup_steps": steps_per_call, "warmup_s": round(warmup_s, 3)}
    result |= {
        "cores": len(os.sched_getaffinity(0)),
        "jax": jax.__version__,
        "load": round(os.getloadavg()[0], 2),
    }
    return state, result


def ours_child(name: str, arguments: list[str], what: str) -> dict[str, Any]:
    """Our side's timing from ``python -m bench.bench_NAME --worker ARGUMENTS``; a failed worker
    raises ``RuntimeError`` naming ``what``."""
    command = [sys.executable, "-m", f"bench.bench_{name}", "--worker", *arguments]
    # One device over all cores, as a run of one seed: no XLA_FLAGS inherited.
    return worker_result(command, what, {"XLA_FLAGS": None})


# ---- the peer (the peers' venv) ---------------------------------------------------------------
def peer_command(python: Path, script: str, steps: int, threads: int, *extra: str) -> list[str]:
    """The command line of ``bench/SCRIPT`` run by ``python`` with ``extra`` arguments, for
    ``steps`` env steps on ``threads`` torch threads."""
    command = [str(python), str(ROOT / "bench" / script), *extra]
    return [*command, "--steps", str(steps), "--threads", str(threads)]


# ---- the driver and its table --------------------------------------------------------------------
def measure(
    ours: Callable[[bool], T],
    peer: Callable[[int, int], T],
    steps: int,
    threads: list[int],
    probe_steps: int | None = None,
) -> tuple[T, list[T], list[T], T]:
    """Ours (``ours(True)``), the peer's ``peer(steps, count)`` at each thread count, ours again
    (``ours(False)``): the four as ``(ours, probes, peer, ours again)``. With ``probe_steps``,
    several counts and a budget above it, the peer first runs ``probe_steps`` at each count (the
    probes), and the whole budget only at the faster one; else no probes."""
    first = ours(True)
    probes: list[T] = []
    if probe_steps is not None and len(threads) > 1 and steps > probe_steps:
        probes = [peer(probe_steps, count) for count in threads]
        threads = [min(probes, key=lambda r: r["seconds"])["threads"]]
    runs = [peer(steps, count) for count in threads]
    again = ours(False)
    return first, probes, runs, again


def ratio(results: Mapping[str, Any]) -> float:
    """The slower of our two rates over the peer's faster (``results``' ``ours``, ``ours_again``
    and ``peer``): the peer's wall-clock over ours at equal work."""
    slower = min(results["ours"]["env_steps_per_s"], results["ours_again"]["env_steps_per_s"])
    return slower / max(r["env_steps_per_s"] for r in results["peer"])


def side_rows(
    who: str,
    ours: T,
    probes: Sequence[T],
    peer: Sequence[T],
    again: T,
    peer_label: Callable[[T], str],
) -> list[tuple[str, T, str]]:
    """The rows of ``timing_table`` in the order they ran, threads stated in a column of their
    own: ours, the peer (``who``) choosing its thread count, the peer (``peer_label``), ours
    again."""

    def xla(r: T) -> str:
        return f"XLA over {r['cores']} cores"

    rows = [(f"ours, jax {ours['jax']}", ours, xla(ours))]
    rows += [(f"{who}, choosing its thread count", r, f"torch {r['threads']}") for r in probes]
    rows += [(peer_label(r), r, f"torch {r['threads']}") for r in peer]
    return [*rows, ("ours again", again, xla(again))]


def timing_table(
    rows: Sequence[tuple[str, Mapping[str, Any], str]],
    *,
    steps_header: str = "env steps timed",
    warmup: bool = True,
    threads: bool = True,
) -> list[str]:
    """Markdown: one row per ``(label, timing, threads)``: the env steps timed, start-up seconds,
    the warm-up's seconds and env steps (``warmup``), training seconds, env steps/s, the threads
    (``threads``) and the load."""
    headers = ["program", steps_header, "start-up s"]
    headers += ["warm-up s (env steps)"] if warmup else []
    headers += ["training s", "env steps/s", *(["threads"] if threads else []), "load"]
    aligns = ["---" if header in ("program", "threads") else "---:" for header in headers]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(aligns) + "|"]
    for label, r, threads_text in rows:
        cells = [label, f"{r['env_steps']:,}", f"{r['startup_s']:.1f}"]
        cells += [f"{r['warmup_s']:.1f} ({r['warmup_steps']:,})"] if warmup else []
        cells += [f"{r['seconds']:.1f}", f"{r['env_steps_per_s']:,.0f}"]
        cells += [threads_text] if threads else []
        lines.append("| " + " | ".join([*cells, f"{r['load']:.1f}"]) + " |")
    return lines


def section(
    head: list[str],
    name: str,
    results_dir: Path,
    measure: Callable[[Path], R],
    table: Callable[[R], list[str]],
) -> str:
    """The Markdown section: ``head`` (title, command, machine line), then the ``table`` of
    ``measure(python)`` with the peers' venv's ``python``, its raw numbers saved as
    ``results_dir/NAME.json``; or, where that venv cannot be built, why nothing was measured."""
    from bench import peers

    try:
        python = peers.ensure()
    except peers.PeersUnavailable as error:
        return "\n".join([*head, f"not measured: {error}", ""])
    started = time.strftime("%H:%M")
    results = measure(python)
    results_dir.mkdir(exist_ok=True)
    (results_dir / f"{name}.json").write_text(json.dumps(results, indent=1))
    lines = [*head, *table(results)]
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).")
    return "\n".join([*lines, ""])


def main(
    argv: list[str] | None,
    *,
    name: str,
    doc: str | None,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    settle: Callable[[argparse.Namespace], A],
    worker: Callable[[A], Mapping[str, Any]],
    section: Callable[[A, str], str],
    results_dir: Path,
) -> int:
    """``python -m bench.bench_NAME ...``: the bench's arguments (``add_arguments``) checked and
    settled (``settle``, whose ``ValueError`` is one ``error:`` line and exit 2); then with
    ``--worker`` our side's timing (``worker``) as a ``RESULT {json}`` line, else the bench's
    ``section`` for the command line, printed and saved as ``results_dir/NAME.md``."""
    parser = argparse.ArgumentParser(
        prog=f"python -m bench.bench_{name}",
        description=doc,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(parser)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        settled = settle(args)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    from rl_jax.training.jax_setup import configure

    configure()
    if args.worker:
        print("RESULT " + json.dumps(worker(settled)), flush=True)
        return 0
    command = " ".join([f"python -m bench.bench_{name}", *(argv or sys.argv[1:])]).strip()
    text = section(settled, command)
    print(text, flush=True)
    (results_dir / f"{name}.md").write_text(text)
    return 0
