"""Our PPO beside Stable-Baselines3's at equal work on MinAtar Breakout (``python -m bench
ppo_minatar_sb3``; ``python -m bench.bench_ppo_minatar_sb3 --steps N --sb3-steps M`` for other
budgets).

Equal work: the recipe of ``--algo ppo --env rl_jax/Breakout-MinAtar`` (gymnax-blines' PPO) on
both sides: 64 envs x 128 steps per rollout, 4 epochs of 8 minibatches of 1,024, an actor MLP and
a critic MLP of 2 x 256 ReLU units on the flattened 10 x 10 x 4 grid, observations as they are,
Adam at 1e-3 falling linearly to 0 over 10M env steps, gamma 0.999, lambda 0.95, the ratio and the
value clipped at 0.2, entropy bonus 0.01, gradients clipped to norm 0.5; against
``PPO("MlpPolicy", ...)`` with the same settings on ``DummyVecEnv(64 x numpy MinAtar Breakout)``
(``bench/sb3_ppo_minatar.py``, which lists them in SB3's terms). Our env is gymnax's Breakout
stepped inside the compiled program, SB3's the original numpy MinAtar (the ``minatar`` package),
stepped in Python; both without sticky actions, on the minimal action set, episodes cut at 1,000
steps.

* **Ours** (a child process of our venv): ``ppo.train_iteration`` repeated, one compiled call
  per iteration (rollout, GAE, the 32 gradient steps, the statistics). Evaluation is left out: a
  run of ours evaluates after each chunk, SB3's ``learn`` does not evaluate, and equal work means
  the training alone. Start-up (init, tracing and compiling) is timed apart, then one untimed
  iteration (the warm-up), then ``--steps`` env steps (whole rollouts of 8,192), timed. Ours may
  run more env steps than the peer (the default does): a longer timing is less noisy. Each side
  states env steps per second; at equal work the ratio of wall-clocks is the ratio of those rates.
* **SB3** (the peers' venv): construction timed apart, then one rollout of ``learn`` untimed (the
  warm-up), then ``--sb3-steps`` more env steps of ``learn`` (whole rollouts), timed.

Cores: one seed each, one side after the other, each alone on the whole machine: ours one process
whose XLA thread pool spans all cores, SB3 on ``--sb3-threads`` torch threads (default 1, which
the recurrent PPO benchmark found the faster beside a busy core; several counts, comma-separated,
each run the whole budget and the faster counts). Order: ours, SB3 (each count), ours again; the
ratio takes the slower of our two rates over SB3's faster. Measure on a quiet machine.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import TypedDict, cast

from bench import sb3_side_by_side as side_by_side
from bench.machine import peer_result
from bench.sb3_side_by_side import parse_threads

ROOT = side_by_side.ROOT
NAME = "ppo_minatar_sb3"
ENV_ID = "rl_jax/Breakout-MinAtar"
ROLLOUT = 8_192  # env steps per rollout: 64 envs x 128 steps, on both sides
STEPS = 2 * ROLLOUT  # the peer's: 2 rollouts after its warm-up one
OURS_STEPS = 40 * ROLLOUT  # ours: 40 iterations after the warm-up one
QUICK_STEPS, QUICK_OURS_STEPS = ROLLOUT, 4 * ROLLOUT
GOAL = 30.0  # the issue's: SB3's wall-clock >= 30x ours at equal work
THREADS = "1"  # SB3's torch threads by default


class Timing(TypedDict, total=False):
    """One side's timed run, as its JSON line gives it (ours: ``cores``, ``jax``; the peer's:
    ``threads`` and the versions)."""

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
    stable_baselines3: str
    torch: str
    minatar: str


class Results(TypedDict):
    """Ours, SB3's whole budget at each thread count it ran, ours again."""

    ours: Timing
    peer: list[Timing]
    ours_again: Timing


def round_up(steps: int, unit: int = ROLLOUT) -> int:
    """``steps`` rounded up to whole rollouts of 8,192 env steps."""
    return side_by_side.round_up(steps, unit)


# ---- ours (a child process: its own JAX, one device over all cores) ---------------------------
def ours(steps: int) -> Timing:
    """Time ``steps`` env steps (whole rollouts) of our PPO, the module docstring's way."""
    import jax

    from rl_jax.agents import ppo as module
    from rl_jax.agents.ppo import ppo
    from rl_jax.training import episodes

    start = time.perf_counter()
    config = ppo.default_config(ENV_ID)
    hparams = cast(module.Hyperparams, ppo.default_hyperparams(ENV_ID))
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    state = ppo.init(jax.random.key(1), config, hparams)

    def iteration(state: module.TrainState, hparams: module.Hyperparams) -> module.TrainState:
        return module.train_iteration(state, config, hparams)[0]

    program = jax.jit(iteration).lower(state, hparams).compile()
    jax.block_until_ready(state)
    startup = time.perf_counter() - start
    _, result = side_by_side.time_ours(
        program,
        state,
        hparams,
        calls=steps // config.batch_size,
        steps_per_call=config.batch_size,
        startup=startup,
        warmup=True,
    )
    return cast(Timing, result)


def _ours_child(steps: int) -> Timing:
    return cast(Timing, side_by_side.ours_child(NAME, ["--steps", str(steps)], "our PPO worker"))


# ---- SB3 (the peers' venv) -----------------------------------------------------------------------
def peer_command(python: Path, steps: int, threads: int) -> list[str]:
    """The command line of ``bench/sb3_ppo_minatar.py`` for ``steps`` env steps on ``threads``
    torch threads."""
    return side_by_side.peer_command(python, "sb3_ppo_minatar.py", steps, threads)


def _peer(python: Path, steps: int, threads: int) -> Timing:
    what = f"SB3's PPO on MinAtar ({threads} threads)"
    return cast(Timing, peer_result(peer_command(python, steps, threads), what))


# ---- the driver and its table --------------------------------------------------------------------
def measure(python: Path, steps: int, ours_steps: int, threads: list[int]) -> Results:
    """Ours, SB3 at each thread count, ours again (module docstring)."""
    first, _, peer, again = side_by_side.measure(
        lambda _: _ours_child(ours_steps),
        lambda steps, count: _peer(python, steps, count),
        steps,
        threads,
    )
    return {"ours": first, "peer": peer, "ours_again": again}


def ratio(results: Results) -> float:
    """The slower of our two rates over SB3's faster: SB3's wall-clock over ours at equal work."""
    return side_by_side.ratio(results)


def table(results: Results) -> list[str]:
    """Markdown: one row per timed run, then the ratio against the goal."""
    ours, again, peer = results["ours"], results["ours_again"], results["peer"]
    rows = [(f"ours, jax {ours['jax']}, XLA over {ours['cores']} cores", ours, "")]
    for r in peer:
        label = (
            f"SB3 {r['stable_baselines3']}, torch {r['torch']} on {r['threads']} thread(s), "
            f"numpy MinAtar {r['minatar']}"
        )
        rows.append((label, r, ""))
    rows.append((f"ours again, XLA over {again['cores']} cores", again, ""))
    faster = max(peer, key=lambda r: r["env_steps_per_s"])
    value = ratio(results)
    verdict = "met" if value >= GOAL else "not met"
    return [
        *side_by_side.timing_table(rows, warmup=False, threads=False),
        "",
        f"Env steps per second, ours (the slower of our two) / SB3's (its faster, "
        f"{faster['threads']} thread(s)) = wall-clock of SB3 / ours at equal work = "
        f"**{value:.1f}x** (goal: >= {GOAL:.0f}x, {verdict}); start-up and one warm-up rollout "
        "apart on each side.",
    ]


def section(steps: int, ours_steps: int, threads: list[int], command: str) -> str:
    """The Markdown section: what it measures, the command, the machine line, the table (or why
    nothing was measured)."""
    from bench.machine import describe

    lines = [
        "## PPO on MinAtar Breakout: ours beside Stable-Baselines3 at equal work",
        "",
        "Training env steps per second of one seed of PPO's MinAtar recipe (gymnax-blines': 64 "
        "envs x 128 steps, 4 epochs x 8 minibatches, actor and critic MLPs of 2 x 256 ReLU, rate "
        "1e-3 falling to 0) on `rl_jax/Breakout-MinAtar` inside the compiled program, beside "
        'SB3\'s `PPO("MlpPolicy")` with the same settings on 64 numpy MinAtar Breakouts in a '
        "`DummyVecEnv`; evaluation left out, start-up and one warm-up rollout timed apart.",
        "",
        f"`{command}`",
        "",
        describe(),
        "",
    ]
    return side_by_side.section(
        lines,
        NAME,
        Path(__file__).resolve().parent / "results",
        lambda python: measure(python, steps, ours_steps, threads),
        table,
    )


def run(quick: bool = False) -> str:
    """``python -m bench ppo_minatar_sb3 [--quick]``: the peer 16,384 env steps and ours 327,680;
    or 8,192 and 32,768."""
    steps, ours_steps = (QUICK_STEPS, QUICK_OURS_STEPS) if quick else (STEPS, OURS_STEPS)
    command = side_by_side.quick_command(NAME, quick)
    return section(steps, ours_steps, parse_threads(THREADS), command)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_ppo_minatar_sb3 [--steps N] [--sb3-steps M]``: the section for
    other budgets."""

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--steps",
            type=int,
            default=OURS_STEPS,
            help=f"our env steps, whole rollouts of {ROLLOUT:,} (default {OURS_STEPS:,})",
        )
        parser.add_argument(
            "--sb3-steps",
            type=int,
            default=STEPS,
            help=f"SB3's env steps, whole rollouts of {ROLLOUT:,} (default {STEPS:,})",
        )
        parser.add_argument(
            "--sb3-threads",
            default=THREADS,
            help="SB3's torch thread counts, comma-separated, each timed (default 1)",
        )

    def settle(args: argparse.Namespace) -> tuple[int, int, list[int]]:
        ours_steps = round_up(args.steps)
        return round_up(args.sb3_steps), ours_steps, parse_threads(args.sb3_threads)

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
