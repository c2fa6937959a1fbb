"""Our recurrent PPO beside sb3-contrib's RecurrentPPO at equal work on CartPoleNoVel-v1
(``python -m bench recurrent_ppo_sb3``; ``python -m bench.bench_recurrent_ppo_sb3 --steps N``
for another budget).

Equal work: the recipe of ``--algo recurrent_ppo --env rl_jax/CartPoleNoVel-v1`` (rl-baselines3-
zoo's ``ppo_lstm`` settings) on both sides: 8 envs x 32 steps per rollout, 20 epochs of one
minibatch of the 256 steps, one 64-unit LSTM shared by a linear policy head and a linear value
head, observations standardised, gamma 0.98, lambda 0.8, Adam at 1e-3 and the clip range 0.2
both falling to 0 over 100,000 env steps, against ``RecurrentPPO("MlpLstmPolicy", ...)`` with the
same settings on ``VecNormalize(DummyVecEnv(8 x gymnasium CartPole-v1, velocities masked))``
(``bench/sb3_recurrent_ppo.py``, which lists them in sb3-contrib's terms). Our env is the JAX
CartPole stepped inside the compiled program, sb3-contrib's gymnasium's, stepped in Python.

* **Ours** (a child process of our venv): ``iterations_per_chunk`` (40) iterations of
  ``recurrent_ppo.train_iteration`` under one ``lax.scan``, one compiled call per 10,240 env
  steps, as a run's chunk but without its evaluation (sb3-contrib's ``learn`` evaluates
  nothing, and equal work means the training alone). Start-up (init, tracing and compiling) is
  timed apart, then one untimed call (the warm-up), then ``--ours-steps`` env steps, timed.
  Ours may run more env steps than the peer (the default does): its timing is short, and a
  longer one is less noisy. Each side states env steps per second; at equal work the ratio of
  wall-clocks is the ratio of those rates.
* **sb3-contrib** (the peers' venv): construction timed apart, then 512 env steps of ``learn``
  untimed (the warm-up), then ``--steps`` more env steps of ``learn``, timed.

Cores: one seed each, one side after the other, each alone on the whole machine: ours one
process whose XLA thread pool spans all cores, sb3-contrib at its faster torch thread count of
``--sb3-threads`` (default 1 and all cores, as ``bench_ppo_sb3``: with a 64-unit LSTM on 8 envs
a second thread can cost more than it gives). Each count first runs ``PROBE_STEPS`` env steps,
and the whole budget runs at the faster one (both are reported). Order: ours, sb3-contrib
(each count), ours again; the ratio takes the slower of our two rates over sb3-contrib's faster.
Measure on a quiet machine: beside another job's load, torch's second thread waited on a busy
core and ran sb3-contrib at 20 env steps/s against 575 on one thread, and the probe takes long.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import TypedDict, cast

from bench.bench_ppo_sb3 import default_threads, parse_threads
from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
NAME = "recurrent_ppo_sb3"
ENV_ID = "rl_jax/CartPoleNoVel-v1"
ROLLOUT = 256  # env steps per rollout: 8 envs x 32 steps, on both sides
CHUNK = 40 * ROLLOUT  # our env steps per compiled call: the recipe's 40 iterations per chunk
STEPS = 100_096  # the peer's: the recipe's 100k env steps in whole rollouts
OURS_STEPS = 409_600  # ours: 40 chunks
QUICK_STEPS, QUICK_OURS_STEPS = 5_120, 20_480
PROBE_STEPS = 5_120  # the peer's run at each thread count that picks the count for the budget


class Timing(TypedDict, total=False):
    """One side's timed run, as its JSON line gives it (ours: ``cores``, ``jax``; the peer's:
    ``threads``, ``warmup_steps`` and the versions)."""

    env_steps: int
    seconds: float
    env_steps_per_s: float
    startup_s: float
    warmup_s: float
    warmup_steps: int
    load: float
    cores: int
    jax: str
    threads: int
    sb3_contrib: str
    stable_baselines3: str
    torch: str


class Results(TypedDict):
    """Ours, the peer's probes (one per thread count; none for a budget within a probe's), the
    peer's whole budget at each count it ran, ours again."""

    ours: Timing
    peer_probes: list[Timing]
    peer: list[Timing]
    ours_again: Timing


def round_up(steps: int, unit: int) -> int:
    """``steps`` rounded up to whole ``unit`` s (rollouts of 256, or our chunks of 10,240)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    return math.ceil(steps / unit) * unit


# ---- ours (a child process: its own JAX, one device over all cores) ---------------------------
def ours(steps: int) -> Timing:
    """Time ``steps`` env steps (whole chunks) of our recurrent PPO, the module docstring's way."""
    import jax

    from rl_jax.agents import recurrent_ppo as module
    from rl_jax.agents.recurrent_ppo import recurrent_ppo
    from rl_jax.training import episodes

    start = time.perf_counter()
    config = recurrent_ppo.default_config(ENV_ID)
    hparams = cast(module.Hyperparams, recurrent_ppo.default_hyperparams(ENV_ID))
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    state = module.init(jax.random.key(1), config, hparams)

    def chunk(state: module.TrainState, hparams: module.Hyperparams) -> module.TrainState:
        def iteration(state: module.TrainState, _: None) -> tuple[module.TrainState, None]:
            return module.train_iteration(state, config, hparams)[0], None

        return jax.lax.scan(iteration, state, None, length=config.iterations_per_chunk)[0]

    program = jax.jit(chunk).lower(state, hparams).compile()
    jax.block_until_ready(state)
    startup = time.perf_counter() - start
    start = time.perf_counter()
    state = jax.block_until_ready(program(state, hparams))
    warmup = time.perf_counter() - start
    per_call = config.batch_size * config.iterations_per_chunk
    calls = steps // per_call
    start = time.perf_counter()
    for _ in range(calls):
        state = program(state, hparams)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    return {
        "env_steps": calls * per_call,
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(calls * per_call / seconds, 1),
        "startup_s": round(startup, 3),
        "warmup_steps": per_call,
        "warmup_s": round(warmup, 3),
        "cores": len(os.sched_getaffinity(0)),
        "jax": jax.__version__,
        "load": round(os.getloadavg()[0], 2),
    }


def _ours_child(steps: int) -> Timing:
    command = [sys.executable, "-m", f"bench.bench_{NAME}", "--worker", "--ours-steps", str(steps)]
    # One device over all cores, as a run of one seed: no XLA_FLAGS inherited.
    return cast(Timing, worker_result(command, "our recurrent PPO worker", {"XLA_FLAGS": None}))


# ---- sb3-contrib (the peers' venv) ---------------------------------------------------------------
def peer_command(python: Path, steps: int, threads: int) -> list[str]:
    """The command line of ``bench/sb3_recurrent_ppo.py`` for ``steps`` env steps on
    ``threads`` torch threads."""
    script = str(ROOT / "bench" / "sb3_recurrent_ppo.py")
    return [str(python), script, "--steps", str(steps), "--threads", str(threads)]


def _peer(python: Path, steps: int, threads: int) -> Timing:
    done = subprocess.run(
        peer_command(python, steps, threads), cwd=ROOT, capture_output=True, text=True
    )
    lines = [x for x in done.stdout.splitlines() if x.startswith("{")]
    if done.returncode or not lines:
        raise RuntimeError(
            f"sb3-contrib's RecurrentPPO ({threads} threads) failed:\n{done.stderr[-3000:]}"
        )
    return cast(Timing, json.loads(lines[-1]))


# ---- the driver and its table --------------------------------------------------------------------
def measure(python: Path, steps: int, ours_steps: int, threads: list[int]) -> Results:
    """Ours, sb3-contrib, ours again (module docstring). With several thread counts and a budget
    above ``PROBE_STEPS``, sb3-contrib first runs ``PROBE_STEPS`` at each count, and the whole
    budget only at the faster one."""
    first = _ours_child(ours_steps)
    probes: list[Timing] = []
    if len(threads) > 1 and steps > PROBE_STEPS:
        probes = [_peer(python, PROBE_STEPS, count) for count in threads]
        threads = [min(probes, key=lambda r: r["seconds"])["threads"]]
    peer = [_peer(python, steps, count) for count in threads]
    again = _ours_child(ours_steps)
    return {"ours": first, "peer_probes": probes, "peer": peer, "ours_again": again}


def ratio(results: Results) -> float:
    """The slower of our two rates over the peer's faster: sb3-contrib's wall-clock over ours
    at equal work."""
    slower = min(results["ours"]["env_steps_per_s"], results["ours_again"]["env_steps_per_s"])
    return slower / max(r["env_steps_per_s"] for r in results["peer"])


def table(results: Results) -> list[str]:
    """Markdown: one row per timed run, then the ratio."""
    ours, again, peer = results["ours"], results["ours_again"], results["peer"]
    lines = [
        "| program | env steps timed | start-up s | warm-up s (env steps) | training s | "
        "env steps/s | threads | load |",
        "|---|---:|---:|---:|---:|---:|---|---:|",
    ]

    def row(label: str, r: Timing, threads: str) -> str:
        return (
            f"| {label} | {r['env_steps']:,} | {r['startup_s']:.1f} | "
            f"{r['warmup_s']:.1f} ({r['warmup_steps']:,}) | {r['seconds']:.1f} | "
            f"{r['env_steps_per_s']:,.0f} | {threads} | {r['load']:.1f} |"
        )

    lines.append(row(f"ours, jax {ours['jax']}", ours, f"XLA over {ours['cores']} cores"))
    for probe in results["peer_probes"]:
        lines.append(
            row("sb3-contrib, choosing its thread count", probe, f"torch {probe['threads']}")
        )
    for r in peer:
        label = f"sb3-contrib {r['sb3_contrib']}, torch {r['torch']}"
        lines.append(row(label, r, f"torch {r['threads']}"))
    lines.append(row("ours again", again, f"XLA over {again['cores']} cores"))
    faster = max(peer, key=lambda r: r["env_steps_per_s"])
    lines += [
        "",
        f"Env steps per second, ours (the slower of our two) / sb3-contrib's (its faster, "
        f"{faster['threads']} thread(s)) = wall-clock of sb3-contrib / ours at equal work = "
        f"**{ratio(results):.1f}x** (goal: >= 20x); start-up and warm-up apart.",
    ]
    return lines


def section(steps: int, ours_steps: int, threads: list[int], command: str) -> str:
    """The Markdown section: machine line, command, the table (or why nothing was measured)."""
    from bench import peers
    from bench.machine import describe

    title = "## Recurrent PPO: ours beside sb3-contrib's RecurrentPPO at equal work"
    lines = [title, "", describe(), "", f"`{command}`", ""]
    try:
        python = peers.ensure()
    except peers.PeersUnavailable as error:
        return "\n".join([*lines, f"not measured: {error}", ""])
    started = time.strftime("%H:%M")
    results = measure(python, steps, ours_steps, threads)
    raw = Path(__file__).resolve().parent / "results"
    raw.mkdir(exist_ok=True)
    (raw / f"{NAME}.json").write_text(json.dumps(results, indent=1))
    lines += table(results)
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).")
    return "\n".join([*lines, ""])


def run(quick: bool = False) -> str:
    """``python -m bench recurrent_ppo_sb3 [--quick]``: the peer 100,096 env steps (the recipe's
    100k in whole rollouts) and ours 409,600; or 5,120 and 20,480."""
    steps, ours_steps = (QUICK_STEPS, QUICK_OURS_STEPS) if quick else (STEPS, OURS_STEPS)
    command = f"python -m bench {NAME}" + (" --quick" if quick else "")
    return section(steps, ours_steps, default_threads(), command)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_recurrent_ppo_sb3 --steps N [--ours-steps M]``: the section for
    another budget."""
    parser = argparse.ArgumentParser(
        prog=f"python -m bench.bench_{NAME}",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--steps", type=int, default=STEPS, help="sb3-contrib's env steps, whole rollouts (100,096)"
    )
    parser.add_argument(
        "--ours-steps",
        type=int,
        default=None,
        help=f"ours, whole chunks of {CHUNK:,} (default {OURS_STEPS:,}, at least --steps)",
    )
    parser.add_argument(
        "--sb3-threads",
        default=",".join(map(str, default_threads())),
        help="sb3-contrib's torch thread counts, each timed (default: 1 and all cores)",
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        steps = round_up(args.steps, ROLLOUT)
        wanted = max(steps, OURS_STEPS) if args.ours_steps is None else args.ours_steps
        ours_steps = round_up(wanted, CHUNK)
        threads = parse_threads(args.sb3_threads)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    from rl_jax.training.jax_setup import configure

    configure()
    if args.worker:
        print("RESULT " + json.dumps(ours(ours_steps)), flush=True)
        return 0
    command = " ".join([f"python -m bench.bench_{NAME}", *(argv or sys.argv[1:])]).strip()
    text = section(steps, ours_steps, threads, command)
    print(text, flush=True)
    (Path(__file__).resolve().parent / "results" / f"{NAME}.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
