"""Weights & Biases logging (``--wandb``): one W&B run per seed, grouped by run directory, with the
run's config and the curves of metrics.jsonl; checked in W&B's offline mode, with no network, by
reading the run files it writes. Without the package, ``--wandb`` is one line before anything
compiles."""

import contextlib
import dataclasses
import importlib.util
import io
import struct
from pathlib import Path

import fake_algorithm as fake
import pytest

from rl_jax import errors
from rl_jax.run import cli, tracking
from rl_jax.run.metrics import read_rows
from rl_jax.run.runner import run
from rl_jax.run.spec import RunSpec

HAS_WANDB = importlib.util.find_spec("wandb") is not None
STEPS_PER_CHUNK = 20  # the fake learner: 4 envs x 5 iterations


def spec_for(out: Path, **changes) -> RunSpec:
    spec = RunSpec(
        algorithm=fake,
        env_id=fake.ENV_ID,
        config=fake.default_config(),
        hparams=(fake.default_hyperparams(),),
        out=out,
        seeds=2,
        total_steps=3 * STEPS_PER_CHUNK,
        checkpoint_interval=0.0,
        log_interval=1e9,
    )
    return dataclasses.replace(spec, **changes)


def wandb_records(path: Path) -> list:
    """The records of an offline ``run-<id>.wandb`` file: W&B's header, then LevelDB's log
    format (32 KiB blocks of chunks, each with a 7-byte header: crc, length, type)."""
    from wandb.proto import wandb_internal_pb2

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    records, pending, position, block = [], b"", 7, 32768
    while position + 7 <= len(data):
        left = block - position % block
        _, length, kind = struct.unpack("<IHB", data[position : position + 7])
        if left < 7 or (length == 0 and kind == 0):  # block trailer or padding
            position += left
            continue
        pending += data[position + 7 : position + 7 + length]
        position += 7 + length
        if kind in (1, 4):  # a whole record, or the last chunk of one
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            records.append(record)
            pending = b""
    return records


def offline_runs(wandb_dir: Path) -> dict[str, dict]:
    """Per W&B run name: its group, config and logged history rows, from the offline files."""
    runs = {}
    for path in sorted(wandb_dir.glob("wandb/offline-run-*/run-*.wandb")):
        found = {"history": []}
        for record in wandb_records(path):
            kind = record.WhichOneof("record_type")
            if kind == "run":
                found["group"] = record.run.run_group
                found["name"] = record.run.display_name
                found["config"] = {i.key: i.value_json for i in record.run.config.update}
            elif kind == "history":
                row = {i.key or "/".join(i.nested_key): i.value_json for i in record.history.item}
                found["history"].append(row)
        runs[found["name"]] = found
    return runs


@pytest.mark.skipif(not HAS_WANDB, reason="wandb is not installed (the tracking extra)")
def test_offline_runs_hold_the_config_and_the_curves(tmp_path, monkeypatch):
    import json

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    monkeypatch.setenv("WANDB_SILENT", "true")
    monkeypatch.delenv("WANDB_PROJECT", raising=False)
    out = tmp_path / "run"
    run(spec_for(out, wandb=True), notify=lambda message: None)

    runs = offline_runs(tmp_path)
    assert sorted(runs) == ["seed_0", "seed_1"]  # one W&B run per seed
    rows = read_rows(out / "metrics.jsonl")
    for seed in (0, 1):
        found = runs[f"seed_{seed}"]
        assert found["group"] == "run"  # the run directory's name
        config = {key: json.loads(value) for key, value in found["config"].items()}
        assert config["seed"] == seed and config["env_id"] == fake.ENV_ID
        assert config["algorithm"] == "fake" and config["config"]["hidden_sizes"] == [8]
        assert config["hparams"]["learning_rate"] == pytest.approx(0.01)
        logged = [
            (json.loads(h["step"]), json.loads(h["eval_return"]), json.loads(h["loss"]))
            for h in found["history"]
        ]
        expected = [
            (row["step"], row["eval_return"], row["loss"]) for row in rows if row["seed"] == seed
        ]
        assert [step for step, _, _ in logged] == [STEPS_PER_CHUNK * c for c in (1, 2, 3)]
        assert logged == expected  # the same float64 values as metrics.jsonl


def test_run_ids_follow_the_run_directory_and_the_run_name(tmp_path):
    assert tracking.run_id(tmp_path / "a", "seed_0") == tracking.run_id(tmp_path / "a", "seed_0")
    assert tracking.run_id(tmp_path / "a", "seed_0") != tracking.run_id(tmp_path / "a", "seed_1")
    assert tracking.run_id(tmp_path / "a", "seed_0") != tracking.run_id(tmp_path / "b", "seed_0")


def test_without_wandb_the_flag_is_one_line_before_anything_is_written(tmp_path, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "wandb", None)  # import wandb fails
    out = tmp_path / "run"
    argv = ["--wandb", "--out", str(out), "--total-steps", "40"]
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        status = errors.guard(
            lambda: cli.run_experiment(fake, fake.ENV_ID, "", argv, cli.Defaults(seeds=1))
        )
    assert status != 0
    lines = stderr.getvalue().strip().splitlines()
    assert len(lines) == 1 and "wandb" in lines[0] and "rl_jax[tracking]" in lines[0], lines
    assert "Traceback" not in stderr.getvalue() and not out.exists()
