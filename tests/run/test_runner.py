"""The runner with the fake learner: a complete run directory, bit-exact resume after a stop at a
chunk boundary or a signal, memory planning, grids, and refusals that leave runs untouched."""

import dataclasses
import json
import os
import shutil
import signal
from pathlib import Path

import fake_algorithm as fake
import jax
import numpy as np
import pytest
from run_helpers import leaves_bytes, snapshot

from rl_jax.errors import CheckpointError, RunError
from rl_jax.run import runner, start
from rl_jax.run.best import load_part
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.metrics import read_rows
from rl_jax.run.plan import make_plan
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec

STEPS_PER_CHUNK = 20  # 4 envs x 5 iterations
TOTAL = 8 * STEPS_PER_CHUNK
COMPARED = ("step", "seed", "eval_return", "train_return", "updates", "loss", "chunk")


def spec_for(out: Path, **changes) -> RunSpec:
    spec = RunSpec(
        algorithm=fake,
        env_id=fake.ENV_ID,
        config=fake.default_config(),
        hparams=(fake.default_hyperparams(),),
        out=out,
        seeds=2,
        total_steps=TOTAL,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
    return dataclasses.replace(spec, **changes)


def compared_rows(run_dir: Path) -> list[tuple]:
    return [tuple(row.get(k) for k in COMPARED) for row in read_rows(run_dir / "metrics.jsonl")]


@pytest.fixture(scope="module")
def full_run(tmp_path_factory):
    """The reference: a run that was never stopped."""
    out = tmp_path_factory.mktemp("full") / "run"
    return run(spec_for(out), notify=lambda message: None)


def test_a_run_leaves_a_complete_directory(full_run):
    out = full_run.run_dir
    assert full_run.step == TOTAL and not full_run.stopped
    record = json.loads((out / "config.json").read_text())
    assert record["identity"]["algorithm"] == "fake" and record["identity"]["seeds"] == 2
    assert record["identity"]["config"]["hidden_sizes"] == [8]
    assert record["identity"]["hparams"] == [
        {"learning_rate": 0.01, "noise": 0.3, "updates_per_step": 1}
    ]
    assert record["environment"]["versions"]["jax"] == jax.__version__
    assert record["algorithm_module"] == "fake_algorithm" and record["total_steps"] == TOTAL
    rows = read_rows(out / "metrics.jsonl")
    assert [(row["step"], row["seed"]) for row in rows] == [
        (STEPS_PER_CHUNK * (c + 1), s) for c in range(8) for s in (0, 1)
    ]
    assert all(np.isfinite(row["eval_return"]) and "loss" in row for row in rows)
    assert (out / "curves.png").stat().st_size > 1000
    results = (out / "results.txt").read_text()
    assert f"final eval return at step {TOTAL}" in results and "wall-clock" in results
    assert sorted(p.name for p in (out / "tensorboard").iterdir()) == ["seed_0", "seed_1"]
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.steps() == [120, 140, 160]  # keep_checkpoints=3
    assert full_run.results[0].returns.tolist() == [
        row["eval_return"] for row in rows if row["step"] == TOTAL
    ]


def test_seeds_differ_and_hparams_reach_the_learner(full_run):
    params = full_run.state.params["layer0"]
    assert params.shape == (1, 2, 2, 8)
    assert not np.array_equal(params[0, 0], params[0, 1])
    assert np.all(
        np.asarray(full_run.state.opt_state.hyperparams["learning_rate"]) == np.float32(0.01)
    )


def test_resume_after_a_stop_at_a_chunk_boundary_is_bit_identical(full_run, tmp_path):
    out = tmp_path / "run"
    first = run(spec_for(out, total_steps=3 * STEPS_PER_CHUNK), notify=lambda message: None)
    assert first.step == 60
    resumed = run(spec_for(out, resume=True), notify=lambda message: None)
    assert resumed.step == TOTAL
    assert leaves_bytes(resumed.state) == leaves_bytes(full_run.state)
    assert compared_rows(out) == compared_rows(full_run.run_dir)
    sessions = json.loads((out / "config.json").read_text())["sessions"]
    assert [session["from_step"] for session in sessions] == [0, 60]


def test_sigint_mid_run_checkpoints_and_resume_is_bit_identical(full_run, tmp_path, monkeypatch):
    """The signal arrives while the first chunk's rows are written, as a Ctrl-C mid-run would.
    (Sent from the run's own thread: a watcher thread raced the run, which with cached programs
    could finish all 8 chunks before the signal landed.)"""
    out = tmp_path / "run"
    rows_of = runner.metric_rows
    # what the run must restore: Python's default, or SIG_IGN where a shell started the tests as
    # a background job (bash ignores SIGINT in those)
    handler_before = signal.getsignal(signal.SIGINT)

    def rows_then_interrupt(*args, **kwargs):
        rows = rows_of(*args, **kwargs)
        os.kill(os.getpid(), signal.SIGINT)
        return rows

    monkeypatch.setattr(runner, "metric_rows", rows_then_interrupt)
    messages = []
    stopped = run(spec_for(out), notify=messages.append)
    monkeypatch.setattr(runner, "metric_rows", rows_of)
    assert stopped.stopped and STEPS_PER_CHUNK <= stopped.step < TOTAL
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.latest_step() == stopped.step
    assert max(row["step"] for row in read_rows(out / "metrics.jsonl")) == stopped.step
    assert any(f"stopped at step {stopped.step}" in message for message in messages)
    assert signal.getsignal(signal.SIGINT) is handler_before  # handler restored
    resumed = run(spec_for(out, resume=True), notify=lambda message: None)
    assert leaves_bytes(resumed.state) == leaves_bytes(full_run.state)
    assert compared_rows(out) == compared_rows(full_run.run_dir)


def test_a_signal_just_after_a_chunks_own_check_still_saves_that_chunk(
    full_run, tmp_path, monkeypatch
):
    """SIGTERM lands after chunk 1's end-of-chunk check and before chunk 2 starts (a window a
    loaded machine hits now and then): the run stops there, and the chunk it trained is saved,
    not lost as if the signal had come during compilation."""
    out = tmp_path / "run"
    checks = runner._stopping
    calls = []

    def check_then_signal(*args, **kwargs):
        answer = checks(*args, **kwargs)
        calls.append(answer)
        if len(calls) == 2:  # the check at the end of the first chunk has just said no
            os.kill(os.getpid(), signal.SIGTERM)
        return answer

    monkeypatch.setattr(runner, "_stopping", check_then_signal)
    messages = []
    stopped = run(spec_for(out, checkpoint_interval=1e9), notify=messages.append)
    monkeypatch.setattr(runner, "_stopping", checks)
    assert calls == [False, False, True]
    assert stopped.stopped and stopped.step == STEPS_PER_CHUNK
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.latest_step() == STEPS_PER_CHUNK
    assert f"stopped at step {STEPS_PER_CHUNK} of {TOTAL}; checkpoint saved." in messages
    resumed = run(spec_for(out, resume=True), notify=lambda message: None)
    assert leaves_bytes(resumed.state) == leaves_bytes(full_run.state)
    assert compared_rows(out) == compared_rows(full_run.run_dir)


def overwrite_with_garbage(step_dir: Path) -> None:
    for path in step_dir.rglob("*"):
        if path.is_file():
            path.write_bytes(b"\x93garbage\xff" * 3)


def test_a_damaged_best_policy_checkpoint_is_passed_over_and_the_resume_goes_on(
    full_run, tmp_path, capsys
):
    """The best policies' latest checkpoint overwritten: the resume says so in one line, goes on
    from the older best record, and trains as a run that never stopped."""
    out = tmp_path / "run"
    run(spec_for(out, total_steps=3 * STEPS_PER_CHUNK), notify=lambda message: None)
    with Checkpointer(out / "best", read_only=True) as checkpointer:
        steps = checkpointer.steps()
    assert len(steps) >= 2, steps  # an older record to fall back on
    overwrite_with_garbage(out / "best" / str(steps[-1]))
    capsys.readouterr()
    resumed = run(spec_for(out, resume=True), notify=lambda message: None)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"warning: the best policies' checkpoint step {steps[-1]} is ")
    assert resumed.step == TOTAL
    assert leaves_bytes(resumed.state) == leaves_bytes(full_run.state)


def test_resume_falls_back_past_a_damaged_latest_checkpoint(full_run, tmp_path, capsys):
    """The latest checkpoint's files overwritten: the resume starts from the one before, says so
    in one stderr line, keeps the damaged one aside and ends as a run that never stopped. Asked to
    keep 1 checkpoint, the run kept 2, or there would be nothing to fall back on."""
    out = tmp_path / "run"
    first = spec_for(out, total_steps=3 * STEPS_PER_CHUNK, keep_checkpoints=1)
    run(first, notify=lambda message: None)
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.steps() == [40, 60]
    overwrite_with_garbage(out / "checkpoints" / "60")
    damaged = snapshot(out / "checkpoints" / "60")
    capsys.readouterr()
    messages = []
    resumed = run(spec_for(out, resume=True, keep_checkpoints=1), notify=messages.append)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("warning: checkpoint step 60 is unreadable (")
    assert "resuming from step 40 instead, the damaged one is kept as " in lines[0]
    assert "resuming from the checkpoint at step 40 (chunk 2)" in messages
    kept = [p for p in (out / "checkpoints").iterdir() if p.name.startswith("damaged-")]
    assert [p.name[: len("damaged-60-")] for p in kept] == ["damaged-60-"]
    assert lines[0].endswith(str(kept[0])) and snapshot(kept[0]) == damaged
    # Resume equals never stopping: the same final state, and metrics.jsonl's rows of the
    # damaged checkpoint's chunk replaced by the redone ones, not repeated.
    assert resumed.step == TOTAL
    assert leaves_bytes(resumed.state) == leaves_bytes(full_run.state)
    assert compared_rows(out) == compared_rows(full_run.run_dir)
    with Checkpointer(out / "checkpoints", read_only=True) as checkpointer:
        assert checkpointer.steps() == [140, 160]  # 2 kept again; the damaged one not pruned
    assert kept[0].is_dir()
    session = json.loads((out / "config.json").read_text())["sessions"][-1]
    assert session["from_step"] == 40
    [record] = session["damaged_checkpoints"]
    assert record["step"] == 60 and record["kept_as"] == kept[0].name
    assert record["problem"].startswith("is unreadable (")
    # The best policies too: best/ at step 60 belonged to the redone chunk and was found again.
    template = make_plan(spec_for(out)).template
    best = [
        load_part(d / "best", fake.policy_fields, template, {}) for d in (out, full_run.run_dir)
    ]
    assert leaves_bytes(best[0][0]) == leaves_bytes(best[1][0])
    assert [best[0][1][k] == best[1][1][k] for k in ("step", "best_returns", "best_steps")] == [
        True
    ] * 3


def test_no_readable_checkpoint_is_one_error_and_changes_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    run(spec_for(out, total_steps=3 * STEPS_PER_CHUNK), notify=lambda message: None)
    for step in (20, 40, 60):
        overwrite_with_garbage(out / "checkpoints" / str(step))
    before = snapshot(out)
    capsys.readouterr()
    with pytest.raises(CheckpointError) as error:
        run(spec_for(out, resume=True), notify=lambda message: None)
    message = str(error.value)
    assert "checkpoint step 60 in " in message and "is unreadable (" in message
    assert message.endswith("the older checkpoints (40, 20) cannot be restored either")
    assert snapshot(out) == before  # nothing moved, deleted or written
    assert capsys.readouterr().err == ""


def test_resuming_a_finished_run_trains_nothing(full_run, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(full_run.run_dir, out)
    messages = []
    again = run(spec_for(out, resume=True), notify=messages.append)
    assert again.step == TOTAL and not again.stopped
    assert compared_rows(out) == compared_rows(full_run.run_dir)
    assert leaves_bytes(again.state) == leaves_bytes(full_run.state)


def test_plan_estimates_the_state_size_before_allocating(full_run, tmp_path):
    plan = make_plan(spec_for(tmp_path / "never"))
    actual = sum(len(b) for b in leaves_bytes(full_run.state))
    # The state on the device (one device here: no padding) plus the host copy a checkpoint
    # takes.
    assert plan.state_bytes == 2 * actual
    assert plan.breakdown[0][0] == "buffer"  # the replay buffer dominates
    assert plan.breakdown[0][1] == 2 * (2 * 64 * 3 * 4)
    assert (plan.chunks, plan.steps_per_chunk) == (8, STEPS_PER_CHUNK)
    assert not (tmp_path / "never").exists()


def test_a_state_too_big_for_memory_is_refused_with_the_estimate(tmp_path):
    out = tmp_path / "run"
    big = dataclasses.replace(fake.default_config(), buffer_size=1_000_000_000)
    with pytest.raises(
        RunError, match=r"needs 44\.70 GB \(buffer 44\.70 GB.*22\.35 GB in training.*only 1\.00 GB"
    ):
        run(spec_for(out, config=big, memory_limit=1 << 30), notify=lambda message: None)
    assert not out.exists()
    # the message names the largest buffer that fits (two digits, rounded down), and it does
    with pytest.raises(RunError, match=r"reduce the replay buffer \(--buffer-size 22000000 fits\)"):
        run(spec_for(out, config=big, memory_limit=1 << 30), notify=lambda message: None)
    fits = dataclasses.replace(big, buffer_size=22_000_000)
    plan = make_plan(spec_for(out, config=fits, memory_limit=1 << 30))
    assert 0.95 * plan.available_bytes < plan.state_bytes <= plan.available_bytes


def test_out_dir_holding_another_run_is_refused_and_untouched(full_run, tmp_path):
    before = snapshot(full_run.run_dir)
    other = spec_for(full_run.run_dir, hparams=(fake.Hyperparams(learning_rate=0.5),))
    with pytest.raises(RunError, match="different run .*learning_rate 0.01 vs 0.5"):
        run(other, notify=lambda message: None)
    with pytest.raises(RunError, match="already holds this run; continue it with --resume"):
        run(spec_for(full_run.run_dir), notify=lambda message: None)
    stray = tmp_path / "stray"
    stray.mkdir()
    (stray / "notes.txt").write_text("mine")
    with pytest.raises(RunError, match="not empty"):
        run(spec_for(stray), notify=lambda message: None)
    assert snapshot(full_run.run_dir) == before


def test_resume_of_another_config_or_a_foreign_checkpoint_is_refused(full_run, tmp_path):
    with pytest.raises(RunError, match="different run .*seeds 2 vs 3"):
        run(spec_for(full_run.run_dir, resume=True, seeds=3), notify=lambda message: None)
    with pytest.raises(RunError, match="no run directory"):
        run(spec_for(tmp_path / "missing", resume=True), notify=lambda message: None)
    # Same config.json, but the checkpoints come from another run (copied in by hand).
    out = tmp_path / "run"
    shutil.copytree(full_run.run_dir, out)
    with Checkpointer(out / "checkpoints") as checkpointer:
        state = checkpointer.restore(make_plan(spec_for(out)).template)[0]
        checkpointer.save(1000, state, {"identity_hash": "0123456789abcdef", "chunk": 49})
    before = snapshot(out)
    with pytest.raises(CheckpointError, match="from another run"):
        run(spec_for(out, resume=True), notify=lambda message: None)
    assert snapshot(out) == before


def test_a_grid_runs_every_config_in_one_program(full_run, tmp_path):
    out = tmp_path / "grid"
    hparams = tuple(fake.Hyperparams(learning_rate=lr) for lr in (0.01, 0.05))
    spec = spec_for(
        out, hparams=hparams, grid_fields=("learning_rate",), total_steps=2 * STEPS_PER_CHUNK
    )
    result = run(spec, notify=lambda message: None)
    rows = read_rows(out / "metrics.jsonl")
    assert {(row["config"], row["learning_rate"]) for row in rows} == {(0, 0.01), (1, 0.05)}
    assert [r.label for r in result.results] == ["learning_rate=0.01", "learning_rate=0.05"]
    assert "ranked" in (out / "results.txt").read_text()
    # Config 0 is the reference run's hyperparameters: same numbers up to float rounding
    # (a batch of 2 configs may be computed with other kernels than a batch of 1).
    reference = {(r["step"], r["seed"]): r for r in read_rows(full_run.run_dir / "metrics.jsonl")}
    for row in rows:
        if row["config"] == 0:
            expected = reference[(row["step"], row["seed"])]
            assert row["eval_return"] == pytest.approx(expected["eval_return"], rel=1e-4)
            assert row["loss"] == pytest.approx(expected["loss"], rel=1e-4)
    lr = np.asarray(result.state.opt_state.hyperparams["learning_rate"])
    np.testing.assert_array_equal(lr, np.float32([[0.01, 0.01], [0.05, 0.05]]))


def test_checkpoints_by_default_space_out_when_writing_them_is_slow():
    """Unset, the interval is 120 s, or long enough that each write takes at most 5% of the time
    from one checkpoint to the next; a given interval is kept as given (0: every chunk)."""
    assert start.checkpoint_interval(None, 0.0) == 120.0
    assert start.checkpoint_interval(None, 5.0) == 120.0
    assert start.checkpoint_interval(None, 30.0) == pytest.approx(570.0)
    assert 30.0 / (30.0 + start.checkpoint_interval(None, 30.0)) == pytest.approx(0.05)
    assert start.checkpoint_interval(0.0, 30.0) == 0.0
    assert start.checkpoint_interval(60.0, 30.0) == 60.0
