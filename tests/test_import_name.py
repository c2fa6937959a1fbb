"""The env package's import name (docs/using_envs.md, "The env package's import name"): rl_jax
claims no top-level import name but its own, and its environments are ``rl_jax.envs``. So a
user's project with an ``envs/`` package of its own, and PyPI's ``envs`` package installed beside
the wheel, each live with rl_jax in one process, and a tiny TD3 run trains beside them; and the
checkout's ``envs/`` folder imported by its old name says, in one line, how to spell it now."""

import json
import os
import sys
import zipfile
from pathlib import Path

import pytest
from child_env import ROOT
from test_install import build_wheel, run_command, succeeded

# PyPI's envs (environment variables as typed settings), pinned: the package of that name.
PYPI_ENVS = "envs==1.4"
# 2 envs x 25 iterations = 50 env steps per chunk, updates from step 50, two chunks.
TINY = {
    "num_envs": 2,
    "iterations_per_chunk": 25,
    "learning_starts": 50,
    "batch_size": 16,
    "buffer_size": 200,
    "num_eval_envs": 1,
    "actor_hidden": (8, 8),
    "critic_hidden": (8, 8),
}
# What the child prints: where each package came from, and the tiny run's result.
TRAIN = f"""
import json, sys
import rl_jax
from rl_jax import envs as rl_envs

run = rl_jax.train(
    "td3", "rl_jax/Pendulum-v1", seeds=1, total_steps=100, out="run", config={TINY!r}, quiet=True
)
report = {{
    "rl_jax": rl_jax.__file__,
    "rl_jax.envs": rl_envs.__file__,
    "made": isinstance(rl_envs.make("rl_jax/Pendulum-v1"), rl_envs.Environment),
    "step": int(run.results.step),
    "returns": [float(value) for value in run.results.returns],
}}
"""
# The user's project: an envs package with a make of its own and a core submodule, names that
# rl_jax's env package also has, and a script that imports it before rl_jax.
PROJECT = {
    "envs/__init__.py": '''"""The project's own environments."""

OWNER = "project"


def make(name):
    return f"project env {name}"
''',
    "envs/core.py": "GRAVITY = 9.81\n",
    "train_both.py": f'''"""The project's own envs, imported before rl_jax, and rl_jax's."""
import envs  # the project's own
{TRAIN}
import envs as again
from envs.core import GRAVITY

report.update(
    own=envs.__file__,
    own_make=envs.make("cave"),
    own_gravity=GRAVITY,
    still_own=again is envs and sys.modules["envs"] is envs,
)
print(json.dumps(report))
''',
}


def _report(done) -> dict:
    return json.loads(succeeded(done).stdout.strip().splitlines()[-1])


def _trained(report: dict) -> None:
    assert report["made"], report
    assert report["step"] == 100 and len(report["returns"]) == 1, report


def test_a_project_with_its_own_envs_package_imports_rl_jax_and_trains(tmp_path):
    """Run from the project's root (``python train_both.py``), its own ``envs`` is on the path
    before anything of rl_jax's: both packages work, and rl_jax's never touches the project's."""
    project = tmp_path / "project"
    for name, text in PROJECT.items():
        (project / name).parent.mkdir(parents=True, exist_ok=True)
        (project / name).write_text(text)
    report = _report(
        run_command(
            [sys.executable, "train_both.py"], project, timeout=600, pythonpath=_inherited()
        )
    )
    assert Path(report["own"]) == project / "envs" / "__init__.py"
    assert report["own_make"] == "project env cave" and report["own_gravity"] == 9.81
    assert report["still_own"], report
    assert Path(report["rl_jax.envs"]).resolve().is_relative_to(ROOT), report
    _trained(report)
    assert (project / "run" / "config.json").exists()


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built once from this checkout, with this environment's setuptools."""
    return build_wheel(tmp_path_factory.mktemp("wheel"), isolated=False)


def test_the_wheel_claims_no_top_level_name_but_rl_jax(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    tops = {name.split("/")[0] for name in names}
    assert {top for top in tops if not top.endswith(".dist-info")} == {"rl_jax"}, tops
    for name in (
        "rl_jax/envs/__init__.py",
        "rl_jax/envs/core/registry.py",
        "rl_jax/envs/mujoco/mujoco_ffi.cc",
        "rl_jax/envs/py.typed",
        "rl_jax/py.typed",
    ):
        assert name in names, name
    (top_level,) = [name for name in names if name.endswith(".dist-info/top_level.txt")]
    assert zipfile.ZipFile(wheel).read(top_level).decode().split() == ["rl_jax"]


def test_the_wheel_beside_pypis_envs_package_trains(wheel, tmp_path):
    """The wheel and PyPI's ``envs`` in one site directory, first on the path (ahead of the
    editable checkout): ``import envs`` is PyPI's package, and rl_jax trains."""
    site = tmp_path / "site"
    install = [sys.executable, "-m", "pip", "install", "--no-deps", "--no-compile", "--quiet"]
    done = run_command([*install, "--target", site, wheel, PYPI_ENVS], tmp_path, timeout=300)
    if done.returncode != 0:
        pytest.fail(
            f"could not install PyPI's {PYPI_ENVS} beside the wheel (this test needs PyPI):\n"
            f"{done.stderr[-2000:]}"
        )
    work = tmp_path / "work"  # outside the checkout: nothing of it on the path
    work.mkdir()
    script = f"""{TRAIN}
import importlib.metadata, os
import envs
from envs import env

os.environ["RL_JAX_IMPORT_NAME"] = "7"
report.update(
    envs=envs.__file__,
    envs_version=importlib.metadata.version("envs"),
    envs_setting=env("RL_JAX_IMPORT_NAME", var_type="integer"),
)
print(json.dumps(report))
"""
    pythonpath = _inherited(site)
    report = _report(run_command([sys.executable, "-c", script], work, 600, pythonpath))
    for name in ("rl_jax", "rl_jax.envs"):
        assert Path(report[name]).is_relative_to(site), (name, report)
    assert Path(report["envs"]) == site / "envs" / "__init__.py"
    assert report["envs_version"] == PYPI_ENVS.split("==")[1] and report["envs_setting"] == 7
    _trained(report)


def test_the_old_name_fails_in_one_line_from_a_checkout():
    """``import envs`` from the repository's root finds the folder, which names the new spelling."""
    done = run_command([sys.executable, "-c", "import envs"], ROOT, timeout=120)
    assert done.returncode == 1
    last = done.stderr.strip().splitlines()[-1]
    assert last == (
        "ImportError: rl_jax's environments are the package rl_jax.envs: "
        "write `from rl_jax import envs`"
    ), done.stderr


def _inherited(*first: Path) -> str | None:
    """``first``, then the parent's PYTHONPATH less the repository root: jax and the rest come as
    they come to this process (a venv, or PYTHONPATH on a machine without one), rl_jax from the
    editable install or, where it is not installed, the root the machine itself set."""
    from child_env import without_root

    entries = [str(path) for path in first]
    rest = without_root()
    joined = os.pathsep.join([*entries, *([rest] if rest else [])])
    return joined or None
