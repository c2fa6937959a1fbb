"""Which learner a run trains, and where it came from.

A learner is named by one string wherever one is chosen (``--algo`` of the scripts and of
``experiments/sweep.py``, ``rl_jax.train``, ``rl_jax.resume``, ``rl_jax.load_policy``):

``td3``
    a built-in learner, or a name given with ``register_algorithm``;
``my_package.my_module:my_learner``
    attribute ``my_learner`` of a module imported as Python imports it, with the current
    directory searched too (as for ``--env MODULE:ID``); ``my_package.my_module`` alone makes
    the module itself the learner;
``path/to/file.py:my_learner``
    attribute ``my_learner`` of that file, imported from its path (its folder is put on the
    Python path, as ``python path/to/file.py`` would); ``path/to/file.py`` alone makes the file
    itself the learner.

From Python the learner object itself works as well. Whatever names it, the learner must offer
the ``rl_jax.training.algorithm.Algorithm`` interface; a missing part is one error line naming it.

A run records where its learner came from (``config.json``, ``"learner"``): ``"builtin"``,
``"module:PACKAGE.MODULE:NAME"`` or ``"file:/absolute/path.py:NAME"``, and for a learner of the
user's own the SHA-256 of its module's source (``"learner_source"``). Opening a run again
(``--resume``, evaluation, rendering, ``load_policy``) imports a built-in learner by itself, and
never anything else: a record is data, and importing what it names would run code the user did
not ask for. A learner of the user's own is named again (the error says how), by any path or
module: a run moved to another folder, or sent to a colleague, opens with the learner's file
wherever it now lies. The learner's ``name`` must be the run's; a source that differs from the
recorded one is accepted with one warning line. A learner this process already trained with or
named (a test, a notebook that goes on with a run it made, a name given to
``register_algorithm``) counts as named.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.machinery
import importlib.util
import os
import shlex
import sys
import types
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

from rl_jax.envs.core import registry
from rl_jax.errors import RunError, UsageError
from rl_jax.run.run_dir import MOVED_MODULES, load_algorithm, recorded_env
from rl_jax.training.algorithm import Algorithm, hooks

#: Name -> where the learner lives (``module``, ``module:attribute``, ``file.py[:attribute]``)
#: or the learner object: the built-in learners and those given to ``register_algorithm``.
ALGORITHMS: dict[str, str | Algorithm] = {
    "td3": "rl_jax.agents.td3:td3",
    "ddpg": "rl_jax.agents.td3:ddpg",
    "td7": "rl_jax.agents.td7:td7",
    "crossq": "rl_jax.agents.crossq:crossq",
    "dqn": "rl_jax.agents.dqn:dqn",
    "reinforce": "rl_jax.agents.reinforce:reinforce",
    "sac": "rl_jax.agents.sac:sac",
    "ppo": "rl_jax.agents.ppo:ppo",
    "recurrent_ppo": "rl_jax.agents.recurrent_ppo:recurrent_ppo",
    "pqn": "rl_jax.agents.pqn:pqn",
    "r2d2": "rl_jax.agents.r2d2:r2d2",
    "c51": "rl_jax.agents.distributional:c51",
    "qrdqn": "rl_jax.agents.distributional:qrdqn",
    "muzero": "rl_jax.agents.muzero:muzero",
    "alphazero": "rl_jax.agents.alphazero:alphazero",
}

#: Where the built-in learners live: the only modules a run's record may make us import.
_BUILTIN_REFERENCES = tuple(ALGORITHMS.values())

#: What ``resolve`` checks a learner has, as the error line shows it.
INTERFACE = {
    "default_config": "default_config(env_id)",
    "default_hyperparams": "default_hyperparams(env_id=None)",
    "init": "init(key, config, hparams)",
    "train_chunk": "train_chunk(state, config, hparams)",
    "policy": "policy(state, config)",
}

BUILTIN = "builtin"
_PACKAGE = "rl_jax"


@dataclasses.dataclass(frozen=True)
class Origin:
    """Where a learner comes from: ``kind`` "builtin", "module" (``where`` a module name) or
    "file" (``where`` an absolute path), and the module's ``attribute`` (None: the module)."""

    kind: str
    where: str = ""
    attribute: str | None = None

    def __str__(self) -> str:
        if self.kind == BUILTIN:
            return BUILTIN
        tail = f":{self.attribute}" if self.attribute else ""
        return f"{self.kind}:{self.where}{tail}"

    @classmethod
    def parse(cls, text: str) -> Origin:
        """The inverse of ``str``; ``RunError`` for a record that is none of its forms."""
        kind, _, rest = text.partition(":")
        if kind == BUILTIN and not rest:
            return cls(BUILTIN)
        if kind in ("module", "file") and rest:
            return cls(kind, *_split_reference(rest))
        raise RunError(f"unknown learner origin {text!r} in the run record")

    def spelling(self, name: str) -> str:
        """How to name this learner again: ``--algo SPELLING``, ``algorithm="SPELLING"``."""
        if self.kind == BUILTIN:
            return name
        return f"{self.where}:{self.attribute}" if self.attribute else self.where

    def describe(self, name: str) -> str:
        """How messages name the learner ``name`` of this origin: built-in, or the file or module
        it came from.
        """
        return f"the built-in {name}" if self.kind == BUILTIN else f"the learner {self}"


# ---- naming a learner -----------------------------------------------------------------------


def register_algorithm(name: str, learner: str | Algorithm) -> None:
    """Make ``name`` a name of ``learner``: a reference as ``--algo`` takes it (``module``,
    ``module:attribute``, ``file.py:attribute``; imported when first used) or the object."""
    ALGORITHMS[name] = learner


def resolve(learner: str | object) -> Algorithm:
    """The learner that ``learner`` names (see the module docstring), checked against the
    interface; ``UsageError`` in one line if there is none."""
    if not isinstance(learner, str):
        return _checked(learner, repr(learner))
    if learner in ALGORITHMS:
        reference = ALGORITHMS[learner]
        if not isinstance(reference, str):
            return _checked(reference, learner)
        try:
            found = _import(reference)
        except UsageError as error:
            raise UsageError(f"algorithm {learner!r} is not available: {error}") from None
        return _checked(found, learner)
    if not _is_reference(learner):
        known = ", ".join(sorted(ALGORITHMS))
        raise UsageError(
            f"unknown algorithm {learner!r}; known algorithms: {known}; a learner of your own is "
            "MODULE:NAME or path/to/file.py:NAME"
        )
    return _checked(_import(learner), learner)


def check_interface(learner: object, label: str) -> None:
    """``UsageError`` naming the first part of the ``Algorithm`` interface ``learner`` lacks."""
    name = getattr(learner, "name", None)
    if not isinstance(name, str) or not name.strip():
        raise UsageError(f"{label} has no name (a string: the learner's name in run directories)")
    for method, signature in INTERFACE.items():
        if not callable(getattr(learner, method, None)):
            raise UsageError(f"{label} has no {signature}")


def _checked(learner: object, label: str) -> Algorithm:
    if isinstance(learner, type) and all(callable(getattr(learner, m, None)) for m in INTERFACE):
        raise UsageError(
            f"{label} is the class {learner.__name__}, not a learner: name an instance of it "
            f"(e.g. `learner = {learner.__name__}()` in its module, then MODULE:learner)"
        )
    try:
        check_interface(learner, label)
    except UsageError as error:
        if not isinstance(learner, types.ModuleType):
            raise
        found = [name for name, value in vars(learner).items() if _looks_like_a_learner(value)]
        if not found:
            raise
        named = ", ".join(f"{label}:{name}" for name in found)
        raise UsageError(f"{error}; the learners in it: {named}") from None
    checked = cast(Algorithm, learner)  # it has the interface's name and methods
    origin_of(checked)  # a learner whose origin cannot be recorded fails here, before any run
    return checked


def _is_reference(text: str) -> bool:
    """Whether ``text`` names a learner by where it lives rather than by a registered name: it
    has an attribute, is a file, or is a module that can be found without importing it."""
    if ":" in text or _is_file(text):
        return True
    try:
        if importlib.util.find_spec(text) is not None:
            return True
    except (ImportError, ValueError):
        return False
    # Not on the path: a module of the current directory is imported from there (_import_module).
    top = text.partition(".")[0]
    return importlib.machinery.PathFinder.find_spec(top, [os.getcwd()]) is not None


def _is_file(where: str) -> bool:
    return where.endswith(".py") or "/" in where or os.sep in where


def _split_reference(text: str) -> tuple[str, str | None]:
    """``(where, attribute)`` of ``where[:attribute]`` (a file's path may itself hold ':')."""
    if text.endswith(".py"):
        return text, None
    where, colon, attribute = text.rpartition(":")
    return (where, attribute or None) if colon else (text, None)


def _import(reference: str) -> object:
    where, attribute = _split_reference(reference)
    module = _import_file(where, reference) if _is_file(where) else _import_module(where, reference)
    if attribute is None:
        return module
    if not hasattr(module, attribute):
        found = [name for name, value in vars(module).items() if _looks_like_a_learner(value)]
        listed = f"learners in it: {', '.join(found)}" if found else "nor any learner"
        raise UsageError(f"{where} has no attribute {attribute!r} ({listed})")
    return getattr(module, attribute)


def _looks_like_a_learner(value: object) -> bool:
    """An object (not a class) with the whole interface: what an error may suggest."""
    if isinstance(value, type) or not isinstance(getattr(value, "name", None), str):
        return False
    return all(callable(getattr(value, method, None)) for method in INTERFACE)


def _import_module(module_name: str, reference: str) -> types.ModuleType:
    """``module_name`` imported, from the current directory if it is not on the path."""
    module_name = MOVED_MODULES.get(module_name, module_name)
    for attempt in range(2):
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError as error:
            missing = error.name or ""
            itself = module_name == missing or module_name.startswith(missing + ".")
            if attempt or not itself or os.getcwd() in sys.path:
                raise UsageError(
                    f"cannot import module {module_name!r} for the learner {reference} "
                    f"({error}); give MODULE:NAME with MODULE importable from the current "
                    "directory or the Python path, or path/to/file.py:NAME"
                ) from None
            sys.path.append(os.getcwd())
        except Exception as error:  # whatever the module raises while it runs: one line
            raise UsageError(f"cannot import the learner {reference}: {_reason(error)}") from None
    raise AssertionError("unreachable")


#: Absolute path -> module, of every learner file imported (a file is imported once).
_FILES: dict[str, types.ModuleType] = {}


def _import_file(where: str, reference: str) -> types.ModuleType:
    path = Path(where).expanduser().absolute()
    if str(path) in _FILES:
        return _FILES[str(path)]
    if not path.is_file():
        raise UsageError(f"no learner file {where} (for {reference})")
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:8]
    module_name = f"_learner_file_{path.stem}_{digest}"
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise UsageError(f"cannot import the learner file {where}: not a Python file")
    module = importlib.util.module_from_spec(spec)
    # Registered before it runs: dataclasses (and inspect, for --help) look their module up.
    sys.modules[module_name] = module
    if str(path.parent) not in sys.path:
        sys.path.append(str(path.parent))  # its own helper modules, as `python FILE` finds them
    try:
        spec.loader.exec_module(module)
    except Exception as error:  # whatever the file raises while it runs: one line
        del sys.modules[module_name]
        raise UsageError(f"cannot import the learner file {where}: {_reason(error)}") from None
    _FILES[str(path)] = module
    return module


def _reason(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


# ---- where a learner came from --------------------------------------------------------------

#: id -> (learner, origin) of every learner this process named or trained with.
_SEEN: dict[int, tuple[Algorithm, Origin]] = {}


def origin_of(learner: Algorithm) -> Origin:
    """Where ``learner`` lives: a module, or a module-level attribute (looked up in the module
    of its type, then in ``__main__``, then in every module). Remembered: this process has
    named it."""
    seen = _SEEN.get(id(learner))
    if seen is not None and seen[0] is learner:
        return seen[1]
    module, attribute = _locate(learner)
    origin = _origin(module, attribute)
    _SEEN[id(learner)] = (learner, origin)
    return origin


def _locate(learner: Algorithm) -> tuple[types.ModuleType, str | None]:
    if isinstance(learner, types.ModuleType):
        return learner, None
    first = [sys.modules.get(type(learner).__module__), sys.modules.get("__main__")]
    # Then every module: a learner object may live elsewhere than its class.
    for module in [*first, *list(sys.modules.values())]:
        if not isinstance(module, types.ModuleType):  # sys.modules may hold other objects
            continue
        for attribute, value in list(vars(module).items()):
            if value is learner and not attribute.startswith("_"):
                return module, attribute
    raise UsageError(
        f"the learner {learner!r} is not a module or an object at module level: a run records "
        "where its learner lives, so that it can be named again; assign it to a name in a module"
    )


def _origin(module: types.ModuleType, attribute: str | None) -> Origin:
    for path, imported in _FILES.items():
        if imported is module:
            return Origin("file", path, attribute)
    name = module.__name__
    if name == _PACKAGE or name.startswith(_PACKAGE + "."):
        return Origin(BUILTIN)
    file = getattr(module, "__file__", None)
    if name == "__main__" and file:
        return Origin("file", str(Path(file).absolute()), attribute)
    return Origin("module", name, attribute)


def reference(learner: Algorithm) -> str:
    """The run record's ``algorithm_module``: ``module:attribute`` for a learner that is
    imported by module name, else its origin."""
    origin = origin_of(learner)
    if origin.kind == "file":
        return str(origin)
    module, attribute = _locate(learner)
    return f"{module.__name__}:{attribute}" if attribute else module.__name__


def record_fields(learner: Algorithm) -> dict[str, str]:
    """What a new run's record says of its learner: where it came from and, for a learner of
    the user's own, the hash of its source (``source_hash``)."""
    fields = {"algorithm_module": reference(learner), "learner": str(origin_of(learner))}
    source = source_hash(learner)
    if origin_of(learner).kind != BUILTIN and source is not None:
        fields["learner_source"] = source
    return fields


def source_hash(learner: Algorithm) -> str | None:
    """``sha256:HEX`` of the source file of the module that holds ``learner``; None where the
    module has no file (a class typed into a notebook)."""
    module, _ = _locate(learner)
    path = getattr(module, "__file__", None)
    try:
        source = Path(path).read_bytes() if path else None
    except OSError:
        source = None
    return None if source is None else "sha256:" + hashlib.sha256(source).hexdigest()


def recorded_origin(record: dict[str, Any]) -> Origin:
    """The origin a run record names; records older than ``"learner"`` give the module of
    ``algorithm_module`` (a built-in one when it is inside rl_jax)."""
    if "learner" in record:
        return Origin.parse(str(record["learner"]))
    module_name, _, attribute = str(record.get("algorithm_module", "")).partition(":")
    module_name = MOVED_MODULES.get(module_name, module_name)
    if module_name == _PACKAGE or module_name.startswith(_PACKAGE + "."):
        return Origin(BUILTIN)
    return Origin("module", module_name, attribute or None)


# ---- opening a run --------------------------------------------------------------------------


def for_run(
    record: dict[str, Any],
    run_dir: Path | str,
    named: str | Algorithm | None = None,
    how: str = "--algo",
) -> Algorithm:
    """The learner to open the run of ``record`` with: ``named`` (checked to be the recorded
    one), else the recorded one if it is built in or this process has named it; else
    ``RunError`` saying how to name it (``how``: "--algo" or "algorithm=")."""
    if named is not None:
        learner = resolve(named)
        check_same(record, learner, run_dir)
        return learner
    origin = recorded_origin(record)
    name = record["identity"]["algorithm"]
    if origin.kind == BUILTIN:
        return _builtin(record, name)
    known = _named_here(origin, name, record)
    if known is not None:
        return known
    spelling = origin.spelling(name)
    ask = f"{how}{spelling!r}" if how.endswith("=") else f"{how} {shlex.quote(spelling)}"
    raise RunError(
        f"{run_dir} was trained with {origin.describe(name)}, which opening a run does not "
        f"import by itself; name it again: {ask}"
    )


def check_same(record: dict[str, Any], learner: Algorithm, run_dir: Path | str) -> None:
    """``RunError`` unless ``learner`` is the one the run of ``record`` was trained with: the
    same name, and built in where the run's was (or of the user's own where the run's was). A
    learner of the user's own may be named by any path or module; where its source differs
    from the run's, one warning line says so."""
    name = record["identity"]["algorithm"]
    recorded, given = recorded_origin(record), origin_of(learner)
    if learner.name != name:
        raise RunError(f"{run_dir} is a {name} run, not a {learner.name} run")
    if (given.kind == BUILTIN) != (recorded.kind == BUILTIN):
        raise RunError(
            f"{run_dir} was trained with {recorded.describe(name)}, not with "
            f"{given.describe(learner.name)}; name the run's own learner"
        )
    if given.kind == BUILTIN:
        return
    warned = (str(run_dir), str(source_hash(learner)))
    if _same_source(record, learner) is False and warned not in _WARNED:
        _WARNED.add(warned)
        print(
            f"warning: {run_dir} was trained with a {name} learner whose source differs from "
            f"that of {given.spelling(name)}; opening the run with it",
            file=sys.stderr,
            flush=True,
        )


#: (run directory, source) pairs already warned of: a run opened once per seed says it once.
_WARNED: set[tuple[str, str]] = set()


def _same_source(record: Mapping[str, object], learner: Algorithm) -> bool | None:
    """Whether ``learner``'s source is the one ``record`` was trained with; None where either
    is unknown (a record from before sources were kept, a learner without a file)."""
    recorded, given = record.get("learner_source"), source_hash(learner)
    return None if recorded is None or given is None else recorded == given


def cli_args(learner: Algorithm) -> list[str]:
    """``--algo SPELLING`` for a command that opens a run of ``learner`` (none when built in)."""
    origin = origin_of(learner)
    return [] if origin.kind == BUILTIN else ["--algo", origin.spelling(learner.name)]


def python_hint(learner: Algorithm) -> str:
    """``, algorithm=...`` for ``rl_jax.resume``'s line when ``learner`` is not built in."""
    origin = origin_of(learner)
    if origin.kind == BUILTIN:
        return ""
    if origin.kind == "module" and origin.where == "__main__" and origin.attribute:
        return f", algorithm={origin.attribute}"
    return f", algorithm={origin.spelling(learner.name)!r}"


def _builtin(record: dict[str, Any], name: str) -> Algorithm:
    """The built-in learner of ``record``, imported from inside rl_jax only."""
    reference = str(record.get("algorithm_module"))
    builtin_modules = {str(where).partition(":")[0] for where in _BUILTIN_REFERENCES}
    module_name = reference.partition(":")[0]
    if MOVED_MODULES.get(module_name, module_name) not in builtin_modules:
        raise RunError(f"the run record names a built-in learner at {reference!r}, not one of ours")
    try:
        learner = load_algorithm(reference)
    except AttributeError:
        learner = None
    if learner is None or getattr(learner, "name", None) != name:
        raise RunError(f"the run record's built-in learner {reference!r} is not its {name}")
    check_interface(learner, reference)
    return cast(Algorithm, learner)  # it has the interface's name and methods


def _named_here(origin: Origin, name: str, record: Mapping[str, object]) -> Algorithm | None:
    """A learner of ``origin`` that this process trained with or named, or registered; or one
    it named elsewhere with the run's name and the run's very source (a copy of the file)."""
    for learner, seen in _SEEN.values():
        if seen == origin:
            return learner
    for learner, seen in _SEEN.values():
        if seen.kind != BUILTIN and learner.name == name and _same_source(record, learner):
            return learner
    for name, registered in ALGORITHMS.items():
        if isinstance(registered, str) and _reference_origin(registered) == origin:
            return resolve(name)
    return None


def _reference_origin(text: str) -> Origin | None:
    """The origin of a registered reference, found without importing it."""
    where, attribute = _split_reference(text)
    if _is_file(where):
        return Origin("file", str(Path(where).expanduser().absolute()), attribute)
    where = MOVED_MODULES.get(where, where)
    if where == _PACKAGE or where.startswith(_PACKAGE + "."):
        return Origin(BUILTIN)
    return Origin("module", where, attribute)


# ---- the env a learner trains on ------------------------------------------------------------


def chosen_env(learner: Algorithm, env_id: str) -> str:
    """The env id of a new run: ``env_id`` as given where the learner owns it
    (``OptionalHooks.owns_env``), else the env registry's id (``UnknownEnvError`` if none)."""
    if hooks(learner).owns_env(env_id):
        return env_id
    return registry.resolve_id(env_id)


def run_env(
    record: dict[str, Any],
    run_dir: Path | str,
    learner: Algorithm | None,
    named: str | None = None,
    how: str = "--env",
) -> str:
    """The env id of the run of ``record``: the recorded id itself where the run's
    ``learner`` owns it (``named``, the user's naming of the env, must then be that id), else
    ``run_dir.recorded_env``. ``learner`` None: the run's built-in learner where it has one."""
    recorded = str(record["identity"]["env_id"])
    if learner is None and recorded_origin(record).kind == BUILTIN:
        learner = for_run(record, run_dir)
    if learner is not None and hooks(learner).owns_env(recorded):
        if named is not None and named != recorded:
            raise RunError(f"{run_dir} is a run on {recorded}, not on {named}")
        return recorded
    return recorded_env(recorded, run_dir, named, how)
