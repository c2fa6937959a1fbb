"""What TD3's network options, TD7 and CrossQ cost: updates/s per seed of the half-cheetah
training program with 5 seeds in one program, side by side with plain TD3.

``python -m bench td3_options`` (long on a CPU: run it alone). Two loops:

* **TD7's loop** (the TD3 paper's: 1 env per seed, 1 update per env step, batch 256, 256 x 256
  actor and critics), where TD7's published settings live: plain TD3, each network option,
  CrossQ and TD7 (256-d embeddings) at those sizes.
* **The CPU recipe's loop** (``td3_cheetah.py``'s default: 4 envs x 4 updates per iteration,
  batch 128, 128 x 128): plain, TD7 at 128-d embeddings and CrossQ at those sizes, the
  candidates for a recipe chosen by return against wall-clock.

Each program is ``bench.cheetah_recipe.measure``: the whole training chunk (env steps, replay,
updates, evaluation) with updates from the first step, one compiled program per option, at two
chunk lengths; the difference of their chunk times leaves the evaluation out. Plain TD3 runs
first and again last in each loop, so a change of load during the run shows as a difference
between its two rows; an option's ratio is to their mean. The matmul FLOPs of one update (every
``dot_general`` of its jaxpr) say how much of a slowdown is arithmetic, not overhead.
"""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any

from bench.machine import describe


def _loop(envs: int, batch: int, width: int) -> dict[str, Any]:
    """A training loop's overrides: ``envs`` envs per seed and as many updates per iteration (one
    update per env step), ``batch``, two hidden layers of ``width`` in actor and critics."""
    layers = [width, width]
    return {
        "num_envs": envs,
        "updates_per_iteration": envs,
        "batch_size": batch,
        "actor_hidden": layers,
        "critic_hidden": layers,
    }


PAPER_LOOP = _loop(1, 256, 256)
CPU_LOOP = _loop(4, 128, 128)
SALE_128 = {"embedding_dim": 128, "embedding_hidden": [128, 128]}
#: (loop name, loop, [(label, overrides)]); plain TD3 first and last. ``"learner"`` names a
#: learner other than td3 (TD7 and CrossQ are learners of their own).
CASES: list[tuple[str, dict[str, Any], list[tuple[str, dict[str, Any]]]]] = [
    (
        "TD7's loop (1 env, 1 update per step, batch 256, 256 x 256)",
        PAPER_LOOP,
        [
            ("plain TD3", {}),
            ("LayerNorm critics (`--critic-norm layer`)", {"critic_norm": "layer"}),
            ("ELU critics (`--critic-activation elu`)", {"critic_activation": "elu"}),
            ("SimBa blocks (`--network simba`)", {"network": "simba"}),
            ("CrossQ at these widths (`--algo crossq`)", {"learner": "crossq"}),
            ("TD7 (`--algo td7`)", {"learner": "td7"}),
            ("plain TD3 (again)", {}),
        ],
    ),
    (
        "the CPU recipe's loop (4 envs x 4 updates, batch 128, 128 x 128)",
        CPU_LOOP,
        [
            ("plain TD3 (`td3_cheetah.py`'s default)", {}),
            ("TD7, 128-d embeddings (`--recipe td7-cpu`)", {"learner": "td7", **SALE_128}),
            ("CrossQ (`--recipe crossq-cpu`)", {"learner": "crossq"}),
            ("LayerNorm critics", {"critic_norm": "layer"}),
            ("plain TD3 (again)", {}),
        ],
    ),
]
SEEDS = 5


def _flops_range(jaxpr: Any) -> tuple[int, int]:
    """Matmul FLOPs of ``jaxpr`` taking every ``cond``'s cheapest and its dearest branch."""
    from bench.td3_programs import _dot_flops, _inner_jaxprs

    low = high = 0
    for equation in jaxpr.eqns:
        name = equation.primitive.name
        if name == "dot_general":
            parts = [(_dot_flops(equation),) * 2]
        elif name == "cond":
            branches = [_flops_range(b.jaxpr) for b in equation.params["branches"]]
            parts = [(min(b[0] for b in branches), max(b[1] for b in branches))]
        elif name == "scan":
            inner = _flops_range(equation.params["jaxpr"].jaxpr)
            parts = [(equation.params["length"] * inner[0], equation.params["length"] * inner[1])]
        else:
            parts = [_flops_range(sub) for sub in _inner_jaxprs(equation)]
        low += sum(p[0] for p in parts)
        high += sum(p[1] for p in parts)
    return low, high


def update_gflop(config: Any, learner_name: str = "td3") -> float:
    """Matmul GFLOP of one seed's whole update (TD7's encoder step and LAP included), the
    delayed actor step counted once per ``policy_delay`` updates: the only branch of the update
    that holds matmuls, so the cheapest path is the critic's and the dearest adds the actor's."""
    import importlib

    import jax
    import jax.numpy as jnp

    from rl_jax.run.learners import resolve as resolve_algorithm

    learner = resolve_algorithm(learner_name)
    module = importlib.import_module(type(learner).__module__)
    hparams = learner.default_hyperparams(config.env_id)
    # shapes are all the tracing needs (an eager init would compile each of its ops)
    state = jax.eval_shape(lambda key: learner.init(key, config, hparams), jax.random.key(0))
    traced = jax.make_jaxpr(
        lambda agent, buffer, key, index: module.update(agent, buffer, key, config, hparams, index)
    )(state.agent, state.buffer, jax.random.key(1), jnp.int32(0))
    low, high = _flops_range(traced.jaxpr)
    return (low + (high - low) / config.policy_delay) / 1e9


def worker(recipe: dict[str, Any], chunks: int) -> dict[str, Any]:
    """One option's program in this (fresh) process: its updates/s without the evaluation at
    the end of each chunk (from two chunk lengths: the time per iteration is the difference of
    their chunk times over the difference of their iterations), and its update's FLOPs."""
    from bench import cheetah_recipe
    from rl_jax.run.learners import resolve as resolve_algorithm

    short = recipe["iterations_per_chunk"]
    runs = [
        cheetah_recipe.measure({**recipe, "iterations_per_chunk": n}, SEEDS, chunks)
        for n in (short, 3 * short)
    ]
    seconds = (runs[1]["chunk_s"] - runs[0]["chunk_s"]) / (2 * short)
    updates = recipe["updates_per_iteration"]
    measured = {
        "updates_per_s_per_run": updates / seconds,
        "env_steps_per_s_per_run": recipe["num_envs"] / seconds,
        "eval_s": runs[0]["chunk_s"] - short * seconds,
        "first_call_s": runs[1]["first_call_s"],
        "load": runs[1]["load"],
    }
    settings = {k: tuple(v) if isinstance(v, list) else v for k, v in recipe.items()}
    learner_name = settings.pop("learner", "td3")
    config = resolve_algorithm(learner_name).default_config(cheetah_recipe.ENV_ID, **settings)
    measured["gflop_per_update"] = update_gflop(config, learner_name)
    return measured


def _measure(recipe: dict[str, Any], chunks: int) -> dict[str, Any]:
    code = (
        "import json, sys\n"
        "from rl_jax.training.jax_setup import configure\n"
        "configure()\n"
        "from bench.bench_td3_options import worker\n"
        "print(json.dumps(worker(json.loads(sys.argv[1]), int(sys.argv[2]))))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code, json.dumps(recipe), str(chunks)],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"the option {recipe} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _iterations(loop: dict[str, Any], overrides: dict[str, Any], quick: bool) -> int:
    """N, the short chunk's iterations: long enough that the 2N iterations between the two
    chunk lengths take several seconds (the evaluation's time varies by a few tenths)."""
    if quick:
        return 10
    heavy = overrides.get("learner") == "td7" or overrides.get("network") == "simba"
    if loop["num_envs"] == 1:
        return 40 if heavy else 300
    return 25 if heavy else 150


def run(quick: bool = False) -> str:
    chunks = 1
    lines = [
        "## TD3's options: updates/s per seed, 5 seeds in one program",
        "",
        describe(),
        "",
        "`python -m bench td3_options`: the half-cheetah training program (env steps, replay, "
        "updates, evaluation), 5 seeds vmapped on one device, updates from the first step; "
        f"each option's program in a fresh process, at two chunk lengths (N and 3N iterations, "
        f"{chunks} timed chunks each after the first call): the time per iteration is the "
        "difference of their chunk times over 2N, which leaves out each chunk's evaluation. "
        "Ratio: to the mean of the two plain-TD3 rows of the same loop. GFLOP: matmul FLOPs "
        "of one seed's update (the actor step once per 2 updates), counted in its jaxpr.",
        "",
    ]
    for title, loop, options in CASES:
        rows = []
        for label, overrides in options:
            iterations = _iterations(loop, overrides, quick)
            recipe = {**loop, **overrides, "iterations_per_chunk": iterations}
            measured = _measure(recipe, chunks)
            rows.append((label, measured))
            print(f"{label}: {measured}", file=sys.stderr, flush=True)
        plain = [m["updates_per_s_per_run"] for label, m in rows if label.startswith("plain")]
        reference = sum(plain) / len(plain)
        lines += [
            f"### {title}",
            "",
            "| option | updates/s per seed | x plain | env steps/s per seed | GFLOP per "
            "update | matmul GFLOP/s, 5 seeds | eval s per chunk | first call s | load |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for label, m in rows:
            flops = m["gflop_per_update"]
            rate = flops * m["updates_per_s_per_run"] * SEEDS
            lines.append(
                f"| {label} | {m['updates_per_s_per_run']:,.0f} | "
                f"{m['updates_per_s_per_run'] / reference:.2f} | "
                f"{m['env_steps_per_s_per_run']:,.0f} | "
                f"{flops:.2f} | {rate:.0f} | {m['eval_s']:.1f} | {m['first_call_s']:.1f} | "
                f"{m['load']:.1f} |"
            )
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    print(run(quick="--quick" in sys.argv))
