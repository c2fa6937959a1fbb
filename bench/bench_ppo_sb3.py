"""Our PPO beside Stable-Baselines3's at equal work on HalfCheetah-v5 (``python -m bench ppo_sb3``;
``python -m bench.bench_ppo_sb3 --steps N`` for another budget).

Equal work: the same env steps (a multiple of the 2,048-step rollout), networks (64 x 64 tanh,
actor and critic apart), rollout (1 env x 2,048 steps), 10 epochs of 32 minibatches of 64,
observation and reward normalisation, clipping and rates: our ``cleanrl`` recipe
(``--algo ppo --env rl_jax/HalfCheetah-v5 --recipe cleanrl``) against
``PPO("MlpPolicy", ...)`` with the same settings on ``VecNormalize(gymnasium HalfCheetah-v5)``
(``bench/sb3_ppo.py``). Our env is MuJoCo C stepped inside the compiled program (the default
backend on a CPU), SB3's is gymnasium's on the same MuJoCo release.

* **Ours** (a child process of our venv): ``ppo.train_iteration`` repeated in one compiled call
  per iteration (rollout, GAE, reward scaling, the 320 gradient steps, the statistics).
  Evaluation is left out: a run of ours evaluates 10 episodes per chunk, SB3's ``learn`` does
  not evaluate, and equal work means the training steps alone. Start-up (init, tracing and
  compiling, from the persistent compilation cache when it holds the program) is timed apart.
* **SB3** (the peers' venv): construction timed apart, then ``model.learn(steps)``.

Cores: one seed each, as the issue's figure (the wall-clock of one run of N env steps) asks, so
the two sides run one after the other, each alone on the whole machine: ours as one process
whose XLA thread pool spans all cores, SB3 at its faster torch thread count of
``--sb3-threads`` (default 1 and all cores: with 64-wide layers and minibatches of 64 a second
thread can cost more than it gives). Each count first runs ``PROBE_STEPS`` env steps, and the
whole budget runs at the faster one (both are reported). The env steps in SB3's main thread,
as its users run it. Order: ours, SB3 (each count), ours again; the ratio takes the
slower of our two timings over SB3's faster.

Where our time goes, in the same worker, per iteration: the whole iteration; the env alone
(2,048 steps of random actions under one ``lax.scan``); the rollout (env steps, acting, the
values of the next observations, GAE and reward scaling); the update alone (10 x 32 gradient
steps on one fixed batch). Each is its own compiled program, timed after compiling: the fastest
of 3 rounds of ``--breakdown`` iterations. The parts overlap (the rollout holds the env steps),
and timed apart they need not add up to the whole exactly.
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
from typing import Any

from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
ENV_ID = "rl_jax/HalfCheetah-v5"
GYM_ID = "HalfCheetah-v5"
RECIPE = "cleanrl"
ROLLOUT = 2048  # env steps per iteration: 1 env x 2,048 steps, on both sides
STEPS = 1_000_000  # the figure
QUICK_STEPS = 20_480
PROBE_STEPS = 20_480  # SB3's run at each thread count that picks the count for the whole budget


def round_steps(steps: int) -> int:
    """``steps`` rounded up to whole rollouts (both sides collect 2,048 steps at a time)."""
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    return math.ceil(steps / ROLLOUT) * ROLLOUT


def parse_threads(text: str) -> list[int]:
    """``"1,2"`` -> ``[1, 2]``: SB3's torch thread counts, each >= 1, no repeats."""
    try:
        counts = [int(part) for part in text.split(",")]
    except ValueError:
        raise ValueError(f"--sb3-threads takes counts like 1,2; got {text!r}") from None
    if not counts or min(counts) < 1 or len(set(counts)) != len(counts):
        raise ValueError(f"--sb3-threads takes distinct counts >= 1, like 1,2; got {text!r}")
    return counts


# ---- ours (a child process: its own JAX, one device over all cores) ---------------------------
def ours(steps: int, breakdown_iterations: int) -> dict[str, Any]:
    """Time ``steps`` env steps of our PPO (module docstring) and, over
    ``breakdown_iterations`` iterations each, its parts."""
    import jax

    from rl_jax.agents import ppo as ppo_module
    from rl_jax.agents.ppo import ppo
    from rl_jax.training import episodes

    start = time.perf_counter()
    config = ppo.default_config(ENV_ID, RECIPE)
    hparams = ppo.default_hyperparams(ENV_ID, RECIPE)
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    state = ppo.init(jax.random.key(1), config, hparams)

    def iteration(state, hparams):
        return ppo_module.train_iteration(state, config, hparams)[0]

    program = jax.jit(iteration).lower(state, hparams).compile()
    jax.block_until_ready(state)
    startup = time.perf_counter() - start
    iterations = steps // config.batch_size
    start = time.perf_counter()
    for _ in range(iterations):
        state = program(state, hparams)
    jax.block_until_ready(state)
    seconds = time.perf_counter() - start
    result = {
        "env_steps": int(state.clock.env_steps),
        "seconds": round(seconds, 3),
        "env_steps_per_s": round(iterations * config.batch_size / seconds, 1),
        "startup_s": round(startup, 3),
        "cores": len(os.sched_getaffinity(0)),
        "jax": jax.__version__,
        "load": round(os.getloadavg()[0], 2),
    }
    if breakdown_iterations:
        result["breakdown_s"] = breakdown(state, config, hparams, breakdown_iterations)
    return result


def breakdown(state: Any, config: Any, hparams: Any, iterations: int) -> dict[str, float]:
    """Seconds per iteration of the whole iteration, the env alone, the rollout and the update
    alone, each its own compiled program timed over rounds of ``iterations`` calls."""
    import jax
    import jax.numpy as jnp

    from rl_jax.agents import ppo as ppo_module
    from rl_jax.training import episodes

    env = episodes.make_train_env(config)
    space = env.action_space()

    def whole(state):
        return ppo_module.train_iteration(state, config, hparams)[0]

    def env_alone(state):
        def step(env_state, key):
            action_key, env_key = jax.random.split(key)
            action = jax.random.uniform(action_key, (config.num_envs, *space.shape), minval=-1.0)
            keys = jax.random.split(env_key, config.num_envs)
            env_state, ts = jax.vmap(env.step)(keys, env_state, action)
            return env_state, jnp.sum(ts.reward)

        keys = jax.random.split(state.key, config.num_steps)
        env_state, rewards = jax.lax.scan(step, state.env_state, keys)
        return state.replace(env_state=env_state, key=keys[-1]), jnp.sum(rewards)

    def rollout(state):
        key, collect_key = jax.random.split(state.key)
        env_state, obs, rows = ppo_module.collect(
            state.agent, state.env_state, state.obs, collect_key, config
        )
        advantage, target, state = ppo_module.targets(rows, state, hparams, config)
        state = state.replace(env_state=env_state, obs=obs, key=key)
        return state, jnp.sum(advantage) + jnp.sum(target)

    _, _, rows = ppo_module.collect(state.agent, state.env_state, state.obs, state.key, config)
    advantage, target, _ = ppo_module.targets(rows, state, hparams, config)
    flat = jax.tree.map(
        lambda x: x.reshape(config.batch_size, *x.shape[2:]),
        ppo_module.Batch(rows.obs, rows.action, rows.log_mu, rows.v_tm1, advantage, target),
    )

    def update(state):
        key, update_key = jax.random.split(state.key)
        agent, metrics = ppo_module.update(
            state.agent, flat, update_key, hparams, config, hparams.learning_rate
        )
        return state.replace(agent=agent, key=key), metrics["policy_loss"]

    parts = {"whole": whole, "env": env_alone, "rollout": rollout, "update": update}
    return {
        name: round(_seconds_per_call(part, state, iterations), 4) for name, part in parts.items()
    }


def _seconds_per_call(part: Any, state: Any, calls: int, rounds: int = 3) -> float:
    """Seconds per call of ``part`` compiled, each call on the state the last one left: the
    fastest of ``rounds`` rounds of ``calls`` calls (the least disturbed by other work)."""
    import jax

    program = jax.jit(part)
    out = jax.block_until_ready(program(state))  # compile and one untimed call
    state = out[0] if isinstance(out, tuple) else out
    best = math.inf
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            out = program(state)
            state = out[0] if isinstance(out, tuple) else out
        jax.block_until_ready(state)
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def _ours_child(steps: int, breakdown_iterations: int) -> dict[str, Any]:
    command = [sys.executable, "-m", "bench.bench_ppo_sb3", "--worker", "--steps", str(steps)]
    command += ["--breakdown", str(breakdown_iterations)]
    # One device over all cores, as a run of one seed: no XLA_FLAGS inherited.
    return worker_result(command, "our PPO worker", {"XLA_FLAGS": None})


# ---- SB3 (the peers' venv) ----------------------------------------------------------------------
def sb3_command(python: Path, steps: int, threads: int) -> list[str]:
    """The command line of ``bench/sb3_ppo.py`` for ``steps`` env steps on ``threads`` threads."""
    script = str(ROOT / "bench" / "sb3_ppo.py")
    return [
        str(python),
        script,
        "--env-id",
        GYM_ID,
        "--steps",
        str(steps),
        "--threads",
        str(threads),
    ]


def _sb3(python: Path, steps: int, threads: int) -> dict[str, Any]:
    environment = {**os.environ, "TF_CPP_MIN_LOG_LEVEL": "3"}
    done = subprocess.run(
        sb3_command(python, steps, threads),
        cwd=ROOT,
        env=environment,
        capture_output=True,
        text=True,
    )
    lines = [x for x in done.stdout.splitlines() if x.startswith("{")]
    if done.returncode or not lines:
        raise RuntimeError(f"SB3's PPO ({threads} threads) failed:\n{done.stderr[-3000:]}")
    return json.loads(lines[-1])


# ---- the driver and its tables -------------------------------------------------------------------
def measure(python: Path, steps: int, threads: list[int], breakdown_iterations: int) -> dict:
    """Ours, SB3, ours again (see the module docstring). With several thread counts and a
    budget above ``PROBE_STEPS``, SB3 first runs ``PROBE_STEPS`` at each count, and the whole
    budget only at the faster one."""
    first = _ours_child(steps, breakdown_iterations)
    probes = []
    if len(threads) > 1 and steps > PROBE_STEPS:
        probes = [_sb3(python, PROBE_STEPS, count) for count in threads]
        threads = [min(probes, key=lambda r: r["seconds"])["threads"]]
    sb3 = [_sb3(python, steps, count) for count in threads]
    again = _ours_child(steps, 0)
    return {"ours": first, "sb3_probes": probes, "sb3": sb3, "ours_again": again}


def table(results: dict[str, Any]) -> list[str]:
    """Markdown: one row per timed run, the ratio, and where our time goes."""
    ours, again, sb3 = results["ours"], results["ours_again"], results["sb3"]
    lines = [
        "| program | env steps | start-up s | training s | env steps/s | threads | load |",
        "|---|---:|---:|---:|---:|---|---:|",
    ]

    def row(label: str, r: dict[str, Any], threads: str) -> str:
        return (
            f"| {label} | {r['env_steps']:,} | {r['startup_s']:.1f} | {r['seconds']:.1f} | "
            f"{r['env_steps_per_s']:,.0f} | {threads} | {r['load']:.1f} |"
        )

    lines.append(row(f"ours, jax {ours['jax']}", ours, f"XLA over {ours['cores']} cores"))
    for probe in results.get("sb3_probes", []):
        lines.append(row("SB3, choosing its thread count", probe, f"torch {probe['threads']}"))
    for r in sb3:
        label = f"SB3 {r['stable_baselines3']}, torch {r['torch']}"
        lines.append(row(label, r, f"torch {r['threads']}"))
    lines.append(row("ours again", again, f"XLA over {again['cores']} cores"))
    slower = max(ours["seconds"], again["seconds"])
    faster_sb3 = min(sb3, key=lambda r: r["seconds"])
    lines += [
        "",
        f"Wall-clock of the training: SB3 (its faster, {faster_sb3['threads']} thread(s)) / ours "
        f"(the slower of our two) = **{faster_sb3['seconds'] / slower:.2f}x**; start-up apart.",
    ]
    if "breakdown_s" in ours:
        lines += ["", *breakdown_table(ours["breakdown_s"])]
    return lines


def breakdown_table(parts: dict[str, float]) -> list[str]:
    """Markdown: seconds per iteration of each part and its share of the whole iteration."""
    whole = parts["whole"]
    labels = {
        "whole": "the whole iteration",
        "env": "the env alone (2,048 steps, random actions)",
        "rollout": "the rollout: env steps, acting, values, GAE, reward scaling",
        "update": "the update alone: 10 epochs x 32 minibatches of 64",
    }
    lines = [
        "Where our time goes, per iteration of 2,048 env steps (each part its own compiled "
        "program, the fastest of 3 rounds; timed apart, the parts need not add up to the whole):",
        "",
        "| part | ms per iteration | share of the whole |",
        "|---|---:|---:|",
    ]
    for name, label in labels.items():
        lines.append(f"| {label} | {parts[name] * 1e3:.1f} | {parts[name] / whole:.0%} |")
    rest = whole - parts["rollout"] - parts["update"]
    lines.append(f"| the rest (whole - rollout - update) | {rest * 1e3:.1f} | {rest / whole:.0%} |")
    return lines


def section(steps: int, threads: list[int], breakdown_iterations: int, command: str) -> str:
    """The Markdown section: machine line, command, the tables (or why nothing was measured)."""
    from bench import peers
    from bench.machine import describe

    lines = ["## PPO: ours beside Stable-Baselines3 at equal work", "", describe(), ""]
    lines += [f"`{command}`", ""]
    try:
        python = peers.ensure()
    except peers.PeersUnavailable as error:
        return "\n".join([*lines, f"not measured: {error}", ""])
    started = time.strftime("%H:%M")
    results = measure(python, round_steps(steps), threads, breakdown_iterations)
    raw = Path(__file__).resolve().parent / "results"
    raw.mkdir(exist_ok=True)
    (raw / "ppo_sb3.json").write_text(json.dumps(results, indent=1))
    lines += table(results)
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).")
    return "\n".join([*lines, ""])


def default_threads() -> list[int]:
    """SB3's thread counts by default: 1 and every core (one count on a 1-core machine)."""
    return sorted({1, os.cpu_count() or 1})


def run(quick: bool = False) -> str:
    """``python -m bench ppo_sb3 [--quick]``: 1M env steps (the issue's figure), or 20,480."""
    steps = QUICK_STEPS if quick else STEPS
    command = "python -m bench ppo_sb3" + (" --quick" if quick else "")
    return section(steps, default_threads(), 3 if quick else 20, command)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_ppo_sb3 --steps N``: the section for another budget."""
    parser = argparse.ArgumentParser(
        prog="python -m bench.bench_ppo_sb3",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--steps", type=int, default=STEPS, help="env steps per side (1M)")
    parser.add_argument(
        "--sb3-threads",
        default=",".join(map(str, default_threads())),
        help="SB3's torch thread counts, each timed (default: 1 and all cores)",
    )
    parser.add_argument(
        "--breakdown", type=int, default=20, help="iterations timed per part of ours (0: none)"
    )
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    try:
        steps = round_steps(args.steps)
        threads = parse_threads(args.sb3_threads)
        if args.breakdown < 0:
            raise ValueError(f"--breakdown must be >= 0, got {args.breakdown}")
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    from rl_jax.training.jax_setup import configure

    configure()
    if args.worker:
        print("RESULT " + json.dumps(ours(steps, args.breakdown)), flush=True)
        return 0
    command = " ".join(["python -m bench.bench_ppo_sb3", *(argv or sys.argv[1:])]).strip()
    text = section(steps, threads, args.breakdown, command)
    print(text, flush=True)
    raw = Path(__file__).resolve().parent / "results"
    (raw / "ppo_sb3.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
