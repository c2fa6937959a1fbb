"""The run directory's identity: ``config.json``, what makes two runs "the same", and the checks
that keep one run's directory from being overwritten or resumed by another.

A run is identified by its algorithm, env, static config, hyperparameters (one set per config of
a grid), number of seeds and first seed. Total steps are not part of it: resuming with a larger
``--total-steps`` extends a run.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import os
import platform
import shlex
import subprocess
import sys
import tempfile
import time
import types
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import jax

from rl_jax.envs.core import registry
from rl_jax.errors import RunError
from rl_jax.run import processes
from rl_jax.run.checkpoint import library_versions
from rl_jax.run.distributed import without_flags
from rl_jax.training import params
from rl_jax.training.algorithm import Config, Hyperparams

CONFIG_FILE = "config.json"
CHECKPOINT_DIR = "checkpoints"
#: The run's lease (``rl_jax.run.lease``): the first file a new run writes, before its record.
LEASE_FILE = "lease.json"
CURVES_FILE = "curves.png"
RESULTS_FILE = "results.txt"


# ---- identity -------------------------------------------------------------------------------


def algorithm_reference(algorithm: object) -> str:
    """An importable reference to the algorithm: ``module`` or ``module:attribute``."""
    if isinstance(algorithm, types.ModuleType):
        return algorithm.__name__
    module = sys.modules.get(type(algorithm).__module__)
    if module is not None:
        for attribute, value in vars(module).items():
            if value is algorithm:
                return f"{module.__name__}:{attribute}"
    raise RunError(f"algorithm {algorithm!r} is not a module or a module-level object")


#: Where the algorithms' modules were before they moved to ``rl_jax.agents``: run directories
#: written then record these in ``algorithm_module``, and must still load and resume.
MOVED_MODULES = {
    "rl_jax.td3": "rl_jax.agents.td3",
    "rl_jax.dqn": "rl_jax.agents.dqn",
    "rl_jax.reinforce": "rl_jax.agents.reinforce",
}


def load_algorithm(reference: str) -> object:
    """The module or module-level object that ``reference`` names; ``RunError`` if it cannot be
    imported."""
    module_name, _, attribute = reference.partition(":")
    module_name = MOVED_MODULES.get(module_name, module_name)
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise RunError(f"cannot import algorithm {reference!r}: {error}") from None
    return getattr(module, attribute) if attribute else module


def identity(
    algorithm_name: str,
    env_id: str,
    config: Config,
    hparams_list: Sequence[Hyperparams],
    seeds: int,
    base_seed: int,
) -> dict[str, Any]:
    """What must agree for a checkpoint of one run to continue as another."""
    return {
        "algorithm": algorithm_name,
        "env_id": env_id,
        "config": params.dataclass_to_dict(config),
        # Through float32, as the learner sees them: 3e-4 typed or computed compares equal.
        "hparams": [params.dataclass_to_dict(params.as_arrays(h)) for h in hparams_list],
        "seeds": seeds,
        "base_seed": base_seed,
    }


def identity_hash(run_identity: Mapping[str, object]) -> str:
    canonical = json.dumps(run_identity, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def describe_difference(saved: dict[str, Any], wanted: dict[str, Any]) -> str:
    """The first differences between two identities, as a short phrase."""
    differences = []
    for key in ("algorithm", "env_id", "seeds", "base_seed"):
        if saved.get(key) != wanted.get(key):
            differences.append(f"{key} {saved.get(key)!r} vs {wanted.get(key)!r}")
    for key in ("config", "hparams"):
        old, new = saved.get(key), wanted.get(key)
        if key == "hparams" and isinstance(old, list) and isinstance(new, list):
            if len(old) != len(new):
                differences.append(f"{len(old)} vs {len(new)} hyperparameter configs")
                continue
            old, new = _merge_lists(old), _merge_lists(new)
        for name in sorted(set(old or {}) | set(new or {})):
            if (old or {}).get(name) != (new or {}).get(name):
                differences.append(f"{name} {(old or {}).get(name)!r} vs {(new or {}).get(name)!r}")
    return ", ".join(differences[:4]) + (", ..." if len(differences) > 4 else "")


def _merge_lists(dicts: list[dict]) -> dict[str, Any]:
    return {k: [d.get(k) for d in dicts] if len(dicts) > 1 else dicts[0].get(k) for k in dicts[0]}


# ---- config.json ----------------------------------------------------------------------------


def git_commit() -> str | None:
    """The source tree's commit (with ``+dirty`` if modified), when run from a git checkout."""
    root = Path(__file__).resolve().parent.parent
    try:
        commit = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=5,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return (commit + ("+dirty" if dirty else "")) or None


def environment_record() -> dict[str, object]:
    """Versions and machine facts needed to reproduce a run."""
    return {
        "versions": {"python": platform.python_version(), **library_versions()},
        "git_commit": git_commit(),
        "platform": platform.platform(),
        "devices": [str(d) for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def write_json_atomic(path: Path, payload: Mapping[str, object]) -> None:
    """Write JSON through a temporary file and a rename, so a crash never leaves half a file
    (the temporary file is this process's own: two writers never share one)."""
    temporary = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    temporary.write_text(json.dumps(payload, indent=2, sort_keys=False) + "\n")
    os.replace(temporary, path)


def read_run_record(run_dir: Path) -> dict[str, Any]:
    """``config.json`` of ``run_dir``, checked as data (``check_record``); ``RunError`` if it is
    not a readable, untouched run record."""
    path = Path(run_dir) / CONFIG_FILE
    if not Path(run_dir).is_dir():
        raise RunError(f"no run directory at {run_dir}")
    if not path.is_file():
        raise RunError(f"{run_dir} is not a run directory (it has no {CONFIG_FILE})")
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise RunError(f"{path} is unreadable: {error}") from None
    if not isinstance(record, dict) or "identity" not in record:
        raise RunError(f"{path} is not an rl_jax run config")
    problem = record_problem(record)
    if problem is not None:
        raise RunError(f"{path} is refused: {problem}")
    return record


#: The top-level fields of config.json and the JSON types each may hold. A record is data: no
#: field is ever imported or called, and one that this code does not know is refused rather
#: than ignored, so that nothing in a record can change what runs without being checked here.
RECORD_FIELDS: dict[str, type] = {
    "identity": dict,
    "identity_hash": str,
    "algorithm_module": str,
    "learner": str,
    "learner_source": str,
    "total_steps": int,
    "steps_per_chunk": int,
    "grid_fields": list,
    "command": str,
    "sessions": list,
    "created": str,
    "environment": dict,
}
IDENTITY_FIELDS: dict[str, type] = {
    "algorithm": str,
    "env_id": str,
    "config": dict,
    "hparams": list,
    "seeds": int,
    "base_seed": int,
}


def record_problem(record: dict[str, Any]) -> str | None:
    """What makes ``record`` no untouched run record, in a phrase; None when it is one.

    Types and field names are checked against ``RECORD_FIELDS`` and ``IDENTITY_FIELDS``; the
    config and hyperparameters hold plain JSON values only; the identity must still hash to
    the ``identity_hash`` written beside it, so that an edit of what the run is (its learner,
    env, env keywords, settings or seeds) is refused. The hash is a check against edits, not a
    signature: the protection against foreign code is that nothing in a record is imported."""
    problem = _fields_problem(record, RECORD_FIELDS, "")
    if problem is None:
        problem = _fields_problem(record["identity"], IDENTITY_FIELDS, "identity.")
    if problem is not None:
        return problem
    identity = record["identity"]
    missing = sorted(set(IDENTITY_FIELDS) - set(identity))
    if missing:
        return f"its identity lacks {', '.join(missing)}"
    if not all(isinstance(values, dict) for values in identity["hparams"]):
        return "identity.hparams is not a list of objects"
    for where, value in [("identity.config", identity["config"])] + [
        (f"identity.hparams[{i}]", values) for i, values in enumerate(identity["hparams"])
    ]:
        if not _plain_data(value):
            return f"{where} holds something other than numbers, strings, booleans and lists"
    if identity["config"].get("env_id", identity["env_id"]) != identity["env_id"]:
        return "its config's env_id is not the run's env_id"
    recorded = record.get("identity_hash")
    if recorded is not None and recorded != identity_hash(identity):
        return "its identity was edited after the run wrote it (it no longer matches identity_hash)"
    return None


def _fields_problem(
    values: Mapping[str, object], fields: dict[str, type], prefix: str
) -> str | None:
    for name, value in values.items():
        if name not in fields:
            return f"it has a field {prefix}{name!r} that rl_jax does not write"
        wanted = fields[name]
        if isinstance(value, bool) or not isinstance(value, wanted):
            return f"{prefix}{name} is not a JSON {wanted.__name__}"
    return None


def _plain_data(values: Mapping[str, object]) -> bool:
    """Each value is a number, string, boolean or null, or a list of them (lists nested): what
    the fields of a learner's config and hyperparameters are written as."""

    def plain(value: object) -> bool:
        if value is None or isinstance(value, (bool, int, float, str)):
            return True
        return isinstance(value, list) and all(plain(item) for item in value)

    return all(plain(value) for value in values.values())


def recorded_env(
    recorded: str, run_dir: Path | str, named: str | None = None, how: str = "--env"
) -> str:
    """The env id ``recorded`` by the run (or sweep) in ``run_dir``, resolved without importing
    anything that the record names: a registered id, ``gymnasium:ID`` of gymnasium's registry,
    or a ``MODULE:ID`` that this process has registered (the user named it). ``named`` is the
    user's own naming of the env (``--env``, ``env=``), which may import its module and must
    resolve to the run's env. Else ``RunError`` says how to name it again (``how``: "--env" or
    "env=")."""
    given = None
    if named is not None:
        try:
            given = registry.resolve_id(named)
        except registry.UnknownEnvError as error:
            raise RunError(str(error)) from None
    try:
        resolved = registry.resolve_id(recorded, imports=False)
    except registry.EnvNotNamedError as error:
        if given is not None:
            raise RunError(f"{run_dir} is a run on {recorded}, not on {given}") from None
        again = f"{how}{recorded!r}" if how.endswith("=") else f"{how} {shlex.quote(recorded)}"
        raise RunError(
            f"{run_dir} trains the environment {recorded!r} of the module {error.module!r}, which "
            f"opening a run does not import by itself; name it again: {again}"
        ) from None
    except registry.UnknownEnvError as error:
        raise RunError(f"{run_dir}: {error}") from None
    if given is not None and given != resolved:
        raise RunError(f"{run_dir} is a run on {resolved}, not on {given}")
    return resolved


def check_out_dir(out: Path, run_identity: dict[str, Any]) -> None:
    """Refuse to start a fresh run in a directory that already holds something, or one that
    cannot be created or written: a probe creates the missing directories and a file in the
    last, then removes what it created (``/proc`` or a read-only mount only says so then).

    The lead process alone probes and the others take its verdict: all start at once, and one
    probing beside another would find the other's probe and refuse a directory nobody used."""
    error = None
    if processes.is_lead():
        try:
            _check_out_dir(out, run_identity)
        except OSError as failed:
            error = RunError(f"cannot use --out {out}: {_reason(failed)}")
        except RunError as refused:
            error = refused
    (refused_by_lead,) = processes.agree(error is not None, at="the check of --out")
    if error is not None:
        raise error
    if refused_by_lead:
        raise RunError(f"process 0 refused --out {out} (its output says why)")


def _check_out_dir(out: Path, run_identity: dict[str, Any]) -> None:
    if not out.exists():
        ancestor = out.absolute().parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        if not ancestor.is_dir():
            raise RunError(f"cannot create --out {out}: {ancestor} is not a directory")
        if not os.access(ancestor, os.W_OK | os.X_OK):
            raise RunError(f"cannot create --out {out}: {ancestor} is not writable")
        _probe_creatable(out)
        return
    if not out.is_dir():
        raise RunError(f"--out {out} exists and is not a directory")
    # A new run killed after taking its lease and before writing its record left the lease
    # alone: the directory holds no run yet (a live owner is refused by the lease itself).
    if not any(not entry.name.startswith(LEASE_FILE) for entry in out.iterdir()):
        try:
            probe_writable(out)
        except OSError as error:
            raise RunError(f"cannot write to --out {out}: {_reason(error)}") from None
        return
    if (out / CONFIG_FILE).is_file():
        saved = read_run_record(out)["identity"]
        if saved == run_identity:
            raise RunError(f"{out} already holds this run; continue it with --resume {out}")
        raise RunError(
            f"{out} already holds a different run ({describe_difference(saved, run_identity)}); "
            "choose another --out"
        )
    raise RunError(f"--out {out} is not empty; choose another --out")


def same_command_again(out: Path, run_identity: dict[str, Any], command: str) -> bool:
    """Whether ``out`` holds this very run, created by this same ``command``: a requeued job (or
    the same command after a crash) then continues it instead of being refused. The flags that
    only place the processes (``rl_jax.run.distributed``) may differ, and so may the name of
    the Python executable."""
    if not command or not (out / CONFIG_FILE).is_file():
        return False
    try:
        record = read_run_record(out)
    except RunError:
        return False  # check_out_dir says what is wrong with it
    saved = with_newer_fields(record["identity"], run_identity)
    recorded = record.get("command", "")
    return (
        saved == run_identity and bool(recorded) and _comparable(recorded) == _comparable(command)
    )


def _comparable(command: str) -> list[str]:
    try:
        words = shlex.split(command)
    except ValueError:
        return [command]
    return without_flags(words[1:])


def _probe_creatable(out: Path) -> None:
    """Create ``out`` (and its missing parents) and a file in it, then remove all of them."""
    missing = []
    directory = out.absolute()
    while not directory.exists():
        missing.append(directory)
        directory = directory.parent
    created: list[Path] = []
    try:
        for directory in reversed(missing):
            try:
                directory.mkdir()
            except FileExistsError:  # made meanwhile by someone else: not ours to remove
                continue
            created.append(directory)
        probe_writable(out)
    except OSError as error:
        raise RunError(f"cannot create --out {out}: {_reason(error)}") from None
    finally:
        for directory in reversed(created):
            with contextlib.suppress(OSError):
                directory.rmdir()


def probe_writable(directory: Path) -> None:
    """Create and remove a file in ``directory``; ``OSError`` if that is not possible."""
    handle, name = tempfile.mkstemp(prefix=".write-probe-", dir=directory)
    os.close(handle)
    os.unlink(name)


def _reason(error: OSError) -> str:
    """The OS's reason for ``error``, with the path it concerns."""
    reason = error.strerror or type(error).__name__
    return f"{reason} ({error.filename})" if error.filename else reason


def with_newer_fields(saved: dict[str, Any], wanted: dict[str, Any]) -> dict[str, Any]:
    """``saved`` with the config and hyperparameter fields it lacks taken from ``wanted``: a
    field a run's record does not have was added to the code after the run was written, and
    resuming fills it from the defaults the record is read with (e.g. TD3's ``lr_decay_steps``,
    0: off, as the run trained). A field only the record has was retired since (a learner's
    ``RETIRED``): reading the record kept it only at its "off" value, so it is dropped."""
    upgraded = dict(saved)
    if isinstance(saved.get("config"), dict) and isinstance(wanted.get("config"), dict):
        upgraded["config"] = _upgraded(saved["config"], wanted["config"])
    saved_hparams, wanted_hparams = saved.get("hparams"), wanted.get("hparams")
    if (
        isinstance(saved_hparams, list)
        and isinstance(wanted_hparams, list)
        and len(saved_hparams) == len(wanted_hparams)
    ):
        upgraded["hparams"] = [
            _upgraded(old, new) for old, new in zip(saved_hparams, wanted_hparams, strict=True)
        ]
    return upgraded


def _upgraded(saved: dict[str, Any], wanted: dict[str, Any]) -> dict[str, Any]:
    """``wanted``'s fields, at ``saved``'s values where it has them."""
    return {**wanted, **{name: value for name, value in saved.items() if name in wanted}}


def check_resume_dir(run_dir: Path, run_identity: dict[str, Any]) -> dict[str, Any]:
    """The record of ``run_dir`` if it is the same run and can be written; ``RunError``
    otherwise."""
    record = read_run_record(run_dir)
    saved = with_newer_fields(record["identity"], run_identity)
    if saved != run_identity:
        raise RunError(
            f"cannot resume {run_dir}: it is a different run "
            f"({describe_difference(saved, run_identity)})"
        )
    try:
        probe_writable(Path(run_dir))
    except OSError as error:
        raise RunError(f"cannot resume {run_dir}: it is not writable: {_reason(error)}") from None
    return record


def new_run_record(
    run_identity: dict[str, Any], algorithm_ref: str, extra: dict[str, Any]
) -> dict[str, Any]:
    return {
        "identity": run_identity,
        "identity_hash": identity_hash(run_identity),
        "algorithm_module": algorithm_ref,
        **extra,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "environment": environment_record(),
    }
