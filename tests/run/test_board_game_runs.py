"""Board-game runs through the run machinery: AlphaZero on ``pgx/tic_tac_toe`` trained with
``rl_jax.train`` (one chunk of a tiny config), opened, resumed and loaded as a ``GamePolicy``
whose moves are legal; its GIF is games of the search against the run's opponent (legal, a frame
per position, the last held); an unknown game and what a board game lacks (replays) end in one
error line; the learners that own no env keep the registry's path.

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
from PIL import Image, ImageSequence
from tiny_board_run import CHUNK, GAME, TINY  # trained: tests/run/conftest.py

import rl_jax
from rl_jax.envs.games import draw
from rl_jax.envs.games import tic_tac_toe_minimax as minimax
from rl_jax.errors import RenderError, RunError, UsageError, guard
from rl_jax.run import cli, learners, render, render_game
from rl_jax.run.metrics import METRICS_FILE
from rl_jax.run.policy import GamePolicy, LoadedPolicy
from rl_jax.training.algorithm import hooks

ROOT = Path(__file__).resolve().parents[2]


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


def _gif_frames(path: Path) -> list[tuple[np.ndarray, float]]:
    """The frames of a GIF with their durations (ms). A GIF keeps a run of equal frames as one
    frame shown that much longer."""
    with Image.open(path) as image:
        return [
            (np.asarray(frame.convert("RGB")), float(frame.info["duration"]))
            for frame in ImageSequence.Iterator(image)
        ]


def _check_legal(played: render_game.PlayedGame) -> None:
    """The moves of a tic-tac-toe game, replayed by the exact solver's rules: each legal, the
    boards pgx reached, and the game over exactly at its last move with the recorded outcome."""
    board = minimax.EMPTY_BOARD
    for move, state in zip(played.moves, played.states[1:], strict=True):
        assert not minimax.is_terminal(board) and move in minimax.legal_moves(board)
        board = minimax.play(board, move)
        assert tuple(draw.board(state).reshape(-1)) == board
    assert minimax.is_terminal(board)
    ours = 0 if played.opened else 1
    won = minimax.winner(board)
    assert played.outcome == (0 if won < 0 else 1 if won == ours else -1)


def test_a_gif_is_games_of_the_search_against_the_run_opponent(
    trained, tmp_path, capsys, monkeypatch
):
    """``Run.save_gif`` plays one game per episode, the search opening the first and moving
    second in the next; a frame per position and the final one held for a second."""
    played_and_drawn = []

    def keep(loaded: LoadedPolicy, episodes: int):
        played_and_drawn.append(play_and_draw(loaded, episodes))
        return played_and_drawn[-1]

    play_and_draw = render_game.play_and_draw
    monkeypatch.setattr(render_game, "play_and_draw", keep)
    path = rl_jax.open_run(trained.run_dir).save_gif(tmp_path / "games.gif", episodes=2)
    line = capsys.readouterr().out
    assert "against random: game 1 (first)" in line and "game 2 (second)" in line
    [(_, games, opponent)] = played_and_drawn
    assert opponent == "random" and [game.opened for game in games] == [True, False]
    for played in games:
        _check_legal(played)
    positions = sum(len(played.states) for played in games)
    held = render_game.HELD_FRAMES
    assert held == 2 and f"{positions + len(games) * held} frames" in line
    frames = _gif_frames(path)
    step = 1000.0 / render_game.MOVES_PER_SECOND
    assert len(frames) == positions  # the held copies of a final frame merge into it
    assert sum(duration for _, duration in frames) == (positions + len(games) * held) * step
    last_of_first = len(games[0].states) - 1
    assert [frames[last_of_first][1], frames[-1][1]] == [(1 + held) * step] * 2
    first = draw.draw_state(games[0].states[0], players=("alphazero", "random"))
    assert frames[0][0].shape == first.shape


def test_the_render_command_draws_a_board_game_run(trained, tmp_path, capsys):
    out = tmp_path / "one.gif"
    assert render.main([str(trained.run_dir), "--out", str(out)]) == 0
    assert "game 1 (first)" in capsys.readouterr().out and out.stat().st_size > 0


def test_a_game_that_cannot_be_drawn_is_one_error_line_before_any_move(trained):
    loaded = LoadedPolicy(trained.run_dir)
    loaded.env_id = "pgx/othello"  # a game AlphaZero plays but draw.py does not draw
    with pytest.raises(RenderError, match="pgx/othello.*pgx/tic_tac_toe, pgx/connect_four"):
        render_game.play_and_draw(loaded, 1)


def test_what_a_board_game_lacks_is_one_error_line(trained):
    run = rl_jax.open_run(trained.run_dir)
    with pytest.raises(RunError, match="load_policy") as error:
        run.evaluate()
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
