"""Drive any ``Algorithm`` through a run: plan, compile, train in chunks, log, checkpoint, resume.

``run(spec)`` is the whole story of an experiment script::

    spec = RunSpec(algorithm=td3, env_id="rl_jax/Pendulum-v1", config=td3.default_config(env_id),
                   hparams=(td3.default_hyperparams(),), out=Path("runs/x"), seeds=5,
                   total_steps=50_000)
    result = run(spec)

All seeds (and all hyperparameter configs of a grid) are one compiled program: the state has
leading ``[configs, seeds]`` axes. Between chunks the host writes metrics, updates the progress
line and checkpoints. SIGINT/SIGTERM finish the current chunk, checkpoint and return with
``stopped=True``; ``RunSpec(resume=True)`` continues from the latest checkpoint and reaches the
same final parameters, bit for bit, as a run that never stopped. If the latest checkpoint is
damaged it continues from the newest readable one (redoing the chunks after it, which give the
same results again) and sets the damaged ones aside, one line on stderr each.

Under ``jax.distributed`` (a sweep on several processes) every process runs ``run`` with the same
spec: all compute and gather, and the lead alone writes the directory and prints
(``rl_jax.run.processes``).

The order of work keeps existing runs safe: every check (directory identity, memory, checkpoint
readability) happens before the first write.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from rl_jax.errors import RunError
from rl_jax.run import distributed, learners, plots, processes
from rl_jax.run.best import BEST_DIR, BestPolicies, policy_part
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.divergence import check_finite, finite_runs
from rl_jax.run.lease import Lease
from rl_jax.run.lease import acquire as acquire_lease
from rl_jax.run.metrics import METRICS_FILE, MetricsLog, read_rows
from rl_jax.run.plan import (
    Plan,
    check_env_steps,
    check_memory,
    estimate_remaining,
    format_plan,
    make_plan,
)
from rl_jax.run.progress import Progress
from rl_jax.run.run_dir import (
    CHECKPOINT_DIR,
    CONFIG_FILE,
    CURVES_FILE,
    RESULTS_FILE,
    check_out_dir,
    check_resume_dir,
    same_command_again,
)
from rl_jax.run.spec import RunResult, RunSpec
from rl_jax.run.start import (
    REQUEUE_SIGNAL,
    GracefulStop,
    Start,
    checkpoint_expectation,
    checkpoint_interval,
    fresh_start,
    restore_start,
    set_aside_damaged,
    write_run_record,
)
from rl_jax.run.tracking import WandbRuns, import_wandb
from rl_jax.training import params
from rl_jax.training.algorithm import ChunkMetrics, Hyperparams, TrainState, hooks
from rl_jax.training.validation import check_ranges

#: Checkpoints a run keeps at the least, whatever ``keep_checkpoints`` asks: with one, a damaged
#: latest checkpoint has nothing to fall back on and the whole run is lost.
MIN_KEEP_CHECKPOINTS = 2


# ---- the loop -------------------------------------------------------------------------------


def grid_values(spec: RunSpec) -> list[dict[str, Any]]:
    """Per config, the fields every metrics row of it carries (none for a single config)."""
    if len(spec.hparams) == 1:
        return [{}]
    return [
        {"config": h, **{name: values[name] for name in spec.grid_fields}}
        for h, values in enumerate(spec.identity["hparams"])
    ]


def metric_rows(
    metrics: ChunkMetrics,
    spec: RunSpec,
    chunk: int,
    wall_clock: float,
    grid: list[dict[str, Any]],
) -> list[dict[str, Any]]:
    """One row per (config, seed) from host-side ``ChunkMetrics`` with ``[H, S]`` leaves."""
    rows = []
    configs, seeds = np.shape(metrics.eval_return)
    for h in range(configs):
        for s in range(seeds):
            row = {"step": int(metrics.env_steps[h, s]), "seed": spec.base_seed + s, **grid[h]}
            row["eval_return"] = float(metrics.eval_return[h, s])
            row["train_return"] = float(metrics.train_return[h, s])
            row["updates"] = int(metrics.updates[h, s])
            row["chunk"] = chunk
            row["wall_time"] = round(wall_clock, 3)
            for name, value in metrics.extra.items():
                row[name] = np.asarray(value[h, s]).item()
            rows.append(row)
    return rows


@dataclasses.dataclass
class Session:
    """One process's part of a run: the open log and checkpointer (the lead's only), and its
    counters."""

    spec: RunSpec
    plan: Plan
    log: MetricsLog | None
    checkpointer: Checkpointer | None
    started: float  # perf_counter when this session started
    earlier_wall_clock: float  # seconds spent by earlier sessions
    step: int
    updates: int
    saved_step: int | None
    best: BestPolicies
    best_checkpointer: Checkpointer | None
    last_save: float = dataclasses.field(default_factory=time.perf_counter)
    save_seconds: float = 0.0  # the latest checkpoint's seconds: copy to the host and write
    saved: bool = False  # whether this session wrote a checkpoint (a stop in compiling: none)

    def checkpoint_due(self) -> bool:
        """Whether the next checkpoint is due: the lead decides, the processes agree on it."""
        interval = checkpoint_interval(self.spec.checkpoint_interval, self.save_seconds)
        return processes.is_lead() and time.perf_counter() - self.last_save >= interval

    @classmethod
    def open(cls, spec: RunSpec, plan: Plan, start: Start, started: float) -> Session:
        """The first writes of the run: directory, config.json, metrics, checkpointer (by the
        lead; the other processes of a distributed run keep counters only)."""
        if not processes.is_lead():
            counters = (start.step, start.updates, start.checkpoint_step, start.best, None)
            return cls(spec, plan, None, None, started, start.wall_clock, *counters)
        # Damaged checkpoints move aside first: the checkpointer must not list them, and the
        # session's record says where they went.
        moved = set_aside_damaged(spec, start)
        try:
            spec.out.mkdir(parents=True, exist_ok=True)
            write_run_record(spec, plan, start, moved)
        except OSError as error:
            reason = error.strerror or type(error).__name__
            raise RunError(f"cannot write the run directory {spec.out}: {reason}") from None
        # On a resume, rows after the restored step (or all rows, if there was no checkpoint
        # yet) belong to the interrupted session and will be written again.
        tracker = WandbRuns(spec) if spec.wandb else None
        log = MetricsLog(spec.out, start.step if spec.resume else None, spec.grid_fields, tracker)
        # best/ keeps as many as checkpoints/: its saves are a subset of the checkpoints' steps,
        # so it then still holds the best policies as of any checkpoint a resume falls back to.
        keep = max(MIN_KEEP_CHECKPOINTS, spec.keep_checkpoints)
        checkpointer = Checkpointer(spec.out / CHECKPOINT_DIR, keep=keep)
        best_checkpointer = None
        if start.best.enabled:
            best_checkpointer = Checkpointer(spec.out / BEST_DIR, keep=keep)
            # Best policies newer than the checkpoint resumed from belong to the interrupted
            # session (a crash between the two saves); they will be found again.
            best_checkpointer.discard_after(start.step)
        return cls(
            spec,
            plan,
            log,
            checkpointer,
            started,
            start.wall_clock,
            start.step,
            start.updates,
            start.checkpoint_step,
            start.best,
            best_checkpointer,
        )

    def wall_clock(self) -> float:
        """Seconds of the whole run so far: earlier starts' time plus this one's."""
        return self.earlier_wall_clock + time.perf_counter() - self.started

    def save(self, state: TrainState, hparams: Hyperparams, chunk: int) -> None:
        """Checkpoint the real ``[configs, seeds]`` runs (no padding: a checkpoint resumes on
        any number of devices)."""
        if self.saved_step == self.step:
            return
        began = time.perf_counter()  # the copy to the host is part of a checkpoint's cost
        with processes.waiting("a checkpoint"):
            runs = self.plan.program.unpad(state, hparams)  # every process takes part
        if self.checkpointer is None or self.log is None:  # not the lead (which has both)
            self.saved_step, self.last_save = self.step, time.perf_counter()
            return
        self.log.flush()  # rows up to this step are on disk before the checkpoint exists
        meta = {
            **checkpoint_expectation(self.spec),
            "chunk": chunk,
            "updates": self.updates,
            "wall_clock": self.wall_clock(),
        }
        # The best policies first: a crash between the two saves leaves a best checkpoint
        # newer than the latest one, which a resume discards (never the other way round).
        if self.best_checkpointer is not None and self.best.changed:
            self.best.save(self.best_checkpointer, self.step, meta)
        self.checkpointer.save(self.step, runs, meta)
        self.saved = True
        self.saved_step, self.last_save = self.step, time.perf_counter()
        self.save_seconds = self.last_save - began

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Append metric rows to the run's log (only the lead process has one)."""
        if self.log is not None:
            self.log.write(rows)

    def close(self) -> None:
        """Close the metrics log and the checkpointers, waiting for pending writes."""
        if self.log is not None:
            self.log.close()
        if self.checkpointer is not None:
            self.checkpointer.close()
        if self.best_checkpointer is not None:
            self.best_checkpointer.close()


def compile_chunk(
    plan: Plan, state: TrainState, hparams: Hyperparams, notify: Callable[[str], None]
) -> Callable:
    """Compile ahead of the first chunk so compile time is reported as such."""
    notify("compiling the train chunk ...")
    started = time.perf_counter()
    compiled = plan.program.compile(state, hparams)
    notify(f"compiled in {time.perf_counter() - started:.1f} s")
    return compiled


def _train(session: Session, start: Start, stop: GracefulStop, progress: Progress) -> TrainState:
    """The chunk loop; returns the last state (checkpointed)."""
    spec, plan, state = session.spec, session.plan, start.state
    if start.chunk >= plan.chunks:
        progress.write(f"nothing to train: the run already reached step {start.step:,}")
        return state
    hparams = params.stack(list(spec.hparams))
    chunk_fn = compile_chunk(plan, state, hparams, progress.write)
    progress.start()
    grid = grid_values(spec)
    estimated = False
    for chunk in range(start.chunk, plan.chunks):
        if _stopping(stop):
            # A signal during compilation: nothing new to save. One that came after the last
            # chunk's own check: that chunk is trained and not yet saved.
            if chunk > start.chunk:
                session.save(state, hparams, chunk - 1)
            break
        chunk_started = time.perf_counter()
        state, metrics = chunk_fn(state, hparams)
        # This process's share first: the wait under a time limit is for the others alone.
        jax.block_until_ready(metrics)
        with processes.waiting("the end of a chunk"):
            metrics = plan.program.gather(metrics)
            finite = plan.program.gather_each(lambda s: finite_runs(s, spec), state)
        chunk_seconds = time.perf_counter() - chunk_started
        # Before anything of this chunk is written: what is saved stays as the last good chunk
        # left it, and a resume continues from there.
        check_env_steps(plan, spec.algorithm, chunk, metrics.env_steps)
        prior_updates = session.updates
        session.step = int(np.max(metrics.env_steps))
        session.updates = int(np.max(metrics.updates))
        session.write(metric_rows(metrics, spec, chunk, session.wall_clock(), grid))
        check_finite(session, metrics, finite)
        fetch = functools.partial(_best, plan, state, session)  # this chunk's state
        session.best.observe(metrics.eval_return, metrics.env_steps, fetch)
        progress.update(session.step, session.updates, metrics.eval_return)
        if not estimated and chunk + 1 < plan.chunks:
            estimated = estimate_remaining(
                spec, progress, chunk_seconds, chunk, plan.chunks, prior_updates, session.updates
            )
        due = session.checkpoint_due()
        if _stopping(stop, due) or chunk + 1 == plan.chunks:
            session.save(state, hparams, chunk)
    return state


def _best(plan: Plan, state: TrainState, session: Session) -> dict[str, object]:
    """The policy parts of every run, for the best policies (a gather: every process)."""
    with processes.waiting("the best policies"):
        fields = session.best.fields
        return plan.program.gather_each(lambda s: policy_part(s, fields), state)


def _stopping(stop: GracefulStop, due: bool = False) -> bool:
    """Whether any process was asked to stop (or finds a checkpoint ``due``): the processes of a
    distributed run stop and save together, since saving gathers the state from all of them.
    SIGUSR1 on any of them (the scheduler's time limit is near) reaches the lead as such."""
    asked = stop.requested is not None
    due, requested, requeue = processes.agree(due, asked, stop.requested == REQUEUE_SIGNAL)
    if requeue:
        stop.requested = REQUEUE_SIGNAL
    elif requested and stop.requested is None:
        stop.requested = "another process"
    if requested and not asked:  # the lead says whose signal stops the run
        stop.relay(processes.stopped_by(asked=1, requeue=2))
    return due or requested


# ---- the end --------------------------------------------------------------------------------


def summarize(spec: RunSpec, wall_clock: float) -> tuple[list[plots.FinalResult], str]:
    """curves.png and the results table from metrics.jsonl."""
    rows = read_rows(spec.out / METRICS_FILE)
    if not rows:
        return [], ""
    curves = plots.curves_from_rows(rows, spec.grid_fields, spec.grid_labels)
    title = f"{spec.algorithm.name} on {spec.env_id}"
    plots.plot_curves(curves, spec.out / CURVES_FILE, title=title)
    results = plots.final_results(curves)
    if len(results) == 1:
        table = plots.results_table(results[0], wall_clock)
    else:
        table = plots.sweep_table(results, wall_clock)
    return results, table


def _render_gif(spec: RunSpec, notify: Callable[[str], None]) -> str | None:
    """policy.gif, rendered by ``python -m rl_jax.run.render`` in a child process: MuJoCo picks its
    OpenGL backend once per process, and the child can choose headless EGL whatever this
    process chose. Returns the error line if rendering failed."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(path for path in sys.path if path)}
    # A learner of the user's own is named to the child (it never imports one by itself). The
    # run's own GIF is named as --out: render replaces it (and says so) where a resumed run
    # made one before, rather than writing policy-2.gif beside it.
    command = [sys.executable, "-m", "rl_jax.run.render", str(spec.out)]
    command += ["--out", str(spec.out / "policy.gif")]
    command += learners.cli_args(spec.algorithm)
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or [f"rendering failed ({done.returncode})"]
        return lines[-1].removeprefix("error: ")
    notify(done.stdout.strip())
    return None


def _finish(
    spec: RunSpec,
    session: Session,
    state: TrainState,
    stopped: bool,
    notify: Callable[[str], None],
) -> RunResult:
    """Plots and the results table (or the resume command when stopped), then the GIF; the lead's
    work alone in a distributed run."""
    if not processes.is_lead():
        return RunResult(spec.out, session.step, stopped, state, [], session.wall_clock(), None)
    results, table = summarize(spec, session.wall_clock())
    gif_error = None
    if stopped:
        saved = "checkpoint saved" if session.saved else "nothing new to save"
        notify(f"stopped at step {session.step:,} of {session.plan.final_steps:,}; {saved}.")
        if spec.resume_command:
            notify(f"resume with: {distributed.resume_hint(spec.resume_command)}")
    else:
        notify(table)
        (spec.out / RESULTS_FILE).write_text(table + "\n")
        if spec.gif:
            gif_error = _render_gif(spec, notify)
    return RunResult(
        spec.out, session.step, stopped, state, results, session.wall_clock(), gif_error
    )


# ---- run ------------------------------------------------------------------------------------


def prepare(spec: RunSpec) -> tuple[Plan, Start]:
    """Every check and the starting state, before anything is written."""
    if spec.seeds < 1:
        raise RunError(f"--seeds must be >= 1, got {spec.seeds}")
    if spec.total_steps < 1:
        raise RunError(f"--total-steps must be >= 1, got {spec.total_steps}")
    if not spec.hparams:
        raise RunError("no hyperparameter config to run")
    check_ranges(spec.algorithm, spec.config, spec.hparams)  # scripts, grids and the API alike
    if spec.wandb:
        import_wandb()  # a missing package is one line before anything compiles, in every process
    if spec.resume:
        learners.check_same(check_resume_dir(spec.out, spec.identity), spec.algorithm, spec.out)
    else:
        check_out_dir(spec.out, spec.identity)
    plan = make_plan(spec)
    check_memory(plan, hooks(spec.algorithm).replay_capacity(spec.config))
    start = restore_start(spec, plan) if spec.resume else None
    start = start or fresh_start(spec, plan)
    # Every process has read what it needs before the lead writes (distributed runs).
    processes.barrier(f"rl_jax prepared {spec.out}")
    return plan, start


def run(spec: RunSpec, notify: Callable[[str], None] = print) -> RunResult:
    """Train ``spec`` to ``total_steps`` (or until a signal), leaving a complete run directory."""
    started = time.perf_counter()
    spec = dataclasses.replace(spec, out=Path(spec.out))
    if not processes.speaks():
        notify = _silent
    # An existing run is owned before anything of it is read; a new one once it is checked.
    # (Every process takes part in _own, which holds a lease on the lead alone.)
    existing = (spec.out / CONFIG_FILE).is_file()
    (existing,) = processes.agree(existing, at="the run directory's record")
    lease = _own(spec) if existing else None
    try:
        if not spec.resume and same_command_again(spec.out, spec.identity, spec.command):
            # a requeued job, or the same command after a crash: it continues the run
            notify(f"{spec.out} holds this run, started by this same command: continuing it")
            spec = dataclasses.replace(spec, resume=True)
        plan, start = prepare(spec)
        if not existing:
            lease = _own(spec)
    except BaseException:
        if lease is not None:
            lease.release()
        raise
    try:
        return _run_owned(spec, plan, start, started, notify)
    finally:
        if lease is not None:
            lease.release()


def _own(spec: RunSpec) -> Lease | None:
    """The run directory's lease, held by the lead process (``rl_jax.run.lease``); every
    process stops with one line when the lead cannot take it."""
    lease, error = None, None
    if processes.is_lead():
        try:
            lease = acquire_lease(spec.out, spec.command)
        except RunError as refused:
            error = refused
    (refused_by_lead,) = processes.agree(error is not None, at="the lease of the run directory")
    if error is not None:
        raise error
    if refused_by_lead:
        raise RunError(f"process 0 could not take {spec.out} (its output says why)")
    return lease


def _run_owned(
    spec: RunSpec, plan: Plan, start: Start, started: float, notify: Callable[[str], None]
) -> RunResult:
    """The run of ``run`` once its directory is this process's: train, then finish."""
    notify(format_plan(spec, plan))
    session = Session.open(spec, plan, start, started)  # after the lines on damaged checkpoints
    if start.checkpoint_step is not None:
        notify(f"resuming from the checkpoint at step {start.step:,} (chunk {start.chunk})")
    runs = spec.seeds * len(spec.hparams)
    progress = Progress(
        plan.final_steps,  # the budget in whole chunks: the line never passes 100%
        start.step,
        start.updates,
        runs,
        file=None if processes.speaks() else io.StringIO(),
        tty=None if processes.speaks() else False,
        log_interval=spec.log_interval,
    )
    try:
        with GracefulStop(progress.write) as stop:
            state = _train(session, start, stop, progress)
            with processes.waiting("the end of the run"):
                state = plan.program.unpad(state, params.stack(list(spec.hparams)))
    finally:
        progress.close()
        session.close()
    stopped = stop.requested is not None and session.step < plan.final_steps
    result = _finish(spec, session, state, stopped, notify)
    # Within ``alone`` (a sweep's own shapes) the sweep requeues once every process has saved.
    requeue = stopped and stop.requested == REQUEUE_SIGNAL
    if requeue and processes.is_lead() and not processes.is_alone():
        distributed.slurm_requeue(notify)
    return result


def _silent(message: str) -> None:
    """The notify of the processes other than the lead."""
