"""``experiments/rocket_report.py``: learned rocket policies next to the analytic controllers, on
tiny real runs (the fake learner and DQN, on the rocket)."""

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import fake_algorithm as fake
import imageio.v3 as iio
import numpy as np
import pytest
from child_env import python_path
from run_helpers import fake_run

from experiments import rocket_report
from rl_jax.agents.dqn import dqn
from rl_jax.envs.classic import rocket_control
from rl_jax.envs.classic.rocket_comparison import PLOT_FILE, TABLE_FILE, Settings
from rl_jax.run.policy import load_policy
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "experiments" / "rocket_report.py"
SETTLE = "rl_jax/RocketSettle-v0"
DT = rocket_control.DT


def _fake_run(out: Path, env_id: str) -> Path:
    return fake_run(out, total_steps=40, env_id=env_id)


def _dqn_run(out: Path) -> Path:
    env_id = "rl_jax/Rocket-v0"
    config = dataclasses.replace(
        dqn.default_config(env_id),
        num_envs=2,
        iterations_per_chunk=25,
        batch_size=16,
        buffer_size=200,
        learning_starts=20,
        num_eval_envs=1,
        hidden=(8, 8),
    )
    hparams = (dqn.default_hyperparams(env_id),)
    spec = RunSpec(dqn, env_id, config, hparams, out, seeds=2, total_steps=50, log_interval=1e9)
    run(spec, notify=lambda message: None)
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("rocket_report")
    return {
        "rocket": _fake_run(root / "fake_rocket", "rl_jax/Rocket-v0"),
        "settle": _fake_run(root / "fake_settle", SETTLE),
        "point": _fake_run(root / "fake_point", fake.ENV_ID),
        "dqn": _dqn_run(root / "dqn_rocket"),
    }


def test_report_writes_plot_and_table_for_every_seed_and_the_analytic_laws(runs, tmp_path, capsys):
    out = tmp_path / "report"
    assert rocket_report.main([str(runs["rocket"]), str(runs["dqn"]), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    table = (out / TABLE_FILE).read_text()
    assert table.strip() in printed
    rows = [line for line in table.splitlines() if line.startswith("| ") and "---" not in line]
    controllers = [row.split(" | ")[0].removeprefix("| ") for row in rows[1:]]
    assert controllers == [
        "bang-bang (time-optimal)",
        "LQR, K = (8, 5.66)",
        "fake (fake_rocket)",
        "fake (fake_rocket)",
        "dqn (dqn_rocket)",
        "dqn (dqn_rocket)",
    ]
    assert "| bang-bang (time-optimal) | - | - | 200 (2.00 s) | yes |" in table
    assert "| LQR, K = (8, 5.66) | - | - | 319 (3.19 s) | yes |" in table
    assert "t* = 2.00 s (step 200)" in table and "in rl_jax/Rocket-v0" in table
    image = iio.imread(out / PLOT_FILE)
    assert image.shape[0] > 500 and image.shape[1] > 1000


def test_dqn_policies_act_with_the_thrust_their_index_stands_for(runs):
    grid = np.stack(np.meshgrid(np.linspace(-2, 2, 21), np.linspace(-2, 2, 21)), axis=-1)
    settings = Settings("rl_jax/Rocket-v0", (1.0, 0.0), 100, 0.01, DT)
    for seed in (0, 1):
        policy = load_policy(runs["dqn"], seed)
        actions = policy(grid.reshape(-1, 2).astype(np.float32))
        assert actions.shape == (441, 1) and set(np.unique(actions)) <= {-1.0, 0.0, 1.0}
    for entry in rocket_report.run_entries(runs["dqn"], "best", settings):
        assert set(np.unique(entry.trajectory.thrusts)) <= {-1.0, 0.0, 1.0}


def test_report_rolls_runs_of_two_rocket_variants_in_the_env_chosen(runs, tmp_path, capsys):
    both = [str(runs["rocket"]), str(runs["settle"])]
    assert rocket_report.main([*both, "--out", str(tmp_path)]) == 2
    _one_line(capsys, "trained on different envs (rl_jax/Rocket-v0, rl_jax/RocketSettle-v0)")
    argv = [*both, "--out", str(tmp_path), "--env", "RocketSettle-v0", "--latest"]
    assert rocket_report.main([*argv, "--start", "-0.5", "0.5", "--steps", "150"]) == 0
    table = (tmp_path / TABLE_FILE).read_text()
    assert "(x, v) = (-0.5, 0.5) in rl_jax/RocketSettle-v0, 150 steps" in table
    assert "kept to step 150?" in table and "latest, step 40" in table
    # Bang-bang from (-0.5, 0.5): t* = 1.08 s, inside the 0.01 box one step earlier.
    assert "| bang-bang (time-optimal) | - | - | 108 (1.08 s) | yes |" in table


def _one_line(capsys, expected: str) -> None:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err
    assert expected in lines[0], lines[0]
    assert "Traceback" not in captured.err + captured.out


def test_report_bad_input_is_one_line(runs, tmp_path, capsys):
    cases = [
        ([str(tmp_path / "none")], f"no run directory at {tmp_path / 'none'}"),
        ([str(runs["point"])], "is a fake run on rl_jax/FakePoint-v0, not on the rocket"),
        ([str(runs["rocket"]), "--env", "rl_jax/CartPole-v1"], "rl_jax/CartPole-v1 is not a"),
        (["--env", "Moon-v0"], "unknown environment 'Moon-v0'"),
        ([str(runs["rocket"]), "--start", "2.5", "0"], "outside |x|, |v| <= 2"),
        ([str(runs["rocket"]), "--tolerance", "0"], "--tolerance must be > 0"),
        ([str(runs["rocket"]), "--out", "/proc/report"], "cannot write the report to /proc"),
    ]
    for argv, expected in cases:
        assert rocket_report.main(argv) == 2, argv
        _one_line(capsys, expected)
    assert not (runs["point"] / TABLE_FILE).exists()


def test_report_command_line_reports_a_missing_run_in_one_line(tmp_path):
    missing = tmp_path / "none"
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(missing)],
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": python_path(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"error: no run directory at {missing}"]
