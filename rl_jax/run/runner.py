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
same final parameters, bit for bit, as a run that never stopped.

The order of work keeps existing runs safe: every check (directory identity, memory, checkpoint
readability) happens before the first write.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from rl_jax.run import plots
from rl_jax.run.best import BEST_DIR, BestPolicies, policy_fields, policy_part
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.metrics import METRICS_FILE, MetricsLog, read_rows
from rl_jax.run.progress import Progress
from rl_jax.run.run_dir import (
    CONFIG_FILE,
    RunError,
    algorithm_reference,
    check_out_dir,
    check_resume_dir,
    identity,
    identity_hash,
    new_run_record,
    write_json_atomic,
)
from rl_jax.training import parallel, params
from rl_jax.training.algorithm import hooks
from rl_jax.training.validation import check_ranges

CHECKPOINT_DIR = "checkpoints"
CURVES_FILE = "curves.png"
RESULTS_FILE = "results.txt"

__all__ = ["DivergenceError", "RunError", "RunResult", "RunSpec", "make_plan", "run"]


class DivergenceError(RunError):
    """A run's parameters or evaluation became non-finite: the run stopped before saving it."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything a run needs. ``hparams`` holds one ``Hyperparams`` per config of a grid."""

    algorithm: Any
    env_id: str
    config: Any
    hparams: tuple[Any, ...]
    out: Path
    seeds: int = 1
    total_steps: int = 100_000
    resume: bool = False
    base_seed: int = 0
    grid_fields: tuple[str, ...] = ()  # hyperparameters a grid varies (logged on every row)
    checkpoint_interval: float = 120.0  # seconds; also at the end and when stopped
    keep_checkpoints: int = 3
    log_interval: float = 30.0  # seconds between progress lines when not on a terminal
    gif: bool = False
    command: str = ""  # the command line, recorded in config.json
    resume_command: str = ""  # printed when stopped
    memory_limit: int | None = None  # bytes the state may use (default: what the OS reports)
    # (env steps/s per seed, number of seeds) measured for the script's default config: the
    # plan's time estimate before anything runs. None: estimated after the first training chunk.
    throughput: tuple[float, int] | None = None

    @property
    def seed_numbers(self) -> range:
        """The seeds of the run: ``base_seed`` and on, the same under every config of a grid."""
        return range(self.base_seed, self.base_seed + self.seeds)

    @property
    def identity(self) -> dict[str, Any]:
        return identity(
            self.algorithm.name,
            self.env_id,
            self.config,
            list(self.hparams),
            self.seeds,
            self.base_seed,
        )


@dataclasses.dataclass
class RunResult:
    run_dir: Path
    step: int  # env steps per seed reached
    stopped: bool  # True when a signal ended the run before total_steps
    state: Any  # the final train state, leaves [configs, seeds, ...]
    results: list[plots.FinalResult]
    wall_clock: float  # seconds over all sessions of the run, compilation included
    gif_error: str | None = None


# ---- the parallel program -------------------------------------------------------------------


def parallel_runner(spec: RunSpec) -> parallel.Runner:
    """All configs x seeds of ``spec`` as one program over the most local devices that split the
    runs evenly (``rl_jax.training.parallel.mesh_shape``): 5 seeds on 2 cores run on one device.

    Never padded: on CPU one device's matmuls and env steps already use every core's threads, so
    a padded run costs its full share. Measured (load 1-2): REINFORCE on the double pendulum, 5
    seeds, 20 updates took 119 s on 1 device against 142 s padded to 3 + 3 on 2 devices (the
    6/5 of the padded seed); TD3 updates, 6 seeds: 0.92 of the matmul rate on one device against
    0.58 sharded (BENCHMARKS.md, TD3 section 1).

    A config with ``loop_seeds`` set (DQN on frames) runs its seeds as an unrolled loop instead
    of a vmap (``rl_jax.training.parallel.seed_loop``): faster for conv nets on CPU."""
    loop_seeds = bool(getattr(spec.config, "loop_seeds", False))
    return parallel.Runner(
        spec.algorithm,
        spec.config,
        len(spec.hparams),
        spec.seeds,
        pad=False,
        loop_seeds=loop_seeds,
    )


# ---- the plan -------------------------------------------------------------------------------


@dataclasses.dataclass
class Plan:
    steps_per_chunk: int
    chunks: int
    final_steps: int
    state_bytes: int  # device_bytes + checkpoint_bytes
    breakdown: list[tuple[str, int]]  # (top-level field of the state, bytes), largest first
    available_bytes: int
    template: Any  # jax.ShapeDtypeStruct tree of the [configs, seeds] state (as checkpointed)
    parallel: parallel.Runner  # the compiled init/chunk of all runs
    device_bytes: int = 0  # the state on the devices, padding copies included
    checkpoint_bytes: int = 0  # the host copy of the real runs a checkpoint write takes


def _leaf_bytes(leaf: Any) -> int:
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.eval_shape(jax.random.key_data, leaf)
    return int(np.prod(leaf.shape)) * np.dtype(leaf.dtype).itemsize


def memory_breakdown(template: Any) -> list[tuple[str, int]]:
    """Bytes of the state per top-level field, largest first."""
    totals: dict[str, int] = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(template)[0]:
        name = jax.tree_util.keystr(path[:1]).strip(".[]'\"") or "state"
        totals[name] = totals.get(name, 0) + _leaf_bytes(leaf)
    return sorted(totals.items(), key=lambda item: -item[1])


def available_memory() -> int:
    """Bytes a new allocation can use: MemAvailable, capped by a cgroup limit if any."""
    available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                available = int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        limit = Path("/sys/fs/cgroup/memory.max").read_text().strip()
        used = int(Path("/sys/fs/cgroup/memory.current").read_text())
        if limit != "max":
            available = min(available, int(limit) - used)
    except (OSError, ValueError):
        pass
    return available


def make_plan(spec: RunSpec) -> Plan:
    """Sizes of the run, computed with ``jax.eval_shape`` (nothing is allocated)."""
    steps_per_chunk = int(hooks(spec.algorithm).env_steps_per_chunk(spec.config))
    if steps_per_chunk <= 0:
        raise RunError(f"the config takes {steps_per_chunk} env steps per chunk; need >= 1")
    chunks = math.ceil(spec.total_steps / steps_per_chunk)
    runner = parallel_runner(spec)
    hparams = params.stack(list(spec.hparams))
    template = runs_template(spec, hparams)
    on_devices = memory_breakdown(runner.template(hparams))
    # Checkpoints go through a host copy of the real runs: count it too.
    checkpoint_copy = dict(memory_breakdown(template))
    breakdown = sorted(
        ((name, size + checkpoint_copy.get(name, 0)) for name, size in on_devices),
        key=lambda item: -item[1],
    )
    available = spec.memory_limit if spec.memory_limit is not None else available_memory()
    device_bytes = sum(size for _, size in on_devices)
    checkpoint_bytes = sum(checkpoint_copy.values())
    return Plan(
        steps_per_chunk,
        chunks,
        chunks * steps_per_chunk,
        device_bytes + checkpoint_bytes,
        breakdown,
        available,
        template,
        runner,
        device_bytes,
        checkpoint_bytes,
    )


def runs_template(spec: RunSpec, hparams: Any) -> Any:
    """Shapes and dtypes of the ``[configs, seeds]`` state (the shared clock unstacked), without
    allocating: what a checkpoint holds, whatever the device layout."""
    one = jax.tree.map(lambda x: jnp.asarray(x[0]), hparams)
    abstract = jax.eval_shape(
        lambda key: spec.algorithm.init(key, spec.config, one), jax.random.key(0)
    )
    runs = (len(spec.hparams), spec.seeds)
    return parallel._map_axes(
        lambda axis, leaf: (
            leaf if axis is None else jax.ShapeDtypeStruct((*runs, *leaf.shape), leaf.dtype)
        ),
        parallel.state_axes(abstract),
        abstract,
    )


def format_bytes(size: float) -> str:
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(size) < 1024 or unit == "TB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.2f} {unit}"
        size /= 1024
    return f"{size:.2f} TB"


def check_memory(plan: Plan) -> None:
    """Refuse, with the estimate, a state that would not fit in memory."""
    if plan.state_bytes > plan.available_bytes:
        largest = ", ".join(f"{name} {format_bytes(size)}" for name, size in plan.breakdown[:2])
        raise RunError(
            f"the train state needs {format_bytes(plan.state_bytes)} ({largest}; "
            f"{format_bytes(plan.device_bytes)} in training and "
            f"{format_bytes(plan.checkpoint_bytes)} for the copy a checkpoint writes) but only "
            f"{format_bytes(plan.available_bytes)} of memory is available; reduce the replay "
            "buffer, the number of envs, --seeds or the grid"
        )


def format_plan(spec: RunSpec, plan: Plan) -> str:
    configs = len(spec.hparams)
    runs = f"{spec.seeds} seed{'s' * (spec.seeds > 1)}"
    if configs > 1:
        runs += f" x {configs} configs ({', '.join(spec.grid_fields)})"
    num_envs = getattr(spec.config, "num_envs", None)
    envs = f", {num_envs} envs each" if num_envs else ""
    largest = ", ".join(f"{name} {format_bytes(size)}" for name, size in plan.breakdown[:3])
    lines = [
        f"plan: {spec.algorithm.name} on {spec.env_id}, {runs}{envs}, one compiled program",
        f"  {plan.final_steps:,} env steps per seed in {plan.chunks} chunks of "
        f"{plan.steps_per_chunk:,} (asked for {spec.total_steps:,})",
        f"  train state {format_bytes(plan.state_bytes)} ({largest}); "
        f"{format_bytes(plan.available_bytes)} of memory available",
        f"  devices: {describe_layout(plan.parallel)}",
        f"  run directory: {spec.out}",
    ]
    estimate = estimate_from_throughput(spec, plan)
    lines.append(estimate or "  estimated time: measured on the first training chunk")
    return "\n".join(lines)


def describe_layout(runner: parallel.Runner) -> str:
    """Which devices run how many runs, padding included."""
    layout = runner.layout
    names = ", ".join(str(device) for device in runner.mesh.devices.flat)
    text = f"{names} ({layout.runs_per_device} run{'s' * (layout.runs_per_device > 1)} each"
    if layout.padding:
        text += f"; {layout.padding} padding copy of a run computed and dropped"
    return text + ")"


# ---- stopping on signals --------------------------------------------------------------------


class GracefulStop:
    """The first SIGINT/SIGTERM asks to stop after the current chunk; a second SIGINT aborts."""

    def __init__(self, notify: Callable[[str], None] = print):
        self.requested: str | None = None
        self._notify = notify
        self._previous: dict[int, Any] = {}

    def _handle(self, signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        if self.requested is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.requested = name
        self._notify(
            f"{name}: stopping after this chunk (a checkpoint follows; Ctrl-C again aborts)"
        )

    def __enter__(self) -> GracefulStop:
        for signum in (signal.SIGINT, signal.SIGTERM):
            # Outside the main thread signals cannot be caught: they stay with the caller.
            with contextlib.suppress(ValueError):
                self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc_info: Any) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)


# ---- starting: fresh or resumed -------------------------------------------------------------


@dataclasses.dataclass
class Start:
    state: Any
    chunk: int  # first chunk to run
    step: int  # env steps per seed already done
    updates: int
    wall_clock: float  # seconds spent by earlier sessions
    checkpoint_step: int | None  # the checkpoint restored, if any
    best: BestPolicies  # the best evaluated policy of every run so far


def _checkpoint_expectation(spec: RunSpec) -> dict[str, Any]:
    return {
        "identity_hash": identity_hash(spec.identity),
        "algorithm": spec.algorithm.name,
        "env_id": spec.env_id,
    }


def restore_start(spec: RunSpec, plan: Plan) -> Start | None:
    """The latest checkpoint of a resumed run (None if it has none yet). Writes nothing."""
    directory = spec.out / CHECKPOINT_DIR
    if not directory.is_dir():
        return None
    with Checkpointer(directory, read_only=True) as checkpointer:
        if checkpointer.latest_step() is None:
            return None
        state, meta = checkpointer.restore(plan.template, expect=_checkpoint_expectation(spec))
    best = BestPolicies.restore(
        spec.out / BEST_DIR,
        policy_fields(spec.algorithm, plan.template),
        plan.template,
        at_most=meta["step"],
        expect=_checkpoint_expectation(spec),
    )
    return Start(
        plan.parallel.place(state, params.stack(list(spec.hparams))),
        meta["chunk"] + 1,
        meta["step"],
        meta.get("updates", 0),
        meta.get("wall_clock", 0.0),
        meta["step"],
        best,
    )


def fresh_start(spec: RunSpec, plan: Plan) -> Start:
    keys = parallel.seed_keys(spec.seed_numbers)
    state = plan.parallel.init(keys, params.stack(list(spec.hparams)))
    best = BestPolicies(policy_fields(spec.algorithm, state), (len(spec.hparams), spec.seeds))
    return Start(state, 0, 0, 0, 0.0, None, best)


def _write_run_record(spec: RunSpec, plan: Plan, start: Start) -> None:
    """config.json: created on a fresh run, updated (total steps, sessions) on a resume."""
    path = spec.out / CONFIG_FILE
    session = {
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "command": spec.command,
        "from_step": start.step,
    }
    if spec.resume:
        from rl_jax.run.run_dir import read_run_record

        record = read_run_record(spec.out)
        record["total_steps"] = spec.total_steps
        record["sessions"] = [*record.get("sessions", []), session]
    else:
        extra = {
            "total_steps": spec.total_steps,
            "steps_per_chunk": plan.steps_per_chunk,
            "grid_fields": list(spec.grid_fields),
            "command": spec.command,
            "sessions": [session],
        }
        record = new_run_record(spec.identity, algorithm_reference(spec.algorithm), extra)
    write_json_atomic(path, record)


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
    metrics: Any, spec: RunSpec, chunk: int, wall_clock: float, grid: list[dict[str, Any]]
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
    """One process's part of a run: the open log and checkpointer, and its counters."""

    spec: RunSpec
    plan: Plan
    log: MetricsLog
    checkpointer: Checkpointer
    started: float  # perf_counter when this session started
    earlier_wall_clock: float  # seconds spent by earlier sessions
    step: int
    updates: int
    saved_step: int | None
    best: BestPolicies
    best_checkpointer: Checkpointer | None
    last_save: float = dataclasses.field(default_factory=time.perf_counter)

    @classmethod
    def open(cls, spec: RunSpec, plan: Plan, start: Start, started: float) -> Session:
        """The first writes of the run: directory, config.json, metrics, checkpointer."""
        try:
            spec.out.mkdir(parents=True, exist_ok=True)
            _write_run_record(spec, plan, start)
        except OSError as error:
            reason = error.strerror or type(error).__name__
            raise RunError(f"cannot write the run directory {spec.out}: {reason}") from None
        # On a resume, rows after the restored step (or all rows, if there was no checkpoint
        # yet) belong to the interrupted session and will be written again.
        log = MetricsLog(spec.out, start.step if spec.resume else None, spec.grid_fields)
        checkpointer = Checkpointer(spec.out / CHECKPOINT_DIR, keep=spec.keep_checkpoints)
        best_checkpointer = None
        if start.best.enabled:
            best_checkpointer = Checkpointer(spec.out / BEST_DIR, keep=spec.keep_checkpoints)
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
        return self.earlier_wall_clock + time.perf_counter() - self.started

    def save(self, state: Any, hparams: Any, chunk: int) -> None:
        """Checkpoint the real ``[configs, seeds]`` runs (no padding: a checkpoint resumes on
        any number of devices)."""
        if self.saved_step == self.step:
            return
        self.log.flush()  # rows up to this step are on disk before the checkpoint exists
        meta = {
            **_checkpoint_expectation(self.spec),
            "chunk": chunk,
            "updates": self.updates,
            "wall_clock": self.wall_clock(),
        }
        # The best policies first: a crash between the two saves leaves a best checkpoint
        # newer than the latest one, which a resume discards (never the other way round).
        if self.best_checkpointer is not None and self.best.changed:
            self.best.save(self.best_checkpointer, self.step, meta)
        self.checkpointer.save(self.step, self.plan.parallel.unpad(state, hparams), meta)
        self.saved_step, self.last_save = self.step, time.perf_counter()

    def close(self) -> None:
        self.log.close()
        self.checkpointer.close()
        if self.best_checkpointer is not None:
            self.best_checkpointer.close()


def compile_chunk(plan: Plan, state: Any, hparams: Any, notify: Callable) -> Callable:
    """Compile ahead of the first chunk so compile time is reported as such."""
    notify("compiling the train chunk ...")
    started = time.perf_counter()
    compiled = plan.parallel.compile(state, hparams)
    notify(f"compiled in {time.perf_counter() - started:.1f} s")
    return compiled


def _train(session: Session, start: Start, stop: GracefulStop, progress: Progress) -> Any:
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
        if stop.requested:  # a signal during compilation: nothing new to save
            break
        chunk_started = time.perf_counter()
        state, metrics = chunk_fn(state, hparams)
        metrics = plan.parallel.gather(metrics)
        chunk_seconds = time.perf_counter() - chunk_started
        prior_updates = session.updates
        session.step = int(np.max(metrics.env_steps))
        session.updates = int(np.max(metrics.updates))
        session.log.write(metric_rows(metrics, spec, chunk, session.wall_clock(), grid))
        check_finite(session, metrics, plan.parallel.gather(_finite_runs(state, spec)))
        session.best.observe(
            metrics.eval_return,
            metrics.env_steps,
            lambda state=state: plan.parallel.gather(policy_part(state, session.best.fields)),
        )
        progress.update(session.step, session.updates, metrics.eval_return)
        if not estimated and chunk + 1 < plan.chunks:
            estimated = _estimate(
                spec,
                progress,
                chunk_seconds,
                plan.chunks - chunk - 1,
                prior_updates,
                session.updates,
            )
        due = time.perf_counter() - session.last_save >= spec.checkpoint_interval
        if due or stop.requested or chunk + 1 == plan.chunks:
            session.save(state, hparams, chunk)
    return state


@jax.jit
def _all_finite(tree: Any) -> jax.Array:
    """``[H, S]``: whether every float leaf of each run of ``tree`` is finite."""
    flags = [
        jnp.all(jnp.isfinite(leaf), axis=tuple(range(2, leaf.ndim)))
        for leaf in jax.tree.leaves(tree)
        if jnp.issubdtype(leaf.dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(flags), axis=0) if flags else jnp.bool_(True)


def _finite_runs(state: Any, spec: RunSpec) -> Any:
    """Per run (padded ``[H, S]``), whether its policy part (or whole state) is finite."""
    fields = policy_fields(spec.algorithm, state)
    return _all_finite(policy_part(state, fields) if fields else state)


def check_finite(session: Session, metrics: Any, finite_state: np.ndarray) -> None:
    """Stop the run, before its state is saved, when a run's parameters or eval return are no
    longer finite, or a loss overflowed to infinity: one line names the runs, the step and the
    likely cause. (A NaN loss alone is no sign: learners report NaN for "no update here", e.g.
    while warming up; a NaN that came from diverging reaches the parameters.)"""
    spec = session.spec
    params_ok = np.asarray(finite_state, bool)
    eval_ok = np.isfinite(np.asarray(metrics.eval_return, dtype=np.float64))
    losses_ok = np.ones_like(eval_ok)
    for value in metrics.extra.values():
        value = np.asarray(value)
        if value.dtype.kind == "f" and value.shape == losses_ok.shape:
            losses_ok &= ~np.isinf(value)
    finite = params_ok & eval_ok & losses_ok
    if finite.all():
        return
    bad = np.argwhere(~finite)
    runs = ", ".join(
        f"seed {spec.base_seed + s}" + (f" of config {h}" if len(spec.hparams) > 1 else "")
        for h, s in bad
    )
    what = [
        name
        for name, ok in (
            ("parameters", params_ok),
            ("eval return", eval_ok),
            ("losses", losses_ok),
        )
        if not ok[~finite].all()
    ]
    rates = sorted(
        {
            f"--{name.replace('_', '-')} {float(np.asarray(getattr(spec.hparams[h], name))):g}"
            for h, _ in bad
            for name in _rate_fields(spec.hparams[h])
        }
    )
    clipping = any(
        f.name == "max_grad_norm" for h, _ in bad for f in dataclasses.fields(spec.hparams[h])
    )
    kept = (
        f"the last finite checkpoint (step {session.saved_step:,}) is kept"
        if session.saved_step is not None
        else "no checkpoint had been written yet"
    )
    raise DivergenceError(
        f"training diverged at step {session.step:,}: {runs} got non-finite "
        f"{' and '.join(what)}; {kept} and the run stops here. Likely cause: a learning rate "
        f"too high for this problem ({', '.join(rates) or 'see config.json'}) or exploding "
        "gradients; try a lower rate"
        + (" or a lower --max-grad-norm (gradient clipping)" if clipping else "")
    )


def _rate_fields(hparams: Any) -> list[str]:
    return [
        f.name
        for f in dataclasses.fields(hparams)
        if f.name == "lr" or f.name.endswith(("_lr", "learning_rate"))
    ]


def _estimate(
    spec: RunSpec,
    progress: Progress,
    chunk_seconds: float,
    remaining_chunks: int,
    prior_updates: int,
    updates: int,
) -> bool:
    """Print the time left from a measured chunk, once the chunk is representative: warm-up
    chunks (random actions, no gradient updates) run many times faster than training ones.
    Returns whether it printed."""
    no_warm_up = getattr(spec.config, "learning_starts", 0) == 0
    if updates == 0 or not (prior_updates > 0 or no_warm_up):
        return False
    remaining = plots.format_duration(chunk_seconds * remaining_chunks)
    progress.write(
        f"measured: a training chunk took {chunk_seconds:.2f} s; about {remaining} left for "
        f"the remaining {remaining_chunks} chunks"
    )
    return True


def estimate_from_throughput(spec: RunSpec, plan: Plan) -> str | None:
    """The plan's time estimate from the script's documented throughput (for its own default
    config only), scaled to the number of runs: a CPU-bound program shares the cores."""
    if spec.throughput is None or spec.resume:
        return None
    steps_per_second, measured_runs = spec.throughput
    runs = spec.seeds * len(spec.hparams)
    rate = steps_per_second * measured_runs / runs
    seconds = plan.final_steps / rate
    return (
        f"  estimated time: about {plots.format_duration(seconds)} of training plus compilation "
        f"(from the script's documented {steps_per_second:,.0f} env steps/s per seed measured "
        f"with {measured_runs} seeds on a 2-core machine; re-estimated after the first training "
        "chunk)"
    )


# ---- the end --------------------------------------------------------------------------------


def summarize(spec: RunSpec, wall_clock: float) -> tuple[list[plots.FinalResult], str]:
    """curves.png and the results table from metrics.jsonl."""
    rows = read_rows(spec.out / METRICS_FILE)
    if not rows:
        return [], ""
    curves = plots.curves_from_rows(rows, spec.grid_fields)
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
    env.setdefault("MUJOCO_GL", "egl")
    command = [sys.executable, "-m", "rl_jax.run.render", str(spec.out)]
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines() or [f"rendering failed ({done.returncode})"]
        return lines[-1].removeprefix("error: ")
    notify(done.stdout.strip())
    return None


def _finish(
    spec: RunSpec, session: Session, state: Any, stopped: bool, notify: Callable[[str], None]
) -> RunResult:
    """Plots and the results table (or the resume command when stopped), then the GIF."""
    results, table = summarize(spec, session.wall_clock())
    gif_error = None
    if stopped:
        notify(
            f"stopped at step {session.step:,} of {session.plan.final_steps:,}; checkpoint saved."
        )
        if spec.resume_command:
            notify(f"resume with: {spec.resume_command}")
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
    if spec.resume:
        check_resume_dir(spec.out, spec.identity)
    else:
        check_out_dir(spec.out, spec.identity)
    plan = make_plan(spec)
    check_memory(plan)
    start = restore_start(spec, plan) if spec.resume else None
    return plan, start or fresh_start(spec, plan)


def run(spec: RunSpec, notify: Callable[[str], None] = print) -> RunResult:
    """Train ``spec`` to ``total_steps`` (or until a signal), leaving a complete run directory."""
    started = time.perf_counter()
    spec = dataclasses.replace(spec, out=Path(spec.out))
    plan, start = prepare(spec)
    notify(format_plan(spec, plan))
    if start.checkpoint_step is not None:
        notify(f"resuming from the checkpoint at step {start.step:,} (chunk {start.chunk})")
    session = Session.open(spec, plan, start, started)
    runs = spec.seeds * len(spec.hparams)
    progress = Progress(
        spec.total_steps, start.step, start.updates, runs, log_interval=spec.log_interval
    )
    try:
        with GracefulStop(progress.write) as stop:
            state = _train(session, start, stop, progress)
            state = plan.parallel.unpad(state, params.stack(list(spec.hparams)))
    finally:
        progress.close()
        session.close()
    stopped = stop.requested is not None and session.step < plan.final_steps
    return _finish(spec, session, state, stopped, notify)
