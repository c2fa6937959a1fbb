"""A run directory is data: opening one, through any entry point, never imports or calls code that
its records name, and a record edited after the run wrote it is refused with one line.

Each tampered copy of ``tests/data/old_run_td3`` (TD3 on Pendulum) names code that leaves a
marker file when it runs: a shell command through ``os:system``, a module shipped inside the
run directory, a module in the current directory, gymnasium's ``module:Env`` spelling. Every
entry point that opens a run (evaluate, render, load_policy, open_run and its policy, evaluation
and GIF, resume from Python and from the scripts, the sweep's resume, rocket_report, the
``rl-jax`` subcommands) is asked to open every copy; each answers with one line and the marker
never appears. A run on an env of the user's own module opens once the user names the env again.
"""

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from child_env import python_path

import rl_jax
from experiments import rocket_report
from rl_jax.__main__ import main as rl_jax_main
from rl_jax.envs.core import registry
from rl_jax.errors import RunError, guard
from rl_jax.run import cli, evaluate, render, sweep
from rl_jax.run.run_dir import identity_hash

ROOT = Path(__file__).resolve().parents[2]
OLD_RUN = ROOT / "tests" / "data" / "old_run_td3"
ENV = {
    **{key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"},
    "PYTHONPATH": python_path(ROOT),
}

# A module that leaves a marker in the current directory when it is imported.
MARKER_MODULE = """
from pathlib import Path
Path("{marker}").write_text("imported")
Pendulum = None
"""


def _tamper(run_dir: Path, env_id: str, env_kwargs: str = "", rehash: bool = True) -> None:
    """Name ``env_id`` (and ``env_kwargs``) in the run's record, as an attacker would: with the
    identity hash written anew, so that only the refusal to import can stop it."""
    path = run_dir / "config.json"
    record = json.loads(path.read_text())
    record["identity"]["env_id"] = env_id
    record["identity"]["config"]["env_id"] = env_id
    record["identity"]["config"]["env_kwargs"] = env_kwargs
    if rehash:
        record["identity_hash"] = identity_hash(record["identity"])
    path.write_text(json.dumps(record, indent=2))


@pytest.fixture
def tampered(tmp_path, monkeypatch):
    """Copies of the old run, each naming code that leaves ``tmp_path/MARKER`` when it runs, run
    from a working directory that holds a marker module of its own."""
    marker = tmp_path / "MARKER"
    work = tmp_path / "work"
    work.mkdir()
    (work / "cwd_markenv.py").write_text(MARKER_MODULE.format(marker=marker))
    monkeypatch.chdir(work)
    monkeypatch.setattr(sys, "path", list(sys.path))  # an import may append the cwd
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # a resume sets it
    copies = {}
    for name, env_id, keywords in [
        ("os_system", "os:system", f"command='touch {marker}'"),
        ("shipped_module", "shipped_markenv:Pendulum", ""),
        ("cwd_module", "cwd_markenv:Pendulum", ""),
        ("gymnasium_module", "gymnasium:cwd_markenv:Pendulum-v1", ""),
    ]:
        run_dir = tmp_path / name
        shutil.copytree(OLD_RUN, run_dir)
        (run_dir / "shipped_markenv.py").write_text(MARKER_MODULE.format(marker=marker))
        _tamper(run_dir, env_id, keywords)
        copies[name] = run_dir
    # An edit that leaves the hash as it was: refused as an edit.
    edited = tmp_path / "edited_keywords"
    shutil.copytree(OLD_RUN, edited)
    _tamper(edited, "rl_jax/Pendulum-v1", "g=20.0", rehash=False)
    copies["edited_keywords"] = edited
    return marker, copies


def _quiet(call: Callable[[], object]) -> tuple[str, int | None]:
    """stderr and exit status of ``call`` under the CLI's guard (one line on a user error)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = guard(call)
    return err.getvalue(), status


def _one_line(err: str, status: int | None) -> str:
    lines = err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def _entry_points(run_dir: Path, tmp_path: Path) -> dict[str, Callable[[], object]]:
    """Every way into a run directory, each a call that the CLI's guard can report."""
    sweep_dir = tmp_path / f"sweep_of_{run_dir.name}"
    if not sweep_dir.exists():
        sweep_dir.mkdir()
        record = json.loads((run_dir / "config.json").read_text())
        saved = {"algo": "td3", "env": record["identity"]["env_id"], "grid": [], "argv": []}
        (sweep_dir / "sweep.json").write_text(json.dumps({**saved, "learner": "builtin"}))
    run = str(run_dir)
    return {
        "evaluate": lambda: evaluate.main([run, "--episodes", "1"]),
        "render": lambda: render.main([run, "--out", str(tmp_path / "r.gif")]),
        "load_policy": lambda: rl_jax.load_policy(run_dir),
        "open_run": lambda: rl_jax.open_run(run_dir).policy(),
        "open_run_evaluate": lambda: rl_jax.open_run(run_dir).evaluate(1),
        "gif": lambda: rl_jax.open_run(run_dir).save_gif(tmp_path / "p.gif"),
        "resume": lambda: rl_jax.resume(run_dir, total_steps=800, quiet=True),
        "train_py_resume": lambda: cli.run_experiment(None, None, "", ["--resume", run]),
        "sweep_resume": lambda: sweep.run_sweep(["--resume", str(sweep_dir)]),
        "rocket_report": lambda: rocket_report.main([run, "--out", str(tmp_path / "report")]),
        "rl_jax_evaluate": lambda: rl_jax_main(["evaluate", run, "--episodes", "1"]),
        "rl_jax_render": lambda: rl_jax_main(["render", run, "--out", str(tmp_path / "s.gif")]),
    }


def test_no_entry_point_runs_code_that_a_record_names(tampered, tmp_path):
    marker, copies = tampered
    refusals = {}
    for kind, run_dir in copies.items():
        for entry, call in _entry_points(run_dir, tmp_path).items():
            if kind == "edited_keywords" and entry == "sweep_resume":
                continue  # the sweep's record names a registered env: it would train
            err, status = _quiet(call)
            refusals[kind, entry] = _one_line(err, status)
            assert not marker.exists(), (kind, entry)
    assert len(refusals) == len(copies) * 12 - 1
    assert not any("markenv" in name for name in sys.modules)
    for (kind, entry), line in refusals.items():
        if kind == "edited_keywords":
            assert "was edited after the run wrote it" in line, (entry, line)
        else:
            assert "does not import by itself; name it again" in line, (kind, entry, line)
    named = refusals["cwd_module", "evaluate"]
    assert named.endswith("name it again: --env cwd_markenv:Pendulum"), named
    assert refusals["cwd_module", "load_policy"].endswith("env='cwd_markenv:Pendulum'")


def test_the_script_refuses_a_tampered_run_in_a_fresh_process(tampered):
    marker, copies = tampered
    for command in (
        [sys.executable, "-m", "rl_jax.run.evaluate", str(copies["shipped_module"])],
        [
            sys.executable,
            str(ROOT / "experiments" / "train.py"),
            "--resume",
            str(copies["os_system"]),
        ],
    ):
        # the run directory as the working directory: its shipped module is importable there
        cwd = copies["cwd_module"].parent / "work" if "cwd_module" in command[-1] else None
        done = subprocess.run(
            command, cwd=cwd or copies["shipped_module"], env=ENV, capture_output=True, text=True
        )
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, done.stderr
        assert "name it again: --env" in lines[0], lines[0]
        assert not marker.exists()


USER_ENVS = """
from rl_jax.envs.classic.pendulum import Pendulum
"""
# The old run's tiny TD3: one chunk of 200 env steps per seed.
TINY = {
    "num_envs": 2, "iterations_per_chunk": 100, "batch_size": 16, "buffer_size": 256,
    "learning_starts": 50, "num_eval_envs": 10, "actor_hidden": (8, 8), "critic_hidden": (8, 8),
}  # fmt: skip


def test_a_run_on_an_env_of_the_users_module_opens_once_it_is_named(tmp_path, monkeypatch):
    """A run trained on ``user_pendulums:Pendulum`` (a module of the user's project): a process
    that has not named that env is asked for it in one line, and loads the run once it names it;
    naming another env is refused."""
    work = tmp_path / "project"
    work.mkdir()
    (work / "user_pendulums.py").write_text(USER_ENVS)
    monkeypatch.chdir(work)
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # train sets it
    run = rl_jax.train(
        "td3", "user_pendulums:Pendulum", total_steps=200, out=tmp_path / "run", config=TINY,
        quiet=True,
    )  # fmt: skip
    # As in a fresh process: the env is not registered, its module not imported.
    monkeypatch.delitem(registry._ENTRY_POINTS, "user_pendulums:Pendulum")
    monkeypatch.delitem(sys.modules, "user_pendulums")
    with pytest.raises(RunError, match="name it again: env='user_pendulums:Pendulum'"):
        rl_jax.load_policy(run.run_dir)
    err, status = _quiet(lambda: evaluate.main([str(run.run_dir), "--episodes", "1"]))
    assert _one_line(err, status).endswith("name it again: --env user_pendulums:Pendulum")
    with pytest.raises(RunError, match="is a run on user_pendulums:Pendulum, not on rl_jax/"):
        rl_jax.load_policy(run.run_dir, env="rl_jax/Pendulum-v1")
    policy = rl_jax.load_policy(run.run_dir, env="user_pendulums:Pendulum")
    action = np.asarray(policy(np.zeros(3, np.float32)))
    assert action.shape == (1,) and np.all(np.abs(action) <= 2.0)
    # Named once in this process, the env is registered: the run opens without naming it again.
    assert rl_jax.open_run(run.run_dir).env_id == "user_pendulums:Pendulum"
    err, status = _quiet(
        lambda: evaluate.main([str(run.run_dir), "--episodes", "1", "--env", "rl_jax/Pendulum-v1"])
    )
    assert "is a run on user_pendulums:Pendulum" in _one_line(err, status)


@pytest.mark.parametrize(
    "change, expected",
    [
        (lambda r: r.update(loader="os:system"), "a field 'loader' that rl_jax does not write"),
        (lambda r: r["identity"].update(seeds="2"), "identity.seeds is not a JSON int"),
        (
            lambda r: r["identity"]["config"].update(actor_hidden={"__class__": 1}),
            "identity.config holds",
        ),
        (lambda r: r["identity"]["config"].update(env_id="os:system"), "config's env_id is not"),
        (lambda r: r.update(algorithm_module="rl_jax.run.launch:main"), "not one of ours"),
    ],
    ids=["unknown field", "wrong type", "an object", "two env ids", "another module"],
)
def test_a_record_is_checked_as_data(tmp_path, change, expected):
    run_dir = tmp_path / "run"
    shutil.copytree(OLD_RUN, run_dir)
    record = json.loads((run_dir / "config.json").read_text())
    change(record)
    record["identity_hash"] = identity_hash(record["identity"])
    (run_dir / "config.json").write_text(json.dumps(record))
    with pytest.raises(RunError, match=expected):
        rl_jax.load_policy(run_dir)
