"""Command-line helpers for experiment scripts: the run contract, flags built from the algorithm's
``Config``/``Hyperparams`` dataclasses (their field docstrings or comments become ``--help``),
validation, and a top-level guard that turns every user error into one line on stderr.

An experiment script is a few lines::

    from rl_jax.run import cli
    from rl_jax.agents import td3

    if __name__ == "__main__":
        cli.main(td3, "rl_jax/Pendulum-v1", __doc__, seeds=5, total_steps=20_000,
                 config={"num_envs": 8}, hparams={"learning_rate": 1e-3})

With ``algorithm=None`` / ``env_id=None`` the script takes ``--algo`` / ``--env`` flags instead.
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

import jax

import envs
from rl_jax.errors import (
    OneLineParser,
    RunError,
    UsageError,
    exit_now,
    guard,
)
from rl_jax.run import runner
from rl_jax.run.flags import (
    add_dataclass_flags,
    add_run_flags,
    flag_name,
    kind_of,
    parse_grid,
    take_recipe,
)
from rl_jax.run.run_dir import load_algorithm, read_run_record
from rl_jax.run.spec import RunSpec
from rl_jax.training import params
from rl_jax.training.algorithm import hooks
from rl_jax.training.jax_setup import configure_jax
from rl_jax.training.params import dataclass_from_dict
from rl_jax.training.validation import out_of_range

#: name -> "module" or "module:attribute" of every algorithm the CLI knows (imported on use).
ALGORITHMS: dict[str, str] = {
    "td3": "rl_jax.agents.td3:td3",
    "ddpg": "rl_jax.agents.td3:ddpg",
    "dqn": "rl_jax.agents.dqn:dqn",
    "reinforce": "rl_jax.agents.reinforce:reinforce",
}
RUNS_ROOT = Path("runs")


def register_algorithm(name: str, reference: str) -> None:
    ALGORITHMS[name] = reference


def resolve_algorithm(name: str) -> Any:
    """The algorithm registered as ``name``."""

    if name not in ALGORITHMS:
        known = ", ".join(sorted(ALGORITHMS))
        raise UsageError(f"unknown algorithm {name!r}; known algorithms: {known}")
    try:
        return load_algorithm(ALGORITHMS[name])
    except RunError as error:
        raise UsageError(f"algorithm {name!r} is not available: {error}") from None


# ---- building the run -----------------------------------------------------------------------


def default_run_dir(env_id: str, algorithm_name: str) -> Path:
    """``runs/<env>__<algo>__<time>/`` (a suffix if that name is taken)."""
    env_name = env_id.split("/")[-1]
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = RUNS_ROOT / f"{env_name}__{algorithm_name}__{stamp}"
    suffix = 1
    while path.exists():
        suffix += 1
        path = RUNS_ROOT / f"{env_name}__{algorithm_name}__{stamp}-{suffix}"
    return path


def _explicit(args: argparse.Namespace, names: list[str]) -> dict[str, Any]:
    return {name: getattr(args, name) for name in names if hasattr(args, name)}


def replace_fields(instance: Any, values: dict[str, Any], what: str) -> Any:
    try:
        return dataclasses.replace(instance, **values)
    except (TypeError, ValueError) as error:
        raise UsageError(f"invalid {what}: {error}") from None


@dataclasses.dataclass
class Defaults:
    """What a script chooses; flags override it."""

    seeds: int = 1
    total_steps: int = 100_000
    config: dict[str, Any] = dataclasses.field(default_factory=dict)
    hparams: dict[str, Any] = dataclasses.field(default_factory=dict)
    # (env steps/s per seed, seeds) measured for this default config: the plan's time estimate
    throughput: tuple[float, int] | None = None
    # offer the algorithm's ``named_recipes`` as ``--recipe NAME`` (a script with recipes of its
    # own offers those instead)
    named_recipes: bool = True
    # the flags as the user typed them, when a script took some out before (its own --recipe):
    # the run records these as its command, so that the command reruns the same run
    typed_argv: tuple[str, ...] | None = None


def _recipes_of(algorithm: Any, defaults: Defaults) -> dict[str, tuple[dict, dict]]:
    return dict(getattr(algorithm, "named_recipes", {})) if defaults.named_recipes else {}


def with_named_recipe(
    argv: list[str], algorithm: Any, defaults: Defaults, env_id: str | None = None
) -> tuple[list[str], Defaults]:
    """``--recipe NAME`` of the algorithm's ``named_recipes`` (whole recipes such as td3's
    ``paper``: config and hyperparameter overrides on top of the env's recipe and the script's
    defaults), taken out of ``argv``; for ``env_id``, with the recipe's overrides for that env
    (``named_recipe_envs``). ``UsageError`` for an unknown name or with ``--resume`` (a resumed
    run keeps the settings it recorded)."""
    recipes = _recipes_of(algorithm, defaults)
    if not recipes:
        return argv, defaults
    name, rest = take_recipe(argv, {"default": None, **recipes}, "default")
    if name == "default":
        return rest, defaults
    if any(arg == "--resume" or arg.startswith("--resume=") for arg in rest):
        raise UsageError(
            "--recipe starts a new run; --resume continues a run with the settings it recorded"
        )
    config, hparams = recipes[name]
    per_env = getattr(algorithm, "named_recipe_envs", {}).get(name, {})
    config = {**config, **per_env.get(env_id, {})}
    return rest, dataclasses.replace(
        defaults,
        config={**defaults.config, **config},
        hparams={**defaults.hparams, **hparams},
        throughput=None,
    )


def _base(algorithm: Any, env_id: str, defaults: Defaults) -> tuple[Any, Any]:
    """The algorithm's recipe for ``env_id`` with the script's overrides."""
    try:
        config = algorithm.default_config(env_id)
        hparams = algorithm.default_hyperparams(env_id)
    except (ValueError, TypeError, KeyError) as error:
        raise UsageError(f"{algorithm.name} cannot run {env_id}: {error}") from None
    config = replace_fields(config, defaults.config, "config")
    return config, replace_fields(hparams, defaults.hparams, "hyperparameters")


def validate_settings(algorithm: Any, config: Any, hparams_list: list[Any]) -> None:
    """Ranges (``rl_jax.training.validation``), then the algorithm's own ``validate(config,
    hparams)`` when it has one: before anything compiles, for every config of a grid."""

    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if kind_of(value) == "int" and not isinstance(value, bool) and value < 0:
            raise UsageError(f"{flag_name(field.name)} must be >= 0, got {value}")
    problem = out_of_range(config, algorithm)
    if problem:
        raise UsageError(problem)
    for hparams in hparams_list:
        problem = out_of_range(hparams, algorithm)
        if problem:
            raise UsageError(problem)
        try:
            hooks(algorithm).validate(config, hparams)
        except ValueError as error:
            raise UsageError(str(error)) from None


def check_env_fits(algorithm: Any, config: Any, hparams: Any) -> None:
    """The algorithm can act in the env (TD3 needs a bounded Box action space, say): its init,
    traced without running, raises the algorithm's own TypeError or ValueError otherwise, which
    ``--env`` with any gymnasium id makes a user error rather than a bug."""
    try:
        jax.eval_shape(lambda key: algorithm.init(key, config, hparams), jax.random.key(0))
    except (TypeError, ValueError) as error:
        raise UsageError(f"{algorithm.name} cannot run {config.env_id}: {error}") from None


def build_parser(
    algorithm: Any, env_id: str, description: str, defaults: Defaults, choose: bool
) -> tuple[argparse.ArgumentParser, list[str], list[str]]:
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    if choose:
        _add_choice_flags(parser)
    add_run_flags(parser, defaults.seeds, defaults.total_steps)
    recipes = _recipes_of(algorithm, defaults)
    if recipes:  # taken out of argv before parsing (with_named_recipe); here for --help
        parser.add_argument(
            "--recipe",
            metavar="NAME",
            default="default",
            help=f"a whole recipe of {algorithm.name} on top of the env's: default (the env's "
            f"own), {', '.join(recipes)} (its named_recipes)",
        )
    config, hparams = _base(algorithm, env_id, defaults)
    config_names = add_dataclass_flags(parser, config, f"{algorithm.name} config (static)")
    hparam_names = add_dataclass_flags(parser, hparams, f"{algorithm.name} hyperparameters")
    return parser, config_names, hparam_names


def _add_choice_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--algo", default=None, metavar="NAME", help=f"algorithm: {', '.join(sorted(ALGORITHMS))}"
    )
    parser.add_argument(
        "--env",
        default=None,
        metavar="ID",
        help="environment id: a registered one (rl_jax/Pendulum-v1); gymnasium:ID for any "
        "gymnasium env, stepped on the host (gymnasium:Pendulum-v1); or MODULE:ID to import "
        "MODULE first, which registers ID with envs.register (your own env: "
        "examples.hover_rocket:examples/HoverRocket-v0); MODULE is searched on the Python path "
        "and in the current directory",
    )


def _choose(argv: list[str], algorithm: Any, env_id: str | None) -> tuple[Any, str, bool]:
    """Algorithm and env: fixed by the script, or from --algo/--env (or the resumed run)."""
    if algorithm is not None and env_id is not None:
        return algorithm, envs.core.registry.resolve_id(env_id), False
    pre = OneLineParser(add_help=False)
    _add_choice_flags(pre)
    pre.add_argument("--resume", type=Path, default=None)
    known, _ = pre.parse_known_args(argv)
    record = read_run_record(known.resume)["identity"] if known.resume else None
    name = known.algo or (record["algorithm"] if record else None)
    env_name = env_id or known.env or (record["env_id"] if record else None)
    if {"-h", "--help"} & set(argv) and (algorithm or name) is None:
        return None, "", True
    if algorithm is None and name is None:
        raise UsageError("--algo is required")
    if env_name is None:
        raise UsageError("--env is required")
    return algorithm or resolve_algorithm(name), envs.core.registry.resolve_id(env_name), True


def _help_without_algorithm(description: str, defaults: Defaults) -> int:
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_choice_flags(parser)
    add_run_flags(parser, defaults.seeds, defaults.total_steps)
    parser.epilog = "Give --algo and --env to list the algorithm's config and hyperparameter flags."
    parser.print_help()
    return 0


def _resumed_settings(args: argparse.Namespace, algorithm: Any, env_id: str) -> dict[str, Any]:
    """Config, hyperparameters, seeds and steps recorded by the run being resumed."""

    record = read_run_record(args.resume)
    saved = record["identity"]
    if saved["algorithm"] != algorithm.name or saved["env_id"] != env_id:
        raise RunError(
            f"cannot resume {args.resume}: it is a {saved['algorithm']} run on "
            f"{saved['env_id']}, this is {algorithm.name} on {env_id}"
        )
    config = dataclass_from_dict(algorithm.default_config(env_id), saved["config"])
    template = algorithm.default_hyperparams()
    hparams = [dataclass_from_dict(template, values) for values in saved["hparams"]]
    return {
        "config": config,
        "hparams": hparams,
        "seeds": saved["seeds"],
        "base_seed": saved["base_seed"],
        "total_steps": record.get("total_steps", 1),
        "grid_fields": tuple(record.get("grid_fields", ())),
    }


def _fresh_settings(algorithm: Any, env_id: str, defaults: Defaults) -> dict[str, Any]:
    """The script's defaults for a new run (flags are applied on top)."""
    config, hparams = _base(algorithm, env_id, defaults)
    return {
        "config": config,
        "hparams": [hparams],
        "seeds": defaults.seeds,
        "base_seed": 0,
        "total_steps": defaults.total_steps,
        "grid_fields": (),
    }


def build_spec(
    args: argparse.Namespace,
    algorithm: Any,
    env_id: str,
    defaults: Defaults,
    names: tuple[list[str], list[str]],
    argv: list[str],
) -> Any:
    """The ``RunSpec`` the flags describe (for ``--resume``: the recorded run, then the flags)."""
    if args.resume is not None and args.out is not None and args.out != args.resume:
        raise UsageError("--out and --resume name different directories; give only --resume")
    resume = args.resume is not None
    settings = (
        _resumed_settings(args, algorithm, env_id)
        if resume
        else _fresh_settings(algorithm, env_id, defaults)
    )
    config = replace_fields(settings["config"], _explicit(args, names[0]), "config")
    explicit_hparams = _explicit(args, names[1])
    hparams = [replace_fields(h, explicit_hparams, "hyperparameters") for h in settings["hparams"]]
    grid_fields = settings["grid_fields"]
    if args.grid:
        grid = parse_grid(args.grid, hparams[0], config)
        if set(grid) & set(explicit_hparams):
            raise UsageError(
                f"{', '.join(set(grid) & set(explicit_hparams))} given as flag and grid"
            )
        hparams, grid_fields = params.expand(hparams[0], grid), tuple(grid)
    validate_settings(algorithm, config, hparams)
    check_env_fits(algorithm, config, hparams[0])
    out = args.resume if resume else (args.out or default_run_dir(env_id, algorithm.name))
    script = shlex.join([Path(sys.executable).name, sys.argv[0]])
    return RunSpec(
        algorithm=algorithm,
        env_id=env_id,
        config=config,
        hparams=tuple(hparams),
        out=Path(out),
        seeds=getattr(args, "seeds", settings["seeds"]),
        total_steps=getattr(args, "total_steps", settings["total_steps"]),
        resume=resume,
        base_seed=getattr(args, "base_seed", settings["base_seed"]),
        grid_fields=grid_fields,
        checkpoint_interval=args.checkpoint_interval,
        keep_checkpoints=args.keep_checkpoints,
        log_interval=args.log_interval,
        gif=args.gif,
        command=shlex.join([Path(sys.executable).name, sys.argv[0], *argv]),
        resume_command=f"{script} --resume {shlex.quote(str(out))}",
        # The documented throughput holds for the script's own config only.
        throughput=None
        if resume or args.grid or _explicit(args, names[0])
        else defaults.throughput,
    )


def run_experiment(
    algorithm: Any = None,
    env_id: str | None = None,
    description: str | None = None,
    argv: list[str] | None = None,
    defaults: Defaults | None = None,
) -> int:
    """Parse flags, run, print the outcome. Returns the exit status."""
    configure_jax()
    argv = list(sys.argv[1:] if argv is None else argv)
    defaults = defaults or Defaults()
    description = (description or "").strip() or None
    algorithm, env_id, choose = _choose(argv, algorithm, env_id)
    if algorithm is None:
        return _help_without_algorithm(description or "", defaults)
    # the run records the command as typed, --recipe included (a script's own too)
    given = argv if defaults.typed_argv is None else list(defaults.typed_argv)
    argv, defaults = with_named_recipe(argv, algorithm, defaults, env_id)
    parser, config_names, hparam_names = build_parser(
        algorithm, env_id, description or "", defaults, choose
    )
    args = parser.parse_args(argv)
    spec = build_spec(args, algorithm, env_id, defaults, (config_names, hparam_names), given)
    result = runner.run(spec)
    print(f"run directory: {result.run_dir}")
    if result.gif_error:
        print(f"error: {result.gif_error}", file=sys.stderr)
        return 1
    return 0


def main(
    algorithm: Any = None,
    env_id: str | None = None,
    description: str | None = None,
    *,
    seeds: int = 1,
    total_steps: int = 100_000,
    config: dict[str, Any] | None = None,
    hparams: dict[str, Any] | None = None,
    argv: list[str] | None = None,
    throughput: tuple[float, int] | None = None,
    named_recipes: bool = True,
    typed_argv: list[str] | None = None,
) -> NoReturn:
    """Entry point of an experiment script: parse, run, exit with the right status.
    ``throughput`` = (env steps/s per seed, seeds) measured for the script's defaults gives the
    plan a time estimate before anything runs."""
    defaults = Defaults(
        seeds,
        total_steps,
        dict(config or {}),
        dict(hparams or {}),
        throughput=throughput,
        named_recipes=named_recipes,
        typed_argv=None if typed_argv is None else tuple(typed_argv),
    )
    exit_now(guard(lambda: run_experiment(algorithm, env_id, description, argv, defaults)))
