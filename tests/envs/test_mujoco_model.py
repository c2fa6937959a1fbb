"""Our MuJoCo models are gymnasium's, bit for bit, and loading them is quiet.

gymnasium's half_cheetah.xml sets ``<compiler settotalmass="14">``, which MuJoCo deprecates: it
warns on stdout and in ``MUJOCO_LOG.TXT`` in the current directory at every compile. We compile
it without the attribute and scale the masses as the compiler does
(``mujoco_backend.set_total_mass``); every numeric field of the model, and a trajectory, must
equal what ``MjModel.from_xml_path`` gives from gymnasium's XML. Importing MJX (and brax, which
imports it) prints no lines about NVIDIA Warp, which these envs do not use."""

import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from child_env import python_path

from rl_jax.envs.mujoco import mujoco_backend
from rl_jax.envs.mujoco.ant import Ant
from rl_jax.envs.mujoco.half_cheetah import HalfCheetah
from rl_jax.envs.mujoco.hopper import Hopper
from rl_jax.envs.mujoco.humanoid import Humanoid
from rl_jax.envs.mujoco.inverted_double_pendulum import InvertedDoublePendulum
from rl_jax.envs.mujoco.inverted_pendulum import InvertedPendulum
from rl_jax.envs.mujoco.reacher import Reacher
from rl_jax.envs.mujoco.swimmer import Swimmer
from rl_jax.envs.mujoco.walker2d import Walker2d

XML_FILES = [
    env.xml_file
    for env in (
        HalfCheetah,
        Ant,
        Hopper,
        Humanoid,
        InvertedDoublePendulum,
        InvertedPendulum,
        Reacher,
        Swimmer,
        Walker2d,
    )
]
ROOT = Path(__file__).resolve().parents[2]
# A user's shell (see tests/run/test_cli.py): without the TF_CPP_MIN_LOG_LEVEL that importing jax
# set in this process.
ENV = {
    **{key: value for key, value in os.environ.items() if key != "TF_CPP_MIN_LOG_LEVEL"},
    "PYTHONPATH": python_path(ROOT),
}


def numeric_fields(model: mujoco.MjModel) -> dict[str, bytes]:
    """The raw bytes of every numeric array of the model, and of its options, statistics and
    visual settings: equal means bit for bit the same model."""
    fields = {}
    for name in dir(model):
        value = getattr(model, name) if not name.startswith("_") else None
        if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
            fields[name] = value.tobytes()
    for part in ("opt", "stat", "vis"):
        for name in dir(getattr(model, part)):
            value = getattr(getattr(model, part), name) if not name.startswith("_") else None
            if isinstance(value, float | int | np.ndarray):
                fields[f"{part}.{name}"] = np.asarray(value).tobytes()
    return fields


def trajectory(model: mujoco.MjModel, steps: int = 100) -> bytes:
    """qpos and qvel after every step of random controls (the same for every model)."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    states = []
    for _ in range(steps):
        data.ctrl[:] = rng.uniform(-1.0, 1.0, model.nu)
        mujoco.mj_step(model, data)
        states.append(np.concatenate([data.qpos, data.qvel]).tobytes())
    return b"".join(states)


@pytest.mark.parametrize("xml_file", XML_FILES)
def test_the_model_is_gymnasiums_bit_for_bit(xml_file, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # where the reference's deprecation warning writes its log
    path = mujoco_backend.gymnasium_asset(xml_file)
    reference = mujoco.MjModel.from_xml_path(str(path))
    ours = mujoco_backend.load_model(xml_file)
    theirs, mine = numeric_fields(reference), numeric_fields(ours)
    assert len(mine) > 400 and "body_mass" in mine and "stat.meaninertia" in mine
    assert [name for name in theirs if theirs[name] != mine.get(name)] == []
    assert np.array_equal(ours.body_mass, reference.body_mass)
    assert trajectory(ours) == trajectory(reference)


def test_half_cheetah_keeps_its_14_kg_and_loads_without_a_warning(tmp_path, monkeypatch, capfd):
    monkeypatch.chdir(tmp_path)
    settotalmass = 'settotalmass="14"'
    assert settotalmass in mujoco_backend.gymnasium_asset("half_cheetah.xml").read_text()
    model = mujoco_backend.load_model("half_cheetah.xml")
    assert model.body_mass.sum() == pytest.approx(14.0, abs=1e-12)
    printed = capfd.readouterr()  # MuJoCo's warnings are printed by C: the file descriptors
    assert printed.out == "" and printed.err == ""
    assert list(tmp_path.iterdir()) == []  # no MUJOCO_LOG.TXT


def test_importing_mjx_or_brax_prints_nothing_about_warp(tmp_path):
    """A fresh interpreter, in an empty directory: our MJX backend and the brax adapter import
    MJX without a line on stdout or stderr, and an env made on each MuJoCo backend leaves no
    file behind."""
    code = (
        "from rl_jax.envs.mujoco import mjx_physics\n"
        "from rl_jax.envs.adapters import brax_adapter\n"
        "from rl_jax import envs\n"
        "for backend in ('mujoco', 'mjx'):\n"
        "    envs.make('rl_jax/HalfCheetah-v5', backend=backend)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        cwd=tmp_path,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout == "" and "warp" not in done.stderr.lower(), done.stdout + done.stderr
    assert list(tmp_path.iterdir()) == []


def test_other_lines_printed_during_the_import_pass_on(monkeypatch, capsys):
    monkeypatch.delitem(sys.modules, "mujoco.mjx.warp", raising=False)
    with mujoco_backend.without_warp_lines():
        print("Failed to import warp: No module named 'warp'")
        print("Failed to import mujoco_warp: No module named 'warp'")
        print("Failed to import warp: CUDA driver not found")
    assert capsys.readouterr().out == "Failed to import warp: CUDA driver not found\n"
