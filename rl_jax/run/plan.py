"""The plan of a run, before anything runs: its compiled program over the devices, chunks, the
state's memory (refused when it would not fit) and the time estimates.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import jax
import numpy as np

from rl_jax.errors import RunError
from rl_jax.run import plots, processes
from rl_jax.run.progress import Progress
from rl_jax.run.spec import RunSpec
from rl_jax.training import parallel, params
from rl_jax.training.algorithm import Algorithm, Hyperparams, TrainState, hooks
from rl_jax.training.device_layout import MIN_BLOCK_SEEDS, plan_layout
from rl_jax.training.split_program import SplitLayout, SplitProgram, split_layout

#: The fewest chunks with which a run on CPU devices is split unevenly rather than padded: the
#: split's extra compiles (one per block) must be paid back by its faster chunks (BENCHMARKS.md,
#: section 8, measures both).
SPLIT_MIN_CHUNKS = 10
LAYOUTS = ("auto", "pad", "split")


def program_for(spec: RunSpec, chunks: int | None = None) -> parallel.Program | SplitProgram:
    """All configs x seeds of ``spec`` as one program spread over every device (those of every
    process under ``jax.distributed``, or this process's own within ``processes.alone``).

    Runs that do not divide over the devices are laid out in one of two ways
    (``spec.layout``: "pad", "split", or "auto" to choose):

    - **padded** (``training.device_layout.plan_layout``): copies of the first seed (or config)
      are computed and dropped, so that every device holds an equal block of one program: 5
      seeds on 2 devices as 3 + 3; on 4 devices as 2 + 2 + 2 on three of them. One compilation,
      one ``shard_map``, and equal blocks for the gathers of a mesh over processes. Where
      devices have compute of their own (GPUs, processes) a chunk takes the busiest device's
      time, which holds as many runs as any split would give it.
    - **split** (``training.split_program``): each device its own program on a block of the
      real runs, 3 + 2, or 2 + 1 + 1 + 1, one compilation per block. CPU devices of one process
      share the same cores, so there a padded copy costs its share of them and a device left
      out leaves its share idle; the split computes the real runs only, on every device.

    "auto" splits a run of one process on CPU devices whose padded layout computes a copy or
    leaves a device out, when it has at least ``SPLIT_MIN_CHUNKS`` chunks to pay back the extra
    compiles; otherwise it pads. ``python -m bench uneven_devices`` measures the layouts side
    by side.

    The copies never reach anything saved: metrics, checkpoints, best policies and curves hold
    the real ``[configs, seeds]`` runs only (``unpad``/``gather``), so a run resumes on any
    number of devices or layout. Each run computes what it computes on one device, bit for bit
    where XLA compiles each device's block to the same kernels (5 seeds as 3 + 3, or 3 + 2,
    against 5 on one device do); a block of a single seed may round differently. A single run
    stays on one device.

    A learner whose ``loop_seeds`` hook says so (DQN on frames) runs its seeds as an unrolled
    loop instead of a vmap (``rl_jax.training.parallel.seed_loop``): faster for conv nets on
    CPU."""
    loop_seeds = bool(hooks(spec.algorithm).loop_seeds(spec.config))
    devices = list(processes.devices())
    num_hparams = len(spec.hparams)
    if choose_split(spec.layout, num_hparams, spec.seeds, devices, chunks):
        return SplitProgram(
            spec.algorithm, spec.config, num_hparams, spec.seeds, devices, loop_seeds=loop_seeds
        )
    return parallel.Program(
        spec.algorithm, spec.config, num_hparams, spec.seeds, devices=devices, loop_seeds=loop_seeds
    )


def choose_split(
    layout: str, num_hparams: int, num_seeds: int, devices: list[jax.Device], chunks: int | None
) -> bool:
    """Whether ``[H, S]`` runs go unevenly split over ``devices`` (see ``program_for``)."""
    if layout not in LAYOUTS:
        raise RunError(f"--layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    one_process = all(d.process_index == jax.process_index() for d in devices)
    if layout == "split" and not one_process:
        raise RunError(
            "--layout split needs the devices of one process: a mesh over processes is padded"
        )
    runs = num_hparams * num_seeds
    if layout == "pad" or runs == 1 or len(devices) == 1 or not one_process:
        return False
    if layout == "split":
        return True
    padded = plan_layout(num_hparams, num_seeds, len(devices))
    split = split_layout(num_hparams, num_seeds, len(devices))
    # The split must leave the busiest device no more runs than padding does (3 seeds on 2
    # devices pad to 2 + 2 rather than split as one block of 3: no block holds a lone seed),
    # and either compute fewer runs or use more devices.
    better = split.runs_per_device < padded.runs_per_device or (
        split.runs_per_device == padded.runs_per_device
        and (padded.padding > 0 or split.devices > padded.devices)
    )
    on_cpu = all(d.platform == "cpu" for d in devices)
    return better and on_cpu and chunks is not None and chunks >= SPLIT_MIN_CHUNKS


@dataclasses.dataclass
class Plan:
    """What a run will compute and hold: chunking of the env steps, the train state's size on the
    devices and in a checkpoint, and the compiled program.
    """

    steps_per_chunk: int
    chunks: int
    final_steps: int
    state_bytes: int  # device_bytes + checkpoint_bytes
    breakdown: list[tuple[str, int]]  # (top-level field of the state, bytes), largest first
    available_bytes: int
    template: TrainState  # ShapeDtypeStruct tree of the [configs, seeds] state, as checkpointed
    program: parallel.Program | SplitProgram  # the compiled init/chunk of all runs
    device_bytes: int = 0  # the state on the devices, padding copies included
    checkpoint_bytes: int = 0  # the host copy of the real runs a checkpoint write takes


def leaf_bytes(leaf: jax.Array | jax.ShapeDtypeStruct) -> int:
    """Bytes of one array or shape (PRNG keys counted as their key data)."""
    if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.eval_shape(jax.random.key_data, leaf)
    return int(np.prod(leaf.shape)) * np.dtype(leaf.dtype).itemsize


def memory_breakdown(template: TrainState) -> list[tuple[str, int]]:
    """Bytes of the state per top-level field, largest first."""
    totals: dict[str, int] = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(template)[0]:
        name = jax.tree_util.keystr(path[:1]).strip(".[]'\"") or "state"
        totals[name] = totals.get(name, 0) + leaf_bytes(leaf)
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
    program = program_for(spec, chunks)
    hparams = params.stack(list(spec.hparams))
    template = runs_template(spec, hparams)
    on_devices = memory_breakdown(program.template(hparams))
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
        program,
        device_bytes,
        checkpoint_bytes,
    )


def runs_template(spec: RunSpec, hparams: Hyperparams) -> TrainState:
    """Shapes and dtypes of the ``[configs, seeds]`` state (the shared clock unstacked), without
    allocating: what a checkpoint holds, whatever the device layout."""
    abstract = parallel.one_run_shapes(spec.algorithm, spec.config, hparams)
    runs = (len(spec.hparams), spec.seeds)
    return parallel.map_axes(
        lambda axis, leaf: (
            leaf if axis is None else jax.ShapeDtypeStruct((*runs, *leaf.shape), leaf.dtype)
        ),
        parallel.state_axes(abstract),
        abstract,
    )


def format_bytes(size: float) -> str:
    """A byte count in B, KB, MB, GB or TB (powers of 1024)."""
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(size) < 1024 or unit == "TB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.2f} {unit}"
        size /= 1024
    return f"{size:.2f} TB"


def buffer_that_fits(plan: Plan, buffer_size: int | None) -> int | None:
    """The largest ``--buffer-size`` (two significant digits, rounded down) with which the state
    fits in memory, everything else unchanged; None where no replay buffer would do."""
    buffer = dict(plan.breakdown).get("buffer")
    if not buffer_size or not buffer:
        return None
    room = plan.available_bytes - (plan.state_bytes - buffer)
    fits = int(buffer_size * room / buffer) if room > 0 else 0
    if fits < 1:
        return None
    step = 10 ** max(len(str(fits)) - 2, 0)
    return fits // step * step


def check_memory(plan: Plan, buffer_size: int | None = None) -> None:
    """Refuse, with the estimate, a state that would not fit in memory (and, given the replay
    buffer's capacity, ``buffer_size``: the learner's ``replay_capacity``, the one that
    would)."""
    if plan.state_bytes > plan.available_bytes:
        largest = ", ".join(f"{name} {format_bytes(size)}" for name, size in plan.breakdown[:2])
        fits = buffer_that_fits(plan, buffer_size)
        hint = f" (--buffer-size {fits} fits)" if fits else ""
        raise RunError(
            f"the train state needs {format_bytes(plan.state_bytes)} ({largest}; "
            f"{format_bytes(plan.device_bytes)} in training and "
            f"{format_bytes(plan.checkpoint_bytes)} for the copy a checkpoint writes) but only "
            f"{format_bytes(plan.available_bytes)} of memory is available; reduce the replay "
            f"buffer{hint}, the number of envs, --seeds or the grid"
        )


def format_plan(spec: RunSpec, plan: Plan) -> str:
    """The plan as the lines printed before training: runs, chunks, state size against the memory
    available, and the time estimate.
    """
    configs = len(spec.hparams)
    runs = plots.count_of(spec.seeds, "seed")
    if configs > 1:
        runs += f" x {configs} configs ({', '.join(spec.grid_labels)})"
    num_envs = hooks(spec.algorithm).envs_per_seed(spec.config)
    envs = f", {plots.count_of(num_envs, 'env')} each" if num_envs else ""
    largest = ", ".join(f"{name} {format_bytes(size)}" for name, size in plan.breakdown[:3])
    lines = [
        f"plan: {spec.algorithm.name} on {spec.env_id}, {runs}{envs}, {_programs(plan)}",
        f"  {budget_line(spec.total_steps, plan)}",
        f"  train state {format_bytes(plan.state_bytes)} ({largest}); "
        f"{format_bytes(plan.available_bytes)} of memory available",
        f"  devices: {describe_layout(plan.program)}",
        *seed_equality_lines(spec.seeds, bool(getattr(plan.program, "loop_seeds", False))),
        f"  run directory: {spec.out}",
    ]
    estimate = estimate_from_throughput(spec, plan)
    lines.append(estimate or "  estimated time: measured on the first training chunk")
    return "\n".join(lines)


def _programs(plan: Plan) -> str:
    """How many compiled programs train the runs: one, or one per block size of an uneven
    split (``SplitProgram``)."""
    layout = plan.program.layout
    shapes = layout.shapes if isinstance(layout, SplitLayout) else 1
    return "one compiled program" if shapes == 1 else f"{shapes} compiled programs"


def budget_line(total_steps: int, plan: Plan) -> str:
    """The env steps a run takes, in whole chunks: a budget that is not a whole number of
    chunks is rounded up, and the line says so (a chunk is one compiled call: it cannot stop
    part way)."""
    chunks = f"{plots.count_of(plan.chunks, 'chunk')} of {plan.steps_per_chunk:,}"
    if plan.final_steps == total_steps:
        return f"{plan.final_steps:,} env steps per seed in {chunks}"
    return (
        f"{total_steps:,} env steps per seed round up to {plan.final_steps:,}, whole chunks: "
        f"{chunks}"
    )


def seed_equality_lines(num_seeds: int, loop_seeds: bool) -> list[str]:
    """Which other runs give a seed of this one the same numbers: with its seeds vmapped in
    blocks of ``device_layout.MIN_BLOCK_SEEDS`` or more, every layout of the command, and not
    the seed run alone. Nothing for one seed, or seeds computed in a loop (a learner's hook)."""
    if num_seeds == 1 or loop_seeds:
        return []
    return [
        f"  seeds: {MIN_BLOCK_SEEDS} or more per block: each seed's numbers are the same in every "
        "layout of this command, not those of the seed run alone (--seeds 1)"
    ]


def describe_layout(program: parallel.Program | SplitProgram) -> str:
    """Which devices run how many runs, padding included."""
    layout = program.layout
    names = ", ".join(str(device) for device in program.devices)
    if isinstance(layout, SplitLayout):
        blocks = " + ".join(str(block.runs) for block in layout.blocks)
        programs = "one program" if layout.shapes == 1 else f"{layout.shapes} programs"
        return f"{names} ({blocks} runs, split unevenly: {programs})"
    text = f"{names} ({plots.count_of(layout.runs_per_device, 'run')} each"
    if layout.padding:
        copies = "copy" if layout.padding == 1 else "copies"
        text += f"; {layout.padding} padding {copies} of a run computed and dropped"
    return text + ")"


# ---- time estimates -------------------------------------------------------------------------


def estimate_remaining(
    spec: RunSpec,
    progress: Progress,
    chunk_seconds: float,
    chunk: int,
    chunks: int,
    prior_updates: int,
    updates: int,
) -> bool:
    """Print the time left from the measured ``chunk`` (counted from 0) of ``chunks``, once the
    chunk is representative: warm-up chunks (random actions, no gradient updates) run many
    times faster than training ones, so the line may come after a few chunks, and it names the
    chunk it measured. Returns whether it printed."""
    no_warm_up = hooks(spec.algorithm).warm_up_steps(spec.config) == 0
    if updates == 0 or not (prior_updates > 0 or no_warm_up):
        return False
    remaining_chunks = chunks - chunk - 1
    remaining = plots.format_duration(chunk_seconds * remaining_chunks)
    which = "the last chunk" if remaining_chunks == 1 else f"the remaining {remaining_chunks}"
    progress.write(
        f"measured: chunk {chunk + 1} of {chunks} took {chunk_seconds:.2f} s; about "
        f"{remaining} left for {which}"
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
        f"with {plots.count_of(measured_runs, 'seed')} on a 2-core machine; re-estimated after "
        "the first training chunk)"
    )


# ---- the budget, chunk by chunk -------------------------------------------------------------


def check_env_steps(
    plan: Plan, algorithm: Algorithm, chunk: int, env_steps: np.ndarray | jax.Array
) -> None:
    """Refuse, with one line that names the hook to define, a learner whose env steps after
    ``chunk`` (counted from 0; every seed and config of the run) are not the plan's: ``chunk +
    1`` times its ``env_steps_per_chunk``. A run's budget, progress, checkpoints and time
    estimates all count in planned chunks, so a learner whose chunk takes more env steps than
    it says would overrun them unnoticed."""
    planned = (chunk + 1) * plan.steps_per_chunk
    reported = np.asarray(env_steps).reshape(-1)
    wrong = reported[reported != planned]
    if wrong.size == 0:
        return
    if hooks(algorithm).defines_hook("env_steps_per_chunk"):
        source = f"{plan.steps_per_chunk:,} per chunk, from its env_steps_per_chunk"
        fix = "make env_steps_per_chunk(config) return"
    else:
        source = (
            f"{plan.steps_per_chunk:,} per chunk, env_steps_per_chunk's default: num_envs x "
            "iterations_per_chunk"
        )
        fix = "define env_steps_per_chunk(config) to return"
    raise RunError(
        f"the learner {algorithm.name} reported {int(wrong[0]):,} env steps per seed after chunk "
        f"{chunk + 1}, but the plan has {planned:,} ({source}); {fix} the env steps one "
        "train_chunk takes per seed"
    )
