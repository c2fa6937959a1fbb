"""rl_jax as another project would install it: the wheel built from this checkout, installed with
its declared dependencies (ranges, no lock) into a fresh venv beside packages a project commonly
has, then a one-seed job through the `rl-jax` command, run outside the checkout.

The venv has no system site-packages, so a dependency the wheel forgets to declare fails here.
pip's own cache is reused; the first run downloads jax, mujoco and the rest (~300 MB).
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parent.parent
# What the wheel is built from; anything else of the checkout must not be needed.
SOURCES = ["pyproject.toml", "README.md", "LICENSE", "rl_jax", "envs"]
# Installed first: the wheel's dependency ranges must resolve beside them without a conflict.
OTHERS = ["requests", "pandas"]
# 2 envs x 25 iterations = 50 env steps per chunk, updates from step 50, two chunks.
TINY = [
    "--algo", "td3", "--env", "rl_jax/Pendulum-v1", "--seeds", "1", "--total-steps", "100",
    "--num-envs", "2", "--iterations-per-chunk", "25", "--learning-starts", "50",
    "--batch-size", "16", "--buffer-size", "200", "--num-eval-envs", "1",
    "--actor-hidden", "8,8", "--critic-hidden", "8,8", "--log-interval", "0",
]  # fmt: skip
# The installed packages, not the checkout: their files, and what the wheel must hold.
INSTALLED = """
import importlib.metadata, importlib.util, json, pathlib, rl_jax
from rl_jax import envs
files = [str(f) for f in importlib.metadata.files("rl_jax")]
print(json.dumps({
    "packages": [str(pathlib.Path(p.__file__).parent) for p in (rl_jax, envs)],
    "top_level_envs": importlib.util.find_spec("envs") is not None,
    "files": [f for f in files if f.endswith(("py.typed", ".cc", "LICENSE"))],
}))
"""


def run_command(
    command: list, cwd: Path, timeout: float, pythonpath: str | None = None
) -> subprocess.CompletedProcess:
    """``command`` in ``cwd`` as a user's shell starts it: with ``pythonpath`` as its PYTHONPATH
    (none by default)."""
    env = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    env.pop("TF_CPP_MIN_LOG_LEVEL", None)  # set by importing jax here; rl_jax sets its own
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    return subprocess.run(
        [str(part) for part in command],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def succeeded(done: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    output = f"{done.stdout}\n{done.stderr}"
    assert done.returncode == 0, f"{done.args} exited {done.returncode}:\n{output}"
    return done


def build_wheel(directory: Path, isolated: bool = True) -> Path:
    """The wheel built from a copy of the checkout's SOURCES (links kept: rl_jax/envs is one),
    in ``directory``; ``isolated=False`` builds with this environment's setuptools (no download)."""
    source = directory / "source"
    source.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            ignore = shutil.ignore_patterns("__pycache__")
            shutil.copytree(ROOT / name, source / name, symlinks=True, ignore=ignore)
        else:
            shutil.copy2(ROOT / name, source / name)
    wheels = directory / "wheels"
    build = [sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", wheels, source]
    isolation = [] if isolated else ["--no-build-isolation"]
    succeeded(run_command([*build, *isolation], directory, timeout=600))
    (wheel,) = wheels.glob("rl_jax-*.whl")
    return wheel


@pytest.mark.timeout(1800)
def test_wheel_installs_beside_other_packages_and_trains(tmp_path):
    wheel = build_wheel(tmp_path)

    venv = tmp_path / "venv"
    succeeded(run_command([sys.executable, "-m", "venv", venv], tmp_path, timeout=120))
    python, rl_jax = venv / "bin" / "python", venv / "bin" / "rl-jax"
    pip = [python, "-m", "pip", "install", "--quiet", "--no-compile"]
    succeeded(run_command([*pip, *OTHERS], tmp_path, timeout=600))
    succeeded(run_command([*pip, wheel], tmp_path, timeout=1200))
    succeeded(run_command([python, "-m", "pip", "check"], tmp_path, timeout=120))
    # Test-only packages are extras, not dependencies.
    shown = run_command([python, "-m", "pip", "show", "pygame-ce", "pytest"], tmp_path, timeout=60)
    assert shown.returncode != 0 and "Name:" not in shown.stdout, shown.stdout

    work = tmp_path / "work"  # outside the checkout: nothing of it on the path
    work.mkdir()
    installed = json.loads(
        succeeded(run_command([python, "-c", INSTALLED], work, timeout=120)).stdout
    )
    assert all(Path(path).is_relative_to(venv) for path in installed["packages"]), installed
    for name in ("rl_jax/py.typed", "rl_jax/envs/py.typed", "LICENSE", "mujoco/mujoco_ffi.cc"):
        assert any(path.endswith(name) for path in installed["files"]), (name, installed)
    assert not installed["top_level_envs"], "the wheel claims the top-level name envs"

    usage = succeeded(run_command([rl_jax, "--help"], work, timeout=120)).stdout
    assert "train" in usage and "sweep" in usage
    unknown = run_command([rl_jax, "trian"], work, timeout=120)
    assert unknown.returncode == 2 and len(unknown.stderr.strip().splitlines()) == 1
    succeeded(run_command([rl_jax, "sweep", "--help"], work, timeout=300))

    succeeded(run_command([rl_jax, "train", *TINY, "--out", "run"], work, timeout=900))
    record = json.loads((work / "run" / "config.json").read_text())
    assert record["identity"]["algorithm"] == "td3"
    rows = [json.loads(line) for line in (work / "run" / "metrics.jsonl").read_text().splitlines()]
    assert rows and all(row["seed"] == 0 for row in rows)
    assert any("eval_return" in row for row in rows)
