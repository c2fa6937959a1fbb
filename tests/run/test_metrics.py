"""metrics.jsonl and TensorBoard events: content, and no lost or repeated rows across a resume."""

import json
import struct
from pathlib import Path

import numpy as np
from tensorboardX.proto import event_pb2

from rl_jax.run.metrics import METRICS_FILE, MetricsLog, read_rows, truncate_rows


def rows_for(steps, seeds=(0, 1), offset=0.0):
    return [
        {"step": step, "seed": seed, "eval_return": step * 10.0 + seed + offset, "loss": 0.5}
        for step in steps
        for seed in seeds
    ]


def read_events(path: Path) -> list:
    """Events of one TFRecord file (length, crc, payload, crc per record)."""
    data, events, offset = path.read_bytes(), [], 0
    while offset + 12 <= len(data):
        (length,) = struct.unpack("<Q", data[offset : offset + 8])
        payload = data[offset + 12 : offset + 12 + length]
        offset += 12 + length + 4
        event = event_pb2.Event()
        event.ParseFromString(payload)
        events.append(event)
    return events


def tensorboard_scalars(run_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """What TensorBoard shows for one run directory: files in name order, and on a SessionLog
    START at step s, every earlier event with step >= s discarded (TensorBoard's purge of
    orphaned data after a restart)."""
    scalars: dict[str, list[tuple[int, float]]] = {}
    for path in sorted(run_dir.glob("events.out.tfevents.*")):
        for event in read_events(path):
            if (
                event.HasField("session_log")
                and event.session_log.status == event.session_log.START
            ):
                for tag in scalars:
                    scalars[tag] = [(s, v) for s, v in scalars[tag] if s < event.step]
            for value in event.summary.value:
                scalars.setdefault(value.tag, []).append((event.step, value.simple_value))
    return scalars


def test_rows_are_json_lines_with_the_contract_fields(tmp_path):
    with MetricsLog(tmp_path) as log:
        log.write(rows_for([10]) + [{"step": 20, "seed": 0, "eval_return": float("nan")}])
        log.write([{"step": 30, "seed": np.int64(1), "eval_return": np.float32(2.5)}])
    lines = (tmp_path / METRICS_FILE).read_text().splitlines()
    rows = [json.loads(line) for line in lines]  # strict JSON: NaN must not appear
    assert rows[0] == {"step": 10, "seed": 0, "eval_return": 100.0, "loss": 0.5}
    assert rows[2]["eval_return"] is None
    assert rows[3] == {"step": 30, "seed": 1, "eval_return": 2.5}
    assert "NaN" not in "".join(lines)


def test_tensorboard_gets_one_run_per_seed(tmp_path):
    with MetricsLog(tmp_path) as log:
        log.write(rows_for([10, 20]))
    seed1 = tensorboard_scalars(tmp_path / "tensorboard" / "seed_1")
    assert seed1["eval_return"] == [(10, 101.0), (20, 201.0)]
    assert seed1["loss"] == [(10, 0.5), (20, 0.5)]
    assert "seed" not in seed1 and "step" not in seed1


def test_sweep_rows_go_to_one_tensorboard_run_per_config_and_seed(tmp_path):
    rows = [
        {"step": 5, "seed": 0, "config": c, "lr": lr, "eval_return": 1.0 + c}
        for c, lr in enumerate([0.001, 0.01])
    ]
    with MetricsLog(tmp_path, grid_fields=("lr",)) as log:
        log.write(rows)
    runs = sorted(
        p.relative_to(tmp_path / "tensorboard").as_posix()
        for p in (tmp_path / "tensorboard").glob("*/*")
    )
    assert runs == ["lr=0.001/seed_0", "lr=0.01/seed_0"]
    assert tensorboard_scalars(tmp_path / "tensorboard" / "lr=0.01" / "seed_0") == {
        "eval_return": [(5, 2.0)]
    }


def test_resume_neither_loses_nor_repeats_rows(tmp_path):
    """Session 1 logs steps 1..5 and dies; its checkpoint was step 3; session 2 goes on."""
    with MetricsLog(tmp_path) as log:
        log.write(rows_for([1, 2, 3, 4, 5], offset=0.0))
    with (tmp_path / METRICS_FILE).open("a") as file:
        file.write('{"step": 6, "seed": 0, "eval_re')  # a line cut short by the crash
    with MetricsLog(tmp_path, resume_step=3) as log:
        log.write(rows_for([4, 5, 6], offset=0.5))
    rows = read_rows(tmp_path / METRICS_FILE)
    keys = [(row["step"], row["seed"]) for row in rows]
    assert keys == [(step, seed) for step in range(1, 7) for seed in (0, 1)]
    expected = rows_for([1, 2, 3]) + rows_for([4, 5, 6], offset=0.5)
    assert [row["eval_return"] for row in rows] == [row["eval_return"] for row in expected]
    for seed in (0, 1):
        shown = tensorboard_scalars(tmp_path / "tensorboard" / f"seed_{seed}")["eval_return"]
        assert shown == [
            (row["step"], row["eval_return"]) for row in expected if row["seed"] == seed
        ]


def test_resume_twice_from_the_same_checkpoint(tmp_path):
    with MetricsLog(tmp_path) as log:
        log.write(rows_for([1, 2, 3]))
    for offset in (0.25, 0.5):  # crash again before a newer checkpoint, resume again
        with MetricsLog(tmp_path, resume_step=1) as log:
            log.write(rows_for([2, 3], offset=offset))
    rows = read_rows(tmp_path / METRICS_FILE)
    assert [(row["step"], row["seed"]) for row in rows] == [
        (s, k) for s in (1, 2, 3) for k in (0, 1)
    ]
    assert rows[-1]["eval_return"] == 31.5
    shown = tensorboard_scalars(tmp_path / "tensorboard" / "seed_1")["eval_return"]
    assert shown == [(1, 11.0), (2, 21.5), (3, 31.5)]


def test_truncate_rows_rewrites_only_when_needed(tmp_path):
    path = tmp_path / METRICS_FILE
    assert truncate_rows(path, 5) == 0  # no file: nothing to do
    path.write_text("".join(json.dumps(row) + "\n" for row in rows_for([1, 2])))
    before = path.stat().st_mtime_ns
    assert truncate_rows(path, 2) == 0 and path.stat().st_mtime_ns == before
    assert truncate_rows(path, 1) == 2
    assert [row["step"] for row in read_rows(path)] == [1, 1]
    assert truncate_rows(path, -1) == 2 and read_rows(path) == []
