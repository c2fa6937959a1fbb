"""The budget is the budget: a run takes the env steps it planned, in whole chunks, and says so.

A learner whose chunks take more env steps than its plan (a learner of one's own without
``env_steps_per_chunk``) is stopped after its first such chunk with one line that names the hook,
through the API and the command line, and what the run saved before stays as it was. A budget
that is not a whole number of chunks is rounded up, the plan line says so, and the progress line
never passes 100%. The counts in these lines read as English: 1 chunk, 1 seed.
"""

import contextlib
import dataclasses
import io
import json
import os
import types
from pathlib import Path

import fake_algorithm as fake
import overrunning_learner
import pytest

import rl_jax
from rl_jax.errors import RunError, guard
from rl_jax.run import cli, plan
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.metrics import read_rows
from rl_jax.run.progress import Progress
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec
from rl_jax.training.algorithm import OptionalHooks, hooks

STEPS_PER_CHUNK = 20  # the fake learner: 4 envs x 5 iterations
ROOT = Path(__file__).resolve().parents[2]
OVERRUN = (
    "the learner overrunning reported 80 env steps per seed after chunk 1, but the plan has 20 "
    "(20 per chunk, env_steps_per_chunk's default: num_envs x iterations_per_chunk); define "
    "env_steps_per_chunk(config) to return the env steps one train_chunk takes per seed"
)


def spec_for(out: Path, algorithm=fake, **changes) -> RunSpec:
    spec = RunSpec(
        algorithm=algorithm,
        env_id=fake.ENV_ID,
        config=fake.default_config(),
        hparams=(fake.default_hyperparams(),),
        out=out,
        seeds=2,
        total_steps=4 * STEPS_PER_CHUNK,
        checkpoint_interval=0.0,
        log_interval=0.0,  # a progress line after every chunk
    )
    return dataclasses.replace(spec, **changes)


# ---- a learner that disagrees with its plan -------------------------------------------------


def test_an_overrunning_learner_is_stopped_through_the_api_with_one_line(tmp_path):
    with pytest.raises(RunError) as stopped:
        rl_jax.train(
            overrunning_learner.learner, fake.ENV_ID, seeds=2, total_steps=80, out=tmp_path / "run"
        )
    assert str(stopped.value) == OVERRUN


def test_an_overrunning_learner_is_stopped_through_the_command_line_with_one_line(tmp_path):
    argv = ["--algo", "overrunning_learner:learner", "--env", fake.ENV_ID, "--seeds", "2"]
    argv += ["--total-steps", "80", "--out", str(tmp_path / "run"), "--log-interval", "0"]
    out, err = io.StringIO(), io.StringIO()
    xla_flags = os.environ.get("XLA_FLAGS")
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = guard(lambda: cli.run_experiment(None, None, "", argv))
    finally:  # run_experiment sets the device count for a process not started yet
        if xla_flags is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = xla_flags
    assert status == 2 and err.getvalue() == f"error: {OVERRUN}\n", err.getvalue()
    assert "Traceback" not in out.getvalue() and "step 80/" not in out.getvalue()


def test_what_was_saved_before_the_overrun_stays(tmp_path):
    """Two chunks as planned, each checkpointed; the third overruns: the run stops before it
    writes anything of that chunk, and its record, rows and checkpoints are those of chunk 2."""
    out = tmp_path / "run"
    overrun = "reported 120 env steps per seed after chunk 3, but the plan has 60 "
    with pytest.raises(RunError, match=overrun):
        run(spec_for(out, overrunning_learner.late), notify=lambda message: None)
    assert json.loads((out / "config.json").read_text())["identity"]["algorithm"] == (
        "overrunning_late"
    )
    rows = read_rows(out / "metrics.jsonl")
    assert sorted({row["step"] for row in rows}) == [20, 40] and len(rows) == 4
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.steps() == [20, 40]
        checkpointer.restore_newest_readable(plan.make_plan(spec_for(out)).template)


def test_whether_a_learner_defines_the_hook_or_takes_its_default():
    class Inherits(OptionalHooks):
        name = "inherits"

    class Defines(OptionalHooks):
        name = "defines"

        def env_steps_per_chunk(self, config):
            return 1

    given = Inherits()
    given.env_steps_per_chunk = lambda config: 1
    for learner, defines in [
        (Inherits(), False),
        (Defines(), True),
        (given, True),
        (fake, True),  # a module
        (overrunning_learner.learner, False),  # an object of a class of its own
    ]:
        assert hooks(learner).defines_hook("env_steps_per_chunk") == defines


def test_a_learner_with_a_wrong_hook_is_told_to_fix_it():
    wrong = types.SimpleNamespace(name="wrong", env_steps_per_chunk=lambda config: 20)
    steps = plan.Plan(20, 5, 100, 0, [], 0, None, None)
    plan.check_env_steps(steps, wrong, 1, [[40, 40]])  # as planned after chunk 2
    with pytest.raises(RunError) as stopped:
        plan.check_env_steps(steps, wrong, 1, [[40, 60]])
    assert str(stopped.value) == (
        "the learner wrong reported 60 env steps per seed after chunk 2, but the plan has 40 (20 "
        "per chunk, from its env_steps_per_chunk); make env_steps_per_chunk(config) return the "
        "env steps one train_chunk takes per seed"
    )


# ---- a budget in whole chunks ---------------------------------------------------------------


def test_a_budget_between_chunks_rounds_up_says_so_and_never_passes_100_percent(tmp_path, capsys):
    lines = []
    result = run(spec_for(tmp_path / "run", total_steps=50), notify=lines.append)
    assert result.step == 60
    assert "  50 env steps per seed round up to 60, whole chunks: 3 chunks of 20" in lines[0]
    progress = [line for line in capsys.readouterr().out.splitlines() if line.startswith("step ")]
    assert [line.split(" |")[0] for line in progress] == [
        "step 20/60 (33%)",
        "step 40/60 (67%)",
        "step 60/60 (100%)",
    ]


def test_one_seed_and_one_chunk_are_counted_in_the_singular(tmp_path, capsys):
    lines = []
    run(spec_for(tmp_path / "run", seeds=1, total_steps=20), notify=lines.append)
    assert "plan: fake on rl_jax/FakePoint-v0, 1 seed, 4 envs each" in lines[0]
    assert "  20 env steps per seed in 1 chunk of 20" in lines[0]
    assert "(1 run each)" in lines[0]
    assert "final eval return at step 20 (1 seed)" in "\n".join(lines)
    assert "step 20/20 (100%)" in capsys.readouterr().out


def test_the_time_estimate_names_the_chunk_it_measured():
    """After warm-up chunks (no updates) the estimate comes from a later chunk, and says which:
    the chunks left are counted from it."""
    learner = types.SimpleNamespace(name="warm", warm_up_steps=lambda config: 40)
    warm_up = types.SimpleNamespace(algorithm=learner, config=None)
    out = io.StringIO()
    progress = Progress(100, file=out, tty=False)
    assert not plan.estimate_remaining(warm_up, progress, 0.5, 0, 5, 0, 0)  # no updates yet
    assert not plan.estimate_remaining(warm_up, progress, 0.5, 1, 5, 0, 10)  # part warm-up
    assert plan.estimate_remaining(warm_up, progress, 0.5, 2, 5, 10, 30)
    assert plan.estimate_remaining(warm_up, progress, 0.5, 3, 5, 30, 50)
    assert out.getvalue().splitlines() == [
        "measured: chunk 3 of 5 took 0.50 s; about 0:00:01 left for the remaining 2",
        "measured: chunk 4 of 5 took 0.50 s; about 0:00:00 left for the last chunk",
    ]


def test_the_estimate_after_the_first_of_five_chunks_counts_four_left(tmp_path):
    lines = []
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        run(spec_for(tmp_path / "run", total_steps=100), notify=lines.append)
    [measured] = [line for line in printed.getvalue().splitlines() if "measured" in line]
    assert measured.startswith("measured: chunk 1 of 5 took ")
    assert measured.endswith(" left for the remaining 4")
