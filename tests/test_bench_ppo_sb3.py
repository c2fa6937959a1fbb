"""PPO beside Stable-Baselines3 (``bench.bench_ppo_sb3``): the settings it calls equal are our
``cleanrl`` recipe's, its arguments and tables, and SB3's script for one rollout where the peers'
venv is built."""

import json
import subprocess
import sys

import pytest

from bench import bench_ppo_sb3 as bench
from bench import peers, sb3_ppo
from rl_jax.agents.ppo import ppo


def test_the_recipe_is_what_the_sb3_side_is_given():
    """``bench/sb3_ppo.py`` hard-codes the recipe's settings in SB3's terms: if the recipe
    changes, the comparison is no longer at equal work."""
    config = ppo.default_config(bench.ENV_ID, bench.RECIPE)
    hparams = ppo.default_hyperparams(bench.ENV_ID, bench.RECIPE)
    assert (config.num_envs, config.num_steps) == (1, sb3_ppo.ROLLOUT) == (1, bench.ROLLOUT)
    assert (config.num_epochs, config.num_minibatches) == (10, 32)
    assert config.batch_size // config.num_minibatches == 64  # SB3's batch_size
    assert (config.hidden, config.activation) == ((64, 64), "tanh")
    assert config.normalize_obs and config.normalize_rewards and config.normalize_advantages
    assert config.clip_value_loss and config.initial_std == 1.0
    expected = {"learning_rate": 3e-4, "gamma": 0.99, "gae_lambda": 0.95, "clip_eps": 0.2}
    expected |= {"value_clip_eps": 0.2, "vf_coef": 0.5, "ent_coef": 0.0, "max_grad_norm": 0.5}
    expected |= {"adam_eps": 1e-5, "reward_clip": 10.0}
    for name, value in expected.items():
        assert float(getattr(hparams, name)) == pytest.approx(value), name


def test_steps_round_up_to_whole_rollouts():
    assert bench.round_steps(1) == 2048
    assert bench.round_steps(4096) == 4096
    assert bench.round_steps(1_000_000) == 489 * 2048
    with pytest.raises(ValueError, match=">= 1"):
        bench.round_steps(0)


def test_thread_counts_parse_or_refuse():
    assert bench.parse_threads("1,2") == [1, 2]
    assert bench.parse_threads("4") == [4]
    for bad in ("", "1,x", "0", "2,2"):
        with pytest.raises(ValueError, match="--sb3-threads"):
            bench.parse_threads(bad)


@pytest.mark.parametrize("argv", [["--steps", "0"], ["--sb3-threads", "a"], ["--breakdown", "-1"]])
def test_bad_arguments_give_one_line_and_exit_2(argv, capsys):
    assert bench.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_sb3_script_refuses_a_bad_budget():
    with pytest.raises(SystemExit):
        sb3_ppo.parse_args(["--steps", "0"])


def _side(seconds, steps=4096, **extra):
    side = {"env_steps": steps, "seconds": seconds, "env_steps_per_s": steps / seconds}
    return {**side, "startup_s": 12.0, "load": 1.5, **extra}


def test_table_compares_the_slower_of_ours_with_the_faster_sb3():
    breakdown = {"whole": 0.2, "env": 0.05, "rollout": 0.08, "update": 0.1}
    results = {
        "ours": _side(2.0, jax="0.9.2", cores=2, breakdown_s=breakdown),
        "ours_again": _side(2.5, jax="0.9.2", cores=2),
        "sb3_probes": [
            _side(3.0, 2048, threads=1, stable_baselines3="2.9.2", torch="2.13.0"),
            _side(4.0, 2048, threads=2, stable_baselines3="2.9.2", torch="2.13.0"),
        ],
        "sb3": [_side(30.0, threads=1, stable_baselines3="2.9.2", torch="2.13.0")],
    }
    text = "\n".join(bench.table(results))
    assert "**12.00x**" in text  # 30 / 2.5
    assert "| ours again | 4,096 | 12.0 | 2.5 | 1,638 | XLA over 2 cores | 1.5 |" in text
    assert "| SB3, choosing its thread count | 2,048 | 12.0 | 4.0 | 512 | torch 2 | 1.5 |" in text
    assert "| the update alone: 10 epochs x 32 minibatches of 64 | 100.0 | 50% |" in text
    assert "| the rest (whole - rollout - update) | 20.0 | 10% |" in text


def test_no_breakdown_no_second_table():
    results = {
        "ours": _side(2.0, jax="0.9.2", cores=2),
        "ours_again": _side(2.0, jax="0.9.2", cores=2),
        "sb3": [_side(30.0, threads=1, stable_baselines3="2.9.2", torch="2.13.0")],
    }
    assert "Where our time goes" not in "\n".join(bench.table(results))


@pytest.mark.slow
@pytest.mark.skipif(not peers.ready(), reason="the peers' venv is not built")
def test_sb3_ppo_times_one_rollout():
    command = bench.sb3_command(peers.PYTHON, 2048, 1)
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["env_steps"] == 2048 and result["threads"] == 1
    assert result["seconds"] > 0 and result["startup_s"] > 0


def test_the_module_runs_as_a_script_with_help():
    done = subprocess.run(
        [sys.executable, "-m", "bench.bench_ppo_sb3", "--help"],
        capture_output=True,
        text=True,
        cwd=bench.ROOT,
    )
    assert done.returncode == 0 and "--sb3-threads" in done.stdout


def test_sb3_runs_the_whole_budget_at_its_faster_probed_thread_count(monkeypatch):
    calls = []

    def fake_sb3(python, steps, threads):
        calls.append((steps, threads))
        return {"seconds": steps / (100.0 if threads == 2 else 50.0), "threads": threads}

    monkeypatch.setattr(bench, "_sb3", fake_sb3)
    monkeypatch.setattr(bench, "_ours_child", lambda steps, breakdown: {"steps": steps})
    big = bench.round_steps(100_000)
    results = bench.measure(None, big, [1, 2], 0)
    assert calls == [(bench.PROBE_STEPS, 1), (bench.PROBE_STEPS, 2), (big, 2)]
    assert [r["threads"] for r in results["sb3"]] == [2]
    calls.clear()
    bench.measure(None, 4096, [1, 2], 0)  # a budget within the probe's: each count runs it
    assert calls == [(4096, 1), (4096, 2)]


def test_run_gives_a_section_with_its_command_and_tables(monkeypatch, tmp_path):
    seen = {}

    def fake_measure(python, steps, threads, breakdown_iterations):
        seen.update(steps=steps, threads=threads, breakdown=breakdown_iterations)
        return {
            "ours": _side(2.0, steps, jax="0.9.2", cores=2),
            "ours_again": _side(2.0, steps, jax="0.9.2", cores=2),
            "sb3": [_side(30.0, steps, threads=1, stable_baselines3="2.9.2", torch="2.13.0")],
        }

    monkeypatch.setattr(bench, "measure", fake_measure)
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    monkeypatch.setattr(bench, "__file__", str(tmp_path / "bench_ppo_sb3.py"))  # results there
    text = bench.run(quick=True)
    assert seen == {"steps": bench.QUICK_STEPS, "threads": bench.default_threads(), "breakdown": 3}
    assert "`python -m bench ppo_sb3 --quick`" in text and "**15.00x**" in text
    assert json.loads((tmp_path / "results" / "ppo_sb3.json").read_text())["sb3"][0]["threads"] == 1


def test_run_says_why_when_the_peers_venv_cannot_be_built(monkeypatch):
    def unavailable():
        raise peers.PeersUnavailable("could not create the venv: no network")

    monkeypatch.setattr(peers, "ensure", unavailable)
    assert "not measured: could not create the venv: no network" in bench.run(quick=True)
