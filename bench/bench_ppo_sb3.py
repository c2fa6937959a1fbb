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
import math
import time
from pathlib import Path
from typing import Any, cast

from bench import sb3_side_by_side as side_by_side
from bench.machine import peer_result
from bench.sb3_side_by_side import default_threads, parse_threads

ROOT = side_by_side.ROOT
NAME = "ppo_sb3"
ENV_ID = "rl_jax/HalfCheetah-v5"
GYM_ID = "HalfCheetah-v5"
RECIPE = "cleanrl"
ROLLOUT = 2048  # env steps per iteration: 1 env x 2,048 steps, on both sides
STEPS = 1_000_000  # the figure
QUICK_STEPS = 20_480
PROBE_STEPS = 20_480  # SB3's run at each thread count that picks the count for the whole budget


def round_steps(steps: int) -> int:
    """``steps`` rounded up to whole rollouts (both sides collect 2,048 steps at a time)."""
    return side_by_side.round_up(steps, ROLLOUT)


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
    hparams = cast(ppo_module.Hyperparams, ppo.default_hyperparams(ENV_ID, RECIPE))
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    state = ppo.init(jax.random.key(1), config, hparams)

    def iteration(state, hparams):
        return ppo_module.train_iteration(state, config, hparams)[0]

    program = jax.jit(iteration).lower(state, hparams).compile()
    jax.block_until_ready(state)
    startup = time.perf_counter() - start
    state, result = side_by_side.time_ours(
        program,
        state,
        hparams,
        calls=steps // config.batch_size,
        steps_per_call=config.batch_size,
        startup=startup,
        warmup=False,
    )
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
        env_state, obs, _, rows = ppo_module.collect(
            state.agent, state.env_state, state.obs, collect_key, config, state.action_mask
        )
        advantage, target, state = ppo_module.targets(rows, state, hparams, config)
        state = state.replace(env_state=env_state, obs=obs, key=key)
        return state, jnp.sum(advantage) + jnp.sum(target)

    _, _, _, rows = ppo_module.collect(
        state.agent, state.env_state, state.obs, state.key, config, state.action_mask
    )
    advantage, target, _ = ppo_module.targets(rows, state, hparams, config)
    batch = ppo_module.Batch(
        rows.obs, rows.action, rows.log_mu, rows.v_tm1, advantage, target, rows.legal
    )
    flat = jax.tree.map(lambda x: x.reshape(config.batch_size, *x.shape[2:]), batch)

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
    arguments = ["--steps", str(steps), "--breakdown", str(breakdown_iterations)]
    return side_by_side.ours_child(NAME, arguments, "our PPO worker")


# ---- SB3 (the peers' venv) ----------------------------------------------------------------------
def sb3_command(python: Path, steps: int, threads: int) -> list[str]:
    """The command line of ``bench/sb3_ppo.py`` for ``steps`` env steps on ``threads`` threads."""
    return side_by_side.peer_command(python, "sb3_ppo.py", steps, threads, "--env-id", GYM_ID)


def _sb3(python: Path, steps: int, threads: int) -> dict[str, Any]:
    return peer_result(sb3_command(python, steps, threads), f"SB3's PPO ({threads} threads)")


# ---- the driver and its tables -------------------------------------------------------------------
def measure(python: Path, steps: int, threads: list[int], breakdown_iterations: int) -> dict:
    """Ours, SB3, ours again (see the module docstring). With several thread counts and a
    budget above ``PROBE_STEPS``, SB3 first runs ``PROBE_STEPS`` at each count, and the whole
    budget only at the faster one."""
    first, probes, sb3, again = side_by_side.measure(
        lambda is_first: _ours_child(steps, breakdown_iterations if is_first else 0),
        lambda steps, count: _sb3(python, steps, count),
        steps,
        threads,
        PROBE_STEPS,
    )
    return {"ours": first, "sb3_probes": probes, "sb3": sb3, "ours_again": again}


def table(results: dict[str, Any]) -> list[str]:
    """Markdown: one row per timed run, the ratio, and where our time goes."""
    ours, again, sb3 = results["ours"], results["ours_again"], results["sb3"]
    rows = side_by_side.side_rows(
        "SB3",
        ours,
        results.get("sb3_probes", []),
        sb3,
        again,
        lambda r: f"SB3 {r['stable_baselines3']}, torch {r['torch']}",
    )
    lines = side_by_side.timing_table(rows, steps_header="env steps", warmup=False)
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
    from bench.machine import describe

    head = ["## PPO: ours beside Stable-Baselines3 at equal work", "", describe(), ""]
    return side_by_side.section(
        [*head, f"`{command}`", ""],
        NAME,
        Path(__file__).resolve().parent / "results",
        lambda python: measure(python, round_steps(steps), threads, breakdown_iterations),
        table,
    )


def run(quick: bool = False) -> str:
    """``python -m bench ppo_sb3 [--quick]``: 1M env steps (the issue's figure), or 20,480."""
    steps = QUICK_STEPS if quick else STEPS
    command = side_by_side.quick_command(NAME, quick)
    return section(steps, default_threads(), 3 if quick else 20, command)


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_ppo_sb3 --steps N``: the section for another budget."""

    def add_arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--steps", type=int, default=STEPS, help="env steps per side (1M)")
        parser.add_argument(
            "--sb3-threads",
            default=",".join(map(str, default_threads())),
            help="SB3's torch thread counts, each timed (default: 1 and all cores)",
        )
        parser.add_argument(
            "--breakdown", type=int, default=20, help="iterations timed per part of ours (0: none)"
        )

    def settle(args: argparse.Namespace) -> tuple[int, list[int], int]:
        steps = round_steps(args.steps)
        threads = parse_threads(args.sb3_threads)
        if args.breakdown < 0:
            raise ValueError(f"--breakdown must be >= 0, got {args.breakdown}")
        return steps, threads, args.breakdown

    return side_by_side.main(
        argv,
        name=NAME,
        doc=__doc__,
        add_arguments=add_arguments,
        settle=settle,
        worker=lambda settled: ours(settled[0], settled[2]),
        section=lambda settled, command: section(*settled, command),
        results_dir=Path(__file__).resolve().parent / "results",
    )


if __name__ == "__main__":
    raise SystemExit(main())
