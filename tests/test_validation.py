"""Hyperparameter and config ranges are checked before anything compiles: one line naming the
flag and its range, a non-zero exit, nothing written; the edges of each range are accepted; and
an --out that cannot be created is one line too."""

import pytest

from rl_jax import cli, runner, validation
from rl_jax.dqn import dqn
from rl_jax.reinforce import reinforce
from rl_jax.run_dir import RunError
from rl_jax.td3 import td3


def run_cli(algorithm, env_id, argv) -> int:
    return cli.guard(lambda: cli.run_experiment(algorithm, env_id, "", argv))


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
        for env_id in {**algorithm.recipes, **algorithm.hparam_recipes}:
            config = algorithm.default_config(env_id)
            hparams = algorithm.default_hyperparams(env_id)
            assert validation.out_of_range(config, algorithm) is None, (algorithm, env_id)
            assert validation.out_of_range(hparams, algorithm) is None, (algorithm, env_id)


@pytest.mark.parametrize("where", ["/proc/x", "file"])
def test_an_out_that_cannot_be_created_is_one_line(where, tmp_path, capsys):
    if where == "file":
        (tmp_path / "file").write_text("not a directory")
        out = tmp_path / "file" / "run"
    else:
        out = where
    line = one_line(capsys, run_cli(td3, "rl_jax/Pendulum-v1", ["--out", str(out)]))
    assert f"cannot create --out {out}" in line or f"cannot write the run directory {out}" in line


def _spec(hparams, out):
    return runner.RunSpec(
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
