"""A planner of the user's own that owns its env (``examples/afterstate_planner.py``) through the
command line, as docs/own_learner.md uses it: trained on ``pgx/tic_tac_toe`` and resumed, loaded
as a ``GamePolicy`` that plays legal moves, matched against a random player (beaten in more
games after 20 short chunks than by an untrained network) and drawn as a GIF, the learner named
again each time; the run tools that play episodes refuse it in one line, and the planner a game
it does not play; its one-ply action values equal a hand computation on two positions."""

import contextlib
import importlib.util
import io
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pgx
import pytest
from PIL import Image

import rl_jax
from rl_jax.errors import guard
from rl_jax.run import cli, evaluate, match, render
from rl_jax.run.policy import GamePolicy

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "afterstate_planner.py"
BY_FILE = "examples/afterstate_planner.py:learner"  # relative to the repository root, the cwd
CHUNK = 32 * 100  # env steps (moves) per chunk: 32 games x 100 iterations
# One seed, 10 chunks, then resumed to 20: the seed and the margin measured below hold for it.
FLAGS = [
    "--algo", BY_FILE, "--env", "pgx/tic_tac_toe", "--hidden", "32", "--num-eval-games", "8",
    "--seeds", "1", "--log-interval", "0", "--checkpoint-interval", "0",
]  # fmt: skip


def in_process(argv: list[str]) -> tuple[str, str, int]:
    """``experiments/train.py argv`` in this process (faster than a new one): (stdout, stderr,
    status), relative paths from the repository root as for the script."""
    out, err = io.StringIO(), io.StringIO()
    xla_flags, cwd = os.environ.get("XLA_FLAGS"), os.getcwd()
    os.chdir(ROOT)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = guard(lambda: cli.run_experiment(None, None, "", argv))
    finally:
        os.chdir(cwd)
        if xla_flags is None:  # run_experiment sets the device count for a fresh process
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = xla_flags
    return out.getvalue(), err.getvalue(), status


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """10 chunks, then a resume to 20 that names the learner again."""
    out = tmp_path_factory.mktemp("own_planner") / "run"
    first = in_process([*FLAGS, "--total-steps", str(10 * CHUNK), "--out", str(out)])
    assert first[2] == 0 and "Traceback" not in first[1], first[1]
    resume = ["--resume", str(out), "--total-steps", str(20 * CHUNK), "--algo", BY_FILE]
    resumed = in_process(resume)
    assert resumed[2] == 0 and "Traceback" not in resumed[1], resumed[1]
    assert f"resuming from the checkpoint at step {10 * CHUNK:,}" in resumed[0]
    return out


def test_the_run_trains_and_resumes(run_dir):
    record = json.loads((run_dir / "config.json").read_text())
    assert record["identity"]["env_id"] == "pgx/tic_tac_toe"  # kept as given: no registry env
    assert record["learner"] == f"file:{EXAMPLE}:learner"
    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [row["step"] for row in rows] == [CHUNK * n for n in range(1, 21)]
    assert all(-1.0 <= row["eval_return"] <= 1.0 for row in rows)
    assert rows[-1]["updates"] == 20 * 100 and rows[-1]["loss"] > 0.0


def _positions(count: int) -> list[pgx.State]:
    """Positions of random games of tic-tac-toe, none of them over."""
    env, found = pgx.make("tic_tac_toe"), list[pgx.State]()
    step, rng = jax.jit(env.step), np.random.default_rng(3)
    while len(found) < count:
        state = env.init(jax.random.key(len(found)))
        while not bool(state.terminated) and len(found) < count:
            found.append(state)
            state = step(state, int(rng.choice(np.flatnonzero(state.legal_action_mask))))
    return found


def test_its_policy_loads_and_plays_legal_moves(run_dir):
    policy = rl_jax.load_policy(run_dir, algorithm=BY_FILE)
    assert isinstance(policy, GamePolicy) and policy.game == "tic_tac_toe"
    for state in _positions(12):
        legal = np.asarray(state.legal_action_mask)
        assert legal[policy.move(state)]  # the planner, from the position
        assert legal[policy(state.observation, legal)]  # the observation-only fallback


def test_the_match_command_plays_it_and_it_beats_random(run_dir, tmp_path, capsys):
    """100 games against a random player, each side opening half. The search of an untrained
    network already wins 63 to 71 of them (it takes a win in one where it sees one); this run's
    won 84 when this was written, and 76 leaves a margin on both sides."""
    out = tmp_path / "match.json"
    argv = [str(run_dir), "--algo", BY_FILE, "--opponent", "random", "--games", "100"]
    assert match.main([*argv, "--json", str(out)]) == 0
    assert "against random, 100 games" in capsys.readouterr().out
    total = json.loads(out.read_text())["total"]
    assert total["games"] == 100 and total["wins"] >= 76, total


def test_render_draws_its_games(run_dir, tmp_path, capsys):
    gif = tmp_path / "game.gif"
    assert render.main([str(run_dir), "--algo", BY_FILE, "--out", str(gif)]) == 0
    assert "against random: game 1 (first)" in capsys.readouterr().out
    with Image.open(gif) as image:
        assert image.n_frames >= 6  # the opening position and at least five moves


# ---- the one-ply action values by hand ------------------------------------------------------


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("afterstate_planner_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _play(moves: list[int]) -> pgx.State:
    """The position after ``moves`` from the opening, the first one X's."""
    env = pgx.make("tic_tac_toe")
    state, step = env.init(jax.random.key(0)), jax.jit(env.step)
    for move in moves:
        state = step(state, move)
    return state


def _values_and_move(example, params, state, config) -> tuple[np.ndarray, int]:
    """The example's action values of ``state`` and its planner's move there, compiled (a new
    program per call: the network a test stands in is read when it is traced)."""

    def both(params, state):
        player = example.planner(params, config)
        return example.search(params, state, config)[0], player(state, jax.random.key(0))

    values, move = jax.jit(both)(params, state)
    return np.asarray(values), int(move)


def test_a_winning_move_is_worth_one(example):
    """X on 0 and 1, O on 3 and 4, X to move: 2 wins at once, whatever V says of the rest."""
    config = example.Config()
    params = example.network(config).init(jax.random.key(1), jnp.zeros((1, 3, 3, 2)))
    values, move = _values_and_move(example, params, _play([0, 3, 1, 4]), config)
    assert values[2] == 1.0
    assert np.all(np.isneginf(values[[0, 1, 3, 4]]))  # taken squares
    assert np.all(np.abs(values[[5, 6, 7, 8]]) < 1.0)  # -V of positions still open
    assert move == 2


class ThreatValue:
    """A stand-in for V: 1 where the player to move can win at once (a line of three squares
    with two of theirs and one empty), else 0."""

    LINES = ((0, 1, 2), (3, 4, 5), (6, 7, 8), (0, 3, 6), (1, 4, 7), (2, 5, 8), (0, 4, 8), (2, 4, 6))

    def apply(self, params, obs):
        mine, theirs = obs[..., 0].reshape(-1, 9), obs[..., 1].reshape(-1, 9)
        empty = ~(mine | theirs)
        wins = [mine[:, a] & mine[:, b] & empty[:, c] for line in self.LINES for a, b, c in
                (line, line[1:] + line[:1], line[2:] + line[:2])]  # fmt: skip
        return jnp.any(jnp.stack(wins), axis=0).astype(jnp.float32)


def test_every_move_but_the_block_loses(example, monkeypatch):
    """X on 4 and 8, O on 0 and 1, X to move: O wins on 2 next unless X takes it. Under V = can
    the mover win at once: the block is worth -0 (O has no win then), every other move -1."""
    monkeypatch.setattr(example, "network", lambda config: ThreatValue())
    values, move = _values_and_move(example, None, _play([4, 0, 8, 1]), example.Config())
    expected = np.array([-np.inf, -np.inf, 0.0, -1.0, -np.inf, -1.0, -1.0, -1.0, -np.inf])
    np.testing.assert_array_equal(values, expected)
    assert move == 2


def test_evaluate_refuses_it_in_one_line(run_dir, capsys):
    """Episodes of an env the learner owns cannot be played: the refusal names what can."""
    assert evaluate.main([str(run_dir), "--algo", BY_FILE]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rl-jax match RUN_DIR" in err[0], err


def test_a_game_it_does_not_play_is_one_line(tmp_path):
    """It owns every pgx/ id, and its config names the games it plays (before any compile)."""
    argv = [*FLAGS[:2], "--env", "pgx/othello", "--out", str(tmp_path / "run")]
    _, err, status = in_process(argv)
    assert status == 2 and "Traceback" not in err, err
    assert err.strip() == (
        "error: afterstate_planner cannot run pgx/othello: the afterstate planner plays "
        "pgx/tic_tac_toe, pgx/connect_four, not pgx/othello"
    )
