"""Run directories written before the package moved into subpackages still resume, load and
render.

``tests/data/old_run_td3`` was written by ``experiments/train.py`` at the flat layout (commit
2b1a0bd: ``rl_jax/td3.py``, its ``config.json`` naming the algorithm ``rl_jax.td3:td3``): TD3 on
Pendulum, 2 seeds, 400 env steps, tiny networks and replay, checkpoint and best policy at 400.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import rl_jax
from rl_jax.run.run_dir import identity_hash

OLD_RUN = Path(__file__).resolve().parents[1] / "data" / "old_run_td3"


@pytest.fixture
def old_run(tmp_path):
    copy = tmp_path / "old_run"
    shutil.copytree(OLD_RUN, copy)
    return copy


def test_the_fixture_is_a_flat_layout_run():
    record = json.loads((OLD_RUN / "config.json").read_text())
    assert record["algorithm_module"] == "rl_jax.td3:td3"


def _without_hyperparameter(run_dir: Path, name: str) -> None:
    """The run as written before ``name`` existed (TD3's ``lr_decay_steps`` is newer)."""
    path = run_dir / "config.json"
    record = json.loads(path.read_text())
    for hparams in record["identity"]["hparams"]:
        del hparams[name]
    # the identity's hash as that code wrote it, in the record and in the checkpoints' metadata
    old, new = record["identity_hash"], identity_hash(record["identity"])
    record["identity_hash"] = new
    path.write_text(json.dumps(record, indent=2))
    for metadata in run_dir.glob("*/*/meta/metadata"):
        metadata.write_text(metadata.read_text().replace(old, new))


@pytest.mark.parametrize(
    "older",
    # the run as written in every run; the one recorded before lr_decay_steps (~6 s) when slow
    [False, pytest.param(True, marks=pytest.mark.slow)],
    ids=["as written", "before lr_decay_steps"],
)
def test_an_old_run_resumes_loads_and_renders(old_run, tmp_path, older):
    if older:
        _without_hyperparameter(old_run, "lr_decay_steps")
    run = rl_jax.open_run(old_run)
    policy = run.policy(seed=0, which="latest")
    action = np.asarray(policy(np.zeros(3, np.float32)))
    assert action.shape == (1,) and np.all(np.abs(action) <= 2.0)
    resumed = rl_jax.resume(old_run, total_steps=600, quiet=True)
    assert resumed.results.step == 600
    gif = resumed.save_gif(tmp_path / "policy.gif", seed=1, which="latest")
    assert gif.stat().st_size > 1000
