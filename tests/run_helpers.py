"""Helpers shared by the run-machinery tests."""

from importlib import metadata
from pathlib import Path

import fake_algorithm as fake
import jax
import numpy as np

from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec

LOCK = Path(__file__).resolve().parents[1] / "requirements.lock"


def locked_version(package: str) -> str | None:
    """``package``'s exact version in requirements.lock (what ``make install`` installs)."""
    prefix = f"{package}=="
    for line in LOCK.read_text().splitlines():
        if line.startswith(prefix):
            return line[len(prefix) :].split()[0]
    return None


#: This process runs the locked jaxlib. Two differently shaped programs (a block of 3 runs and one
#: of 5) compile to the same kernels there, so their runs are compared bit for bit; another XLA
#: may fuse them differently and round the last bit of some values otherwise (``make
#: test-latest``: jax 0.12 moved one loss by 1 ulp), so elsewhere they are compared to a tolerance.
ON_THE_LOCKED_JAX = metadata.version("jaxlib") == locked_version("jaxlib")


def leaf_arrays(state) -> list[np.ndarray]:
    """Every leaf as a numpy array (typed keys as their key data)."""

    def to_array(leaf):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        return np.asarray(leaf)

    return [to_array(leaf) for leaf in jax.tree.leaves(state)]


def leaves_bytes(state) -> list[bytes]:
    """The raw bytes of every leaf (typed keys as their key data): equal means bit-identical."""
    return [leaf.tobytes() for leaf in leaf_arrays(state)]


def snapshot(directory: Path) -> dict[str, bytes]:
    """Every file under ``directory`` with its content (to prove nothing changed)."""
    return {
        str(path.relative_to(directory)): path.read_bytes()
        for path in sorted(Path(directory).rglob("*"))
        if path.is_file()
    }


def fake_run(out: Path, total_steps: int, env_id: str = fake.ENV_ID, seeds: int = 2) -> Path:
    """A finished run of the fake learner in ``out`` (seconds to make): a real run directory
    for tools that read one (render, reports)."""
    spec = RunSpec(
        fake,
        env_id,
        fake.default_config(env_id),
        (fake.default_hyperparams(),),
        out,
        seeds=seeds,
        total_steps=total_steps,
        log_interval=1e9,
    )
    run(spec, notify=lambda message: None)
    return out
