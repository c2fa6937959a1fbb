"""Our AlphaZero's self-play beside pgx's own AlphaZero example at equal settings, Connect Four
(``python -m bench alphazero_pgx [--quick]``; ``python -m bench.bench_alphazero_pgx --games G
--simulations S --calls N --network mlp,resnet --pgx-example DIR`` for other sizes).

What is timed is one self-play call on each side, compiled first: ``G`` games of Connect Four
played side by side for ``M`` steps (42, a whole game at most), every step one Gumbel MuZero
search (mctx's ``gumbel_muzero_policy``: ``S`` simulations, 16 considered root actions, Gumbel
scale 1, mctx's default completed-Q transform) with the true game as the model, and one move.

* **Ours** (a child process of our venv): ``alphazero.self_play`` under ``jax.jit``, the
  Connect Four recipe's config with ``num_envs=G``, ``max_game_length=M``,
  ``num_simulations=S``; its 10% random moves and sampled opening moves are part of it, as in
  training.
* **pgx's** (the peers' venv): the ``selfplay`` function of ``examples/alphazero/train.py`` of
  github.com/sotetsuk/pgx at commit ``PGX_COMMIT`` (the commit pgx's v2.6.0 release was cut
  from; the example last changed before it), run by ``bench/pgx_alphazero.py``, which says how
  the script is loaded (its own ``key=value`` command line; ``wandb`` and
  ``pgx.make_baseline_model`` stood in for, as neither is used by self-play).

**The same network.** pgx's example uses a haiku ResNet (``AZNet``); ours is an MLP. The
``mlp`` row runs the example's own ``selfplay`` with its ``forward`` replaced by a haiku MLP of
exactly our widths (``--hidden``, the recipe's 256 x 256: the flattened board, Linear + ReLU
layers, a linear policy head, a tanh value head: 89,608 parameters on both sides), so both sides
evaluate the same network at the same batch sizes. The optional ``resnet`` row keeps the
example's ``AZNet`` (``RESNET_CHANNELS`` channels, ``RESNET_BLOCKS`` residual block(s), batch
norm, SAME padding) beside our closest setting, ``conv_layers`` ``CONV_LAYERS`` (VALID padding)
before the MLP; the networks differ there and the table gives each side's parameter count.

**What a move is.** Both sides run ``G x M`` search-and-move slots per call (the *move slots*,
the equal work, and the headline rate). pgx's example restarts a finished game at once
(``auto_reset``), so each of its slots is a move from a live position; ours plays each game once
from the opening and leaves a finished game idle (still searched, vmapped) until the ``M``
steps are over, so it makes fewer moves than slots; *moves played* counts those (positions
before the game's end, ``Positions.alive``), and its rate is given beside. Our worker also times
``alphazero.continuous_self_play`` (``self_play_steps`` = ``M``: an ended game restarts at once,
as pgx's do, and the slots' games carry from call to call as in training), where every slot is
a move: that line is the like-for-like one per move played.

Cores: one side after the other, each alone on the whole machine, one process each whose XLA
thread pool spans all cores (one CPU device: the example's ``pmap`` runs over one device). The
first call (tracing, compiling, one run) is timed apart as start-up; then ``N`` calls with fresh
keys are timed (the ``resnet`` row: a third of them). Order: ours, pgx's, ours again; the ratio
takes the slower of our two rates over pgx's. The two venvs' jax versions differ (ours 0.9.2;
the peers' 0.10.2, which SBX needs), so a fourth run times ours again inside the peers' venv
(our source on its jax, flax and pgx), and its ratio to pgx's is given beside: the part of the
difference that is the jax version's. Measure on a quiet machine.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
import urllib.request
from pathlib import Path
from typing import TypedDict, cast

from bench.machine import peer_result, worker_result

ROOT = Path(__file__).resolve().parent.parent
NAME = "alphazero_pgx"
ENV_ID = "pgx/connect_four"  # ours; pgx's example calls it connect_four
#: The pgx commit whose ``examples/alphazero`` is run: the one pgx's v2.6.0 release (the pgx we
#: pin) was made from (the installed 2.6.0's ``pgx/`` sources are this commit's but for the
#: version string and Shogi's env version); ``examples/alphazero`` last changed in 18799f81.
PGX_COMMIT = "079b2d730e3845c25d49d99e0ccf9a374dd04cb9"
#: The example's files at ``PGX_COMMIT`` and their sha256: a copy that differs is refused.
EXAMPLE_FILES = {
    "train.py": "2116beffdb36dbf0bc255c6f8e725deb6c91a9ebb50412edf620dcd857280c37",
    "network.py": "1dbed283f7ba43decba7d8340a50bed2f40c3ed8c88d205d890228e4ee17e26b",
}
EXAMPLE_URL = "https://raw.githubusercontent.com/sotetsuk/pgx/{commit}/examples/alphazero/{name}"
CACHE = (
    Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    / "rl_jax"
    / f"pgx-alphazero-{PGX_COMMIT}"
)

GAMES = 64  # the Connect Four recipe's num_envs
SIMULATIONS = 32  # the recipe's num_simulations
MAX_MOVES = 42  # a whole Connect Four game at most: the recipe's max_game_length
HIDDEN = (256, 256)  # the recipe's MLP
CALLS = 10
QUICK_GAMES, QUICK_SIMULATIONS, QUICK_CALLS = 16, 16, 10
RESNET_CHANNELS, RESNET_BLOCKS = 64, 1  # AZNet's for the resnet row
CONV_LAYERS = (64, 3, 1, 64, 3, 1)  # ours for the resnet row (docs/learners/alphazero.md)
NETWORKS = ("mlp", "resnet")


class Settings(TypedDict):
    """What both sides are given."""

    games: int
    simulations: int
    max_moves: int
    calls: int
    network: str  # mlp or resnet


class Timing(TypedDict, total=False):
    """One side's timed run, as its JSON line gives it."""

    network: str
    params: int
    games: int
    simulations: int
    max_moves: int
    calls: int
    move_slots: int
    moves_played: int
    seconds: float
    slots_per_s: float
    moves_per_s: float
    startup_s: float
    # ours only: continuous self-play (self_play_steps = max_moves) timed the same way
    continuous_moves_played: int
    continuous_seconds: float
    continuous_slots_per_s: float
    continuous_moves_per_s: float
    continuous_startup_s: float
    devices: int
    cores: int
    jax: str
    pgx: str
    mctx: str
    haiku: str
    train_py_sha256: str
    load: float


class Row(TypedDict):
    """One network's runs: ours, pgx's example, ours again, ours on the peers' jax."""

    settings: Settings
    ours: Timing
    peer: Timing
    ours_again: Timing
    ours_peer_jax: Timing


class ExampleUnavailable(RuntimeError):
    """pgx's example could not be had at ``PGX_COMMIT`` (no copy, no network, a wrong digest)."""


# ---- pgx's example file --------------------------------------------------------------------
def digest(path: Path) -> str:
    """A file's sha256, hex."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def check_example(directory: Path) -> Path:
    """``directory`` if it holds ``EXAMPLE_FILES`` with their digests; else ExampleUnavailable."""
    for name, expected in EXAMPLE_FILES.items():
        path = directory / name
        if not path.is_file():
            raise ExampleUnavailable(f"{path} is missing")
        if digest(path) != expected:
            raise ExampleUnavailable(
                f"{path} is not pgx's examples/alphazero/{name} at {PGX_COMMIT[:8]} "
                f"(sha256 {digest(path)}, expected {expected})"
            )
    return directory


def example_dir(given: Path | None = None) -> Path:
    """Where pgx's example is: ``given`` (``--pgx-example``), else ``CACHE``, downloaded there
    from GitHub at ``PGX_COMMIT`` on first use; either way its files' digests are checked."""
    if given is not None:
        return check_example(given)
    missing = [n for n in EXAMPLE_FILES if not (CACHE / n).is_file()]
    if missing:
        CACHE.mkdir(parents=True, exist_ok=True)
        for name in missing:
            url = EXAMPLE_URL.format(commit=PGX_COMMIT, name=name)
            try:
                with urllib.request.urlopen(url, timeout=30) as response:
                    text = response.read()
            except OSError as error:
                raise ExampleUnavailable(
                    f"could not download {url} ({error}); put the example's train.py and "
                    f"network.py at {PGX_COMMIT[:8]} in {CACHE} (e.g. `git -C PGX_CLONE show "
                    f"{PGX_COMMIT}:examples/alphazero/{name}`) or pass --pgx-example DIR"
                ) from error
            partial = CACHE / f"{name}.part"
            partial.write_bytes(text)
            partial.replace(CACHE / name)
    return check_example(CACHE)


# ---- ours (a child process: its own JAX, one device over all cores) -------------------------
def our_config(settings: Settings) -> object:
    """The Connect Four recipe's config at ``settings`` (the ``resnet`` row: ``CONV_LAYERS``),
    playing whole games as pgx's example does (``_ours_continuous`` times the recipe's
    continuous self-play)."""
    import dataclasses

    from rl_jax.agents import alphazero

    config = alphazero.default_config(ENV_ID)
    return dataclasses.replace(
        config,
        num_envs=settings["games"],
        num_simulations=settings["simulations"],
        max_game_length=settings["max_moves"],
        conv_layers=CONV_LAYERS if settings["network"] == "resnet" else (),
        self_play_steps=0,
    )


def ours(settings: Settings) -> Timing:
    """Time ``settings['calls']`` compiled calls of ``alphazero.self_play``, after one call
    timed apart as start-up (tracing, compiling, one run)."""
    import jax
    import jax.numpy as jnp
    import mctx
    import pgx

    from rl_jax.agents import alphazero

    start = time.perf_counter()
    config = cast(alphazero.Config, our_config(settings))
    hparams = alphazero.default_hyperparams(ENV_ID)
    game = config.make_game()
    obs = jax.vmap(game.init)(jax.random.split(jax.random.key(0), 2)).observation
    net_params = alphazero.make_network(config).init(jax.random.key(0), obs[:1])
    params = sum(x.size for x in jax.tree.leaves(net_params))
    program = jax.jit(alphazero.self_play, static_argnums=2)
    keys = jax.random.split(jax.random.key(1), settings["calls"] + 1)
    jax.block_until_ready(program(net_params, keys[0], config, hparams))
    startup = time.perf_counter() - start
    played = jnp.zeros((), jnp.float32)
    start = time.perf_counter()
    for key in keys[1:]:
        positions = program(net_params, key, config, hparams)
        played = played + jnp.sum(positions.alive)
    moves = int(jax.block_until_ready(played))
    seconds = time.perf_counter() - start
    slots = settings["calls"] * config.num_envs * config.max_game_length
    continuous = _ours_continuous(net_params, config, hparams, settings["calls"])
    return {
        "network": settings["network"],
        "params": int(params),
        "games": config.num_envs,
        "simulations": config.num_simulations,
        "max_moves": config.max_game_length,
        "calls": settings["calls"],
        "move_slots": slots,
        "moves_played": moves,
        "seconds": round(seconds, 3),
        "slots_per_s": round(slots / seconds, 1),
        "moves_per_s": round(moves / seconds, 1),
        "startup_s": round(startup, 3),
        **continuous,
        "devices": jax.device_count(),
        "cores": len(os.sched_getaffinity(0)),
        "jax": jax.__version__,
        "pgx": pgx.__version__,
        "mctx": getattr(mctx, "__version__", "?"),
        "load": round(os.getloadavg()[0], 2),
    }


def _ours_continuous(
    net_params: object, config: object, hparams: object, calls: int
) -> dict[str, float]:
    """Our continuous self-play (``self_play_steps`` = the whole-game steps: an ended game
    restarts at once, as pgx's example does) timed the same way, the slots' games carried from
    call to call as in training: ``continuous_*`` fields of the timing (every slot a move)."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    from rl_jax.agents import alphazero

    start = time.perf_counter()
    base = cast(alphazero.Config, config)
    # self-play never touches the replay, but the config asks it to hold what one iteration of
    # continuous self-play can store
    steps = base.max_game_length
    config = dataclasses.replace(
        base,
        self_play_steps=steps,
        buffer_size=max(base.buffer_size, base.num_envs * (2 * steps - 1)),
    )
    program = jax.jit(alphazero.continuous_self_play, static_argnums=3)
    keys = jax.random.split(jax.random.key(2), calls + 2)
    states = alphazero.games_init(keys[0], config).states
    states, _ = jax.block_until_ready(program(net_params, states, keys[1], config, hparams))
    startup = time.perf_counter() - start
    played = jnp.zeros((), jnp.float32)
    start = time.perf_counter()
    for key in keys[2:]:
        states, positions = program(net_params, states, key, config, hparams)
        played = played + jnp.sum(positions.alive)
    moves = int(jax.block_until_ready(played))
    seconds = time.perf_counter() - start
    return {
        "continuous_moves_played": moves,
        "continuous_seconds": round(seconds, 3),
        "continuous_slots_per_s": round(calls * base.num_envs * base.max_game_length / seconds, 1),
        "continuous_moves_per_s": round(moves / seconds, 1),
        "continuous_startup_s": round(startup, 3),
    }


def _ours_child(settings: Settings, python: str = sys.executable) -> Timing:
    command = [python, "-m", f"bench.bench_{NAME}", "--worker", json.dumps(settings)]
    # one device over all cores: no XLA_FLAGS inherited
    return cast(Timing, worker_result(command, "our self-play worker", {"XLA_FLAGS": None}))


# ---- pgx's example (the peers' venv) ---------------------------------------------------------
def peer_command(python: Path, directory: Path, settings: Settings) -> list[str]:
    """The command line of ``bench/pgx_alphazero.py`` for ``settings``."""
    command = [
        str(python),
        str(ROOT / "bench" / "pgx_alphazero.py"),
        "--example-dir",
        str(directory),
        "--games",
        str(settings["games"]),
        "--simulations",
        str(settings["simulations"]),
        "--max-moves",
        str(settings["max_moves"]),
        "--calls",
        str(settings["calls"]),
        "--network",
        settings["network"],
        "--hidden",
        ",".join(str(w) for w in HIDDEN),
    ]
    if settings["network"] == "resnet":
        command += ["--channels", str(RESNET_CHANNELS), "--blocks", str(RESNET_BLOCKS)]
    return command


def _peer(python: Path, directory: Path, settings: Settings) -> Timing:
    # the example sets its own devices: no XLA_FLAGS inherited
    command = peer_command(python, directory, settings)
    return cast(Timing, peer_result(command, "pgx's AlphaZero example", {"XLA_FLAGS": None}))


# ---- the driver and its table ----------------------------------------------------------------
def measure(python: Path, directory: Path, settings: Settings) -> Row:
    """Ours, pgx's example, ours again (module docstring); then ours in the peers' venv, on
    the example's jax, which tells a jax version's part in the ratio from ours."""
    first = _ours_child(settings)
    peer = _peer(python, directory, settings)
    again = _ours_child(settings)
    same_jax = _ours_child(settings, str(python))
    return {
        "settings": settings,
        "ours": first,
        "peer": peer,
        "ours_again": again,
        "ours_peer_jax": same_jax,
    }


def ratio(row: Row, rate: str = "slots_per_s") -> float:
    """The slower of our two rates over pgx's: its wall-clock over ours for the same slots
    (``rate`` ``moves_per_s``: per move played)."""
    ours, again, peer = (cast(dict[str, float], row[k]) for k in ("ours", "ours_again", "peer"))
    return min(ours[rate], again[rate]) / peer[rate]


def continuous_ratio(row: Row) -> float:
    """The slower of our two continuous self-play runs over pgx's example, per move played
    (every slot is a move on both sides)."""
    ours = min(row["ours"]["continuous_moves_per_s"], row["ours_again"]["continuous_moves_per_s"])
    return ours / row["peer"]["moves_per_s"]


def same_jax_ratio(row: Row) -> float:
    """Ours in the peers' venv (the example's jax) over pgx's, per move slot."""
    return row["ours_peer_jax"]["slots_per_s"] / row["peer"]["slots_per_s"]


def continuous(timing: Timing) -> Timing:
    """Our timing's continuous self-play fields as a timing of their own (every slot a move)."""
    fields = ("moves_played", "seconds", "slots_per_s", "moves_per_s", "startup_s")
    return cast(Timing, {**timing, **{f: timing[f"continuous_{f}"] for f in fields}})  # type: ignore[literal-required]


def table(rows: list[Row]) -> list[str]:
    """Markdown: one line per timed run, then each network's ratios."""
    lines = [
        "| network | program | params | move slots timed | moves played | start-up s | "
        "timed s | move slots/s | moves played/s | load |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]

    def line(network: str, label: str, r: Timing) -> str:
        return (
            f"| {network} | {label} | {r['params']:,} | {r['move_slots']:,} | "
            f"{r['moves_played']:,} | {r['startup_s']:.1f} | {r['seconds']:.2f} | "
            f"{r['slots_per_s']:,.0f} | {r['moves_per_s']:,.0f} | {r['load']:.1f} |"
        )

    for row in rows:
        ours, peer, again = row["ours"], row["peer"], row["ours_again"]
        if row["settings"]["network"] == "mlp":
            network = "MLP " + " x ".join(str(w) for w in HIDDEN)
            theirs = "pgx example `selfplay`, haiku MLP"
            mine = "ours `self_play`"
        else:
            network = "conv / ResNet"
            theirs = f"pgx example `selfplay`, AZNet {RESNET_CHANNELS} ch x {RESNET_BLOCKS} block"
            mine = f"ours `self_play`, conv_layers {','.join(map(str, CONV_LAYERS))} + MLP"
        lines.append(line(network, f"{mine}, jax {ours['jax']}", ours))
        if "continuous_slots_per_s" in ours:
            lines.append(
                line(
                    network,
                    f"ours `continuous_self_play` (`self_play_steps` {ours['max_moves']})",
                    continuous(ours),
                )
            )
        lines.append(line(network, f"{theirs}, jax {peer['jax']}, haiku {peer['haiku']}", peer))
        lines.append(line(network, f"{mine} again", again))
        same = row["ours_peer_jax"]
        lines.append(line(network, f"{mine}, in the peers' venv, jax {same['jax']}", same))
    lines.append("")
    for row in rows:
        s = row["settings"]
        lines.append(
            f"- **{s['network']}** ({s['games']} games x {s['max_moves']} steps x "
            f"{s['simulations']} simulations, {s['calls']} timed calls): move slots/s, ours "
            f"(the slower of two) / pgx's example = **{ratio(row):.2f}x**; per move played "
            f"{ratio(row, 'moves_per_s'):.2f}x (ours leaves finished games idle, pgx's restarts "
            f"them); ours on the example's jax / pgx's example, move slots/s: "
            f"{same_jax_ratio(row):.2f}x."
            + (
                f" With `self_play_steps` (ended games restarted, as pgx's are), per move "
                f"played: **{continuous_ratio(row):.2f}x**."
                if "continuous_moves_per_s" in row["ours"]
                else ""
            )
        )
    return lines


def section(settings: Settings, networks: list[str], given: Path | None, command: str) -> str:
    """The Markdown section: what it measures, the command, the machine line, the table (or why
    nothing was measured)."""
    from bench import peers
    from bench.machine import describe

    lines = [
        "## AlphaZero self-play: ours beside pgx's AlphaZero example at equal settings",
        "",
        "Self-play move slots per second on Connect Four: `alphazero.self_play` beside the "
        f"`selfplay` of pgx's `examples/alphazero/train.py` (commit {PGX_COMMIT[:8]}, pgx "
        "2.6.0's), the same games, steps, simulations and Gumbel MuZero search; the `mlp` row "
        "with the example's network replaced by a haiku MLP of our widths "
        "(`bench/bench_alphazero_pgx.py` says how each side is run and counted).",
        "",
        f"`{command}`",
        "",
        describe(),
        "",
    ]
    try:
        python = peers.ensure()
        directory = example_dir(given)
    except (peers.PeersUnavailable, ExampleUnavailable) as error:
        return "\n".join([*lines, f"not measured: {error}", ""])
    started = time.strftime("%H:%M")
    rows = [measure(python, directory, row_settings(settings, n)) for n in networks]
    raw = Path(__file__).resolve().parent / "results"
    raw.mkdir(exist_ok=True)
    (raw / f"{NAME}.json").write_text(json.dumps(rows, indent=1))
    lines += table(rows)
    lines.append(f"\nStarted {started}, finished {time.strftime('%H:%M')} (UTC).")
    return "\n".join([*lines, ""])


def row_settings(settings: Settings, network: str) -> Settings:
    """``settings`` for one row: the ``resnet`` row times a third of the calls (at least one),
    as pgx's ResNet costs several times the MLP per position."""
    calls = max(1, settings["calls"] // 3) if network == "resnet" else settings["calls"]
    return {**settings, "network": network, "calls": calls}


def default_settings(quick: bool) -> Settings:
    """The full run's sizes (the recipe's 64 games, 32 simulations, ``CALLS`` timed calls) or
    ``--quick``'s (16 games, 16 simulations, ``QUICK_CALLS`` calls)."""
    if quick:
        return Settings(
            games=QUICK_GAMES,
            simulations=QUICK_SIMULATIONS,
            max_moves=MAX_MOVES,
            calls=QUICK_CALLS,
            network="mlp",
        )
    return Settings(
        games=GAMES, simulations=SIMULATIONS, max_moves=MAX_MOVES, calls=CALLS, network="mlp"
    )


def run(quick: bool = False) -> str:
    """``python -m bench alphazero_pgx [--quick]``: the mlp and resnet rows at the recipe's
    sizes; or the mlp row alone, smaller."""
    networks = ["mlp"] if quick else list(NETWORKS)
    command = f"python -m bench {NAME}" + (" --quick" if quick else "")
    return section(default_settings(quick), networks, None, command)


def parse_networks(text: str) -> list[str]:
    """``mlp,resnet`` -> ``["mlp", "resnet"]``; an unknown name is a ValueError."""
    names = [n for n in text.split(",") if n]
    unknown = sorted(set(names) - set(NETWORKS))
    if unknown or not names:
        raise ValueError(f"--network takes names from {NETWORKS}, got {text!r}")
    return names


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.bench_alphazero_pgx [--games G] [--simulations S] [--calls N]
    [--network mlp,resnet] [--pgx-example DIR] [--quick]``."""
    parser = argparse.ArgumentParser(
        prog=f"python -m bench.bench_{NAME}",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--quick", action="store_true", help="the smoke run's sizes")
    parser.add_argument("--games", type=int, help=f"games per call (default {GAMES})")
    parser.add_argument("--simulations", type=int, help=f"simulations (default {SIMULATIONS})")
    parser.add_argument("--max-moves", type=int, help=f"steps per call (default {MAX_MOVES})")
    parser.add_argument("--calls", type=int, help=f"timed calls (default {CALLS})")
    parser.add_argument("--network", help="mlp, resnet or both, comma-separated")
    parser.add_argument(
        "--pgx-example",
        type=Path,
        help="a directory with the example's train.py and network.py (digests are checked)",
    )
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    from rl_jax.training.jax_setup import configure

    configure()
    if args.worker:
        print("RESULT " + json.dumps(ours(cast(Settings, json.loads(args.worker)))), flush=True)
        return 0
    settings = default_settings(args.quick)
    for name in ("games", "simulations", "max_moves", "calls"):
        value = getattr(args, name)
        if value is not None:
            if value < 1:
                print(f"error: --{name.replace('_', '-')} must be >= 1", file=sys.stderr)
                return 2
            settings[name] = value
    try:
        default = "mlp" if args.quick else ",".join(NETWORKS)
        networks = parse_networks(args.network or default)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    command = " ".join([f"python -m bench.bench_{NAME}", *(argv or sys.argv[1:])]).strip()
    text = section(settings, networks, args.pgx_example, command)
    print(text, flush=True)
    (Path(__file__).resolve().parent / "results" / f"{NAME}.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
