"""A run's command line, read once, and the ``RunSpec`` it asks for.

``read`` reads argv in one pass: every flag that any run takes (the learner and env, ``--algo``
and ``--env``; ``--recipe``; the run's own flags, ``--seeds`` to ``--resume``; the distribution
flags; ``--help``) lands typed in a ``CommandLine``. What that pass leaves are the learner's own
flags, one per field of its ``Config`` and ``Hyperparams``, which only the chosen learner can
name. ``choose`` then picks the learner, the env and the recipe (from the script, the flags or
the resumed run's record), and ``run_spec`` reads the learner's flags and makes the ``RunSpec``
that the runner reads. ``--help`` is printed from the same flags (``help_parser``).
"""

from __future__ import annotations

import argparse
import dataclasses
import shlex
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax

from rl_jax import envs
from rl_jax.errors import OneLineParser, RunError, UsageError
from rl_jax.run import distributed, learners, recipe_choice
from rl_jax.run.flags import add_dataclass_flags, add_run_flags, flag_name, kind_of, parse_grid
from rl_jax.run.learners import ALGORITHMS
from rl_jax.run.run_dir import read_run_record
from rl_jax.run.spec import RunSpec
from rl_jax.training import params
from rl_jax.training.algorithm import Algorithm, Config, Hyperparams, hooks
from rl_jax.training.params import D, dataclass_from_dict
from rl_jax.training.recipes import Recipe
from rl_jax.training.validation import buffer_too_small, out_of_range

RUNS_ROOT = Path("runs")

#: Where ``help_env`` looks when a learner's recipes name no env: continuous, then discrete.
HELP_ENVS = ("rl_jax/Pendulum-v1", "rl_jax/CartPole-v1")


@dataclasses.dataclass
class Defaults:
    """What a script chooses; flags override it. Settings themselves come from the learner's
    recipes (``rl_jax.training.recipes``): ``--recipe NAME``, else the env's ``"default"``."""

    seeds: int = 1
    total_steps: int = 100_000


@dataclasses.dataclass(frozen=True)
class CommandLine:
    """argv, read once. ``None``: not given (``seeds``, ``total_steps`` and ``base_seed`` then
    come from the script, the recipe or the resumed run). ``learner_flags`` are the tokens left
    for the learner's own flags, in the order typed."""

    typed: tuple[str, ...]  # argv as typed: the run records it, --recipe included
    algo: str | None = None
    env: str | None = None
    recipe: str | None = None
    resume: Path | None = None
    out: Path | None = None
    seeds: int | None = None
    total_steps: int | None = None
    base_seed: int | None = None
    grid: tuple[str, ...] = ()
    checkpoint_interval: float | None = None
    keep_checkpoints: int = 3
    log_interval: float = 30.0
    layout: str = "auto"
    gif: bool = False
    wandb: bool = False
    help: bool = False
    distribution: distributed.Options = distributed.Options()
    learner_flags: tuple[str, ...] = ()


def _common_flags(parser: argparse.ArgumentParser, defaults: Defaults, total_steps: int) -> None:
    """The flags every run takes, in ``--help``'s order: the run's, then the distribution's."""
    add_run_flags(parser, defaults.seeds, total_steps)
    distributed.add_flags(parser)


def _choice_flags(parser: argparse.ArgumentParser) -> None:
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


def _recipe_flag(parser: argparse.ArgumentParser, about: str = "") -> None:
    parser.add_argument("--recipe", metavar="NAME", default=None, help=about or "a recipe")


def read(argv: Sequence[str]) -> CommandLine:
    """Every flag a run takes, read from ``argv`` in one pass; the rest are the learner's."""
    parser = OneLineParser(add_help=False)
    _choice_flags(parser)
    _recipe_flag(parser)
    _common_flags(parser, Defaults(), Defaults().total_steps)
    parser.add_argument("-h", "--help", action="store_true")
    known, rest = parser.parse_known_args(list(argv))
    given = vars(known)
    return CommandLine(
        typed=tuple(argv),
        algo=known.algo,
        env=known.env,
        recipe=known.recipe,
        resume=known.resume,
        out=known.out,
        seeds=given.get("seeds"),
        total_steps=given.get("total_steps"),
        base_seed=given.get("base_seed"),
        grid=tuple(known.grid),
        checkpoint_interval=known.checkpoint_interval,
        keep_checkpoints=known.keep_checkpoints,
        log_interval=known.log_interval,
        layout=known.layout,
        gif=known.gif,
        wandb=known.wandb,
        help=known.help,
        distribution=distributed.options_from(known),
        learner_flags=tuple(rest),
    )


# ---- the learner, the env and the recipe ------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Choice:
    """The learner, the env and the recipe a command line runs; ``chosen``: the learner and env
    came from ``--algo``/``--env`` or the resumed run rather than the script; ``env_given``: the
    env did not come from ``help_env``; ``record``: the resumed run's."""

    algorithm: Algorithm
    env_id: str
    recipe: Recipe
    chosen: bool
    env_given: bool = True
    record: dict[str, Any] | None = None


def choose(line: CommandLine, algorithm: Algorithm | None, env_id: str | None) -> Choice | None:
    """The learner and env: fixed by the script, or from ``--algo``/``--env`` (or the resumed
    run's record); then the recipe. ``None``: ``--help`` with no learner to show. With ``--help``
    and no env, the env is the learner's default one (``help_env``)."""
    record = read_run_record(line.resume) if line.resume else None
    name = line.recipe
    if algorithm is not None and env_id is not None:
        if line.algo is not None or line.env is not None:
            flag = "--algo" if line.algo is not None else "--env"
            raise UsageError(
                f"{flag}: this script runs {algorithm.name} on {env_id}; experiments/train.py "
                "takes --algo and --env"
            )
        if record is not None and record.get("learner") == "builtin":
            algorithm = recipe_choice.resumed_learner(algorithm, record["identity"]["algorithm"])
        algorithm, name = recipe_choice.script_recipe(algorithm, name)
        env = learners.chosen_env(algorithm, env_id)
        recipe = recipe_choice.recipe_named(algorithm, env, name, record is not None)
        return Choice(algorithm, env, recipe, False, True, record)
    if line.help and (algorithm or line.algo or record) is None:
        return None
    if algorithm is None and line.algo is None and record is None:
        raise UsageError("--algo is required")
    if (env_id or line.env or record) is None and not line.help:
        raise UsageError("--env is required")
    if algorithm is None and line.algo is not None:
        algorithm = learners.resolve(line.algo)
    elif algorithm is None:  # the resumed run's own learner, if built in (never imported else)
        assert record is not None and line.resume is not None  # checked above
        algorithm = learners.for_run(record, line.resume, how="--algo")
    env_name = env_id or line.env
    if record is not None and line.resume is not None:  # after the learner, which may register it
        env_name = learners.run_env(record, line.resume, algorithm, env_name, "--env")
    given = env_name is not None
    env = learners.chosen_env(algorithm, env_name if env_name is not None else help_env(algorithm))
    recipe = recipe_choice.recipe_named(algorithm, env, name, record is not None)
    return Choice(algorithm, env, recipe, True, given, record)


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


# ---- --help ---------------------------------------------------------------------------------


def help_parser(
    choice: Choice, description: str, defaults: Defaults
) -> tuple[argparse.ArgumentParser, list[str], list[str]]:
    """The parser ``--help`` prints: every flag of ``read`` and the learner's own, with the
    defaults of ``choice``'s recipe; and the names of the config's and hyperparameters' flags."""
    algorithm, env_id, recipe = choice.algorithm, choice.env_id, choice.recipe
    if choice.chosen and not choice.env_given:
        description = (
            f"{description}\n\nDefaults below are {algorithm.name}'s for {env_id}; "
            "give --env ID to see those of another env."
        ).strip()
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    if choice.chosen:
        _choice_flags(parser)
    add_run_flags(parser, defaults.seeds, recipe.total_steps or defaults.total_steps)
    recipes = hooks(algorithm).recipes.names(env_id)
    others = "" if choice.chosen else recipe_choice.other_learners_recipes(algorithm, env_id)
    _recipe_flag(
        parser,
        f"the whole set of {algorithm.name}'s settings for {env_id} that the flags below start "
        "from: " + "; ".join(f"{name}: {about}" for name, about in recipes.items()) + others,
    )
    config, hparams = recipe_choice.recipe_settings(algorithm, env_id, recipe)
    distributed.add_flags(parser)
    config_names = add_dataclass_flags(parser, config, f"{algorithm.name} config (static)")
    hparam_names = add_dataclass_flags(parser, hparams, f"{algorithm.name} hyperparameters")
    return parser, config_names, hparam_names


def generic_help(description: str, defaults: Defaults) -> str:
    """``--help`` with no learner chosen: the flags every run takes."""
    parser = OneLineParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    _choice_flags(parser)
    _common_flags(parser, defaults, defaults.total_steps)
    parser.epilog = "Give --algo and --env to list the algorithm's config and hyperparameter flags."
    return parser.format_help()


# ---- the run ----------------------------------------------------------------------------------


def learner_flags(
    line: CommandLine, config: Config, hparams: Hyperparams
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The learner's own flags of ``line``: (config fields given, hyperparameters given). Any
    other token left over is one error line."""
    parser = OneLineParser(add_help=False)
    config_names = add_dataclass_flags(parser, config, "config")
    hparam_names = add_dataclass_flags(parser, hparams, "hyperparameters")
    given = vars(parser.parse_args(list(line.learner_flags)))
    return (
        {name: given[name] for name in config_names if name in given},
        {name: given[name] for name in hparam_names if name in given},
    )


def run_spec(line: CommandLine, choice: Choice, defaults: Defaults) -> RunSpec:
    """The ``RunSpec`` that ``line`` describes (for ``--resume``: the recorded run, then the
    flags), on ``choice``'s learner, env and recipe."""
    algorithm, env_id, recipe = choice.algorithm, choice.env_id, choice.recipe
    if line.resume is not None and line.out is not None and line.out != line.resume:
        raise UsageError("--out and --resume name different directories; give only --resume")
    resume = line.resume is not None
    settings = (
        _resumed_settings(line.resume, algorithm, env_id)
        if line.resume is not None
        else _fresh_settings(algorithm, env_id, defaults, recipe)
    )
    given_config, given_hparams = learner_flags(line, settings.config, settings.hparams[0])
    config = replace_fields(settings.config, given_config, "config")
    hparams = [replace_fields(h, given_hparams, "hyperparameters") for h in settings.hparams]
    grid_fields = settings.grid_fields
    if line.grid:
        grid = parse_grid(list(line.grid), hparams[0], config)
        if set(grid) & set(given_hparams):
            raise UsageError(f"{', '.join(set(grid) & set(given_hparams))} given as flag and grid")
        hparams, grid_fields = params.expand(hparams[0], grid), tuple(grid)
    validate_settings(algorithm, config, hparams)
    check_env_fits(algorithm, config, hparams[0])
    out = line.resume if line.resume is not None else line.out
    out = out if out is not None else default_run_dir(env_id, algorithm.name)
    # A learner of the user's own is named again on resume (never imported from the record),
    # and so is an env of the user's own module.
    named = shlex.join(learners.cli_args(algorithm)) if choice.chosen else ""
    if envs.core.registry.names_a_module(env_id):
        named = f"{named} --env {shlex.quote(env_id)}".strip()
    script = shlex.join(program())
    return RunSpec(
        algorithm=algorithm,
        env_id=env_id,
        config=config,
        hparams=tuple(hparams),
        out=Path(out),
        seeds=line.seeds if line.seeds is not None else settings.seeds,
        total_steps=line.total_steps if line.total_steps is not None else settings.total_steps,
        resume=resume,
        base_seed=line.base_seed if line.base_seed is not None else settings.base_seed,
        grid_fields=grid_fields,
        checkpoint_interval=line.checkpoint_interval,
        keep_checkpoints=line.keep_checkpoints,
        log_interval=line.log_interval,
        layout=line.layout,
        gif=line.gif,
        wandb=line.wandb,
        command=shlex.join([*program(), *line.typed]),
        resume_command=f"{script} --resume {shlex.quote(str(out))} {named}".strip(),
        # The recipe's measured throughput holds for its own config only.
        throughput=None if resume or line.grid or given_config else recipe.throughput,
    )


@dataclasses.dataclass(frozen=True)
class _Settings:
    """Where a run's settings start before its flags: the recipe's, or the resumed run's."""

    config: Config
    hparams: list[Hyperparams]
    seeds: int
    base_seed: int
    total_steps: int
    grid_fields: tuple[str, ...] = ()


def _resumed_settings(resume: Path, algorithm: Algorithm, env_id: str) -> _Settings:
    """Config, hyperparameters, seeds and steps recorded by the run being resumed."""
    record = read_run_record(resume)
    saved = record["identity"]
    if saved["algorithm"] != algorithm.name or saved["env_id"] != env_id:
        raise RunError(
            f"cannot resume {resume}: it is a {saved['algorithm']} run on "
            f"{saved['env_id']}, this is {algorithm.name} on {env_id}"
        )
    learners.check_same(record, algorithm, resume)
    template = algorithm.default_hyperparams()
    return _Settings(
        config=dataclass_from_dict(algorithm.default_config(env_id), saved["config"]),
        hparams=[dataclass_from_dict(template, values) for values in saved["hparams"]],
        seeds=saved["seeds"],
        base_seed=saved["base_seed"],
        total_steps=record.get("total_steps", 1),
        grid_fields=tuple(record.get("grid_fields", ())),
    )


def _fresh_settings(
    algorithm: Algorithm, env_id: str, defaults: Defaults, recipe: Recipe
) -> _Settings:
    """The script's defaults under ``recipe`` for a new run (flags are applied on top)."""
    config, hparams = recipe_choice.recipe_settings(algorithm, env_id, recipe)
    total_steps = recipe.total_steps or defaults.total_steps
    return _Settings(config, [hparams], defaults.seeds, 0, total_steps)


def replace_fields(instance: D, values: Mapping[str, Any], what: str) -> D:
    """``instance`` with ``values``; a value its field refuses is one ``UsageError``. A list (as
    JSON or a notebook gives a layer list) becomes a tuple: settings are hashed when compiled."""
    values = {name: tuple(v) if isinstance(v, list) else v for name, v in values.items()}
    try:
        return dataclasses.replace(instance, **values)
    except (TypeError, ValueError) as error:
        raise UsageError(f"invalid {what}: {error}") from None


def validate_settings(
    algorithm: Algorithm, config: Config, hparams_list: Sequence[Hyperparams]
) -> None:
    """Ranges (``rl_jax.training.validation``), then the algorithm's own ``validate(config,
    hparams)`` when it has one: before anything compiles, for every config of a grid."""
    for field in dataclasses.fields(config):
        value = getattr(config, field.name)
        if kind_of(value) == "int" and not isinstance(value, bool) and value < 0:
            raise UsageError(f"{flag_name(field.name)} must be >= 0, got {value}")
    problem = out_of_range(config, algorithm) or buffer_too_small(config, algorithm)
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
    main_module = sys.modules.get("__main__")
    spec = main_module.__spec__ if main_module is not None else None
    if spec is not None and spec.name == "rl_jax.__main__":
        return [python, "-m", "rl_jax", *words[1:]]
    return words


def spec_for(
    algorithm: Algorithm, env_id: str, argv: Sequence[str], defaults: Defaults | None = None
) -> RunSpec:
    """The ``RunSpec`` that a script of ``algorithm`` on ``env_id`` runs for ``argv``, read as
    ``rl_jax.run.cli`` reads it, without joining processes or running anything."""
    line = read(argv)
    choice = choose(line, algorithm, env_id)
    if choice is None or line.help:
        raise UsageError("--help describes a run rather than asking for one")
    return run_spec(line, choice, defaults or Defaults())
