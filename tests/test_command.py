"""The `rl-jax` command (rl_jax/__main__.py): its help, its one-line errors, and the subcommands
reaching the scripts' entry points. tests/test_install.py runs it from an installed wheel."""

import importlib
import shlex
import sys
import tomllib
import types
from pathlib import Path

import pytest

from rl_jax import __main__ as command

ROOT = Path(__file__).resolve().parent.parent


def test_console_script_names_the_entry_point():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    module, _, name = scripts["rl-jax"].partition(":")
    assert getattr(importlib.import_module(module), name) is command.main


def test_help_lists_every_subcommand(capsys):
    assert command.main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: rl-jax COMMAND")
    for name in ("train", "sweep", "evaluate", "render", "match"):
        assert f"\n  {name} " in out


@pytest.mark.parametrize("argv", [["trian", "--algo", "td3"], [], ["--seeds", "2"]])
def test_unknown_or_missing_command_is_one_line_and_exit_2(argv, capsys):
    assert command.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    assert len(captured.err.splitlines()) == 1 and captured.err.startswith("error: ")


def test_train_help_names_the_command(capsys, monkeypatch):
    monkeypatch.setattr("sys.argv", ["rl-jax"])  # the command replaces it; restored after
    with pytest.raises(SystemExit) as exit_:
        command.main(["train", "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: rl-jax train ") and "--algo NAME" in out


@pytest.mark.parametrize(
    ("main_module", "program"),
    [(None, ["rl-jax", "train"]), ("rl_jax.__main__", ["PYTHON", "-m", "rl_jax", "train"])],
)
def test_a_train_run_records_commands_that_start_it_again(
    main_module, program, monkeypatch, tmp_path
):
    """Started as ``rl-jax train`` (or ``python -m rl_jax train``), a run records its command and
    its resume command as that program, never as ``python 'rl-jax train'``."""
    from rl_jax.run import cli, runner

    specs = []

    def capture(spec):
        specs.append(spec)
        return types.SimpleNamespace(run_dir=spec.out, gif_error=None)

    spec = None if main_module is None else types.SimpleNamespace(name=main_module)
    monkeypatch.setitem(sys.modules, "__main__", types.SimpleNamespace(__spec__=spec))
    monkeypatch.setattr("sys.argv", ["rl-jax"])  # the command replaces it; restored after
    monkeypatch.setattr(runner, "run", capture)
    out = str(tmp_path / "my run")
    argv = ["--algo", "td3", "--env", "rl_jax/Pendulum-v1", "--seeds", "2", "--out", out]
    with pytest.raises(SystemExit) as exit_:
        command.main(["train", *argv])
    assert exit_.value.code == 0
    python = Path(sys.executable).name
    program = [python if word == "PYTHON" else word for word in program]
    assert shlex.split(specs[0].command) == [*program, *argv]
    assert shlex.split(specs[0].resume_command) == [*program, "--resume", out]
    assert cli.program("experiments/train.py") == [python, "experiments/train.py"]
