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
import time
from pathlib import Path
from typing import TypedDict, cast

from bench import sb3_side_by_side as side_by_side
from bench.machine import peer_result
from bench.sb3_side_by_side import default_threads, parse_threads, round_up

ROOT = side_by_side.ROOT
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
    per_call = config.batch_size * config.iterations_per_chunk
    _, result = side_by_side.time_ours(
        program,
        state,
        hparams,
        calls=steps // per_call,
        steps_per_call=per_call,
        startup=startup,
        warmup=True,
    )
    return cast(Timing, result)


def _ours_child(steps: int) -> Timing:
    result = side_by_side.ours_child(NAME, ["--ours-steps", str(steps)], "our recurrent PPO worker")
    return cast(Timing, result)


# ---- sb3-contrib (the peers' venv) ---------------------------------------------------------------
def peer_command(python: Path, steps: int, threads: int) -> list[str]:
    """The command line of ``bench/sb3_recurrent_ppo.py`` for ``steps`` env steps on
    ``threads`` torch threads."""
    return side_by_side.peer_command(python, "sb3_recurrent_ppo.py", steps, threads)


def _peer(python: Path, steps: int, threads: int) -> Timing:
    what = f"sb3-contrib's RecurrentPPO ({threads} threads)"
    return cast(Timing, peer_result(peer_command(python, steps, threads), what))


# ---- the driver and its table --------------------------------------------------------------------
def measure(python: Path, steps: int, ours_steps: int, threads: list[int]) -> Results:
    """Ours, sb3-contrib, ours again (module docstring). With several thread counts and a budget
    above ``PROBE_STEPS``, sb3-contrib first runs ``PROBE_STEPS`` at each count, and the whole
    budget only at the faster one."""
    first, probes, peer, again = side_by_side.measure(
        lambda _: _ours_child(ours_steps),
        lambda steps, count: _peer(python, steps, count),
        steps,
        threads,
        PROBE_STEPS,
    )
    return {"ours": first, "peer_probes": probes, "peer": peer, "ours_again": again}


def ratio(results: Results) -> float:
    """The slower of our two rates over the peer's faster: sb3-contrib's wall-clock over ours
    at equal work."""
    return side_by_side.ratio(results)


def table(results: Results) -> list[str]:
    """Markdown: one row per timed run, then the ratio."""
    rows = side_by_side.side_rows(
        "sb3-contrib",
        results["ours"],
        results["peer_probes"],
        results["peer"],
        results["ours_again"],
        lambda r: f"sb3-contrib {r['sb3_contrib']}, torch {r['torch']}",
    )
    faster = max(results["peer"], key=lambda r: r["env_steps_per_s"])
    return [
        *side_by_side.timing_table(rows),
        "",
        f"Env steps per second, ours (the slower of our two) / sb3-contrib's (its faster, "
        f"{faster['threads']} thread(s)) = wall-clock of sb3-contrib / ours at equal work = "
        f"**{ratio(results):.1f}x** (goal: >= 20x); start-up and warm-up apart.",
    ]


def section(steps: int, ours_steps: int, threads: list[int], command: str) -> str:
    """The Markdown section: machine line, command, the table (or why nothing was measured)."""
    from bench.machine import describe

    title = "## Recurrent PPO: ours beside sb3-contrib's RecurrentPPO at equal work"
    return side_by_side.section(
        [title, "", describe(), "", f"`{command}`", ""],
        NAME,
        Path(__file__).resolve().parent / "results",
        lambda python: measure(python, steps, ours_steps, threads),
        table,
    )


def run(quick: bool = False) -> str:
    """``python -m bench recurrent_ppo_sb3 [--quick]``: the peer 100,096 env steps (the recipe's
    100k in whole rollouts) and ours 409,600; or 5,120 and 20,480."""
    steps, ours_steps = (QUICK_STEPS, QUICK_OURS_STEPS) if quick else (STEPS, OURS_STEPS)
    return section(steps, ours_steps, default_threads(), side_by_side.quick_command(NAME, quick))


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_recurrent_ppo_sb3 --steps N [--ours-steps M]``: the section for
    another budget."""

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--steps",
            type=int,
            default=STEPS,
            help="sb3-contrib's env steps, whole rollouts (100,096)",
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

    def settle(args: argparse.Namespace) -> tuple[int, int, list[int]]:
        steps = round_up(args.steps, ROLLOUT)
        wanted = max(steps, OURS_STEPS) if args.ours_steps is None else args.ours_steps
        return steps, round_up(wanted, CHUNK), parse_threads(args.sb3_threads)

    return side_by_side.main(
        argv,
        name=NAME,
        doc=__doc__,
        add_arguments=add_arguments,
        settle=settle,
        worker=lambda settled: ours(settled[1]),
        section=lambda settled, command: section(*settled, command),
        results_dir=Path(__file__).resolve().parent / "results",
    )


if __name__ == "__main__":
    raise SystemExit(main())
