"""The divergence guard: a run whose parameters, eval return or losses stop being finite ends at
that chunk with one line (seeds, config, step, likely cause), exits non-zero, and never saves the
non-finite state; NaN losses alone (learners' "no update here") do not stop it."""

import os
import subprocess
import sys
import types
from pathlib import Path

import jax
import numpy as np
import pytest
from child_env import python_path

from rl_jax.agents.dqn import dqn
from rl_jax.agents.td3 import td3
from rl_jax.run import command
from rl_jax.run.checkpoint import Checkpointer
from rl_jax.run.divergence import DivergenceError, check_finite
from rl_jax.run.plan import make_plan
from rl_jax.run.run_dir import CHECKPOINT_DIR

ROOT = Path(__file__).resolve().parents[2]
ENV_ID = "rl_jax/Pendulum-v1"


def _latest(run_dir: Path):
    """The latest checkpoint of ``run_dir``, restored as the resume of it would."""
    spec = command.spec_for(td3, ENV_ID, ["--resume", str(run_dir)])
    with Checkpointer(run_dir / CHECKPOINT_DIR, read_only=True) as checkpointer:
        state, _ = checkpointer.restore(make_plan(spec).template)
    return state


def _session(hparams, saved_step=100, step=200, base_seed=0):
    spec = types.SimpleNamespace(hparams=tuple(hparams), base_seed=base_seed)
    return types.SimpleNamespace(spec=spec, saved_step=saved_step, step=step)


def _metrics(eval_return, **extra):
    return types.SimpleNamespace(eval_return=np.asarray(eval_return, np.float32), extra=extra)


def test_nan_losses_alone_are_no_divergence():
    """Warm-up chunks (and TD3's delayed actor loss) report NaN losses with finite parameters."""
    nan = np.full((1, 2), np.nan, np.float32)
    metrics = _metrics([[-1200.0, -1300.0]], critic_loss=nan, actor_loss=nan, q=nan)
    check_finite(_session([td3.default_hyperparams()]), metrics, np.ones((1, 2), bool))


def test_an_infinite_loss_stops_the_run_naming_seed_config_and_rates():
    grid = [td3.default_hyperparams(), td3.default_hyperparams(actor_lr=1e6, critic_lr=1e6)]
    loss = np.array([[1.0, 2.0], [np.inf, 3.0]], np.float32)
    metrics = _metrics(np.zeros((2, 2)), critic_loss=loss, actor_loss=np.full((2, 2), np.nan))
    with pytest.raises(DivergenceError) as raised:
        check_finite(_session(grid, base_seed=7), metrics, np.ones((2, 2), bool))
    line = str(raised.value)
    assert "\n" not in line
    assert line.startswith("training diverged at step 200: seed 7 of config 1 got non-finite")
    assert "losses" in line and "parameters" not in line
    assert "the last finite checkpoint (step 100) is kept" in line
    assert "--actor-lr 1e+06" in line and "--critic-lr 1e+06" in line
    assert "--actor-lr 0.0003" not in line  # config 0 did not diverge
    assert "--max-grad-norm" not in line  # TD3 has no gradient clipping to suggest


def test_non_finite_parameters_or_eval_name_every_seed_and_suggest_clipping():
    metrics = _metrics([[1.0, np.nan, 3.0]], loss=np.zeros((1, 3), np.float32))
    params = np.array([[False, True, True]])
    hparams = dqn.default_hyperparams(learning_rate=1e6)
    with pytest.raises(DivergenceError) as raised:
        check_finite(_session([hparams], saved_step=None), metrics, params)
    line = str(raised.value)
    assert "seed 0, seed 1 got non-finite parameters and eval return" in line
    assert "no checkpoint had been written yet" in line
    assert "--learning-rate 1e+06" in line and "--max-grad-norm" in line


def test_a_diverging_script_exits_non_zero_and_saves_no_non_finite_checkpoint(tmp_path):
    """The real script in a fresh interpreter, tiny: 2 envs x 50 iterations = 100 env steps a
    chunk, updates from step 100 with rates of 1e6. The first chunk (no updates yet) is saved;
    the second's parameters are non-finite and are not."""
    out = tmp_path / "run"
    argv = [
        *("--num-envs", "2", "--updates-per-iteration", "2", "--iterations-per-chunk", "50"),
        *("--learning-starts", "100", "--batch-size", "32", "--buffer-size", "1000"),
        *("--num-eval-envs", "2", "--actor-hidden", "16,16", "--critic-hidden", "16,16"),
        *("--actor-lr", "1e6", "--critic-lr", "1e6", "--checkpoint-interval", "0"),
        *("--seeds", "2", "--total-steps", "400", "--log-interval", "0", "--out", str(out)),
    ]
    env = {key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"}
    done = subprocess.run(
        [sys.executable, str(ROOT / "experiments" / "td3_pendulum.py"), *argv],
        cwd=tmp_path,
        env={**env, "PYTHONPATH": python_path(ROOT), "RL_JAX_CPU_DEVICES": "1"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    assert lines[0].startswith(
        "error: training diverged at step 200: seed 0, seed 1 got non-finite"
    )
    assert "the last finite checkpoint (step 100) is kept" in lines[0]
    assert "learning rate too high" in lines[0]
    assert not (out / "results.txt").exists()  # the end of a run is not reached
    with Checkpointer(out / CHECKPOINT_DIR, read_only=True) as checkpointer:
        assert checkpointer.steps() == [100]
    state = _latest(out)
    assert int(state.clock.env_steps) == 100
    # train_return is NaN by design until an episode ends (Pendulum's last 200 steps).
    leaves = jax.tree.leaves((state.agent, state.buffer, state.obs, state.noise))
    floats = [np.asarray(leaf) for leaf in leaves if np.issubdtype(leaf.dtype, np.floating)]
    assert floats and all(np.isfinite(leaf).all() for leaf in floats)
    rows = [line for line in (out / "metrics.jsonl").read_text().splitlines() if line]
    assert any('"step": 200' in row for row in rows)  # the diverged chunk's rows are logged
