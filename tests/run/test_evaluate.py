"""Re-evaluating a run's policies on fresh episodes (``python -m rl_jax.run.evaluate``): every
seed's best (and latest) policy, its returns those of direct rollouts of the same policy, and the
command line's table and one-line errors."""

import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from child_env import python_path
from run_helpers import fake_run

import rl_jax
from rl_jax.envs.memory.masked import GymnasiumMask
from rl_jax.errors import UsageError
from rl_jax.run import evaluate
from rl_jax.run.policy import LoadedPolicy, RecurrentPolicy
from rl_jax.training.episodes import episode_returns

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return fake_run(tmp_path_factory.mktemp("evaluate") / "run", total_steps=60)


def test_every_seeds_best_and_latest_policy_is_evaluated(run_dir):
    evaluations = evaluate.evaluate_run(run_dir, episodes=6, latest=True)
    assert [(e.seed, e.which) for e in evaluations] == [
        (0, "best"),
        (0, "latest"),
        (1, "best"),
        (1, "latest"),
    ]
    for e in evaluations:
        loaded = LoadedPolicy(run_dir, e.seed, which=e.which)
        assert e.step == loaded.step and e.run_eval == pytest.approx(loaded.eval_return)
        assert e.returns.shape == (6,) and np.all(e.returns <= 0.0)  # reward -x^2
    table = evaluate.table(evaluations)
    assert "each policy on 6 fresh episodes" in table and "mean over seeds, latest" in table


def test_returns_are_those_of_stepping_the_env_one_episode_at_a_time(run_dir):
    loaded = LoadedPolicy(run_dir, seed=1)
    returns = evaluate.evaluate_policy(loaded, episodes=3, key=7)
    env, act = loaded.env(), loaded.act()
    reset_key, step_key = jax.random.split(jax.random.key(7))
    for episode, reset in enumerate(jax.random.split(reset_key, 3)):
        state, ts = env.reset(reset)
        total, time = 0.0, 0
        while True:
            keys = jax.random.split(jax.random.fold_in(step_key, time), 3)
            state, ts = env.step(keys[episode], state, act(ts.obs))
            total, time = total + float(ts.reward), time + 1
            if bool(ts.terminated) or bool(ts.truncated):
                break
        assert returns[episode] == pytest.approx(total, rel=1e-5)
    assert np.asarray(
        jax.jit(lambda k: episode_returns(jax.vmap(act), env, k, 3))(jax.random.key(7))
    ) == pytest.approx(returns)


def test_command_line_prints_the_table_or_one_error_line(run_dir, capsys):
    def command(*args):
        argv = [sys.executable, "-m", "rl_jax.run.evaluate", *map(str, args)]
        env = {"PYTHONPATH": python_path(ROOT, ROOT / "tests"), "PATH": "/usr/bin:/bin"}
        return subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, env=env)

    # The command in a fresh process: a learner not built in is named, never imported from the
    # run's record (this process has imported it); an error that gets as far as opening the run
    # is one line there too.
    done = command(run_dir, "--episodes", "4", "--seed", "1", "--algo", "fake_algorithm")
    assert done.returncode == 0, done.stderr
    assert "     1  best" in done.stdout and "     0  best" not in done.stdout
    done = command(run_dir)  # no learner imported yet
    lines = done.stderr.strip().splitlines()
    expected = "name it again: --algo fake_algorithm"
    assert done.returncode != 0 and len(lines) == 1 and expected in lines[0], done.stderr
    # The other errors through the command's main, in this process.
    for args, expected in [
        ((run_dir, "--seed", "9", "--algo", "fake_algorithm"), "--seed 9 is not in this run"),
        ((run_dir.parent / "missing",), "no run directory"),
        ((run_dir, "--episodes", "0"), "--episodes"),
        ((run_dir, "--gymnasium", "--algo", "fake_algorithm"), "no twin registered in gymnasium"),
        ((run_dir, "--gymnax", "--algo", "fake_algorithm"), "is not a gymnax env"),
    ]:
        try:
            status = evaluate.main(list(map(str, args)))
        except SystemExit as exit_:  # argparse's own errors
            status = exit_.code
        lines = capsys.readouterr().err.strip().splitlines()
        assert status != 0 and len(lines) == 1 and expected in lines[0], lines


def test_gymnasium_twins_are_named_by_the_runs_env_id():
    assert evaluate.gymnasium_id("rl_jax/HalfCheetah-v5") == "HalfCheetah-v5"
    assert evaluate.gymnasium_id("rl_jax/CartPole-v1") == "CartPole-v1"
    assert evaluate.gymnasium_id("gymnasium:Pendulum-v1") == "Pendulum-v1"
    for foreign in ("rl_jax/Rocket-v0", "examples.hover_rocket:examples/HoverRocket-v0"):
        with pytest.raises(UsageError, match="no twin registered in gymnasium"):
            evaluate.gymnasium_id(foreign)


def test_masked_ids_have_gymnasiums_env_under_the_same_mask_as_twin():
    name, twin = evaluate.gymnasium_twin("rl_jax/PendulumNoVel-v1", {"g": 9.81})
    assert name == "Pendulum-v1 masked as rl_jax/PendulumNoVel-v1"
    assert isinstance(twin, GymnasiumMask) and twin.spec.kwargs["g"] == 9.81
    assert twin.reset(seed=0)[0][2] == 0.0
    name, twin = evaluate.gymnasium_twin("rl_jax/Pendulum-v1", {})
    assert name == "Pendulum-v1" and not isinstance(twin, GymnasiumMask)


def test_a_recurrent_run_on_a_masked_id_replays_in_gymnasiums_masked_twin(tmp_path, monkeypatch):
    """A tiny recurrent PPO run on CartPoleNoVel-v1, its policy played in gymnasium's CartPole-v1
    with the velocities zeroed, reset per episode."""
    config = {"num_envs": 8, "num_steps": 8, "seq_len": 4, "num_minibatches": 2}
    config |= {"cell_size": 8, "iterations_per_chunk": 2, "num_eval_envs": 4}
    run = rl_jax.train(
        "recurrent_ppo",
        "rl_jax/CartPoleNoVel-v1",
        total_steps=8 * 8 * 2,
        out=tmp_path / "run",
        config=config,
        quiet=True,
    )
    played = []

    def spy(env, policy, episodes, key):
        played.append((env, policy))
        return play(env, policy, episodes, key)

    play = evaluate._play
    monkeypatch.setattr(evaluate, "_play", spy)
    (evaluation,) = evaluate.evaluate_run(run.run_dir, episodes=3, gymnasium=True)
    assert evaluation.env == "CartPole-v1 masked as rl_jax/CartPoleNoVel-v1"
    assert evaluation.returns.shape == (3,) and np.all(np.isfinite(evaluation.returns))
    assert np.all(evaluation.returns >= 1.0)
    ((env, policy),) = played
    assert isinstance(env, GymnasiumMask) and env.spec.id == "CartPole-v1"
    assert isinstance(policy, RecurrentPolicy)
    assert "of gymnasium's CartPole-v1 masked as" in evaluate.table([evaluation])


def test_gymnasium_episodes_are_seeded_and_played_to_their_end():
    import gymnasium

    def push_right(obs):
        return 1

    returns = evaluate.gymnasium_returns(push_right, "CartPole-v1", episodes=3, key=11)
    for episode, expected in enumerate(returns):
        env = gymnasium.make("CartPole-v1")
        env.reset(seed=11 + episode)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(1)
            total, done = total + reward, terminated or truncated
        assert expected == total
    assert np.all((returns > 5) & (returns < 100))  # pushing one way topples the pole early
