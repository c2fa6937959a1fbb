"""The driver shared by the benchmarks of our PPO beside a Stable-Baselines3 peer
(``bench.sb3_side_by_side``): the order of the runs and the thread probe, the table's columns,
the peer's command line and JSON line, the section and the command line; also SB3's value-loss
weight in ``bench/sb3_ppo.py`` against our HalfCheetah recipe's, and our side's parts on
HalfCheetah (slow)."""

import json
import sys

import pytest

from bench import machine, peers, sb3_ppo
from bench import sb3_side_by_side as side_by_side
from rl_jax.agents.ppo import ppo


def test_sb3_ppo_weighs_the_value_loss_as_our_recipe():
    """Our loss is ``policy + vf_coef * 0.5 * mean squared error``, SB3's ``policy + vf_coef *
    mean squared error``: at equal work SB3's ``vf_coef`` is half ours."""
    from bench import bench_ppo_sb3

    hparams = ppo.default_hyperparams(bench_ppo_sb3.ENV_ID, bench_ppo_sb3.RECIPE)
    assert float(hparams.vf_coef) == pytest.approx(2 * sb3_ppo.VF_COEF)


def test_measure_runs_ours_the_peer_and_ours_again_probing_only_where_asked():
    calls = []

    def ours(first):
        calls.append(("ours", first))
        return {"first": first}

    def peer(steps, threads):
        calls.append(("peer", steps, threads))
        return {"seconds": steps / (100.0 if threads == 2 else 50.0), "threads": threads}

    first, probes, runs, again = side_by_side.measure(ours, peer, 1000, [1, 2], probe_steps=100)
    assert calls == [
        ("ours", True),
        ("peer", 100, 1),
        ("peer", 100, 2),
        ("peer", 1000, 2),
        ("ours", False),
    ]
    assert (first, again) == ({"first": True}, {"first": False})
    assert [r["threads"] for r in probes] == [1, 2] and [r["threads"] for r in runs] == [2]
    for steps, threads, probe_steps in ((100, [1, 2], 100), (1000, [1], 100), (1000, [1, 2], None)):
        calls.clear()
        _, probes, _, _ = side_by_side.measure(ours, peer, steps, threads, probe_steps)
        assert probes == [] and calls[1:-1] == [("peer", steps, count) for count in threads]


def _timing(steps, seconds, **extra):
    timing = {"env_steps": steps, "seconds": seconds, "env_steps_per_s": steps / seconds}
    timing |= {"startup_s": 3.04, "warmup_s": 0.46, "warmup_steps": 256, "load": 0.5}
    return {**timing, **extra}


def test_the_table_has_the_columns_asked_for():
    ours = _timing(10_240, 1.0, jax="0.9.2", cores=2)
    peer = _timing(2_048, 4.0, threads=1, version="2.9.2")
    label = lambda r: f"SB3 {r['version']}"  # noqa: E731
    rows = side_by_side.side_rows("SB3", ours, [peer], [peer], ours, label)
    assert [label for label, _, _ in rows] == [
        "ours, jax 0.9.2",
        "SB3, choosing its thread count",
        "SB3 2.9.2",
        "ours again",
    ]
    xla = "XLA over 2 cores"
    assert [threads for _, _, threads in rows] == [xla, "torch 1", "torch 1", xla]
    full = side_by_side.timing_table(rows)
    assert full[:2] == [
        "| program | env steps timed | start-up s | warm-up s (env steps) | training s | "
        "env steps/s | threads | load |",
        "|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    assert full[4] == "| SB3 2.9.2 | 2,048 | 3.0 | 0.5 (256) | 4.0 | 512 | torch 1 | 0.5 |"
    bare = side_by_side.timing_table(rows, steps_header="env steps", warmup=False, threads=False)
    assert bare[:2] == [
        "| program | env steps | start-up s | training s | env steps/s | load |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    assert bare[2] == "| ours, jax 0.9.2 | 10,240 | 3.0 | 1.0 | 10,240 | 0.5 |"


def test_ratio_takes_the_slower_of_ours_over_the_faster_peer():
    results = {
        "ours": _timing(1000, 1.0),
        "ours_again": _timing(1000, 2.0),
        "peer": [_timing(100, 10.0), _timing(100, 4.0)],
    }
    assert side_by_side.ratio(results) == pytest.approx(500 / 25)


def test_the_peer_command_puts_the_budget_and_threads_last(tmp_path):
    command = side_by_side.peer_command(tmp_path / "python", "sb3_x.py", 256, 2, "--env-id", "E")
    assert command == [
        str(tmp_path / "python"),
        str(side_by_side.ROOT / "bench" / "sb3_x.py"),
        "--env-id",
        "E",
        "--steps",
        "256",
        "--threads",
        "2",
    ]


def test_the_peer_result_is_its_last_json_line_or_an_error_naming_it(monkeypatch):
    script = "print('warming up'); print('{\"seconds\": 1}'); print('{\"seconds\": 2}')"
    assert machine.peer_result([sys.executable, "-c", script], "peer") == {"seconds": 2}
    failing = "import sys; print('{}'); sys.exit('gone')"
    with pytest.raises(RuntimeError, match="the peer's PPO failed:\ngone"):
        machine.peer_result([sys.executable, "-c", failing], "the peer's PPO")
    # variables given as None are removed from the peer's environment, others set
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    show = "import json, os; print(json.dumps({k: os.environ.get(k) for k in ('XLA_FLAGS', 'A')}))"
    command = [sys.executable, "-c", show]
    inherited = machine.peer_result(command, "peer")
    assert inherited == {"XLA_FLAGS": "--xla_force_host_platform_device_count=2", "A": None}
    changed = machine.peer_result(command, "peer", {"XLA_FLAGS": None, "A": "1"})
    assert changed == {"XLA_FLAGS": None, "A": "1"}


def test_time_ours_counts_the_timed_calls_and_the_warm_up():
    import jax.numpy as jnp

    def program(state, hparams):
        return state + hparams

    state, timing = side_by_side.time_ours(
        program, jnp.zeros(()), 1.0, calls=3, steps_per_call=64, startup=1.23456, warmup=True
    )
    assert float(state) == 4.0  # the warm-up call and the 3 timed ones
    assert timing["env_steps"] == 192 and timing["warmup_steps"] == 64
    assert timing["startup_s"] == 1.235 and timing["env_steps_per_s"] > 0
    assert {"cores", "jax", "load", "env_steps_per_s", "warmup_s"} <= timing.keys()
    state, timing = side_by_side.time_ours(
        program, jnp.zeros(()), 1.0, calls=2, steps_per_call=64, startup=0.0, warmup=False
    )
    assert float(state) == 2.0 and "warmup_s" not in timing and timing["env_steps"] == 128


def test_section_saves_the_raw_numbers_or_says_why_not(monkeypatch, tmp_path):
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    text = side_by_side.section(
        ["## title", ""],
        "name",
        tmp_path / "results",
        lambda python: {"python": str(python)},
        lambda results: [f"| {results['python']} |"],
    )
    assert text.startswith(f"## title\n\n| {tmp_path / 'python'} |\n\nStarted ")
    saved = json.loads((tmp_path / "results" / "name.json").read_text())
    assert saved == {"python": str(tmp_path / "python")}

    def unavailable():
        raise peers.PeersUnavailable("no network")

    monkeypatch.setattr(peers, "ensure", unavailable)
    text = side_by_side.section(["## title", ""], "name", tmp_path, dict, list)
    assert text == "## title\n\nnot measured: no network\n"


def _main(argv, tmp_path):
    def add_arguments(parser):
        parser.add_argument("--steps", type=int, default=5)

    def settle(args):
        return side_by_side.round_up(args.steps, 4)

    return side_by_side.main(
        argv,
        name="fake",
        doc="A fake bench.",
        add_arguments=add_arguments,
        settle=settle,
        worker=lambda steps: {"steps": steps},
        section=lambda steps, command: f"{command}: {steps}",
        results_dir=tmp_path,
    )


def test_main_settles_its_arguments_then_runs_the_worker_or_the_section(tmp_path, capsys):
    assert _main(["--steps", "0"], tmp_path) == 2
    assert capsys.readouterr().err == "error: steps must be >= 1, got 0\n"
    assert _main(["--steps", "5", "--worker"], tmp_path) == 0
    assert capsys.readouterr().out == 'RESULT {"steps": 8}\n'
    assert _main(["--steps", "5"], tmp_path) == 0
    text = "python -m bench.bench_fake --steps 5: 8"
    assert capsys.readouterr().out == text + "\n" and (tmp_path / "fake.md").read_text() == text


@pytest.mark.slow  # compiles one PPO iteration on HalfCheetah and its four parts
def test_our_ppo_side_on_half_cheetah_times_the_whole_and_its_parts():
    from bench import bench_ppo_sb3

    result = bench_ppo_sb3.ours(bench_ppo_sb3.ROLLOUT, 1)
    assert result["env_steps"] == bench_ppo_sb3.ROLLOUT and result["seconds"] > 0
    assert set(result["breakdown_s"]) == {"whole", "env", "rollout", "update"}
    assert min(result["breakdown_s"].values()) > 0
