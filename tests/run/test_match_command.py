"""``rl-jax match`` (``python -m rl_jax.run.match``): each seed's search of a board-game run
against a reference player. Its numbers are those of ``play_match`` of the learner's own
``position_policy`` against that player on the same key (the command adds nothing to the games);
the JSON holds them with the settings; ``--seed``, ``--latest`` and ``--simulations`` choose what
plays; every refusal is one error line and a non-zero status. Each match of a new player
compiles (seconds): the file plays one seed's match through the command and the same match
directly, and checks every seed's numbers on recorded matches.

The run is the tiny AlphaZero run of tests/run/conftest.py (``trained``), shared with
test_board_game_runs.py."""

import dataclasses
import json
import math

import jax
import numpy as np
import pgx
import pytest
from run_helpers import fake_run
from tiny_board_run import GAME, SEEDS, TINY

from rl_jax import __main__ as command
from rl_jax.envs.games.elo import elo_estimate
from rl_jax.envs.games.match import MatchResult, play_match
from rl_jax.envs.games.tic_tac_toe_minimax import minimax_player
from rl_jax.run import match
from rl_jax.run.policy import LoadedPolicy
from rl_jax.run.run_dir import CONFIG_FILE, identity_hash
from rl_jax.training.algorithm import hooks


def _direct(run_dir, seed, which, opponent, key, games, simulations=None):
    """``play_match`` of the seed's ``position_policy`` (its config's simulations replaced
    when given) against ``opponent``: what the command's numbers must equal."""
    loaded = LoadedPolicy(run_dir, seed, which=which)
    config = loaded.config
    if simulations is not None:
        config = dataclasses.replace(config, num_simulations=simulations)
    player = hooks(loaded.algorithm).position_policy(loaded.state, config)
    env = pgx.make(GAME.removeprefix("pgx/"))
    return loaded, play_match(env, player, opponent, jax.random.key(key), games)


def _check_counts(entry, wins, draws, losses):
    """One ``_counts_dict`` of the JSON against the counts it was made from."""
    games = wins + draws + losses
    elo = elo_estimate(wins, draws, losses)
    assert entry == {
        "games": games,
        "wins": wins,
        "draws": draws,
        "losses": losses,
        "wins_pct": 100 * wins / games,
        "draws_pct": 100 * draws / games,
        "losses_pct": 100 * losses / games,
        "score": elo.score,
        "elo": elo.difference if math.isfinite(elo.difference) else None,
        "elo_low": elo.low if math.isfinite(elo.low) else None,
        "elo_high": elo.high if math.isfinite(elo.high) else None,
    }


def test_a_seeds_numbers_are_those_of_a_direct_match(trained, tmp_path, capsys):
    """``--seed 1 --latest --simulations 2`` against minimax: the numbers printed and written
    are those of ``play_match`` of a player built here from that seed's latest checkpoint,
    with that many simulations, on the same key."""
    out = tmp_path / "match.json"
    run_dir = trained.run_dir
    argv = [str(run_dir), "--seed", "1", "--latest", "--simulations", "2"]
    argv += ["--opponent", "minimax", "--games", "4", "--key", "3", "--json", str(out)]
    assert match.main(argv) == 0
    printed = capsys.readouterr().out
    data = json.loads(out.read_text())
    assert {key: value for key, value in data.items() if key not in ("seeds", "total")} == {
        "run_dir": str(run_dir),
        "env_id": GAME,
        "config": 0,
        "opponent": "minimax",
        "opponent_simulations": None,  # only mcts has any
        "games": 4,
        "key": 3,
        "which": "latest",
        "simulations": 2,
    }
    [entry] = data["seeds"]
    loaded, direct = _direct(run_dir, 1, "latest", minimax_player, 3, 4, simulations=2)
    assert (entry["seed"], entry["which"], entry["step"]) == (1, "latest", loaded.step)
    assert (entry["simulations"], entry["eval_return"]) == (2, loaded.eval_return)
    assert (entry["wins"], entry["draws"], entry["losses"]) == direct.counts()
    _check_counts({key: entry[key] for key in data["total"]}, *direct.counts())
    _check_counts(entry["moving_first"], *direct.counts(direct.first_moved))
    _check_counts(entry["moving_second"], *direct.counts(~direct.first_moved))
    _check_counts(data["total"], *direct.counts())
    heading = f"seed 1: its latest policy (step {loaded.step:,}"
    assert f"{heading}" in printed and "seed 0" not in printed
    assert "the search with 2 simulations, against minimax, 4 games" in printed
    assert direct.table() in printed  # the seed's table, as play_match gives it
    assert "     1  latest" in printed and " all " not in printed  # one seed: no total row


#: What the recording ``play_match`` below returns for the n-th seed: outcomes of 4 games.
OUTCOMES = ([1, 0, -1, 0], [1, 1, 0, -1])


def test_every_seed_by_default_and_the_json_of_its_numbers(trained, tmp_path, capsys, monkeypatch):
    """By default every seed plays its best policy with the run's ``num_simulations``, all on
    ``jax.random.key(--key)``; what the command prints and writes are the numbers of the matches
    it was given. The games are not played here (the test above plays them): ``play_match``
    records its calls and returns a different result for each seed."""
    played = []

    def record(env, first, second, key, num_games):
        played.append((env.id, key, num_games))
        outcomes = np.array(OUTCOMES[len(played) - 1])
        return MatchResult(outcomes, np.arange(4) % 2 == 0, np.full(4, 5))

    monkeypatch.setattr(match, "play_match", record)
    out = tmp_path / "all.json"
    argv = ["match", str(trained.run_dir), "--opponent", "mcts", "--opponent-simulations", "50"]
    assert command.main([*argv, "--games", "4", "--key", "7", "--json", str(out)]) == 0
    assert [(game, games) for game, _, games in played] == [("tic_tac_toe", 4)] * SEEDS
    for _, key, _ in played:
        assert np.array_equal(jax.random.key_data(key), jax.random.key_data(jax.random.key(7)))
    data = json.loads(out.read_text())
    assert (data["opponent"], data["opponent_simulations"]) == ("mcts", 50)
    assert (data["which"], data["simulations"], data["key"]) == ("best", None, 7)
    printed = capsys.readouterr().out
    totals = [0, 0, 0]
    for seed, (entry, outcomes) in enumerate(zip(data["seeds"], OUTCOMES, strict=True)):
        loaded = LoadedPolicy(trained.run_dir, seed)
        assert (entry["seed"], entry["which"], entry["step"]) == (seed, "best", loaded.step)
        assert entry["simulations"] == TINY["num_simulations"]
        result = MatchResult(np.array(outcomes), np.arange(4) % 2 == 0, np.full(4, 5))
        _check_counts({key: entry[key] for key in data["total"]}, *result.counts())
        _check_counts(entry["moving_first"], *result.counts(result.first_moved))
        _check_counts(entry["moving_second"], *result.counts(~result.first_moved))
        assert f"seed {seed}: its best policy" in printed and result.table() in printed
        totals = [total + count for total, count in zip(totals, result.counts(), strict=True)]
    _check_counts(data["total"], *totals)
    summary = printed[printed.index("the search of each seed against mcts 50, 4 games each") :]
    rows = [line.split() for line in summary.splitlines()[4:] if line.strip()]
    assert [row[0] for row in rows] == [*map(str, range(SEEDS)), "all", "wrote"]
    assert rows[-2][1:5] == ["37.5", "37.5", "25.0", "0.562"]  # 3 wins, 3 draws, 2 losses
    assert rows[-1] == ["wrote", str(out)]


def _connect_four_record(trained, tmp_path):
    """The record (config.json alone) of a Connect Four run: the refusal of minimax comes
    from the recorded game, before any policy is restored."""
    record = json.loads((trained.run_dir / CONFIG_FILE).read_text())
    identity = record["identity"]
    identity["env_id"] = identity["config"]["env_id"] = "pgx/connect_four"
    record["identity_hash"] = identity_hash(identity)
    run_dir = tmp_path / "connect_four"
    run_dir.mkdir()
    (run_dir / CONFIG_FILE).write_text(json.dumps(record))
    return run_dir


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (("{run}", "--opponent", "alphabeta"), "invalid choice: 'alphabeta'"),
        (("{run}", "--games", "0"), "argument --games: must be >= 1"),
        (("{run}", "--games", "3"), "--games must be even"),
        (("{run}", "--seed", "9"), "--seed 9 is not in this run"),
        (("{tmp}",), "is not a run directory"),
        (("{tmp}/missing",), "no run directory"),
        (("{connect_four}", "--opponent", "minimax"), "minimax opponent plays tic_tac_toe only"),
        (("{fake}", "--algo", "fake_algorithm"), "no board-game run"),
    ],
)
def test_a_refusal_is_one_error_line(trained, tmp_path, capsys, args, expected):
    places = {"run": str(trained.run_dir), "tmp": str(tmp_path)}
    if "{connect_four}" in args:
        places["connect_four"] = str(_connect_four_record(trained, tmp_path))
    if "{fake}" in args:
        places["fake"] = str(fake_run(tmp_path / "fake", total_steps=20))
    argv = [arg.format(**places) for arg in args]
    try:
        status = match.main(argv)
    except SystemExit as exit_:  # argparse's own errors
        status = exit_.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert expected in lines[0] and "Traceback" not in captured.err + captured.out


def test_rl_jax_help_lists_the_command(capsys):
    assert command.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "\n  match " in out and "rl-jax match runs/" in out
