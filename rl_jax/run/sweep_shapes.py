"""A sweep's shapes (grid points of different config fields, one program each) over the processes
of ``jax.distributed``: each process compiles and trains only the shapes it is given, on its own
devices, instead of every process taking part in every shape one after another.

Which is faster is the busier of the two plans, counted in runs per device (every shape of a
sweep has the same configs x seeds; their costs per run are taken as equal):

- one after another: every shape spread over all ``P x D`` devices, ``shapes x
  runs_per_device(P x D)``;
- spread: process ``i`` takes shapes ``i, i + P, ...`` on its ``D`` devices, ``ceil(shapes / P)
  x runs_per_device(D)``.

Ties go to spreading, which gathers nothing between processes. 2 shapes of 5 seeds on 2
processes of one device: 5 runs per device spread, 2 x 3 one after another. 3 shapes of 5
seeds: 2 x 5 against 3 x 3, so one after another. On one process shapes always run one after
another.

Each process writes the run directories of its own shapes, so ``OUT`` must be one directory that
every process sees (a cluster's shared file system; on one machine it is). Process 0 prints the
plan and the progress of its own shapes, waits for the others (``processes.wait_for_all``) and
writes the sweep's summary from every shape's metrics. A signal stops the process it reaches
after its chunk, with a checkpoint (a scheduler signals every process); the others finish their
own shapes first, and the sweep ends as stopped, to be resumed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import jax

from rl_jax.errors import RunError, user_errors
from rl_jax.run import checkpoint, distributed, processes, runner
from rl_jax.run.spec import RunSpec
from rl_jax.run.start import REQUEUE_SIGNAL, GracefulStop
from rl_jax.training.device_layout import plan_layout


def owners(
    num_shapes: int, num_configs: int, num_seeds: int, num_processes: int, local_devices: int
) -> list[int] | None:
    """The process that trains each shape, or None where the shapes are better run one after
    another over every process's devices (see the module's docstring)."""
    if num_processes < 2 or num_shapes < 2:
        return None
    every = num_processes * local_devices
    together = plan_layout(num_configs, num_seeds, every, min_devices=every).runs_per_device
    alone = plan_layout(num_configs, num_seeds, local_devices).runs_per_device
    if math.ceil(num_shapes / num_processes) * alone > num_shapes * together:
        return None
    return [index % num_processes for index in range(num_shapes)]


def say_stopped_before(shape: str, spec: RunSpec, notify: Callable[[str], None]) -> None:
    """The two lines of a sweep stopped by a signal before ``shape`` (``spec``'s): what is kept,
    and the command that resumes it."""
    notify(f"stopped before {shape}; the shapes before it are saved.")
    if spec.resume_command:
        notify(f"resume with: {distributed.resume_hint(spec.resume_command)}")


def run_own(
    specs: Sequence[RunSpec],
    labels: Sequence[str],
    owner: Sequence[int],
    notify: Callable[[str], None],
) -> bool:
    """Train this process's shapes alone, then wait for every process to finish its own.
    Returns whether any process was stopped (a signal) before finishing. A user error in one
    process's shape (a refused resume, memory) still lets it reach the wait, so that every
    process ends with one line rather than waiting for it. A signal once a shape is trained stops
    this process before its next shape; SIGUSR1 on any process requeues the job once, from
    process 0 after every process has saved (a requeue ends the job's every process)."""
    me = jax.process_index()
    for index, (label, process) in enumerate(zip(labels, owner, strict=True), 1):
        notify(f"== shape {index}/{len(specs)}: {label} (process {process})")
    stopped, failure = False, None
    between = "before this process's next shape (the shapes trained are kept"
    with GracefulStop(notify, when=between) as stop:
        with processes.alone(), checkpoint.writing_alone():
            for spec, process in zip(specs, owner, strict=True):
                if process != me:
                    continue
                if stop.requested is not None:
                    stopped = True
                    say_stopped_before(spec.out.name, spec, notify)
                    break
                try:
                    stopped = runner.run(spec, notify).stopped
                except user_errors() as error:
                    failure = error
                if stopped or failure is not None:
                    break
        _wait_for_the_others(specs)
        stopped_any, failed_any, requeue = processes.agree(
            stopped, failure is not None, stop.requested == REQUEUE_SIGNAL
        )
    if failure is not None:
        raise failure
    if failed_any:
        raise RunError("a shape of another process failed (its error is on that process's stderr)")
    if stopped_any and requeue and processes.speaks():
        distributed.slurm_requeue(notify)
    return stopped_any


def _wait_for_the_others(specs: Sequence[RunSpec]) -> None:
    """Every process's shapes trained; one line naming the first process that ended without."""
    try:
        processes.wait_for_all(f"rl_jax sweep shapes trained {specs[0].out.parent}")
    except Exception as error:  # the coordinator's report: the first line says which process
        reason = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise RunError(
            f"another process of the sweep ended before its shapes did: {reason}"
        ) from None
