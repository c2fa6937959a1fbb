"""Board-game runs through the run machinery: AlphaZero on ``pgx/tic_tac_toe`` trained with
``rl_jax.train`` (one chunk of a tiny config), opened, resumed and loaded as a ``GamePolicy``
whose moves are legal; an unknown game and the features a board game lacks (GIFs, replays) end
in one error line; the learners that own no env keep the registry's path.

That a model-free run is untouched bit for bit is ``tests/agents/test_learner_records.py``'s
(recorded metrics of short runs) and ``tests/run/test_api.py``'s (open, resume, evaluate)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pgx
import pytest
from child_env import python_path

import rl_jax
from rl_jax.errors import RunError, UsageError, guard
from rl_jax.run import cli, learners
from rl_jax.run.metrics import METRICS_FILE
from rl_jax.run.policy import GamePolicy
from rl_jax.training.algorithm import hooks

ROOT = Path(__file__).resolve().parents[2]
GAME = "pgx/tic_tac_toe"
# 8 games x 9 moves = 72 env steps per chunk: the smallest config that trains (one update).
TINY = {
    "num_envs": 8,
    "num_simulations": 4,
    "max_considered_actions": 4,
    "iterations_per_chunk": 1,
    "updates_per_iteration": 1,
    "batch_size": 16,
    "num_eval_games": 4,
    "hidden": (16,),
    "buffer_size": 200,
}
CHUNK = 72


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("board") / "run"
    return rl_jax.train(
        "alphazero", GAME, seeds=1, total_steps=CHUNK, out=out, config=TINY, quiet=True
    )


def _steps(run_dir: Path) -> list[int]:
    lines = (run_dir / METRICS_FILE).read_text().splitlines()
    return sorted({json.loads(line)["step"] for line in lines})


def test_a_run_is_written_opened_and_resumed(trained):
    record = json.loads((trained.run_dir / "config.json").read_text())
    assert record["identity"]["env_id"] == GAME
    assert record["learner"] == "builtin"
    opened = rl_jax.open_run(trained.run_dir)
    assert (opened.algorithm, opened.env_id) == ("alphazero", GAME)
    assert "final eval" in opened.table
    assert _steps(trained.run_dir) == [CHUNK]
    resumed = rl_jax.resume(trained.run_dir, total_steps=2 * CHUNK, quiet=True)
    assert resumed.env_id == GAME
    assert _steps(trained.run_dir) == [CHUNK, 2 * CHUNK]


def _positions(count: int) -> list[pgx.State]:
    """Positions of random games of tic-tac-toe, none of them over."""
    env, found = pgx.make("tic_tac_toe"), list[pgx.State]()
    step, rng = jax.jit(env.step), np.random.default_rng(3)
    while len(found) < count:
        state = env.init(jax.random.key(len(found)))
        while not bool(state.terminated) and len(found) < count:
            found.append(state)
            state = step(state, rng.choice(np.flatnonzero(np.asarray(state.legal_action_mask))))
    return found


def test_load_policy_gives_legal_moves_by_search_and_by_network(trained):
    policy = rl_jax.load_policy(trained.run_dir)
    assert isinstance(policy, GamePolicy)
    assert (policy.game, policy.env_id, policy.num_simulations) == ("tic_tac_toe", GAME, 4)
    for state in _positions(10):
        legal = np.asarray(state.legal_action_mask)
        move = policy.move(state)
        assert isinstance(move, int) and legal[move]
        assert policy.move(state) == move  # no Gumbel noise, a fixed key
        greedy = policy(np.asarray(state.observation), legal)
        assert isinstance(greedy, int) and legal[greedy]
    with pytest.raises(ValueError, match="plays tic_tac_toe, not connect_four"):
        policy.move(pgx.make("connect_four").init(jax.random.key(0)))


def test_what_a_board_game_lacks_is_one_error_line(trained):
    run = rl_jax.open_run(trained.run_dir)
    for attempt in (run.save_gif, run.evaluate):
        with pytest.raises(RunError, match="load_policy") as error:
            attempt()
        assert "\n" not in str(error.value)
    with pytest.raises(UsageError, match="unknown game 'pgx/chequers'.*tic_tac_toe"):
        rl_jax.train("alphazero", "pgx/chequers", total_steps=CHUNK, config=TINY, quiet=True)


def test_an_unknown_game_on_the_command_line_is_one_error_line(tmp_path):
    env = {**os.environ, "PYTHONPATH": python_path(ROOT), "TF_CPP_MIN_LOG_LEVEL": "3"}
    script = ROOT / "experiments" / "train.py"
    command = [sys.executable, str(script), "--algo", "alphazero", "--env", "pgx/no_such_game"]
    done = subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode != 0
    lines = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert "unknown game 'pgx/no_such_game'" in lines[0] and "connect_four" in lines[0]
    assert not (tmp_path / "runs").exists()


def test_minimax_evaluation_of_another_game_on_the_command_line_is_one_error_line(
    tmp_path, monkeypatch, capsys
):
    """train.py's code in this process (the fresh process is the test above)."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # a run sets it
    argv = ["--algo", "alphazero", "--env", "pgx/connect_four", "--eval-opponent", "minimax"]
    status = guard(lambda: cli.run_experiment(None, None, "", argv))
    captured = capsys.readouterr()
    assert status != 0
    lines = [line for line in captured.err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in captured.err + captured.out
    assert "'minimax' is exact tic-tac-toe only" in lines[0] and "'mcts'" in lines[0]
    assert not (tmp_path / "runs").exists()


def test_only_alphazero_owns_env_ids():
    for name in learners.ALGORITHMS:
        learner = learners.resolve(name)
        assert hooks(learner).owns_env(GAME) == (name == "alphazero"), name
        assert not hooks(learner).owns_env("rl_jax/CartPole-v1")
    td3 = learners.resolve("td3")
    assert learners.chosen_env(td3, "Pendulum-v1") == "rl_jax/Pendulum-v1"
    with pytest.raises(Exception, match="unknown environment 'pgx/tic_tac_toe'"):
        learners.chosen_env(td3, GAME)
