"""Command-line helpers for experiment scripts: the run contract, flags built from the algorithm's
``Config``/``Hyperparams`` dataclasses (their field docstrings or comments become ``--help``),
validation, and a top-level guard that turns every user error into one line on stderr.

An experiment script is a few lines::

    from rl_jax.run import cli
    from rl_jax.agents.td3 import td3

    if __name__ == "__main__":
        cli.main(td3, "rl_jax/Pendulum-v1", __doc__, seeds=5, total_steps=20_000)

Its settings are the learner's recipe for the env (``--recipe NAME``, else the env's default),
then the flags.

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

from rl_jax import envs
from rl_jax.errors import (
    OneLineParser,
    RunError,
    UsageError,
    exit_now,
)
from rl_jax.run import distributed, learners, processes, recipe_choice, runner
from rl_jax.run.flags import (
    add_dataclass_flags,
    add_run_flags,
    flag_name,
    kind_of,
    parse_grid,
)
from rl_jax.run.learners import ALGORITHMS
from rl_jax.run.run_dir import read_run_record, recorded_env
from rl_jax.run.spec import RunSpec
from rl_jax.training import params
from rl_jax.training.algorithm import Algorithm, Config, Hyperparams, hooks
from rl_jax.training.params import D, dataclass_from_dict
from rl_jax.training.recipes import Recipe
from rl_jax.training.validation import out_of_range

RUNS_ROOT = Path("runs")


def resolve_algorithm(name: str | object) -> Algorithm:
    """The learner ``name`` names: a built-in or registered name, ``MODULE:NAME``,
    ``path/to/file.py:NAME`` or the learner object (``rl_jax.run.learners``)."""
    return learners.resolve(name)


def program(argv0: str | None = None) -> list[str]:
    """The words that start this program again, for the run's recorded commands:
    ``python SCRIPT`` for a script, ``rl-jax COMMAND`` for the console command and
    ``python -m rl_jax COMMAND`` for the package run as a module. ``rl_jax.__main__`` sets
    ``sys.argv[0]`` to ``"rl-jax COMMAND"`` in both of the latter cases (for argparse's
    usage lines); only the ``__main__`` module tells them apart."""
    argv0 = sys.argv[0] if argv0 is None else argv0
    python = Path(sys.executable).name
    if not argv0.startswith("rl-jax "):
        return [python, argv0]
    words = argv0.split()
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is not None and spec.name == "rl_jax.__main__":
        return [python, "-m", "rl_jax", *words[1:]]
    return words


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


def replace_fields(instance: D, values: dict[str, Any], what: str) -> D:
    try:
        return dataclasses.replace(instance, **values)
    except (TypeError, ValueError) as error:
        raise UsageError(f"invalid {what}: {error}") from None


@dataclasses.dataclass
class Defaults:
    """What a script chooses; flags override it. Settings themselves come from the learner's
    recipes (``rl_jax.training.recipes``): ``--recipe NAME``, else the env's ``"default"``."""

    seeds: int = 1
    total_steps: int = 100_000


def validate_settings(
    algorithm: Algorithm, config: Config, hparams_list: list[Hyperparams]
) -> None:
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


def check_env_fits(algorithm: Algorithm, config: Config, hparams: Hyperparams) -> None:
    """The algorithm can act in the env (TD3 needs a bounded Box action space, say): its init,
    traced without running, raises the algorithm's own TypeError or ValueError otherwise, which
    ``--env`` with any gymnasium id makes a user error rather than a bug."""
    try:
        jax.eval_shape(lambda key: algorithm.init(key, config, hparams), jax.random.key(0))
    except (TypeError, ValueError) as error:
        raise UsageError(f"{algorithm.name} cannot run {config.env_id}: {error}") from None


def build_parser(
    algorithm: Algorithm,
    env_id: str,
    description: str,
    defaults: Defaults,
    choose: bool,
    recipe: Recipe | None = None,
) -> tuple[argparse.ArgumentParser, list[str], list[str]]:
    """The parser of a script's flags, their defaults from ``recipe`` (None: the env's)."""
    recipe = recipe or hooks(algorithm).recipe(env_id)
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    if choose:
        _add_choice_flags(parser)
    add_run_flags(parser, defaults.seeds, recipe.total_steps or defaults.total_steps)
    recipes = hooks(algorithm).recipes.names(env_id)
    others = "" if choose else recipe_choice.other_learners_recipes(algorithm, env_id)
    # taken out of argv before parsing (take_recipe); here for --help
    parser.add_argument(
        "--recipe",
        metavar="NAME",
        default="default",
        help=f"the whole set of {algorithm.name}'s settings for {env_id} that the flags below "
        "start from: " + "; ".join(f"{name}: {about}" for name, about in recipes.items()) + others,
    )
    config, hparams = recipe_choice.recipe_settings(algorithm, env_id, recipe)
    distributed.add_flags(parser)  # taken out of argv before parsing (distributed.start)
    config_names = add_dataclass_flags(parser, config, f"{algorithm.name} config (static)")
    hparam_names = add_dataclass_flags(parser, hparams, f"{algorithm.name} hyperparameters")
    return parser, config_names, hparam_names


def _add_choice_flags(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--algo",
        default=None,
        metavar="NAME",
        help=f"algorithm: {', '.join(sorted(ALGORITHMS))}; or a learner of your own, "
        "MODULE:NAME (MODULE searched on the Python path and in the current directory) or "
        "path/to/file.py:NAME (docs/own_learner.md)",
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


@dataclasses.dataclass(frozen=True)
class Choice:
    """What the command line chooses before the learner's own flags can be read, from one pass
    over argv: the learner, the env, the recipe's name, the resumed run's record, whether the
    learner and env came from the command line (``--algo``, ``--env``) rather than the script,
    and the rest of argv (``--recipe`` taken out) for the learner's parser."""

    algorithm: Algorithm | None
    env_id: str
    chosen: bool
    recipe: str | None = None
    record: dict[str, Any] | None = None
    rest: tuple[str, ...] = ()
    env_given: bool = False


def _choose(argv: list[str], algorithm: Algorithm | None, env_id: str | None) -> Choice:
    """Algorithm and env: fixed by the script, or from --algo/--env (or the resumed run). With
    ``--help`` and no env, the env is the learner's default one (``help_env``), whose defaults
    the help then shows."""
    pre = OneLineParser(add_help=False)
    _add_choice_flags(pre)
    pre.add_argument("--resume", type=Path, default=None)
    recipe, rest = recipe_choice.split_recipe(argv)
    # --algo, --env and --resume stay in argv for the learner's parser, which lists them too
    known, _ = pre.parse_known_args(rest)
    record = read_run_record(known.resume) if known.resume else None
    given = known.env is not None or record is not None
    if algorithm is not None and env_id is not None:
        if record is not None and record.get("learner") == "builtin":
            algorithm = recipe_choice.resumed_learner(algorithm, record["identity"]["algorithm"])
        algorithm, recipe = recipe_choice.script_recipe(algorithm, recipe)
        env = envs.core.registry.resolve_id(env_id)
        return Choice(algorithm, env, False, recipe, record, tuple(rest), given)
    wants_help = bool({"-h", "--help"} & set(argv))
    if wants_help and (algorithm or known.algo or record) is None:
        return Choice(None, "", True)
    if algorithm is None and known.algo is None and record is None:
        raise UsageError("--algo is required")
    if (env_id or known.env or record) is None and not wants_help:
        raise UsageError("--env is required")
    if algorithm is None and known.algo is not None:
        algorithm = resolve_algorithm(known.algo)
    elif algorithm is None:  # the resumed run's own learner, if built in (never imported else)
        algorithm = learners.for_run(record, known.resume, how="--algo")
    env_name = env_id or known.env
    if record is not None:  # after the learner, whose module may register the run's env
        env_name = recorded_env(record["identity"]["env_id"], known.resume, env_name, "--env")
    if env_name is None:
        env_name = help_env(algorithm)
    env = envs.core.registry.resolve_id(env_name)
    return Choice(algorithm, env, True, recipe, record, tuple(rest), given)


#: Where ``help_env`` looks when a learner's recipes name no env: continuous, then discrete.
HELP_ENVS = ("rl_jax/Pendulum-v1", "rl_jax/CartPole-v1")


def help_env(algorithm: Algorithm) -> str:
    """The env whose defaults ``--help`` shows when no ``--env`` is given: the first env of the
    learner's default recipes, else the first of ``HELP_ENVS`` it has a config for."""
    recipes = hooks(algorithm).recipes.recipes
    named = [env for recipe in recipes if recipe.name == "default" for env in recipe.envs]
    for env_id in [*named, *HELP_ENVS]:
        try:
            algorithm.default_config(env_id)
        except Exception:  # a learner of the user's own may refuse an env in any way
            continue
        return env_id
    raise UsageError(f"--env is required: {algorithm.name} has no default env to show flags for")


def _help_without_algorithm(description: str, defaults: Defaults) -> int:
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _add_choice_flags(parser)
    add_run_flags(parser, defaults.seeds, defaults.total_steps)
    distributed.add_flags(parser)
    parser.epilog = "Give --algo and --env to list the algorithm's config and hyperparameter flags."
    parser.print_help()
    return 0


def _resumed_settings(
    args: argparse.Namespace, algorithm: Algorithm, env_id: str
) -> dict[str, Any]:
    """Config, hyperparameters, seeds and steps recorded by the run being resumed."""

    record = read_run_record(args.resume)
    saved = record["identity"]
    if saved["algorithm"] != algorithm.name or saved["env_id"] != env_id:
        raise RunError(
            f"cannot resume {args.resume}: it is a {saved['algorithm']} run on "
            f"{saved['env_id']}, this is {algorithm.name} on {env_id}"
        )
    learners.check_same(record, algorithm, args.resume)
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


def _fresh_settings(
    algorithm: Algorithm, env_id: str, defaults: Defaults, recipe: Recipe
) -> dict[str, Any]:
    """The script's defaults under ``recipe`` for a new run (flags are applied on top)."""
    config, hparams = recipe_choice.recipe_settings(algorithm, env_id, recipe)
    return {
        "config": config,
        "hparams": [hparams],
        "seeds": defaults.seeds,
        "base_seed": 0,
        "total_steps": recipe.total_steps or defaults.total_steps,
        "grid_fields": (),
    }


def build_spec(
    args: argparse.Namespace,
    algorithm: Algorithm,
    env_id: str,
    defaults: Defaults,
    names: tuple[list[str], list[str]],
    argv: list[str],
    recipe: Recipe | None = None,
) -> RunSpec:
    """The ``RunSpec`` the flags describe (for ``--resume``: the recorded run, then the flags),
    on ``recipe``'s settings (None: the env's default recipe)."""
    recipe = recipe or hooks(algorithm).recipe(env_id)
    if args.resume is not None and args.out is not None and args.out != args.resume:
        raise UsageError("--out and --resume name different directories; give only --resume")
    resume = args.resume is not None
    settings = (
        _resumed_settings(args, algorithm, env_id)
        if resume
        else _fresh_settings(algorithm, env_id, defaults, recipe)
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
    script = shlex.join(program())
    # A learner of the user's own is named again on resume (never imported from the record).
    named = shlex.join(learners.cli_args(algorithm)) if hasattr(args, "algo") else ""
    if envs.core.registry.names_a_module(env_id):  # never imported from the record either
        named = f"{named} --env {shlex.quote(env_id)}".strip()
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
        layout=args.layout,
        gif=args.gif,
        wandb=args.wandb,
        command=shlex.join([*program(), *argv]),
        resume_command=f"{script} --resume {shlex.quote(str(out))} {named}".strip(),
        # The recipe's measured throughput holds for its own config only.
        throughput=None if resume or args.grid or _explicit(args, names[0]) else recipe.throughput,
    )


def run_experiment(
    algorithm: Algorithm | None = None,
    env_id: str | None = None,
    description: str | None = None,
    argv: list[str] | None = None,
    defaults: Defaults | None = None,
) -> int:
    """Parse flags, run, print the outcome. Returns the exit status."""
    typed = list(sys.argv[1:] if argv is None else argv)
    argv = distributed.start(typed)  # JAX's settings, and the processes joined if asked
    defaults = defaults or Defaults()
    description = (description or "").strip() or None
    choice = _choose(argv, algorithm, env_id)
    algorithm, env_id = choice.algorithm, choice.env_id
    if algorithm is None:
        return _help_without_algorithm(description or "", defaults)
    if choice.chosen and {"-h", "--help"} & set(argv) and not choice.env_given:
        description = (
            f"{description or ''}\n\nDefaults below are {algorithm.name}'s for {env_id}; "
            "give --env ID to see those of another env."
        ).strip()
    resuming = choice.record is not None
    recipe = recipe_choice.recipe_named(algorithm, env_id, choice.recipe, resuming)
    parser, config_names, hparam_names = build_parser(
        algorithm, env_id, description or "", defaults, choice.chosen, recipe
    )
    args = parser.parse_args(list(choice.rest))
    names = (config_names, hparam_names)
    # the run records the command as typed, --recipe included
    spec = build_spec(args, algorithm, env_id, defaults, names, typed, recipe)
    result = runner.run(spec)
    if not processes.is_lead():
        return 0
    print(f"run directory: {result.run_dir}")
    if result.gif_error:
        print(f"error: {result.gif_error}", file=sys.stderr)
        return 1
    return 0


def main(
    algorithm: Algorithm | None = None,
    env_id: str | None = None,
    description: str | None = None,
    *,
    seeds: int = 1,
    total_steps: int = 100_000,
    argv: list[str] | None = None,
) -> NoReturn:
    """Entry point of an experiment script: parse, run, exit with the right status. The
    settings are the learner's recipe for the env (``--recipe NAME``, else its default)."""
    defaults = Defaults(seeds, total_steps)
    run = lambda: run_experiment(algorithm, env_id, description, argv, defaults)  # noqa: E731
    exit_now(distributed.guarded(run))
