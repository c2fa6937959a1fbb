"""SBX's TD3 (``sbx-rl``, Stable-Baselines3 in JAX) timed on a gymnasium env: the peer that
``bench_peers`` sets beside ours. Runs in its own venv (``bench/peers.py`` builds it: SBX needs
jax 0.10, we pin 0.9.2), so it imports nothing of rl_jax.

    .venv-peers/bin/python bench/sbx_td3.py --env-id HalfCheetah-v5 --hidden 256,256 \
        --batch-size 256 --updates 2000

SBX as its users run it: one env, one gradient update per env step (``train_freq=1``,
``gradient_steps=1``), the networks and batch given. ``learning_starts`` random steps and a
short warm-up of updates (compilation) run first, untimed; then ``--updates`` env steps with one
update each are timed. Prints one JSON line: updates/s and the seconds they took.

``bench/sbx_sac.py`` runs this with SBX's SAC (``main(algo="SAC")``).
"""

from __future__ import annotations

import argparse
import json
import os
import time


def main(argv: list[str] | None = None, algo: str = "TD3", doc: str | None = None) -> None:
    """Time ``sbx.<algo>`` ("TD3" or "SAC") as the module docstring says; ``doc``: --help's."""
    parser = argparse.ArgumentParser(description=doc or __doc__)
    parser.add_argument("--env-id", default="HalfCheetah-v5")
    parser.add_argument("--hidden", default="256,256", help="widths of actor and critic layers")
    parser.add_argument("--batch-size", type=int, default=256)
    parser.add_argument("--updates", type=int, default=2000, help="timed env steps (1 update each)")
    parser.add_argument("--learning-starts", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=300, help="untimed updates (compilation)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    import gymnasium as gym
    import jax
    import sbx

    hidden = [int(width) for width in args.hidden.split(",")]
    # SAC: the temperature learned towards an entropy of -|A| (SBX's "auto", its default)
    own = {"ent_coef": "auto", "target_entropy": "auto"} if algo == "SAC" else {}
    model = getattr(sbx, algo)(
        "MlpPolicy",
        gym.make(args.env_id),
        learning_starts=args.learning_starts,
        batch_size=args.batch_size,
        train_freq=1,
        gradient_steps=1,
        policy_kwargs={"net_arch": hidden},
        seed=args.seed,
        verbose=0,
        **own,
    )
    model.learn(args.learning_starts + args.warmup)
    jax.block_until_ready(model.policy.qf_state.params)
    start = time.perf_counter()
    model.learn(args.updates, reset_num_timesteps=False)
    jax.block_until_ready(model.policy.qf_state.params)
    seconds = time.perf_counter() - start
    result = {
        "peer": "sbx",
        "algo": algo,
        "sbx": sbx.__version__,
        "jax": jax.__version__,
        "env_id": args.env_id,
        "hidden": hidden,
        "batch_size": args.batch_size,
        "updates": args.updates,
        "seconds": round(seconds, 3),
        "updates_per_s": round(args.updates / seconds, 2),
        "load": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
