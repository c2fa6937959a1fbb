"""``python -m rl_jax.run.match RUN_DIR``: each seed's trained search against a reference player.

A board-game run (a learner that moves from its game's own positions, ``position_policy``:
AlphaZero on ``pgx/tic_tac_toe`` or ``pgx/connect_four``) evaluates itself during training on a
few games per chunk. This plays, for every seed of the run (``--seed``: one), the policy kept in
``best/`` (``--latest``: the latest checkpoint's) as its search, ``--games`` games against
``--opponent`` on both colours, each side opening half of them, with
``rl_jax.envs.games.match.play_match`` seeded by ``--key``: the same games' randomness for
every seed. It prints per seed the win/draw/loss table by colour, then a summary over the
seeds: the win, draw and loss rates, the score (a win 1, a draw 1/2) and the Elo difference
with its 95% interval (``rl_jax.envs.games.elo``). ``--json PATH`` writes the same numbers.

The opponents (``rl_jax.envs.games.opponents``): ``random`` (a uniformly random legal move),
``mcts`` (pure MCTS with random rollouts, ``--opponent-simulations`` per move) and ``minimax``
(exact, tic-tac-toe only). ``--simulations`` plays the search with that many simulations
instead of the run's ``num_simulations``: the learner's ``position_policy`` given the run's
config with that field replaced.

    python -m rl_jax.run.match runs/results/alphazero-tictactoe-vs-minimax --opponent minimax
    python -m rl_jax.run.match runs/ttt --opponent mcts --opponent-simulations 1000 --games 100
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import jax
import pgx

from rl_jax.envs.games import opponents
from rl_jax.envs.games.elo import EloEstimate, elo_estimate
from rl_jax.envs.games.match import MatchResult, Player, play_match
from rl_jax.errors import OneLineParser, UsageError, exit_now, guard, parse_int, positive_int
from rl_jax.run.learners import for_run
from rl_jax.run.policy import (
    LoadedPolicy,
    add_run_choice,
    command_line_env,
    command_line_learner,
)
from rl_jax.run.run_dir import read_run_record
from rl_jax.training.algorithm import Algorithm, hooks
from rl_jax.training.jax_setup import configure

#: The field of a learner's config that ``--simulations`` replaces.
SIMULATIONS_FIELD = "num_simulations"
DEFAULT_OPPONENT_SIMULATIONS = 1000


@dataclasses.dataclass(frozen=True)
class SeedMatch:
    """One seed's games: what was loaded (``which``: "best", or "latest" also where a seed
    kept no best policy), the search's simulations, and the games from its side."""

    seed: int
    which: str
    step: int  # env step of the policy played
    eval_return: float | None  # the run's own evaluation of it
    simulations: int | None  # the search's (None: the learner's config has no such field)
    result: MatchResult  # the search is the first player

    def heading(self, opponent: str) -> str:
        """The line above the seed's table: the policy, its search and the match."""
        value = "" if self.eval_return is None else f", eval return {self.eval_return:.2f}"
        search = "" if self.simulations is None else f" with {self.simulations} simulations"
        return (
            f"seed {self.seed}: its {self.which} policy (step {self.step:,}{value}), the "
            f"search{search}, against {opponent}, {len(self.result.outcomes)} games"
        )


@dataclasses.dataclass(frozen=True)
class RunMatch:
    """The settings of a ``match_run`` and its games, one ``SeedMatch`` per seed."""

    run_dir: Path
    env_id: str
    config_index: int
    opponent: str
    opponent_simulations: int
    games: int  # per seed
    key: int
    which: str  # what was asked for: "best" or "latest"
    simulations: int | None  # the --simulations override; None: the run's own
    seeds: list[SeedMatch]

    def opponent_name(self) -> str:
        """The opponent as the tables name it: ``"minimax"``, ``"mcts 1000"``."""
        return opponents.describe(self.opponent, self.opponent_simulations)

    def total(self) -> tuple[int, int, int]:
        """``(wins, draws, losses)`` of the search over all seeds' games."""
        counts = [seed.result.counts() for seed in self.seeds]
        wins, draws, losses = (sum(column) for column in zip(*counts, strict=True))
        return wins, draws, losses

    def summary(self) -> str:
        """One row per seed and one for all their games: win, draw and loss rates, the score
        and the Elo difference with its 95% interval."""
        lines = [
            f"the search of each seed against {self.opponent_name()}, {self.games} games each",
            "",
            "  seed  policy        step  wins %  draws %  losses %  score  Elo, 95% interval",
            "  ----  ------  ----------  ------  -------  --------  -----  -----------------",
        ]
        for seed in self.seeds:
            start = f"  {seed.seed:4d}  {seed.which:6s}  {seed.step:10,d}"
            lines.append(start + _rates(*seed.result.counts()))
        if len(self.seeds) > 1:
            lines.append(f"  {'all':>4s}  {'':6s}  {'':10s}" + _rates(*self.total()))
        return "\n".join(lines)

    def as_dict(self) -> dict[str, object]:
        """The settings and the numbers of ``summary`` (per seed also by colour), as JSON
        data: an Elo bound that a score of 0 or 1 makes infinite is null."""
        return {
            "run_dir": str(self.run_dir),
            "env_id": self.env_id,
            "config": self.config_index,
            "opponent": self.opponent,
            "opponent_simulations": (
                self.opponent_simulations if self.opponent == "mcts" else None
            ),
            "games": self.games,
            "key": self.key,
            "which": self.which,
            "simulations": self.simulations,
            "seeds": [_seed_dict(seed) for seed in self.seeds],
            "total": _counts_dict(*self.total()),
        }


def _rates(wins: int, draws: int, losses: int) -> str:
    """The summary's columns after the policy: rates in %, the score, the Elo interval."""
    games = wins + draws + losses
    elo = elo_estimate(wins, draws, losses)
    return (
        f"  {100 * wins / games:6.1f}  {100 * draws / games:7.1f}  {100 * losses / games:8.1f}"
        f"  {elo.score:5.3f}  {elo.difference:+.0f} [{elo.low:+.0f}, {elo.high:+.0f}]"
    )


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


def _counts_dict(wins: int, draws: int, losses: int) -> dict[str, object]:
    """Counts, rates in %, the score and the Elo difference with its 95% interval."""
    games = wins + draws + losses
    elo: EloEstimate = elo_estimate(wins, draws, losses)
    return {
        "games": games,
        "wins": wins,
        "draws": draws,
        "losses": losses,
        "wins_pct": 100 * wins / games,
        "draws_pct": 100 * draws / games,
        "losses_pct": 100 * losses / games,
        "score": elo.score,
        "elo": _finite(elo.difference),
        "elo_low": _finite(elo.low),
        "elo_high": _finite(elo.high),
    }


def _seed_dict(seed: SeedMatch) -> dict[str, object]:
    result = seed.result
    return {
        "seed": seed.seed,
        "which": seed.which,
        "step": seed.step,
        "eval_return": seed.eval_return,
        "simulations": seed.simulations,
        **_counts_dict(*result.counts()),
        "moving_first": _counts_dict(*result.counts(result.first_moved)),
        "moving_second": _counts_dict(*result.counts(~result.first_moved)),
    }


def search_player(
    loaded: LoadedPolicy, simulations: int | None = None
) -> tuple[Player, int | None]:
    """The loaded learner's ``position_policy`` (its trained search as a ``(state, key) ->
    action`` player) and the simulations it searches with; ``simulations`` replaces the
    config's ``num_simulations`` first. ``UsageError`` for a learner without a position policy
    or without that field."""
    config = loaded.config
    name = loaded.algorithm.name
    if simulations is not None:
        if SIMULATIONS_FIELD not in {field.name for field in dataclasses.fields(config)}:
            raise UsageError(f"--simulations: {name}'s config has no {SIMULATIONS_FIELD} field")
        try:
            config = dataclasses.replace(config, **{SIMULATIONS_FIELD: simulations})
        except (TypeError, ValueError) as error:
            raise UsageError(f"--simulations {simulations}: {error}") from None
    player = hooks(loaded.algorithm).position_policy(loaded.state, config)
    if player is None:
        raise UsageError(_no_board_game(loaded.run_dir, name, loaded.env_id))
    searched = getattr(config, SIMULATIONS_FIELD, None)
    return player, None if searched is None else int(searched)


def _no_board_game(run_dir: Path, learner: str, env_id: str) -> str:
    return (
        f"{run_dir} is a run of {learner} on {env_id}, no board-game run: a match plays a "
        "learner that moves from its own game's positions (position_policy: AlphaZero on "
        "pgx/tic_tac_toe or pgx/connect_four)"
    )


def pgx_game(env_id: str) -> pgx.Env:
    """The pgx game of a board-game run's env id: ``pgx.make(GAME)`` for ``pgx/GAME``."""
    try:
        return pgx.make(env_id.rpartition("/")[2])
    except ValueError as error:
        raise UsageError(f"{env_id} is no pgx game to play a match on: {error}") from None


def match_run(
    run_dir: str | Path,
    opponent: str = "mcts",
    opponent_simulations: int = DEFAULT_OPPONENT_SIMULATIONS,
    games: int = 100,
    seeds: list[int] | None = None,
    config_index: int | None = None,
    latest: bool = False,
    key: int = 0,
    simulations: int | None = None,
    algorithm: str | Algorithm | None = None,
    env: str | None = None,
    on_seed: Callable[[SeedMatch, RunMatch], None] | None = None,
) -> RunMatch:
    """``games`` games of each seed's search (every seed of the run, or ``seeds``) against
    ``opponent``, on the key ``jax.random.key(key)`` for every seed; ``on_seed`` is called
    after each seed's match with it and the settings. ``latest``: the latest checkpoint's
    policies, not the best; ``algorithm`` and ``env`` name a run's learner and env of the
    user's own, as ``--algo`` and ``--env`` do."""
    if games < 1 or games % 2:
        raise UsageError(f"--games must be even and positive (each side opens half), got {games}")
    run_dir = Path(run_dir)
    # what the run plays and against whom, checked before any policy is restored
    record = read_run_record(run_dir)
    learner = for_run(record, run_dir, algorithm, how="algorithm=")
    env_id = record["identity"]["env_id"]
    if not hooks(learner).owns_env(env_id):
        raise UsageError(_no_board_game(run_dir, learner.name, env_id))
    game = pgx_game(env_id)
    try:
        other = opponents.opponent_player(opponent, game, opponent_simulations)
    except ValueError as error:
        raise UsageError(f"--opponent: {error}") from None
    which = "latest" if latest else "best"
    chosen = None if seeds is None else seeds[0]
    first = LoadedPolicy(run_dir, chosen, config_index, which, learner, env)
    report = RunMatch(
        run_dir,
        first.env_id,
        first.config_index,
        opponent,
        opponent_simulations,
        games,
        key,
        which,
        simulations,
        [],
    )
    for seed in first.seeds if seeds is None else seeds:
        loaded = first
        if seed != first.seed:
            loaded = LoadedPolicy(run_dir, seed, first.config_index, which, learner, first.env_id)
        player, searched = search_player(loaded, simulations)
        result = play_match(game, player, other, jax.random.key(key), games)
        played = SeedMatch(seed, loaded.which, loaded.step, loaded.eval_return, searched, result)
        report.seeds.append(played)
        if on_seed is not None:
            on_seed(played, report)
    return report


def _print_seed(played: SeedMatch, report: RunMatch) -> None:
    print(played.heading(report.opponent_name()))
    print(played.result.table())
    print()


def main(argv: list[str] | None = None, prog: str = "python -m rl_jax.run.match") -> int:
    """``python -m rl_jax.run.match RUN_DIR``: play each seed's search against an opponent and
    print the tables. Returns the exit status. ``prog`` is the command named in ``--help`` and
    errors (``rl-jax match``)."""
    parser = OneLineParser(prog=prog, description=__doc__.split("\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run directory (holds config.json)")
    parser.add_argument(
        "--opponent",
        choices=opponents.OPPONENTS,
        default="mcts",
        help="random, mcts (pure MCTS with random rollouts) or minimax (exact, tic-tac-toe "
        "only) (default: mcts)",
    )
    parser.add_argument(
        "--opponent-simulations",
        type=positive_int,
        default=DEFAULT_OPPONENT_SIMULATIONS,
        help=f"simulations per move of the mcts opponent (default: {DEFAULT_OPPONENT_SIMULATIONS})",
    )
    parser.add_argument(
        "--games",
        type=positive_int,
        default=100,
        help="games per seed, even: each side opens half of them (default: 100)",
    )
    add_run_choice(parser, "only this seed (default: every seed)")
    parser.add_argument(
        "--latest",
        action="store_true",
        help="play each seed's latest checkpoint (default: its best evaluated policy)",
    )
    parser.add_argument(
        "--key", type=parse_int, default=0, help="the games' random key (default: 0)"
    )
    parser.add_argument(
        "--simulations",
        type=positive_int,
        default=None,
        help="the search's simulations per move (default: the run's num_simulations)",
    )
    parser.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the numbers here"
    )
    args = parser.parse_args(argv)

    def run() -> int:
        configure()
        learner = command_line_learner(args.run_dir, args.algo)  # first: it may register the env
        env_id = command_line_env(args.run_dir, args.env, learner)
        report = match_run(
            args.run_dir,
            args.opponent,
            args.opponent_simulations,
            args.games,
            None if args.seed is None else [args.seed],
            args.config_index,
            args.latest,
            args.key,
            args.simulations,
            learner,
            env_id,
            on_seed=_print_seed,
        )
        print(report.summary())
        if args.json is not None:
            try:
                args.json.write_text(json.dumps(report.as_dict(), indent=2) + "\n")
            except OSError as error:
                raise UsageError(f"--json: cannot write {args.json}: {error.strerror}") from None
            print(f"\nwrote {args.json}")
        return 0

    return guard(run)


if __name__ == "__main__":
    # Run the imported module's main, not this __main__ copy, so that its exception classes are
    # the ones the guard knows.
    from rl_jax.run.match import main as module_main

    exit_now(module_main())
