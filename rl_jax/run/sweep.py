"""Sweeps: a grid over hyperparameters (vmapped in one program) and config fields (one program
per shape) x seeds, each shape a run directory of its own, ranked together at the end
(``experiments/sweep.py`` is the script; its docstring is the user's guide).

Grid names are hyperparameter or config fields, or the short names of ``ALIASES``. Every shape
runs through ``rl_jax.run.runner.run``, with its checkpoints, progress and ``--resume``, on one
process or on several (``jax.distributed``: process 0 writes and prints, all compute).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax

from rl_jax.errors import (
    OneLineParser,
    RunError,
    UsageError,
    exit_now,
    guard,
)
from rl_jax.run import (
    cli,
    command,
    distributed,
    flags,
    learners,
    plots,
    processes,
    recipe_choice,
    runner,
    sweep_shapes,
)
from rl_jax.run.metrics import METRICS_FILE, read_rows
from rl_jax.run.run_dir import recorded_env
from rl_jax.run.start import REQUEUE_SIGNAL, GracefulStop
from rl_jax.training import params
from rl_jax.training.algorithm import Algorithm, hooks

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from rl_jax.run.spec import RunSpec

ALIASES = {
    "lr": ("actor_lr", "critic_lr", "learning_rate"),
    "width": ("actor_hidden", "critic_hidden", "hidden_sizes"),
    "batch": ("batch_size",),
    "buffer": ("buffer_size",),
}
BUILTIN_NAMES = tuple(learners.ALGORITHMS)  # before any name is registered
SWEEP_FLAGS = ("--algo", "--env", "--grid", *distributed.VALUE_FLAGS)


@dataclasses.dataclass(frozen=True)
class Axis:
    """One --grid: a name, the fields it sets together, and the values."""

    name: str
    fields: tuple[str, ...]
    values: tuple[Any, ...]
    static: bool  # a config field: one compiled program per value


def parse_axis(spec: str, config: DataclassInstance, hparams: DataclassInstance) -> Axis:
    """One ``--grid NAME=V1,V2`` as an axis: the config or hyperparameter fields the name sets
    (an alias may set several) and the parsed values.
    """
    name, text = flags.split_grid_spec(spec)
    static = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    dynamic = {f.name: getattr(hparams, f.name) for f in dataclasses.fields(hparams)}
    known = {**static, **dynamic}
    fields = tuple(f for f in ALIASES.get(name, (name,)) if f in known and f not in flags.NOT_FLAGS)
    if not fields:
        choices = ", ".join([*ALIASES, *dynamic, *static])
        raise UsageError(f"--grid {name}: unknown field; known: {choices}")
    values = flags.grid_values(name, text, known[fields[0]])
    return Axis(name, fields, values, fields[0] in static)


def combos(axes: list[Axis]) -> list[dict[str, Any]]:
    """Field values of every point of the product grid (first axis slowest)."""
    points = params.product({axis.name: axis.values for axis in axes})
    return [{field: point[axis.name] for axis in axes for field in axis.fields} for point in points]


def shape_label(point: dict[str, Any], axes: list[Axis]) -> str:
    """A point of the static axes as ``name=value,...`` (``base`` when there are none), which
    names its run directory.
    """
    parts = []
    for axis in axes:
        value = point[axis.fields[0]]
        text = "x".join(map(str, value)) if isinstance(value, tuple) else str(value)
        parts.append(f"{axis.name}={text}")
    return ",".join(parts) or "base"


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """The sweep's own flags, and every other argument for the runs it starts."""
    parser = OneLineParser(add_help=False)
    parser.add_argument("--algo")
    parser.add_argument("--env")
    parser.add_argument("--grid", action="append", default=[])
    distributed.add_flags(parser)  # read by distributed.start; recorded in no sweep.json
    return parser.parse_known_args(argv)


#: The fields of ``sweep.json`` and their JSON types (list fields hold strings). It is data: a
#: field this code does not write, or a value of another type, is refused.
SWEEP_FIELDS: dict[str, type | tuple[type, ...]] = {
    "algo": str,
    "env": str,
    "grid": list,
    "learner": (str, type(None)),
    "argv": list,
}


def sweep_record(out: Path) -> dict[str, Any]:
    """The ``sweep.json`` of a sweep directory, checked as data; ``RunError`` when there is none
    or it is not one that this code wrote."""
    path = out / "sweep.json"
    if not path.is_file():
        raise RunError(f"no sweep at {out} (no sweep.json)")
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise RunError(f"{path} is unreadable: {error}") from None
    if not isinstance(record, dict) or not {"algo", "env", "grid", "argv"} <= set(record):
        raise RunError(f"{path} is not an rl_jax sweep record")
    for name, value in record.items():
        wanted = SWEEP_FIELDS.get(name)
        strings = not isinstance(value, list) or all(isinstance(item, str) for item in value)
        if wanted is None or not isinstance(value, wanted) or not strings:
            raise RunError(f"{path} is refused: its field {name!r} is not one rl_jax writes")
    return record


def build_specs(
    argv: list[str],
) -> tuple[list[RunSpec], list[str], Path, argparse.Namespace]:
    """One RunSpec per shape of the grid, with its hyperparameter grid inside."""
    sweep_args, rest = parse_args(argv)
    resume = "--resume" in rest
    algorithm = None
    if resume:
        out = Path(rest[rest.index("--resume") + 1])
        saved = sweep_record(out)
        algorithm = _resumed_learner(saved, sweep_args.algo, out)
        # the sweep's env, never imported from its record (run_dir.recorded_env); an env the
        # learner owns is its recorded id itself
        owned = algorithm is not None and hooks(algorithm).owns_env(saved["env"])
        env = saved["env"] if owned else recorded_env(saved["env"], out, sweep_args.env, "--env")
        if owned and sweep_args.env not in (None, env):
            raise RunError(f"{out} is a sweep on {env}, not on {sweep_args.env}")
        sweep_args.algo, sweep_args.env = saved["algo"], env
        sweep_args.grid = saved["grid"]
        rest = [*saved["argv"], *rest]
    if not sweep_args.algo or not sweep_args.env:
        raise UsageError("--algo and --env are required")

    algorithm = algorithm or learners.resolve(sweep_args.algo)
    sweep_args.learner = str(learners.origin_of(algorithm))
    sweep_args.algo = learners.origin_of(algorithm).spelling(algorithm.name)
    env_id = learners.chosen_env(algorithm, sweep_args.env)
    line = command.read(rest)
    recipe = recipe_choice.recipe_named(algorithm, env_id, line.recipe, line.resume is not None)
    out = line.resume or line.out or default_out(env_id, algorithm.name)
    line = dataclasses.replace(line, resume=None, out=None)
    named = learners.cli_args(algorithm)
    choice = command.Choice(algorithm, env_id, recipe, chosen=False)
    base = command.run_spec(line, choice, command.Defaults())
    axes = [parse_axis(spec, base.config, base.hparams[0]) for spec in sweep_args.grid]
    static = [axis for axis in axes if axis.static]
    dynamic = [axis for axis in axes if not axis.static]
    specs, labels = [], []
    for point in combos(static):
        config = command.replace_fields(base.config, point, "config")
        hparams = [
            command.replace_fields(base.hparams[0], p, "hyperparameters") for p in combos(dynamic)
        ]
        command.validate_settings(algorithm, config, hparams)
        label = shape_label(point, static)
        specs.append(
            dataclasses.replace(
                base,
                config=config,
                hparams=tuple(hparams),
                out=Path(out) / label,
                resume=resume and (Path(out) / label / "config.json").is_file(),
                grid_fields=tuple(axis.fields[0] for axis in dynamic),
                grid_names=tuple(axis.name for axis in dynamic),  # lr, not actor_lr
                command=shlex.join([*command.program(), *sys.argv[1:]]),
                resume_command=shlex.join([*command.program(), "--resume", str(out), *named]),
                throughput=None,
            )
        )
        labels.append(label)
    return specs, labels, Path(out), sweep_args


def _resumed_learner(saved: dict[str, Any], named: str | None, out: Path) -> Algorithm:
    """The learner of a resumed sweep: ``--algo`` if given (built in where the sweep's is, and
    checked by name and source against each shape's run on resume), else the sweep's own if it
    is built in; a learner of the user's own is never imported from the record
    (``rl_jax.run.learners``)."""
    # A sweep recorded before "learner" was kept ran a built-in or a registered name.
    recorded = saved.get("learner") or ("builtin" if saved["algo"] in BUILTIN_NAMES else None)
    if named is not None:  # any spelling of the sweep's learner: each shape's run checks it
        learner = learners.resolve(named)
        given = learners.origin_of(learner)
        builtin = (given.kind == learners.BUILTIN, recorded == learners.BUILTIN)
        if recorded is not None and builtin[0] != builtin[1]:
            own = learners.Origin.parse(recorded).describe(saved["algo"])
            raise RunError(
                f"{out} is a sweep of {own}, not of {given.describe(learner.name)}; name the "
                "sweep's own learner"
            )
        return learner
    if recorded == learners.BUILTIN:
        return learners.resolve(saved["algo"])
    raise RunError(
        f"{out} is a sweep of the learner {recorded or saved['algo']}, which a resume does not "
        f"import by itself; name it again: --algo {shlex.quote(saved['algo'])}"
    )


def default_out(env_id: str, algorithm_name: str) -> Path:
    """The default directory of a sweep: ``runs/<env>__<algo>-sweep__<time>/``."""
    return command.default_run_dir(env_id, f"{algorithm_name}-sweep")


def write_record(out: Path, argv: list[str], sweep_args: argparse.Namespace) -> None:
    """Write ``sweep.json`` (learner, env, grid and the runs' arguments) unless it exists, so a
    resume repeats the same sweep.
    """
    passed = [a for a in argv if a not in ("--resume",)]
    record = {"algo": sweep_args.algo, "env": sweep_args.env, "grid": sweep_args.grid}
    record["learner"] = sweep_args.learner
    record["argv"] = [a for a in _without_sweep_flags(passed) if a != str(out)]
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "sweep.json").exists():
        (out / "sweep.json").write_text(json.dumps(record, indent=2) + "\n")


def _without_sweep_flags(argv: list[str]) -> list[str]:
    kept, skip = [], False
    for arg in argv:
        if skip:
            skip = False
            continue
        if arg in (*SWEEP_FLAGS, "--out"):
            skip = True
            continue
        if arg.split("=")[0] in (*SWEEP_FLAGS, *distributed.SWITCH_FLAGS, "--out"):
            continue
        kept.append(arg)
    return kept


def summarize(out: Path, specs: list[RunSpec], labels: list[str], wall_clock: float) -> str:
    """curves.png (one curve per config of every shape) and the ranked results.txt."""
    curves = []
    for spec, label in zip(specs, labels, strict=True):
        rows = read_rows(spec.out / METRICS_FILE)
        for curve in plots.curves_from_rows(rows, spec.grid_fields, spec.grid_labels):
            prefix = "" if label == "base" else label
            curve.label = ", ".join(part for part in (prefix, curve.label) if part) or "base"
            curves.append(curve)
    title = f"{specs[0].algorithm.name} on {specs[0].env_id}: sweep"
    plots.plot_curves(curves, out / "curves.png", title=title, statistic="mean")
    table = plots.sweep_table(plots.final_results(curves), wall_clock)
    (out / "results.txt").write_text(table + "\n")
    return table


def run_sweep(argv: list[str], description: str = "") -> int:
    """The sweep of ``argv`` (the script's flags), shape after shape, then its summary. Under
    ``jax.distributed`` every process runs this with the same flags; the lead writes and prints,
    and the shapes are shared out between the processes where that is faster
    (``rl_jax.run.sweep_shapes``)."""
    started = time.perf_counter()
    specs, labels, out, sweep_args = build_specs(argv)
    lead = processes.is_lead()
    notify = print if lead else _silent
    if lead:
        write_record(out, argv, sweep_args)
    sizes = (len(specs[0].hparams), specs[0].seeds, processes.count(), jax.local_device_count())
    owner = sweep_shapes.owners(len(specs), *sizes)
    if owner is None:
        stopped = _run_in_turn(specs, labels, notify)
    else:  # each process its own shapes
        stopped = sweep_shapes.run_own(specs, labels, owner, notify)
    if stopped:
        return 0
    if lead:
        table = summarize(out, specs, labels, time.perf_counter() - started)
        if len(specs) > 1:  # a single shape's run has just printed this same ranking
            print(table)
        print(f"sweep directory: {out}")
    return 0


def _run_in_turn(specs: list[RunSpec], labels: list[str], notify: Callable[[str], None]) -> bool:
    """Every shape over every process's devices, one after another; whether one was stopped.
    A signal that comes once a shape's last chunk is trained (its last save, its plots, the
    next shape's start) stops the sweep before the next shape, as it would have stopped the
    shape: ``--resume`` continues it, and SIGUSR1 requeues it under SLURM."""
    between = "before the next shape (the shapes trained are kept"
    with GracefulStop(notify, when=between) as stop:
        for index, spec in enumerate(specs, 1):
            # every process starts the shape, or none does
            asked, requeue = processes.agree(
                stop.requested is not None,
                stop.requested == REQUEUE_SIGNAL,
                at="the start of a shape",
            )
            if asked:
                return _stop_between_shapes(requeue, index, specs, notify)
            notify(f"== shape {index}/{len(specs)}: {labels[index - 1]}")
            if runner.run(spec, notify).stopped:
                return True
        return False


def _stop_between_shapes(
    requeue: bool, index: int, specs: list[RunSpec], notify: Callable[[str], None]
) -> bool:
    """The sweep stops before shape ``index`` of ``specs``, asked by a signal; SIGUSR1 on any
    process (``requeue``) puts the job back in SLURM's queue."""
    sweep_shapes.say_stopped_before(f"shape {index}/{len(specs)}", specs[index - 1], notify)
    if requeue and processes.is_lead():
        distributed.slurm_requeue(notify)
    return True


def _silent(message: str) -> None:
    """What the processes other than the lead print: nothing."""


def main(description: str, argv: list[str] | None = None) -> None:
    """A sweep script's whole body: ``--help`` shows ``description`` and the flags; over several
    processes (``rl_jax.run.distributed``'s flags) they join first; user errors are one line."""
    argv = sys.argv[1:] if argv is None else argv
    if {"-h", "--help"} & set(argv):
        exit_now(guard(lambda: cli.run_experiment(None, None, description, argv)))

    def sweep() -> int:
        distributed.start(argv)  # before JAX starts: device count, cache, the processes
        return run_sweep(argv, description)

    exit_now(distributed.guarded(sweep))
