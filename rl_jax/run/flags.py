"""Flags from dataclasses: one per field of an algorithm's ``Config``/``Hyperparams`` (typed by
the field's default, documented by ``field_docs``), the run contract's flags, and ``--grid``.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rl_jax.errors import UsageError, parse_float, parse_int, positive_int
from rl_jax.run.field_docs import field_docs
from rl_jax.run.plan import LAYOUTS, SPLIT_MIN_CHUNKS

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

#: Config fields that are not flags: the env is chosen by the script (or --env).
NOT_FLAGS = ("env_id",)


def parse_bool(text: str) -> bool:
    """argparse type: 1/true/yes/on or 0/false/no/off, in any case."""
    lowered = text.strip().lower()
    if lowered in ("1", "true", "yes", "on"):
        return True
    if lowered in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"invalid boolean value: {text!r}")


def non_negative_float(text: str) -> float:
    """argparse type: a float >= 0."""
    value = parse_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


#: A config or hyperparameter field's value: a Python scalar, a tuple (widths) or a 0-d array.
FieldValue = bool | int | float | str | tuple | np.generic | np.ndarray


def kind_of(default: FieldValue) -> str:
    """bool, int, float, str or tuple: how a field's values are parsed."""
    if isinstance(default, tuple):
        return "tuple"
    if isinstance(default, (bool, np.bool_)):
        return "bool"
    if isinstance(default, (int, np.integer)):
        return "int"
    if isinstance(default, (float, np.floating)):
        return "float"
    if hasattr(default, "dtype") and getattr(default, "ndim", 1) == 0:
        return {"b": "bool", "i": "int", "u": "int", "f": "float"}.get(default.dtype.kind, "str")
    return "str"


def parser_for(default: FieldValue) -> Callable[[str], FieldValue]:
    """The argparse type that parses a value of ``default``'s kind: bool, int, float, a
    comma-separated tuple, or a string.
    """
    kind = kind_of(default)
    if isinstance(default, tuple):  # kind "tuple"
        # An empty default says nothing of its elements: widths and sizes are whole numbers.
        element = parser_for(default[0]) if default else parse_int

        def parse_tuple(text: str) -> tuple:
            parts = [part for part in text.replace(" ", "").split(",") if part]
            return tuple(element(part) for part in parts)

        return parse_tuple
    return {"bool": parse_bool, "int": parse_int, "float": parse_float}.get(kind, str)


def _metavar(default: FieldValue) -> str:
    if isinstance(default, tuple):  # kind "tuple"
        return f"{kind_of(default[0]).upper() if default else 'X'},..."
    return kind_of(default).upper()


def describe_default(default: FieldValue) -> str:
    """A default as its flag would take it: ``256,256`` for a tuple, 7 digits of a float."""
    if isinstance(default, tuple):
        return ",".join(str(v) for v in default)
    if hasattr(default, "item"):
        default = default.item()
    if isinstance(default, float):
        # Float32 leaves widen to noise digits (0.995 -> 0.9950000047683716): 7 significant
        # digits are what float32 holds.
        return f"{default:.7g}"
    return str(default)


# ---- the parser -----------------------------------------------------------------------------


def flag_name(field: str) -> str:
    """The command-line flag of a config field: ``batch_size`` -> ``--batch-size``."""
    return "--" + field.replace("_", "-")


def add_dataclass_flags(
    parser: argparse.ArgumentParser, instance: DataclassInstance, title: str
) -> list[str]:
    """One flag per field of ``instance``; absent flags stay absent (explicit ones override)."""
    group = parser.add_argument_group(title)
    docs = field_docs(type(instance))
    names = []
    for field in dataclasses.fields(instance):
        if field.name in NOT_FLAGS:
            continue
        default = getattr(instance, field.name)
        doc = docs.get(field.name) or f"{type(instance).__name__}.{field.name}"
        help_text = f"{doc} (default: {describe_default(default)})".replace("%", "%%")
        if kind_of(default) == "bool":
            group.add_argument(
                flag_name(field.name),
                dest=field.name,
                help=help_text,
                action=argparse.BooleanOptionalAction,
                default=argparse.SUPPRESS,
            )
        else:
            group.add_argument(
                flag_name(field.name),
                dest=field.name,
                help=help_text,
                type=parser_for(default),
                default=argparse.SUPPRESS,
                metavar=_metavar(default),
            )
        names.append(field.name)
    return names


def add_run_flags(parser: argparse.ArgumentParser, seeds: int, total_steps: int) -> None:
    """The run contract: --seeds, --total-steps, --out, --resume, --gif, and run settings."""
    # Long only because it is one flat list of flags, each a call read on its own.
    group = parser.add_argument_group("run")
    add = group.add_argument
    add(
        "--seeds",
        type=positive_int,
        default=argparse.SUPPRESS,
        metavar="N",
        help=f"independent seeds, trained together in one compiled program (default: {seeds})",
    )
    add(
        "--total-steps",
        type=positive_int,
        default=argparse.SUPPRESS,
        metavar="N",
        help=f"env steps per seed, rounded up to whole chunks (default: {total_steps:,})",
    )
    add(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="run directory to create (default: runs/<env>__<algo>__<time>/)",
    )
    add(
        "--resume",
        type=Path,
        default=None,
        metavar="DIR",
        help="continue the run in DIR from its latest checkpoint (its config is reused)",
    )
    add(
        "--gif",
        action="store_true",
        help="at the end, write policy.gif of the deterministic policy of the best seed",
    )
    add(
        "--wandb",
        action="store_true",
        help="also log each seed's curves and the config to Weights & Biases, one W&B run per "
        'seed grouped by run directory (needs wandb: pip install "rl_jax[tracking]")',
    )
    add(
        "--base-seed",
        type=parse_int,
        default=argparse.SUPPRESS,
        metavar="N",
        help="seed numbers are base-seed .. base-seed + seeds - 1 (default: 0)",
    )
    add(
        "--grid",
        action="append",
        default=[],
        metavar="NAME=V1,V2,...",
        help="sweep a hyperparameter over values (repeat for a product grid); all configs and "
        "seeds run as one compiled program",
    )
    add(
        "--checkpoint-interval",
        type=non_negative_float,
        default=None,
        metavar="SECONDS",
        help="minimum seconds between checkpoints; one is always written at the end and when "
        "stopped by Ctrl-C/SIGTERM (default: 120, or more where writing one takes over 5%% of "
        "that, as a large replay buffer can)",
    )
    add(
        "--keep-checkpoints",
        type=positive_int,
        default=3,
        metavar="N",
        help="checkpoints kept on disk, newest first; at least 2, so that a --resume has an older "
        "one to fall back on if the latest is damaged (default: 3)",
    )
    add(
        "--layout",
        choices=LAYOUTS,
        default="auto",
        help="runs that do not divide over the devices: pad them with copies computed and "
        "dropped (one program), split them unevenly (a program per block size), or auto: split "
        f"on CPU devices for runs of {SPLIT_MIN_CHUNKS} chunks or more, pad elsewhere (default: "
        "auto)",
    )
    add(
        "--log-interval",
        type=non_negative_float,
        default=30.0,
        metavar="SECONDS",
        help="seconds between progress lines when the output is not a terminal (default: 30)",
    )


# ---- grids ----------------------------------------------------------------------------------


def split_grid_spec(spec: str) -> tuple[str, str]:
    """``"learning-rate=1e-4,3e-4"`` -> ``("learning_rate", "1e-4,3e-4")``."""
    name, equals, values = spec.partition("=")
    name = name.strip().lstrip("-").replace("-", "_")
    if not equals or not values.strip():
        raise UsageError(f"--grid {spec!r}: expected NAME=V1,V2,...")
    return name, values


def grid_values(name: str, text: str, default: FieldValue) -> tuple[FieldValue, ...]:
    """The comma-separated values of one ``--grid``, parsed as ``default``'s kind (tuples, e.g.
    widths, are written 64x64 so that commas can separate values)."""
    kind = kind_of(default)
    parse = parser_for(default)
    try:
        return tuple(
            parse(value.replace("x", ",") if kind == "tuple" else value)
            for value in text.split(",")
            if value.strip()
        )
    except argparse.ArgumentTypeError as error:
        raise UsageError(f"--grid {name} takes {kind} values: {error}") from None


def parse_grid(
    specs: list[str], hparams: DataclassInstance, config: DataclassInstance
) -> dict[str, list[FieldValue]]:
    """``["lr=1e-4,3e-4", "tau=0.005,0.02"]`` -> ``{"learning_rate": [...], "tau": [...]}``."""
    fields = {f.name: getattr(hparams, f.name) for f in dataclasses.fields(hparams)}
    static = {f.name for f in dataclasses.fields(config)}
    grid: dict[str, list[Any]] = {}
    for spec in specs:
        name, values = split_grid_spec(spec)
        if name in static:
            raise UsageError(
                f"--grid {name}: {name} is a static config field (it changes shapes); only "
                f"hyperparameters can be swept in one program: {', '.join(fields)}"
            )
        if name not in fields:
            raise UsageError(f"--grid {name}: unknown hyperparameter; known: {', '.join(fields)}")
        if name in grid:
            raise UsageError(f"--grid {name} given twice")
        grid[name] = list(grid_values(name, values, fields[name]))
    return grid
