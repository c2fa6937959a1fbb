"""pgx's own AlphaZero example (``examples/alphazero/train.py`` of github.com/sotetsuk/pgx) timed
on its self-play: the peer ``bench_alphazero_pgx`` sets beside our ``alphazero.self_play``. Runs
in the peers' venv (``bench/peers.py``: jax, dm-haiku, omegaconf, pydantic, pgx, mctx); imports
nothing of rl_jax.

    .venv-peers/bin/python bench/pgx_alphazero.py --example-dir DIR --games 64 --calls 3

``DIR`` holds the example's ``train.py`` and ``network.py`` as the driver fetched and checked
them (``bench_alphazero_pgx.example_dir``). The example is a script; it is loaded as a module
(``__name__`` is not ``"__main__"``, so its training loop does not run) after three things its
module level needs are set up, none of which touches the self-play it defines:

* its settings come from the command line (``OmegaConf.from_cli`` reads ``sys.argv``): ``argv``
  is set to ``env_id=connect_four selfplay_batch_size=G num_simulations=S max_num_steps=M`` (and
  ``num_channels``/``num_layers`` for its ResNet), the way a user runs it;
* ``wandb`` (logging, used only in its ``__main__`` block) is an empty stand-in module, so the
  peers' venv need not install it;
* ``pgx.make_baseline_model`` is replaced by a stand-in that returns nothing: the example asks
  at module level for ``connect_four_v0``, a baseline pgx does not ship (and would download),
  used only by its ``evaluate``, which is not run here.

Then, with ``--network mlp`` (the default), the module's global ``forward`` (its haiku
``transform_with_state`` of ``AZNet``) is replaced by a haiku MLP of exactly our
``PolicyValueNet``'s shape: the flattened board as float32, ``--hidden`` Linear + ReLU layers, a
linear policy head and a tanh value head; ``selfplay`` and its ``recurrent_fn`` look ``forward``
up when they are traced, so they run the MLP. With ``--network resnet`` the example's own
``AZNet`` (``--channels`` x ``--blocks``, ResNet v2 with batch norm) is kept.

Its ``selfplay`` (``jax.pmap`` over the local devices: one CPU device here, all cores) plays
``selfplay_batch_size`` games for ``max_num_steps`` steps, each step one Gumbel MuZero search
(mctx's ``gumbel_muzero_policy``, ``num_simulations``, 16 considered actions, Gumbel scale 1) and
one move; a finished game restarts at once (``pgx.experimental.auto_reset``), so every step of
every game is a move from a live position. The parameters are initialised and replicated as its
``__main__`` does. The first call (tracing, compiling, one run) is timed apart as start-up; then
``--calls`` calls, each with a fresh key, timed. Prints one JSON line: move slots (games x
steps), moves from live positions (all of them, by ``auto_reset``), games finished, seconds,
rates, parameter count, versions and the load.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import sys
import time
import types
from pathlib import Path
from typing import Any

ENV_ID = "connect_four"  # pgx's id; ours is pgx/connect_four


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line: where the example is, the self-play sizes, the network."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--example-dir", type=Path, required=True)
    parser.add_argument("--games", type=int, default=64, help="selfplay_batch_size")
    parser.add_argument("--simulations", type=int, default=32, help="num_simulations")
    parser.add_argument("--max-moves", type=int, default=42, help="max_num_steps")
    parser.add_argument("--calls", type=int, default=3, help="timed self-play calls")
    parser.add_argument("--network", choices=("mlp", "resnet"), default="mlp")
    parser.add_argument("--hidden", default="256,256", help="the MLP's widths (--network mlp)")
    parser.add_argument("--channels", type=int, default=64, help="AZNet's num_channels")
    parser.add_argument("--blocks", type=int, default=5, help="AZNet's num_layers")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if min(args.games, args.simulations, args.max_moves, args.calls) < 1:
        parser.error("--games, --simulations, --max-moves and --calls must be >= 1")
    args.hidden = tuple(int(w) for w in args.hidden.split(",") if w)
    return args


def example_argv(args: argparse.Namespace) -> list[str]:
    """The example's command line (``OmegaConf.from_cli``'s ``key=value`` pairs) for ``args``."""
    argv = [
        "train.py",
        f"env_id={ENV_ID}",
        f"selfplay_batch_size={args.games}",
        f"num_simulations={args.simulations}",
        f"max_num_steps={args.max_moves}",
        f"seed={args.seed}",
    ]
    if args.network == "resnet":
        argv += [f"num_channels={args.channels}", f"num_layers={args.blocks}"]
    return argv


def load_example(args: argparse.Namespace) -> Any:
    """The example's ``train.py`` as a module, with the module docstring's three stand-ins."""
    import pgx

    directory = args.example_dir.resolve()
    sys.modules.setdefault("wandb", types.ModuleType("wandb"))

    def no_baseline(model_id: str) -> None:
        # the example's module level asks for one; only its evaluate (not run) would call it
        return None

    pgx.make_baseline_model = no_baseline
    sys.path.insert(0, str(directory))  # its "from network import AZNet"
    saved = sys.argv
    sys.argv = example_argv(args)
    try:
        spec = importlib.util.spec_from_file_location(
            "pgx_alphazero_example", directory / "train.py"
        )
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        sys.argv = saved
    return module


def mlp_forward(num_actions: int, hidden: tuple[int, ...]) -> Any:
    """A haiku ``transform_with_state`` with the example's ``forward`` signature (``(x,
    is_eval)`` -> ``(logits, value)``): our ``PolicyValueNet`` without a conv torso."""
    import haiku as hk  # type: ignore[import-not-found]  # the peers' venv's
    import jax
    import jax.numpy as jnp

    def forward_fn(x: jax.Array, is_eval: bool = False) -> tuple[jax.Array, jax.Array]:
        del is_eval  # no batch norm: training and evaluation are the same
        x = x.reshape(x.shape[0], -1).astype(jnp.float32)
        for width in hidden:
            x = jax.nn.relu(hk.Linear(width)(x))
        logits = hk.Linear(num_actions)(x)
        value = jnp.tanh(hk.Linear(1)(x))[:, 0]
        return logits, value

    return hk.without_apply_rng(hk.transform_with_state(forward_fn))


def file_digest(path: Path) -> str:
    """The sha256 of a file, hex."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main(argv: list[str] | None = None) -> None:
    """Load, initialise, compile, time ``selfplay``, print the JSON line."""
    args = parse_args(argv)
    start = time.perf_counter()
    import haiku as hk
    import jax
    import jax.numpy as jnp
    import mctx
    import pgx

    example = load_example(args)
    if args.network == "mlp":
        example.forward = mlp_forward(example.env.num_actions, args.hidden)
    forward = example.forward
    devices = jax.local_devices()
    key = jax.random.PRNGKey(args.seed)
    dummy = jax.vmap(example.env.init)(jax.random.split(key, 2))
    model = forward.init(key, dummy.observation)  # (params, state), as its __main__
    params = sum(x.size for x in jax.tree.leaves(model[0]))
    model = jax.tree.map(lambda x: jnp.stack([x] * len(devices)), model)

    def call(key: jax.Array) -> Any:
        keys = jax.random.split(key, len(devices))
        return jax.block_until_ready(example.selfplay(model, keys))

    keys = jax.random.split(jax.random.PRNGKey(args.seed + 1), args.calls + 1)
    call(keys[0])
    startup = time.perf_counter() - start
    finished = 0
    start = time.perf_counter()
    for key in keys[1:]:
        data = call(key)
        finished += int(jnp.sum(data.terminated))
    seconds = time.perf_counter() - start
    slots = args.calls * args.games * args.max_moves
    result = {
        "peer": "pgx examples/alphazero selfplay",
        "network": args.network,
        "hidden": list(args.hidden) if args.network == "mlp" else None,
        "channels": args.channels if args.network == "resnet" else None,
        "blocks": args.blocks if args.network == "resnet" else None,
        "params": int(params),
        "games": args.games,
        "simulations": int(example.config.num_simulations),
        "max_moves": int(example.config.max_num_steps),
        "batch": int(example.config.selfplay_batch_size),
        "calls": args.calls,
        "move_slots": slots,
        "moves_played": slots,  # auto_reset: every step is a move from a live position
        "games_finished": finished,
        "seconds": round(seconds, 3),
        "slots_per_s": round(slots / seconds, 1),
        "moves_per_s": round(slots / seconds, 1),
        "startup_s": round(startup, 3),
        "devices": len(devices),
        "cores": len(os.sched_getaffinity(0)),
        "train_py_sha256": file_digest(args.example_dir / "train.py"),
        "jax": jax.__version__,
        "pgx": pgx.__version__,
        "mctx": getattr(mctx, "__version__", "?"),
        "haiku": hk.__version__,
        "load": round(os.getloadavg()[0], 2),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
