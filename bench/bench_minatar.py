"""MinAtar: env steps/s of our in-program MinAtar games (gymnax's, through ``envs.from_gymnax``)
next to gymnax's own loop and to the original numpy MinAtar, measured side by side in one run.

* Ours: ``rl_jax/<Game>-MinAtar`` in ``jit(lax.scan(vmap(AutoReset(env).step)))`` over a block of
  steps, uniform random actions drawn inside the scan, ``block_until_ready`` after each block:
  exactly what the learners run (``bench_classic.jax_rollout``).
* gymnax's own loop: ``gymnax.make("<Game>-MinAtar")`` with its default params in
  ``jit(lax.scan(vmap(env.step)))``, the same random actions; gymnax's ``step`` resets inside
  itself, as ``AutoReset`` does for ours (both compute a reset on every step and select it where
  the episode ended). Ours over gymnax at the same number of envs is the adapter's cost.
* numpy MinAtar (the ``minatar`` package): one ``minatar.Environment`` stepped from a Python
  loop with pre-drawn uniform random actions of the game's minimal action set (gymnax's default
  action set) and ``sticky_action_prob=0.0`` (gymnax has no sticky actions); each step is
  ``act(a)`` then ``state()`` (the observation, which the JAX envs also compute every step), and
  ``reset()`` when the episode ends.

Episode ends: gymnax (and so ours) truncates Breakout, SpaceInvaders and Asterix at 1,000 steps
(``max_steps_in_episode``), numpy MinAtar never truncates them; Freeway ends after 2,500 steps
in gymnax and after 2,501 in numpy MinAtar (its own timer). With random actions the other three
end by losing well before 1,000 steps (numpy MinAtar, seed 0: Breakout about 8 steps on average,
SpaceInvaders and Asterix about 65, none over 300), so the cap changes nothing here. In the JAX
envs a step costs the same whether or not its episode ended (the reset is computed anyway);
numpy MinAtar pays for a reset only when one happens, which in Breakout is every ~8 steps.

``python -m bench minatar`` runs all four games at 1, 64 and 1,024 envs (``--quick``: Breakout
alone, smaller blocks, one round); ``python -m bench.bench_minatar --games Breakout,Freeway``
picks games.
"""

from __future__ import annotations

import argparse
import os
import sys

import gymnax
import jax
import numpy as np
from minatar import Environment

from bench.bench_classic import jax_rollout, measure_interleaved
from bench.machine import describe

GAMES = ("Breakout", "SpaceInvaders", "Asterix", "Freeway")
SIZES = (1, 64, 1024)
NUMPY = "numpy MinAtar, one at a time from Python"
GYMNAX = "gymnax jit(scan(vmap(env.step)))"
OURS = "ours jit(scan(vmap(AutoReset(env).step)))"


def gymnax_rollout(game: str, num_envs: int, block: int):
    """``block`` steps of ``num_envs`` gymnax envs in one compiled scan, gymnax's own autoreset,
    default params; returns a function that runs one block and gives its env steps."""
    env, params = gymnax.make(f"{game}-MinAtar")
    num_actions = env.action_space(params).n
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def body(state, key):
        key_action, key_step = jax.random.split(key)
        action = jax.random.randint(key_action, (num_envs,), 0, num_actions)
        _, state, reward, *_ = step(jax.random.split(key_step, num_envs), state, action, params)
        return state, reward.sum()

    @jax.jit
    def run(state, key):
        state, rewards = jax.lax.scan(body, state, jax.random.split(key, block))
        return state, rewards.sum()

    reset = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))
    _, state = reset(jax.random.split(jax.random.PRNGKey(0), num_envs), params)
    key = jax.random.PRNGKey(1)
    jax.block_until_ready(run(state, key))  # compile outside the timing

    def once() -> int:
        jax.block_until_ready(run(state, key))
        return num_envs * block

    return once


def numpy_rollout(game: str, block: int = 1000):
    """``block`` steps of one numpy MinAtar env from a Python loop: ``act`` and ``state`` per
    step, ``reset`` when the episode ends; random actions of the minimal action set, drawn
    beforehand; no sticky actions."""
    env = Environment(game.lower().replace("spaceinvaders", "space_invaders"), 0.0)
    env.seed(0)
    env.reset()
    actions = np.random.default_rng(0).choice(env.minimal_action_set(), block).tolist()

    def once() -> int:
        for action in actions:
            _, terminal = env.act(action)
            env.state()
            if terminal:
                env.reset()
        return block

    return once


def rollouts(game: str, sizes: tuple[int, ...], blocks: dict[int, int]) -> dict:
    """``{(implementation, num_envs): once}`` for one game, numpy MinAtar first."""
    runs = {(NUMPY, 1): numpy_rollout(game)}
    for num_envs in sizes:
        runs[GYMNAX, num_envs] = gymnax_rollout(game, num_envs, blocks[num_envs])
        runs[OURS, num_envs] = jax_rollout(f"rl_jax/{game}-MinAtar", num_envs, blocks[num_envs])
    return runs


def _block(num_envs: int, quick: bool) -> int:
    """Steps per compiled call: large batches get fewer, so that one call stays short."""
    steps = 500 if num_envs <= 64 else 100
    return steps // 5 if quick else steps


def times(ratio: float) -> str:
    """A ratio as the table gives it: one decimal, or two significant digits below 1 (a small
    batch's per-call cost can put a JAX loop at a few hundredths of numpy's, which one decimal
    would print as 0.0x)."""
    return f"{ratio:,.1f}x" if ratio >= 0.95 else f"{ratio:.2g}x"


def rows(game: str, rates: dict) -> list[str]:
    """Table rows of one game: steps/s, ratio over numpy MinAtar, and ours over gymnax."""
    baseline = rates[NUMPY, 1]
    lines = []
    for (implementation, num_envs), rate in rates.items():
        gymnax_rate = rates.get((GYMNAX, num_envs))
        versus = f"{rate / gymnax_rate:,.2f}x" if implementation == OURS and gymnax_rate else "-"
        lines.append(
            f"| {game} | {implementation} | {num_envs:,} | {rate:,.0f} "
            f"| {times(rate / baseline)} | {versus} |"
        )
    return lines


def run(
    quick: bool = False,
    games: tuple[str, ...] | None = None,
    sizes: tuple[int, ...] = SIZES,
    min_time: float | None = None,
    rounds: int | None = None,
    blocks: dict[int, int] | None = None,
    command: str | None = None,
) -> str:
    """The Markdown section: machine line, command, one row per (game, implementation, envs)."""
    games = games or (GAMES[:1] if quick else GAMES)
    min_time = min_time if min_time is not None else (0.2 if quick else 0.5)
    rounds = rounds or (1 if quick else 3)
    blocks = blocks or {n: _block(n, quick) for n in sizes}
    command = command or "PYTHONPATH=$PWD python -m bench minatar" + (" --quick" if quick else "")
    lines = [
        "## MinAtar: ours vs gymnax's own loop vs numpy MinAtar",
        "",
        describe(),
        "",
        f"`{command}`",
        "",
        "Env steps/s (uniform random actions, episodes restarting when they end), median of "
        f"{rounds} interleaved round(s) of >= {min_time} s each; ratio over numpy MinAtar "
        "stepped one at a time in the same rounds, and ours over gymnax at the same number of "
        "envs. No sticky actions; gymnax cuts episodes at 1,000 steps (Freeway: 2,500), numpy "
        "MinAtar does not (Freeway: 2,501).",
        "",
        "| game | implementation | envs | steps/s | vs numpy MinAtar | ours vs gymnax |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for game in games:
        rates = measure_interleaved(rollouts(game, sizes, blocks), rounds, min_time)
        lines.extend(rows(game, rates))
    load = f"load avg {[round(x, 2) for x in os.getloadavg()]} at end"
    return "\n".join([*lines, "", load, ""])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], epilog="(python -m bench minatar: defaults)"
    )
    parser.add_argument("--quick", action="store_true", help="Breakout alone, a smoke run")
    parser.add_argument(
        "--games",
        type=lambda text: tuple(text.split(",")),
        default=None,
        help=f"comma-separated, of {','.join(GAMES)} (default all; --quick: Breakout)",
    )
    args = parser.parse_args(argv)
    unknown = sorted(set(args.games or ()) - set(GAMES))
    if unknown:
        parser.error(f"unknown game(s) {unknown}; MinAtar games: {list(GAMES)}")
    from rl_jax.training.jax_setup import configure

    configure()
    given = sys.argv[1:] if argv is None else argv
    command = " ".join(["PYTHONPATH=$PWD python -m bench.bench_minatar", *given])
    print(run(args.quick, args.games, command=command), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
