"""The Python API (``rl_jax.train`` / ``open_run`` / ``resume`` and the ``Run`` object) on a tiny
real TD3 run, and the usage page's notebook block executed as written (with a smaller budget)."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import rl_jax
from rl_jax import envs
from rl_jax.errors import RunError, UsageError
from rl_jax.run.api import evaluate_policy

ENV_ID = "rl_jax/Pendulum-v1"
# 2 envs x 50 iterations = 100 env steps per chunk; updates from step 100.
TINY = {
    "num_envs": 2,
    "updates_per_iteration": 2,
    "iterations_per_chunk": 50,
    "learning_starts": 100,
    "batch_size": 32,
    "buffer_size": 1000,
    "num_eval_envs": 2,
    "actor_hidden": (16, 16),
    "critic_hidden": (16, 16),
}
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "run"
    return rl_jax.train("td3", ENV_ID, seeds=2, total_steps=300, out=out, config=TINY, quiet=True)


def test_train_returns_the_run_with_its_results_and_files(trained):
    run = trained
    assert run.algorithm == "td3" and run.env_id == ENV_ID and run.seeds == [0, 1]
    assert run.results.step == 300 and run.results.returns.shape == (2,)
    assert np.all(run.results.best >= run.results.returns)
    assert "final eval return at step 300 (2 seeds)" in run.table
    for name in ("config.json", "metrics.jsonl", "results.txt", "curves.png", "best"):
        assert (run.run_dir / name).exists(), name
    opened = rl_jax.open_run(run.run_dir)
    np.testing.assert_array_equal(opened.results.returns, run.results.returns)
    assert opened.table == run.table


def test_evaluate_policy_and_plot(trained):
    scores = trained.evaluate(episodes=3)
    assert sorted(scores) == [0, 1] and all(np.isfinite(v) for v in scores.values())
    assert trained.evaluate(episodes=3) == scores  # same key, same episodes
    action = trained.policy(0)(np.array([1.0, 0.0, 0.0], np.float32))
    assert action.shape == (1,) and -2.0 <= float(action[0]) <= 2.0
    shown = trained.plot()
    assert Path(getattr(shown, "filename", shown) or trained.run_dir / "curves.png").exists()


def test_evaluate_policy_matches_a_step_by_step_rollout():
    """The vmapped evaluation against a plain Python loop with the same keys and policy."""
    env = envs.make(ENV_ID)
    params = env.default_params
    act = lambda obs: jnp.clip(-2.0 * obs[1:2] - 0.5 * obs[2:3], -2.0, 2.0)  # noqa: E731
    key = jax.random.key(3)
    got = evaluate_policy(env, act, key, episodes=3)
    reset_key, step_key = jax.random.split(key)
    reset_keys = jax.random.split(reset_key, 3)
    for i in range(3):
        state, ts = env.reset(reset_keys[i], params)
        total = 0.0
        for t in range(env.max_episode_steps):
            step_keys = jax.random.split(jax.random.fold_in(step_key, t), 3)
            state, ts = env.step(step_keys[i], state, act(ts.obs), params)
            total += float(ts.reward)
            if bool(ts.terminated) or bool(ts.truncated):
                break
        assert got[i] == pytest.approx(total, rel=1e-4)


def test_resume_continues_to_the_same_result_as_the_scripts(trained, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(trained.run_dir, copy)
    resumed = rl_jax.resume(copy, total_steps=400, quiet=True)
    assert resumed.results.step == 400
    assert rl_jax.open_run(copy).results.step == 400


def test_bad_input_is_one_clear_error(tmp_path):
    with pytest.raises(UsageError, match="unknown algorithm 'nope'"):
        rl_jax.train("nope", ENV_ID)
    with pytest.raises(UsageError, match="invalid config"):
        rl_jax.train("td3", ENV_ID, config={"no_such_field": 1}, out=tmp_path / "x")
    with pytest.raises(RunError, match="no run directory at"):
        rl_jax.open_run(tmp_path / "missing")


def test_the_readme_notebook_block_runs(tmp_path, monkeypatch, capsys):
    page = (ROOT / "docs" / "usage.md").read_text()
    section = page.split("## From a notebook", 1)[1]
    code = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    call = 'rl_jax.train("td3", "rl_jax/Pendulum-v1", seeds=5, total_steps=20_000)'
    assert call in code
    smaller = f'rl_jax.train("td3", "rl_jax/Pendulum-v1", seeds=2, total_steps=200, out={str(tmp_path / "nb")!r}, config={TINY!r}, quiet=True)'  # noqa: E501
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(code.replace(call, smaller), namespace)
    assert (tmp_path / "pendulum.gif").stat().st_size > 100
    assert namespace["same"].run_dir == namespace["run"].run_dir
    assert "final eval return at step 200 (2 seeds)" in capsys.readouterr().out


def test_a_list_setting_from_a_notebook_or_json_becomes_a_tuple():
    """``config={"hidden": [8]}`` (a notebook's or a JSON file's list) is hashed when compiled:
    it is taken as the tuple its field holds, and checked as one."""
    from rl_jax.agents import r2d2
    from rl_jax.run.command import replace_fields
    from rl_jax.training.validation import out_of_range

    config = replace_fields(r2d2.default_config("rl_jax/CartPole-v1"), {"hidden": [8, 8]}, "config")
    assert config.hidden == (8, 8) and hash(config)
    assert out_of_range(config) is None
