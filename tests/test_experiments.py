"""Real TD3 through the command line: a stopped and resumed run ends bit-identical to one that
never stopped, and the bad inputs only a real learner can show (a resume of another algorithm's
or env's run, a replay buffer too big for memory) end in one line with the estimate."""

import dataclasses
from pathlib import Path

import pytest
from run_helpers import leaves_bytes, snapshot

from rl_jax.agents.td3 import ddpg, td3
from rl_jax.errors import guard
from rl_jax.run import cli, command
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR

ENV_ID = "rl_jax/Pendulum-v1"
# Tiny and fast: 2 envs x 50 iterations = 100 env steps per chunk; updates from step 100.
FLAGS = [
    "--num-envs", "2", "--updates-per-iteration", "2", "--iterations-per-chunk", "50",
    "--learning-starts", "100", "--batch-size", "32", "--buffer-size", "1000",
    "--num-eval-envs", "2", "--actor-hidden", "16,16", "--critic-hidden", "16,16",
    "--seeds", "2", "--log-interval", "0", "--checkpoint-interval", "0",
]  # fmt: skip
CHUNK = 100


def run_cli(algorithm, env_id, argv) -> int:
    return guard(lambda: cli.run_experiment(algorithm, env_id, "", argv))


def final_state(run_dir: Path, algorithm=td3, env_id=ENV_ID):
    """The latest checkpoint of a run directory, and its step."""
    spec = command.spec_for(algorithm, env_id, FLAGS)
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        state, meta = checkpointer.restore(plan.template)
    return state, meta["step"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """4 chunks in one go; and 2 chunks, stopped, then resumed to 4."""
    root = tmp_path_factory.mktemp("td3")
    assert (
        run_cli(
            td3, ENV_ID, [*FLAGS, "--total-steps", str(4 * CHUNK), "--out", str(root / "whole")]
        )
        == 0
    )
    assert (
        run_cli(
            td3, ENV_ID, [*FLAGS, "--total-steps", str(2 * CHUNK), "--out", str(root / "split")]
        )
        == 0
    )
    stopped = final_state(root / "split")
    assert (
        run_cli(td3, ENV_ID, ["--resume", str(root / "split"), "--total-steps", str(4 * CHUNK)])
        == 0
    )
    return root, stopped


def test_resumed_td3_run_is_bit_identical_to_an_unstopped_one(runs, capsys):
    root, (stopped_state, stopped_step) = runs
    whole, whole_step = final_state(root / "whole")
    resumed, resumed_step = final_state(root / "split")
    assert stopped_step == 2 * CHUNK and whole_step == resumed_step == 4 * CHUNK
    assert leaves_bytes(resumed) == leaves_bytes(whole)
    # Updates happened after the resume point: the comparison is of trained parameters.
    assert int(resumed.clock.updates) > int(stopped_state.clock.updates) > 0
    assert leaves_bytes(resumed.agent.actor) != leaves_bytes(stopped_state.agent.actor)


def _one_line_error(capsys, status: int, expected: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    assert expected in lines[0], lines[0]
    return lines[0]


def test_resume_of_another_algorithm_or_env_is_refused(runs, capsys):
    root, _ = runs
    before = snapshot(root / "whole")
    status = run_cli(ddpg, ENV_ID, ["--resume", str(root / "whole")])
    _one_line_error(capsys, status, "it is a td3 run on rl_jax/Pendulum-v1, this is ddpg on")
    status = run_cli(td3, "rl_jax/Rocket-v0", ["--resume", str(root / "whole")])
    _one_line_error(capsys, status, "this is td3 on rl_jax/Rocket-v0")
    assert snapshot(root / "whole") == before


def test_replay_buffer_too_big_is_refused_before_allocating(tmp_path, capsys):
    out = tmp_path / "big"
    argv = ["--buffer-size", "4e9", "--seeds", "5", "--out", str(out)]
    line = _one_line_error(capsys, run_cli(td3, ENV_ID, argv), "the train state needs ")
    # 5 seeds x 4e9 transitions x (obs 3 + action 1 + reward + next obs 3 + 2 flags) x 4 bytes.
    assert "buffer " in line and "TB" in line and "of memory is available" in line
    assert not out.exists()


# ---- the best policy of every seed, and loading it -------------------------------------------


def best_policies(run_dir: Path):
    """The ``agent`` of the best-policy checkpoint of a run and its metadata."""
    from rl_jax.run.best import BEST_DIR, policy_part

    spec = command.spec_for(td3, ENV_ID, FLAGS)
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / BEST_DIR, read_only=True) as checkpointer:
        part, meta = checkpointer.restore(policy_part(plan.template, ("agent",)))
    return part["agent"], meta


def test_each_seed_keeps_the_policy_of_its_best_eval(runs):
    import numpy as np

    from rl_jax.run.metrics import read_rows

    root, _ = runs
    agent, meta = best_policies(root / "whole")
    rows = read_rows(root / "whole" / "metrics.jsonl")
    compared = 0
    for s in range(2):
        evals = [(row["eval_return"], -row["step"]) for row in rows if row["seed"] == s]
        best_return, best_step = max(evals)
        assert meta["best_returns"][0][s] == pytest.approx(best_return, rel=1e-6)
        assert meta["best_steps"][0][s] == -best_step
        # The kept policy is the one the run had at that step (its checkpoint, when kept).
        with Checkpointer(root / "whole" / CHECKPOINT_DIR, read_only=True) as checkpointer:
            kept = checkpointer.steps()
        if -best_step in kept:
            state, _ = final_state_at(root / "whole", -best_step)
            one = jax_index(state.agent, s)
            assert leaves_bytes(jax_index(agent, s)) == leaves_bytes(one)
            compared += 1
    # The latest policy differs from the best one unless the best eval was the last.
    assert compared >= 1
    assert np.isfinite(meta["best_returns"]).all()


def test_a_resumed_run_keeps_the_same_best_policies(runs):
    root, _ = runs
    whole, whole_meta = best_policies(root / "whole")
    split, split_meta = best_policies(root / "split")
    assert leaves_bytes(whole) == leaves_bytes(split)
    assert whole_meta["best_returns"] == split_meta["best_returns"]
    assert whole_meta["best_steps"] == split_meta["best_steps"]


def test_load_policy_drives_gymnasiums_own_pendulum_as_our_env(runs):
    """numpy in, numpy out; from the same start state, gymnasium's Pendulum-v1 driven by the
    loaded policy returns what our env gives for the same policy."""
    import gymnasium
    import jax
    import numpy as np

    import rl_jax
    from rl_jax.run import render

    root, _ = runs
    policy = rl_jax.load_policy(root / "whole")
    loaded = policy.loaded
    meta = best_policies(root / "whole")[1]
    best_seed = max(range(2), key=lambda s: meta["best_returns"][0][s])
    assert loaded.which == "best" and loaded.seed == best_seed
    assert loaded.step == meta["best_steps"][0][best_seed]
    assert loaded.eval_return == meta["best_returns"][0][best_seed]
    obs = np.array([[1.0, 0.0, 0.5], [0.0, -1.0, -2.0]], np.float32)
    batch = policy(obs)
    assert isinstance(batch, np.ndarray) and batch.shape == (2, 1)
    np.testing.assert_array_equal(policy(obs[1]), batch[1])
    np.testing.assert_allclose(batch, np.asarray(jax.vmap(loaded.act())(obs)), rtol=1e-6)
    with pytest.raises(ValueError, match=r"expected an observation of shape \(3,\)"):
        policy(np.zeros(4))

    env = loaded.env()
    gym_env = gymnasium.make("Pendulum-v1")
    for episode in range(3):
        (ours,) = render.rollout(env, loaded.act(), jax.random.key(episode), 1)
        first = ours["states"][0]
        gym_env.reset(seed=episode)
        gym_env.unwrapped.state = np.array([float(first.theta), float(first.theta_dot)])
        obs, total = gym_env.unwrapped._get_obs(), 0.0
        for _ in range(200):
            obs, reward, terminated, truncated, _ = gym_env.step(policy(obs))
            total += reward
            if terminated or truncated:
                break
        assert total == pytest.approx(ours["return"], rel=1e-3, abs=0.5)
    latest = rl_jax.load_policy(root / "whole", seed=0, which="latest")
    assert latest.loaded.which == "latest" and latest.loaded.step == 4 * CHUNK


def test_load_policy_refuses_what_the_run_does_not_have(runs):
    import rl_jax
    from rl_jax.errors import PolicyError

    root, _ = runs
    with pytest.raises(PolicyError, match=r"--seed 7 is not in this run \(seeds \[0, 1\]\)"):
        rl_jax.load_policy(root / "whole", seed=7)
    with pytest.raises(PolicyError, match="which must be one of best, latest"):
        rl_jax.load_policy(root / "whole", which="last")


def final_state_at(run_dir: Path, step: int):
    spec = command.spec_for(td3, ENV_ID, FLAGS)
    plan = make_plan(dataclasses.replace(spec, out=run_dir))
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        return checkpointer.restore(plan.template, step=step)


def jax_index(tree, seed: int):
    import jax

    return jax.tree.map(lambda leaf: leaf[0, seed], tree)


def test_the_readme_load_policy_section_runs(runs, capsys):
    """The usage page's block (docs/usage.md), as written, on a trained run."""
    import re

    root, _ = runs
    page = (Path(__file__).resolve().parent.parent / "docs" / "usage.md").read_text()
    section = page.split("## The trained policy in your own code", 1)[1]
    (code,) = re.findall(r"```python\n(.*?)```", section, flags=re.S)[:1]
    assert 'load_policy("runs/pendulum")' in code
    exec(code.replace('"runs/pendulum"', repr(str(root / "whole"))), {})
    assert re.search(r"^return -?\d+\.\d$", capsys.readouterr().out, flags=re.M)


def test_a_diverging_run_stops_with_one_line_and_keeps_its_finite_checkpoint(tmp_path, capsys):
    """TD3 with rates of 1e6: the first chunk (random actions, no updates) is checkpointed; the
    updates of the second make the parameters non-finite, and the run stops there without
    saving them."""
    import jax
    import numpy as np

    out = tmp_path / "diverged"
    argv = [*FLAGS, "--actor-lr", "1e6", "--critic-lr", "1e6", "--total-steps", str(4 * CHUNK)]
    status = run_cli(td3, ENV_ID, [*argv, "--out", str(out)])
    line = _one_line_error(capsys, status, f"training diverged at step {2 * CHUNK}: seed 0")
    assert f"the last finite checkpoint (step {CHUNK}) is kept" in line
    assert "--actor-lr 1e+06" in line and "--critic-lr 1e+06" in line
    with Checkpointer(out / CHECKPOINT_DIR, read_only=True) as checkpointer:
        assert checkpointer.steps() == [CHUNK]
    state, step = final_state(out)
    assert step == CHUNK
    leaves = jax.tree.leaves(state.agent)
    floats = [leaf for leaf in leaves if np.issubdtype(leaf.dtype, np.floating)]
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in floats if leaf.size)
