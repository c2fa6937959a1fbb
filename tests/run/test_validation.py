"""Hyperparameter and config ranges are checked before anything compiles: one line naming the
flag and its range, a non-zero exit, nothing written; the edges of each range are accepted; and
an --out that cannot be created or written, or a --resume of no writable run directory, is one
line too (from the script itself as well)."""

import dataclasses
import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from child_env import python_path

from rl_jax.agents.dqn import dqn
from rl_jax.agents.reinforce import reinforce
from rl_jax.agents.td3 import td3
from rl_jax.errors import RunError, guard
from rl_jax.run import cli, run_dir, runner
from rl_jax.run.spec import RunSpec
from rl_jax.training import validation

ROOT = Path(__file__).resolve().parents[2]


def run_cli(algorithm, env_id, argv) -> int:
    return guard(lambda: cli.run_experiment(algorithm, env_id, "", argv))


def one_line(capsys, status: int) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert "Traceback" not in captured.err + captured.out
    return lines[0]


@pytest.mark.parametrize(
    ("algorithm", "env_id", "argv", "message"),
    [
        (td3, "rl_jax/Pendulum-v1", ["--gamma", "2"], "--gamma must be in [0, 1], got 2"),
        (td3, "rl_jax/Pendulum-v1", ["--tau=-1"], "--tau must be in (0, 1], got -1"),
        (td3, "rl_jax/Pendulum-v1", ["--tau", "0"], "--tau must be in (0, 1], got 0"),
        (td3, "rl_jax/Pendulum-v1", ["--actor-lr", "0"], "--actor-lr must be > 0, got 0"),
        (
            td3,
            "rl_jax/Pendulum-v1",
            ["--exploration-correlation", "1.5"],
            "--exploration-correlation must be in [0, 1), got 1.5",
        ),
        (
            td3,
            "rl_jax/Pendulum-v1",
            ["--exploration-noise=-0.1"],
            "--exploration-noise must be >= 0, got -0.1",
        ),
        (dqn, "rl_jax/CartPole-v1", ["--epsilon-end", "1.5"], "--epsilon-end must be in [0, 1]"),
        (
            dqn,
            "rl_jax/CartPole-v1",
            ["--epsilon-start", "1.5"],
            "--epsilon-start must be in [0, 1], got 1.5",
        ),
        (dqn, "rl_jax/CartPole-v1", ["--learning-rate", "0"], "--learning-rate must be > 0, got 0"),
        (dqn, "rl_jax/CartPole-v1", ["--tau", "1.5"], "--tau must be in (0, 1], got 1.5"),
        (
            dqn,
            "rl_jax/CartPole-v1",
            ["--priority-beta-start=-0.1"],
            "--priority-beta-start must be in [0, 1], got -0.1",
        ),
        (
            td3,
            "rl_jax/Pendulum-v1",
            ["--actor-hidden", "0,16"],
            "--actor-hidden must have every value >= 1, got 0,16",
        ),
        (dqn, "rl_jax/CartPole-v1", ["--priority-alpha", "2"], "--priority-alpha must be in"),
        (dqn, "rl_jax/CartPole-v1", ["--max-grad-norm", "0"], "--max-grad-norm must be > 0, got 0"),
        (dqn, "rl_jax/CartPole-v1", ["--batch-size", "0"], "batch_size must be >= 1, got 0"),
        (
            td3,
            "rl_jax/Pendulum-v1",  # recipe: 4 envs, batch 256, 1,000 warm-up steps
            ["--buffer-size", "10"],
            "--buffer-size must be >= 1000 (--learning-starts: the random warm-up's transitions, "
            "of all 4 envs together, would be overwritten before the first update), got 10",
        ),
        (
            dqn,
            "rl_jax/CartPole-v1",  # recipe: batch 64
            ["--buffer-size", "32", "--learning-starts", "0"],
            "--buffer-size must be >= 64 (--batch-size: every update draws a batch from it), "
            "got 32",
        ),
        (
            reinforce,
            "rl_jax/CartPole-v1",
            ["--learning-rate=-1e-3"],
            "--learning-rate must be > 0, got -0.001",
        ),
        (
            td3,
            "rl_jax/Pendulum-v1",
            ["--grid", "gamma=0.9,1.5"],
            "--gamma must be in [0, 1], got 1.5",
        ),
        (
            td3,
            "rl_jax/Pendulum-v1",
            ["--grid", "tau=0.005,0"],
            "--tau must be in (0, 1], got 0",
        ),
    ],
)
def test_out_of_range_values_are_one_line_naming_the_flag(
    algorithm, env_id, argv, message, tmp_path, capsys
):
    out = tmp_path / "run"
    line = one_line(capsys, run_cli(algorithm, env_id, [*argv, "--out", str(out)]))
    assert message in line, line
    assert not out.exists()


def test_the_edges_of_each_range_and_every_recipe_are_accepted():
    assert validation.out_of_range(td3.default_hyperparams(gamma=1.0, tau=1.0), td3) is None
    edges = td3.default_hyperparams(gamma=0.0, exploration_correlation=0.0, exploration_noise=0.0)
    assert validation.out_of_range(edges, td3) is None
    assert validation.out_of_range(dqn.default_hyperparams(epsilon_end=1.0), dqn) is None
    assert validation.out_of_range(reinforce.default_hyperparams(max_grad_norm=0.0)) is None
    for algorithm in (td3, dqn, reinforce):
        for recipe in algorithm.recipes:
            for env_id in recipe.envs or ("rl_jax/Hopper-v5",):
                config = algorithm.default_config(env_id, recipe.name)
                hparams = algorithm.default_hyperparams(env_id, recipe.name)
                where = (algorithm, env_id, recipe.name)
                assert validation.out_of_range(config, algorithm) is None, where
                assert validation.out_of_range(hparams, algorithm) is None, where


@pytest.mark.parametrize("where", ["/proc/x", "/sys/x", "file/run", "file"])
def test_an_out_that_cannot_be_created_is_one_line(where, tmp_path, capsys):
    """Refused in the checks before the plan is printed, with the OS's reason."""
    (tmp_path / "file").write_text("not a directory")
    out = Path(where) if where.startswith("/") else tmp_path / where
    status = run_cli(td3, "rl_jax/Pendulum-v1", ["--out", str(out)])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert status == 2 and len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert "Traceback" not in captured.err + captured.out and captured.out == ""
    if where == "file":
        assert f"--out {out} exists and is not a directory" in lines[0]
    else:
        assert f"cannot create --out {out}" in lines[0]
    assert (tmp_path / "file").read_text() == "not a directory"


@pytest.mark.parametrize("where", ["/proc/x", "file", "missing/run"])
def test_a_resume_of_no_run_directory_is_one_line(where, tmp_path, capsys):
    (tmp_path / "file").write_text("not a run")
    run = Path(where) if where.startswith("/") else tmp_path / where
    line = one_line(capsys, run_cli(td3, "rl_jax/Pendulum-v1", ["--resume", str(run)]))
    assert f"no run directory at {run}" in line
    assert not (tmp_path / "missing").exists()


def test_the_out_probe_leaves_nothing_behind(tmp_path):
    """Creatable: the probe's directories and file are removed again."""
    run_dir.check_out_dir(tmp_path / "a" / "b" / "run", {})
    (tmp_path / "empty").mkdir()
    run_dir.check_out_dir(tmp_path / "empty", {})
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["empty"]


def _read_only(*args, **kwargs):
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(kwargs.get("dir")))


def test_a_read_only_out_or_resume_directory_is_refused(tmp_path, monkeypatch):
    """A directory that exists but takes no file (a read-only mount; root ignores file modes,
    so the file system's refusal is simulated) is refused before the run starts."""
    identity = {
        "algorithm": "td3", "env_id": "rl_jax/Pendulum-v1", "config": {}, "hparams": [{}],
        "seeds": 1, "base_seed": 0,
    }  # fmt: skip
    run = tmp_path / "run"
    run.mkdir()
    (run / run_dir.CONFIG_FILE).write_text(json.dumps({"identity": identity}))
    (tmp_path / "empty").mkdir()
    assert run_dir.check_resume_dir(run, identity)["identity"] == identity
    assert sorted(p.name for p in run.iterdir()) == [run_dir.CONFIG_FILE]
    monkeypatch.setattr(run_dir.tempfile, "mkstemp", _read_only)
    with pytest.raises(RunError, match=r"cannot resume .*run: it is not writable: Read-only"):
        run_dir.check_resume_dir(run, identity)
    with pytest.raises(RunError, match=r"cannot write to --out .*empty: Read-only file system"):
        run_dir.check_out_dir(tmp_path / "empty", identity)
    with pytest.raises(RunError, match=r"cannot create --out .*new: Read-only file system"):
        run_dir.check_out_dir(tmp_path / "new", identity)
    assert not (tmp_path / "new").exists()


def _spec(hparams, out):
    return RunSpec(
        algorithm=td3,
        env_id="rl_jax/Pendulum-v1",
        config=td3.default_config("rl_jax/Pendulum-v1"),
        hparams=tuple(hparams),
        out=out,
        total_steps=100,
    )


def test_the_python_api_path_checks_ranges_before_writing(tmp_path):
    """``runner.prepare`` (scripts, grids, rl_jax.train, a hand-made RunSpec) checks every
    hyperparameter config of a grid before the directory is touched."""
    good = td3.default_hyperparams("rl_jax/Pendulum-v1")
    out = tmp_path / "run"
    with pytest.raises(validation.RangeError, match=r"^--gamma must be in \[0, 1\], got 2$"):
        runner.prepare(_spec([good.replace(gamma=2.0)], out))
    bad_second = [good, good.replace(exploration_correlation=1.5)]
    with pytest.raises(
        RunError, match=r"^--exploration-correlation must be in \[0, 1\), got 1.5 \(config 1"
    ):
        runner.prepare(_spec(bad_second, out))
    assert not out.exists()


def test_the_buffer_must_hold_a_batch_and_the_warm_up_and_may_equal_them(tmp_path):
    config = td3.default_config("rl_jax/Pendulum-v1", learning_starts=1000, batch_size=256)

    def too_small(config, algorithm=td3):
        return validation.buffer_too_small(config, algorithm)

    assert too_small(dataclasses.replace(config, buffer_size=1000)) is None
    assert "must be >= 1000 " in too_small(dataclasses.replace(config, buffer_size=999))
    no_warm_up = dataclasses.replace(config, learning_starts=0)
    assert too_small(dataclasses.replace(no_warm_up, buffer_size=256)) is None
    assert "must be >= 256 " in too_small(dataclasses.replace(no_warm_up, buffer_size=255))
    # no buffer: reinforce's hooks say so
    assert too_small(reinforce.default_config("rl_jax/CartPole-v1"), reinforce) is None
    # The Python API path (runner.prepare) refuses it too, before anything is written.
    out = tmp_path / "run"
    spec = _spec([td3.default_hyperparams("rl_jax/Pendulum-v1")], out)
    spec = dataclasses.replace(spec, config=dataclasses.replace(config, buffer_size=10))
    with pytest.raises(validation.RangeError, match=r"^--buffer-size must be >= 1000 \("):
        runner.prepare(spec)
    assert not out.exists()


def test_check_ranges_accepts_the_edges_for_every_config_of_a_grid():
    base = td3.default_hyperparams()
    edges = [
        base.replace(gamma=1.0, tau=1.0, exploration_correlation=0.0),
        base.replace(gamma=0.0, exploration_noise=0.0, target_noise=0.0),
    ]
    validation.check_ranges(td3, td3.default_config("rl_jax/Pendulum-v1"), edges)
    config = dqn.default_config("rl_jax/CartPole-v1")
    dqn_edges = [dqn.default_hyperparams().replace(epsilon_start=1.0, priority_alpha=0.0)]
    validation.check_ranges(dqn, config, dqn_edges)


SCRIPT = ROOT / "experiments" / "td3_pendulum.py"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", "/proc/x"], "error: cannot create --out /proc/x: "),
        (["--out", "{file}"], "exists and is not a directory"),
        (["--resume", "/proc/x"], "error: no run directory at /proc/x"),
        (["--gamma", "2", "--out", "{tmp}/run"], "error: --gamma must be in [0, 1], got 2"),
    ],
)
def test_the_script_says_one_line_and_exits_non_zero(argv, message, tmp_path):
    """From a fresh interpreter, as a user runs it: one stderr line, status 2, no traceback."""
    (tmp_path / "file").write_text("x")
    argv = [a.format(file=tmp_path / "file", tmp=tmp_path) for a in argv]
    env = {key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"}
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *argv],
        cwd=tmp_path,
        env={**env, "PYTHONPATH": python_path(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert message in lines[0] and "Traceback" not in done.stdout + done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
