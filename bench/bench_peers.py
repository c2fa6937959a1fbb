"""Ours beside the peers at equal work: our TD3 training loop, SBX's TD3 and the PyTorch script,
with the same networks, batch size and one gradient update per env step, in one run on the
same 2 cores (``python -m bench peers``).

* **Ours**: 5 seeds as one compiled program (``rl_jax.training.parallel.Program``), 4 envs per
  seed with 4 updates per iteration, on the device layout the scripts choose (1 device for 5
  seeds) and on 2 devices (padded to 3 + 3), each timed over whole training chunks (env steps,
  replay, updates, a one-episode evaluation) once compiled.
* **SBX** (``bench/sbx_td3.py``) and **PyTorch** (``bench/torch_td3.py``, one thread): two
  processes at once, one per core, as a user fills this machine; their rates are summed. They run
  in their own pinned venv (``bench/peers.py``): SBX needs jax 0.10.
* The cases: half cheetah at the paper's 256 x 256 with batch 256 and with batch 128, and
  Pendulum with 64 x 64 networks (batch 256). FLOPs per update are the matmuls of our traced
  update (``bench.td3_programs.update_flops``); the peers do the same products.

Order per case: ours, SBX, PyTorch, ours again; both of our timings are reported, so a change of
load during the case shows. Ratios are ours (the better layout) over the peer's two processes.

``bench_peers_sac`` runs the same cases for SAC through this module's ``report``: ours against
SBX's SAC (``bench/sbx_sac.py``; there is no PyTorch SAC script).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.machine import worker_result

ROOT = Path(__file__).resolve().parent.parent
SEEDS = 5
# name: (our env id, gymnasium id, hidden width, batch size, timed updates per peer process)
CASES = {
    "cheetah 256x256, batch 256": ("rl_jax/HalfCheetah-v5", "HalfCheetah-v5", 256, 256, 3000),
    "cheetah 256x256, batch 128": ("rl_jax/HalfCheetah-v5", "HalfCheetah-v5", 256, 128, 4000),
    "pendulum 64x64, batch 256": ("rl_jax/Pendulum-v1", "Pendulum-v1", 64, 256, 6000),
}
QUICK_UPDATES = 300


# ---- ours (a child process: the device count is set before JAX starts) ---------------------
def learner_parts(algo: str) -> tuple[Any, Any, Any]:
    """``(learner, update_flops, update_dots)`` of ``algo`` ("td3" or "sac"): the learner and the
    functions that count its update's matmul FLOPs and list its products."""
    if algo == "td3":
        from bench import td3_programs
        from rl_jax.agents.td3 import td3

        return td3, td3_programs.update_flops, td3_programs.update_dots
    if algo == "sac":
        from bench import sac_programs
        from rl_jax.agents.sac import sac

        return sac, sac_programs.update_flops, sac_programs.update_dots
    raise ValueError(f"unknown learner {algo!r}: td3 or sac")


def ours(case: str, devices: int, quick: bool, algo: str = "td3") -> dict[str, Any]:
    import jax

    from bench.td3_programs import best_seconds, dots_program, matmul_program
    from rl_jax.training import episodes, parallel, params

    learner, update_flops, update_dots = learner_parts(algo)
    env_id, _, width, batch, _ = CASES[case]
    iterations = 50 if quick else 250
    config = learner.default_config(
        env_id,
        actor_hidden=(width, width),
        critic_hidden=(width, width),
        batch_size=batch,
        num_envs=4,
        updates_per_iteration=4,
        iterations_per_chunk=iterations,
        learning_starts=0,
        buffer_size=100_000,
        num_eval_envs=1,
    )
    episodes.make_train_env(config)  # built outside any trace (see bench.cheetah_recipe)
    hparams = params.stack([learner.default_hyperparams(env_id)])
    runner = parallel.Program(learner, config, 1, SEEDS, devices=jax.devices()[:devices])
    state = runner.init(parallel.seed_keys(range(SEEDS)), hparams)
    state, metrics = runner.train_chunk(state, hparams)  # compile and fill the buffer a little
    jax.block_until_ready(metrics)
    chunks, start = 0, time.perf_counter()
    while chunks < 2 or time.perf_counter() - start < (3.0 if quick else 25.0):
        state, metrics = runner.train_chunk(state, hparams)
        jax.block_until_ready(metrics)
        chunks += 1
    seconds = time.perf_counter() - start
    updates = SEEDS * chunks * iterations * config.updates_per_iteration
    flops = update_flops(config)["per_update"]
    result = {
        "updates_per_s": round(updates / seconds, 1),
        "flops_per_update": flops,
        "devices": devices,
        "layout": f"{runner.layout.padded_seeds} runs on {runner.layout.devices} device(s)",
        "load": round(os.getloadavg()[0], 2),
    }
    # The roofline: the update's own matmuls alone, at their shapes, in the same layout.
    call, dot_flops = dots_program(config, SEEDS, 10 if quick else 50, devices, update_dots)
    call()
    result["dots_alone_updates_per_s"] = round(dot_flops / best_seconds(call, 3) / flops, 1)
    if devices == 1:
        matmul, matmul_flops = matmul_program(1)
        matmul()
        result["matmul_1024_gflops"] = round(matmul_flops / best_seconds(matmul, 3) / 1e9, 1)
    return result


def _ours_child(case: str, devices: int, quick: bool, algo: str = "td3") -> dict[str, Any]:
    command = [sys.executable, "-m", "bench.bench_peers", "--worker", case, str(devices)]
    command += ["--algo", algo, *(["--quick"] if quick else [])]
    return worker_result(command, f"our worker for {case!r}")


# ---- the peers: two processes at once -------------------------------------------------------
def _peer_commands(
    peer: str, python: Path, case: str, quick: bool, algo: str = "td3"
) -> list[list[str]]:
    _, gym_id, width, batch, updates = CASES[case]
    updates = QUICK_UPDATES if quick else updates
    if peer == "sbx":
        base = [str(python), str(ROOT / "bench" / f"sbx_{algo}.py"), "--env-id", gym_id]
        base += ["--hidden", f"{width},{width}", "--batch-size", str(batch)]
        base += ["--updates", str(updates)]
    else:
        base = [str(python), "-m", "bench.torch_td3", "--env-id", gym_id, "--hidden", str(width)]
        base += ["--batch-size", str(batch), "--learning-starts", "1000"]
        base += ["--time-only", str(updates)]
    return [[*base, "--seed", str(seed)] for seed in (1, 2)]


def _two_processes(commands: list[list[str]]) -> list[dict[str, Any]]:
    environment = {**os.environ, "PYTHONPATH": str(ROOT), "TF_CPP_MIN_LOG_LEVEL": "3"}
    environment.pop("XLA_FLAGS", None)  # no device split: each process is one user's run
    children = [
        subprocess.Popen(
            command, cwd=ROOT, env=environment, stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )
        for command in commands
    ]
    results = []
    for child in children:
        out, err = child.communicate()
        lines = [x for x in out.decode().splitlines() if x.startswith("{")]
        if child.returncode or not lines:
            raise RuntimeError(f"peer {child.args[:3]} failed:\n{err.decode()[-2000:]}")
        results.append(json.loads(lines[-1]))
    return results


def _peer_rate(runs: list[dict[str, Any]]) -> float:
    """Updates/s of all processes together (SBX reports updates/s, the script env steps/s in
    its learning phase, one update each)."""
    return sum(r.get("updates_per_s", r.get("learning_steps_per_s", 0.0)) for r in runs)


# ---- the driver -----------------------------------------------------------------------------
#: The peers each learner is set beside (the PyTorch script is a TD3).
PEERS = {"td3": ("sbx", "torch"), "sac": ("sbx",)}


def measure_case(case: str, python: Path, quick: bool, algo: str = "td3") -> dict[str, Any]:
    first = {d: _ours_child(case, d, quick, algo) for d in (1, 2)}
    measured: dict[str, Any] = {"ours": first}
    for peer in PEERS[algo]:
        measured[peer] = _two_processes(_peer_commands(peer, python, case, quick, algo))
    measured["ours_again"] = {d: _ours_child(case, d, quick, algo) for d in (1, 2)}
    return measured


def run(quick: bool = False) -> str:
    return report(quick, "td3", "Ours beside SBX and the PyTorch script at equal work", "peers")


def report(quick: bool, algo: str, title: str, name: str) -> str:
    """The Markdown section of ``python -m bench NAME``: every case of ``algo`` measured beside
    its peers; the raw numbers go to ``bench/results/NAME.json``."""
    from bench import peers
    from bench.machine import describe

    lines = [
        f"## {title}",
        "",
        describe(),
        "",
        f"`python -m bench {name}" + (" --quick`" if quick else "`"),
        "",
    ]
    try:
        python = peers.ensure()
    except peers.PeersUnavailable as error:
        return "\n".join([*lines, f"not measured: {error}", ""])
    started = time.strftime("%H:%M")
    results = {}
    for case in CASES:
        results[case] = measure_case(case, python, quick, algo)
    raw = Path(__file__).resolve().parent / "results"
    raw.mkdir(exist_ok=True)
    (raw / f"{name}.json").write_text(json.dumps(results, indent=1))
    lines += table(results)
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).")
    return "\n".join([*lines, ""])


PEER_NAMES = {"sbx": "SBX", "torch": "PyTorch"}


def table(results: dict[str, Any]) -> list[str]:
    """The Markdown tables of ``results`` (case -> ``measure_case``'s dict): rates and ratios,
    then each case's roofline. A peer's columns appear when the cases measured it."""
    names = [p for p in PEER_NAMES if all(p in r for r in results.values())]
    peer_headers = "".join(f" {PEER_NAMES[p]} x2 |" for p in names)
    ratio_headers = "".join(f" ours / {PEER_NAMES[p]} |" for p in names)
    lines = [
        "Updates/s summed over each side's seeds or processes (one update per env step for all); "
        "GFLOP/s = updates/s x the update's matmul FLOPs. Ours: 5 seeds in one program, measured "
        "before and after the peers, on 1 device / on 2 devices (3 + 3, one run padded). Peers: "
        "2 processes at once.",
        "",
        "| case | MFLOP/update | ours 1 dev (before, after) | ours 2 dev (before, after) |"
        f"{peer_headers}{ratio_headers} ours GFLOP/s | load |",
        "|---|---:|---|---|" + "---:|" * (2 * len(names) + 1) + "---|",
    ]
    roofs = []
    for case, r in results.items():
        flops = r["ours"][1]["flops_per_update"]
        rate = {
            d: (r["ours"][d]["updates_per_s"], r["ours_again"][d]["updates_per_s"]) for d in (1, 2)
        }
        best = max(min(pair) for pair in rate.values())  # the better layout, its worse timing
        peer = {p: _peer_rate(r[p]) for p in names}
        loads = [r["ours"][1]["load"], *(x["load"] for x in r["sbx"]), r["ours_again"][2]["load"]]
        lines.append(
            f"| {case} | {flops / 1e6:.1f} | {rate[1][0]:.0f}, {rate[1][1]:.0f} | "
            f"{rate[2][0]:.0f}, {rate[2][1]:.0f} |"
            + "".join(f" {peer[p]:.0f} |" for p in names)
            + "".join(f" {best / peer[p]:.2f}x |" for p in names)
            + f" {best * flops / 1e9:.1f} | {min(loads):.1f}-{max(loads):.1f} |"
        )
        roof = {
            d: max(r[when][d]["dots_alone_updates_per_s"] for when in ("ours", "ours_again"))
            for d in (1, 2)
        }
        top = max(roof.values())  # the faster layout's roofline bounds any of our loops
        matmul = r["ours"][1]["matmul_1024_gflops"]
        sbx = peer["sbx"]
        roofs.append(
            f"| {case} | {roof[1]:.0f} ({roof[1] * flops / 1e9:.0f} GFLOP/s) | "
            f"{roof[2]:.0f} ({roof[2] * flops / 1e9:.0f} GFLOP/s) | {matmul:.0f} | "
            f"{min(rate[1]) / roof[1]:.2f}, {min(rate[2]) / roof[2]:.2f} | "
            f"{best * flops / 1e9 / matmul:.2f} | {sbx / top:.2f} | {2 * sbx / top:.2f} | "
            f"{4 * sbx / top:.2f} |"
        )
    lines += [
        "",
        "The roofline of each case: the update's own matrix products alone, at their exact "
        "shapes, for 5 seeds on 1 device or 3 + 3 on 2 (`bench.td3_programs.dots_program`: what "
        "the loop would reach if everything but its matmuls were free; padding not counted), "
        "beside the 1024x1024 matmul rate, all measured in our worker. The peers' columns "
        "divide by the faster layout's roofline: a ratio above 1 is beyond any loop over these "
        "products at these shapes on this CPU.",
        "",
        "| case | dots alone, 1 dev: updates/s | dots alone, 2 dev | 1024^2 matmul GFLOP/s | "
        "ours / dots alone (1 dev, 2 dev) | ours (better layout) / 1024^2 matmul | "
        "SBX x2 / dots alone | 2 x SBX x2 / dots alone | 4 x SBX x2 / dots alone |",
        "|---|---:|---:|---:|---|---:|---:|---:|---:|",
        *roofs,
    ]
    return lines


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if args[:1] != ["--worker"]:
        raise SystemExit("usage: python -m bench peers (this module's --worker is internal)")
    case, devices, quick = args[1], int(args[2]), "--quick" in args
    algo = args[args.index("--algo") + 1] if "--algo" in args else "td3"
    from rl_jax.training.jax_setup import configure

    configure(cpu_devices=devices)
    print("RESULT " + json.dumps(ours(case, devices, quick, algo)), flush=True)


if __name__ == "__main__":
    main()
