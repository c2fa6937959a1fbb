"""What the commands print says what it means, once: each ``rl-jax`` subcommand's help names
``rl-jax COMMAND``; a sweep labels its grid by the names the user gave (``lr``, not the
``learning_rate`` the alias sets) and prints its ranking once; and ``render`` never replaces a GIF
without saying so."""

import sys
import types

import fake_algorithm as fake
import pytest
from run_helpers import fake_run

from rl_jax import __main__ as rl_jax_main
from rl_jax.run import learners, render, runner, sweep

# Tiny: 4 envs x 5 iterations = 20 env steps per chunk.
TINY = ["--seeds", "2", "--total-steps", "40", "--log-interval", "0"]


@pytest.mark.parametrize("command", ["train", "sweep", "evaluate", "render"])
def test_each_rl_jax_command_names_itself_in_its_help(command, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", list(sys.argv))  # rl_jax's main names the program there
    with pytest.raises(SystemExit) as done:
        rl_jax_main.main([command, "--help"])
    assert done.value.code == 0
    usage = capsys.readouterr().out.splitlines()[0]
    assert usage.startswith(f"usage: rl-jax {command} ["), usage


def test_a_sweep_labels_its_grid_by_the_given_name_and_ranks_once(tmp_path, capsys):
    learners.register_algorithm("fake", "fake_algorithm")
    out = tmp_path / "sweep"
    argv = ["--algo", "fake", "--env", fake.ENV_ID, *TINY, "--grid", "lr=1e-3,1e-2"]
    assert sweep.run_sweep([*argv, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "2 seeds x 2 configs (lr), 4 envs each" in printed
    assert printed.count("final eval return at step 40, ranked") == 1, printed
    assert "lr=0.001" in printed and "lr=0.01" in printed and "learning_rate=" not in printed
    ranking = (out / "results.txt").read_text()
    assert "lr=0.001" in ranking and "learning_rate" not in ranking
    assert (out / "base" / "results.txt").read_text().count("lr=0.01 ") == 1


def test_render_writes_a_new_gif_beside_one_that_exists_and_says_when_it_replaces(tmp_path, capsys):
    run_dir = fake_run(tmp_path / "run", total_steps=40)
    first = render.write_gif(run_dir, seed=0)
    second = render.write_gif(run_dir, seed=1)
    third = render.write_gif(run_dir, seed=1)
    assert [first.name, second.name, third.name] == ["policy.gif", "policy-2.gif", "policy-3.gif"]
    printed = capsys.readouterr().out
    assert "replaced" not in printed and f"-> {run_dir / 'policy-2.gif'}" in printed
    before = first.read_bytes()
    assert render.write_gif(run_dir, seed=1, out=first) == first
    assert first.read_bytes() != before  # seed 1's policy, asked for by name
    line = capsys.readouterr().out.strip()
    assert line.endswith(f"-> {first} (replaced the file that was there)"), line


def test_renders_help_says_what_happens_to_an_existing_gif(capsys):
    with pytest.raises(SystemExit):
        render.main(["--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "usage: python -m rl_jax.run.render" in help_text
    assert "replaced if it exists" in help_text and "policy-2.gif" in help_text


def test_the_runs_own_gif_is_replaced_by_a_resumed_run_that_makes_it_again(tmp_path, monkeypatch):
    """``--gif`` names the run's policy.gif to the child that renders it: a resume with
    ``--gif`` makes that file again (and says so) rather than a policy-2.gif."""
    commands = []

    def child(command, **kwargs):
        commands.append(command)
        return types.SimpleNamespace(returncode=0, stdout="", stderr="")

    monkeypatch.setattr(runner.subprocess, "run", child)
    spec = types.SimpleNamespace(out=tmp_path, algorithm=fake)
    assert runner._render_gif(spec, lambda message: None) is None
    [command] = commands
    assert command[command.index("--out") + 1] == str(tmp_path / "policy.gif")
