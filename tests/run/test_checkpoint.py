"""Checkpoints: exact round trips of every leaf kind, orbax's quirks handled, damage and crashes."""

import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from importlib import metadata
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from child_env import python_path
from run_helpers import snapshot

from rl_jax.errors import CheckpointError
from rl_jax.run.checkpoint import Checkpointer, DamagedCheckpointError, set_aside

ROOT = Path(__file__).resolve().parents[2]


class Inner(NamedTuple):
    weights: jax.Array
    count: jax.Array


def make_state(offset: float = 0.0) -> dict:
    """Leading [configs, seeds] axes like a runner state, with every awkward leaf kind."""
    return {
        "params": Inner(
            jnp.arange(24, dtype=jnp.float32).reshape(1, 2, 3, 4) / 7.0 + offset,
            jnp.array([[3, 4]], jnp.int32),
        ),
        "key": jax.random.split(jax.random.key(42), 2).reshape(1, 2),
        "legacy_key": jnp.stack([jax.random.PRNGKey(1), jax.random.PRNGKey(2)])[None],
        "empty": jnp.zeros((1, 2, 0, 5), jnp.float32),  # orbax cannot save zero-size arrays
        "flags": jnp.array([[True, False]]),
        "small": np.uint8(7),
        "name": "half cheetah",  # a string leaf goes through the JSON metadata
        "half": jnp.full((1, 2), 1.5, jnp.bfloat16),
    }


def template_of(state):
    return jax.tree.map(
        lambda leaf: (
            jax.ShapeDtypeStruct(leaf.shape, leaf.dtype) if hasattr(leaf, "dtype") else leaf
        ),
        state,
    )


def assert_bitwise_equal(a, b):
    leaves_a, tree_a = jax.tree.flatten(a)
    leaves_b, tree_b = jax.tree.flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        if isinstance(x, str):
            assert x == y
            continue
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            assert jax.random.key_impl(x) == jax.random.key_impl(y)
            x, y = jax.random.key_data(x), jax.random.key_data(y)
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()


def test_round_trip_is_bit_exact_for_every_leaf_kind(tmp_path):
    state = make_state()
    with Checkpointer(tmp_path / "ck") as checkpointer:
        checkpointer.save(10, state, {"algorithm": "td3", "identity_hash": "abc"})
        restored, meta = checkpointer.restore(template_of(state), expect={"identity_hash": "abc"})
    assert_bitwise_equal(restored, state)
    assert isinstance(restored["params"], Inner)  # the template's structure, not plain dicts
    assert restored["empty"].shape == (1, 2, 0, 5)
    assert meta["step"] == 10 and meta["algorithm"] == "td3"
    assert meta["versions"]["orbax-checkpoint"] == metadata.version("orbax-checkpoint")
    # Typed keys come back as keys that still draw the same numbers.
    draw = jax.random.normal(restored["key"][0, 1], (3,))
    np.testing.assert_array_equal(draw, jax.random.normal(state["key"][0, 1], (3,)))


def test_restore_from_abstract_eval_shape_template(tmp_path):
    state = make_state()
    del state["name"], state["small"]
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, state)
        restored, _ = checkpointer.restore(jax.eval_shape(lambda: make_state_arrays()))
    assert_bitwise_equal(restored, state)


def make_state_arrays():
    state = make_state()
    del state["name"], state["small"]
    return state


def test_save_of_a_step_not_newer_than_the_latest_raises(tmp_path):
    # orbax alone returns False and writes nothing: a silent loss of the newer state.
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(5, make_state())
        for step in (5, 3):
            with pytest.raises(CheckpointError, match=f"cannot save checkpoint step {step}"):
                checkpointer.save(step, make_state(1.0))
        restored, _ = checkpointer.restore(template_of(make_state()))
    assert_bitwise_equal(restored, make_state())


def test_keeps_the_n_latest(tmp_path):
    with Checkpointer(tmp_path, keep=2) as checkpointer:
        for step in (1, 2, 3, 4):
            checkpointer.save(step, make_state(float(step)))
        assert checkpointer.steps() == [3, 4]
        older, meta = checkpointer.restore(template_of(make_state()), step=3)
    assert meta["step"] == 3
    assert_bitwise_equal(older, make_state(3.0))


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda s: {**s, "half": jax.ShapeDtypeStruct((1, 2), jnp.float32)}, "has dtype bfloat16"),
        (lambda s: {**s, "flags": jax.ShapeDtypeStruct((1, 3), jnp.bool_)}, "has shape"),
        (lambda s: {k: v for k, v in s.items() if k != "flags"}, "state leaves"),
    ],
)
def test_mismatched_template_raises_one_line(tmp_path, change, message):
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, make_state())
        with pytest.raises(CheckpointError, match=message) as error:
            checkpointer.restore(change(template_of(make_state())))
    assert "\n" not in str(error.value)


def test_checkpoint_of_another_run_is_refused(tmp_path):
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, make_state(), {"identity_hash": "run-a"})
        with pytest.raises(CheckpointError, match="from another run"):
            checkpointer.restore(template_of(make_state()), expect={"identity_hash": "run-b"})


def test_missing_checkpoints_raise(tmp_path):
    with pytest.raises(CheckpointError, match="no checkpoint directory"):
        Checkpointer(tmp_path / "absent", read_only=True)
    with (
        Checkpointer(tmp_path) as checkpointer,
        pytest.raises(CheckpointError, match="no checkpoint in"),
    ):
        checkpointer.restore(template_of(make_state()))
    assert not (tmp_path / "absent").exists()  # read-only opening creates nothing


def _corrupt_arrays(step_dir: Path) -> None:
    for path in (step_dir / "arrays").rglob("*"):
        if path.is_file() and path.parent.name == "d":
            path.write_bytes(path.read_bytes()[:7])


def _corrupt_meta(step_dir: Path) -> None:
    for path in (step_dir / "meta").iterdir():
        if path.name == "metadata":
            path.write_text('{"leaves": [')


def overwrite_with_garbage(step_dir: Path) -> None:
    """Every file of a checkpoint overwritten, as a bad disk or a stray copy would."""
    for path in step_dir.rglob("*"):
        if path.is_file():
            path.write_bytes(b"\x93garbage\xff" * 3)


DAMAGES = [
    _corrupt_arrays,
    _corrupt_meta,
    lambda d: shutil.rmtree(d / "arrays"),
    overwrite_with_garbage,
]


@pytest.mark.parametrize("damage", DAMAGES)
def test_corrupt_checkpoint_raises_one_clear_line(tmp_path, damage):
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, make_state(1.0))
        checkpointer.save(2, make_state(2.0))
    damage(tmp_path / "2")
    with Checkpointer(tmp_path, read_only=True) as checkpointer:
        with pytest.raises(CheckpointError) as error:
            checkpointer.restore(template_of(make_state()))
        message = str(error.value)
        assert "\n" not in message and "step 2" in message and "unreadable" in message
        assert "older checkpoints: [1]" in message  # says how to fall back
        older, _ = checkpointer.restore(template_of(make_state()), step=1)
    assert_bitwise_equal(older, make_state(1.0))


def _three_steps(directory: Path) -> None:
    with Checkpointer(directory) as checkpointer:
        for step in (1, 2, 3):
            checkpointer.save(step, make_state(float(step)), {"identity_hash": "run-a"})


@pytest.mark.parametrize("damage", DAMAGES)
def test_the_newest_readable_checkpoint_is_restored_past_damaged_ones(tmp_path, damage, caplog):
    _three_steps(tmp_path)
    damage(tmp_path / "3")
    before = snapshot(tmp_path)
    with Checkpointer(tmp_path, read_only=True) as checkpointer:
        state, meta, skipped = checkpointer.restore_newest_readable(
            template_of(make_state()), expect={"identity_hash": "run-a"}
        )
    assert meta["step"] == 2
    assert_bitwise_equal(state, make_state(2.0))
    assert [s.step for s in skipped] == [3]
    assert skipped[0].problem.startswith("is unreadable (") and "\n" not in skipped[0].problem
    assert snapshot(tmp_path) == before  # reading writes nothing
    # orbax's own log lines about the damaged files would be noise beside our one line.
    assert not [r for r in caplog.records if r.name == "absl" and r.levelno >= 30]


def test_no_readable_checkpoint_is_one_line_naming_them_all(tmp_path):
    _three_steps(tmp_path)
    for step in (1, 2, 3):
        overwrite_with_garbage(tmp_path / str(step))
    before = snapshot(tmp_path)
    with (
        Checkpointer(tmp_path, read_only=True) as checkpointer,
        pytest.raises(DamagedCheckpointError) as error,
    ):
        checkpointer.restore_newest_readable(template_of(make_state()))
    message = str(error.value)
    assert message.startswith(f"checkpoint step 3 in {tmp_path} is unreadable (")
    assert message.endswith("; the older checkpoints (2, 1) cannot be restored either")
    assert "\n" not in message
    assert snapshot(tmp_path) == before


def test_a_checkpoint_of_another_run_is_refused_not_passed_over(tmp_path):
    _three_steps(tmp_path)
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(4, make_state(4.0), {"identity_hash": "run-b"})
    with (
        Checkpointer(tmp_path, read_only=True) as checkpointer,
        pytest.raises(CheckpointError, match="step 4 .* is from another run") as error,
    ):
        checkpointer.restore_newest_readable(
            template_of(make_state()), expect={"identity_hash": "run-a"}
        )
    assert not isinstance(error.value, DamagedCheckpointError)


def test_a_damaged_checkpoint_set_aside_is_kept_and_its_step_saved_again(tmp_path):
    _three_steps(tmp_path)
    overwrite_with_garbage(tmp_path / "3")
    damaged = snapshot(tmp_path / "3")
    kept = set_aside(tmp_path, 3)
    assert kept.parent == tmp_path and kept.name.startswith("damaged-3-")
    assert snapshot(kept) == damaged  # moved whole, not deleted
    with Checkpointer(tmp_path, keep=2) as checkpointer:
        assert checkpointer.steps() == [1, 2]  # orbax no longer lists it
        # Saving step 3 again is not skipped (orbax skips a step not newer than its latest),
        # and pruning to the 2 latest leaves the damaged one alone.
        for step in (3, 4):
            checkpointer.save(step, make_state(float(step)))
        assert checkpointer.steps() == [3, 4]
        restored, _ = checkpointer.restore(template_of(make_state()), step=3)
    assert_bitwise_equal(restored, make_state(3.0))
    assert snapshot(kept) == damaged
    assert set_aside(tmp_path, 3) != kept  # a second one in the same second gets its own name


def test_leftover_partial_write_is_ignored_then_cleaned(tmp_path):
    """A step directory that was never finalized (orbax renames it on completion)."""
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, make_state(1.0))
    partial = tmp_path / "2.orbax-checkpoint-tmp-1700000000"
    shutil.copytree(tmp_path / "1", partial)
    _corrupt_arrays(partial)
    with Checkpointer(tmp_path, read_only=True) as checkpointer:
        assert checkpointer.steps() == [1]
        restored, _ = checkpointer.restore(template_of(make_state()))
    assert_bitwise_equal(restored, make_state(1.0))
    assert partial.exists()  # read-only leaves the directory as it was
    with Checkpointer(tmp_path) as checkpointer:
        assert not partial.exists()
        checkpointer.save(2, make_state(2.0))
        restored, _ = checkpointer.restore(template_of(make_state()))
    assert_bitwise_equal(restored, make_state(2.0))


CRASH_SCRIPT = textwrap.dedent(
    """
    import os, signal, sys
    import numpy as np
    import jax.numpy as jnp
    from rl_jax.run.checkpoint import Checkpointer
    mode, directory = sys.argv[1], sys.argv[2]
    checkpointer = Checkpointer(directory)
    checkpointer.save(1, {"w": jnp.full((4,), 1.0)})
    if mode == "at_commit":
        # Die the instant all data of step 2 is written, before orbax's rename commits it.
        from orbax.checkpoint._src.path import atomicity
        def die(*args, **kwargs):
            os.kill(os.getpid(), signal.SIGKILL)
        atomicity.AtomicRenameTemporaryPath.finalize = die
        big = {"w": jnp.full((4,), 2.0)}
    else:
        big = {f"x{i}": jnp.full((2_000_000,), float(i)) for i in range(40)}
        big["w"] = jnp.full((4,), 2.0)
    print("ready", flush=True)
    checkpointer.save(2, big)
    print("saved", flush=True)
    """
)


def _run_crash(tmp_path: Path, mode: str) -> tuple[int, bool]:
    directory = tmp_path / "ck"
    env = {**os.environ, "PYTHONPATH": python_path(ROOT)}
    process = subprocess.Popen(
        [sys.executable, "-c", CRASH_SCRIPT, mode, str(directory)],
        stdout=subprocess.PIPE,
        env=env,
        text=True,
    )
    assert process.stdout.readline().strip() == "ready"
    saw_partial = False
    if mode == "mid_write":
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and process.poll() is None:
            if list(directory.glob("2.orbax-checkpoint-tmp*")):
                saw_partial = True
                process.send_signal(signal.SIGKILL)
                break
            time.sleep(0.001)
    return process.wait(timeout=120), saw_partial


def test_kill_at_commit_leaves_previous_checkpoint_usable(tmp_path):
    code, _ = _run_crash(tmp_path, "at_commit")
    assert code == -signal.SIGKILL
    directory = tmp_path / "ck"
    assert list(directory.glob("2.orbax-checkpoint-tmp*"))  # step 2's data is there, uncommitted
    assert not (directory / "2").exists()
    template = {"w": jax.ShapeDtypeStruct((4,), jnp.float32)}
    with Checkpointer(directory, read_only=True) as checkpointer:
        restored, meta = checkpointer.restore(template)
    assert meta["step"] == 1
    np.testing.assert_array_equal(restored["w"], np.full((4,), 1.0, np.float32))
    with Checkpointer(directory) as checkpointer:  # and the run can carry on saving
        checkpointer.save(2, {"w": jnp.full((4,), 3.0)})
        assert checkpointer.steps() == [1, 2]


def test_kill_mid_write_leaves_a_usable_checkpoint(tmp_path):
    code, saw_partial = _run_crash(tmp_path, "mid_write")
    assert saw_partial and code == -signal.SIGKILL
    directory = tmp_path / "ck"
    with Checkpointer(directory, read_only=True) as checkpointer:
        latest = checkpointer.latest_step()
        template = {"w": jax.ShapeDtypeStruct((4,), jnp.float32)}
        if latest == 2:  # the write won the race against the kill: then it must be whole
            template.update(
                {f"x{i}": jax.ShapeDtypeStruct((2_000_000,), jnp.float32) for i in range(40)}
            )
        restored, _ = checkpointer.restore(template)
    np.testing.assert_array_equal(restored["w"], np.full((4,), float(latest), np.float32))


def test_restore_places_arrays_with_the_given_sharding(tmp_path):
    sharding = jax.sharding.SingleDeviceSharding(jax.devices()[-1])
    state = {"a": jnp.ones((1, 2, 3))}
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(1, state)
        restored, _ = checkpointer.restore(template_of(state), sharding=sharding)
    assert restored["a"].sharding == sharding


def test_metadata_is_plain_json(tmp_path):
    with Checkpointer(tmp_path) as checkpointer:
        checkpointer.save(7, make_state(), {"note": "x"})
        meta = checkpointer.metadata()
    json.dumps(meta)
    kinds = {record["path"]: record["kind"] for record in meta["leaves"]}
    assert kinds["['empty']"] == "empty" and kinds["['key']"] == "key"
    assert kinds["['name']"] == "json" and kinds["['legacy_key']"] == "array"
