"""Recurrent PPO beside sb3-contrib (``bench.bench_recurrent_ppo_sb3``): the settings it calls
equal are our CartPoleNoVel recipe's, its arguments and table, our side for one chunk, and
sb3-contrib's script for one rollout where the peers' venv is built."""

import json
import subprocess
import sys

import pytest

from bench import bench_recurrent_ppo_sb3 as bench
from bench import peers, sb3_recurrent_ppo
from rl_jax.agents.recurrent_ppo import recurrent_ppo


def test_the_recipe_is_what_the_peer_is_given():
    """``bench/sb3_recurrent_ppo.py`` hard-codes the recipe's settings in sb3-contrib's terms: if
    the recipe changes, the comparison is no longer at equal work."""
    config = recurrent_ppo.default_config(bench.ENV_ID)
    hparams = recurrent_ppo.default_hyperparams(bench.ENV_ID)
    peer = sb3_recurrent_ppo
    assert (config.num_envs, config.num_steps) == (peer.NUM_ENVS, peer.NUM_STEPS)
    assert config.batch_size == peer.ROLLOUT == bench.ROLLOUT
    assert config.batch_size * config.iterations_per_chunk == bench.CHUNK
    assert config.num_epochs == peer.NUM_EPOCHS
    assert config.batch_size // config.num_minibatches == peer.BATCH_SIZE  # one minibatch
    assert config.seq_len == config.num_steps  # whole rollouts of each env as sequences
    assert (config.cell, config.cell_size, config.hidden) == ("lstm", peer.LSTM_SIZE, ())
    # the peer's net_arch=[] and shared LSTM: no layers after the cell, no critic cell
    assert getattr(config, "head_hidden", ()) == () and not getattr(config, "critic_cell", False)
    assert config.normalize_obs and config.normalize_advantages
    expected = {
        "learning_rate": peer.LEARNING_RATE,
        "lr_decay_steps": peer.DECAY_STEPS,
        "clip_eps": peer.CLIP_RANGE,
        "clip_decay_steps": peer.DECAY_STEPS,
        "gamma": peer.GAMMA,
        "gae_lambda": peer.GAE_LAMBDA,
        "vf_coef": 2 * peer.VF_COEF,  # ours halves the mean squared error, sb3-contrib does not
        "ent_coef": 0.0,
        "max_grad_norm": peer.MAX_GRAD_NORM,
        "adam_eps": 1e-5,
    }
    for name, value in expected.items():
        assert float(getattr(hparams, name)) == pytest.approx(value), name


def test_the_peer_decays_as_ours_over_env_steps_before_the_rollout():
    decay = sb3_recurrent_ppo.Decay(1e-3)
    assert decay(1.0) == 1e-3  # before the model exists (its optimizer's first rate)

    class Model:
        num_timesteps = sb3_recurrent_ppo.ROLLOUT + 50_000

    decay.model = Model()
    assert decay(0.3) == pytest.approx(5e-4)
    Model.num_timesteps = 500_000
    assert decay(0.0) == 0.0


def test_steps_round_up_to_whole_units():
    assert bench.round_up(1, bench.ROLLOUT) == 256
    assert bench.round_up(100_000, bench.ROLLOUT) == bench.STEPS
    assert bench.round_up(2048, bench.CHUNK) == 10_240
    with pytest.raises(ValueError, match=">= 1"):
        bench.round_up(0, bench.ROLLOUT)


@pytest.mark.parametrize("argv", [["--steps", "0"], ["--ours-steps", "0"], ["--sb3-threads", "a"]])
def test_bad_arguments_give_one_line_and_exit_2(argv, capsys):
    assert bench.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_peer_script_refuses_a_bad_budget():
    with pytest.raises(SystemExit):
        sb3_recurrent_ppo.parse_args(["--steps", "0"])


def _side(seconds, steps=10_240, **extra):
    side = {"env_steps": steps, "seconds": seconds, "env_steps_per_s": steps / seconds}
    return {**side, "startup_s": 12.0, "warmup_s": 1.0, "warmup_steps": 512, "load": 1.5, **extra}


def _peer(seconds, steps, threads):
    versions = {"sb3_contrib": "2.9.2", "torch": "2.13.0"}
    return _side(seconds, steps, threads=threads, **versions)


def test_table_compares_the_slower_of_ours_with_the_faster_peer():
    results = {
        "ours": _side(1.0, jax="0.9.2", cores=2),  # 10,240/s
        "ours_again": _side(1.25, jax="0.9.2", cores=2),  # 8,192/s
        "peer_probes": [_peer(20.0, 10_240, 1), _peer(25.0, 10_240, 2)],
        "peer": [_peer(25.0, 10_240, 1)],  # 409.6/s
    }
    text = "\n".join(bench.table(results))
    assert "**20.0x**" in text  # 8,192 / 409.6
    assert bench.ratio(results) == pytest.approx(20.0)
    assert (
        "| ours again | 10,240 | 12.0 | 1.0 (512) | 1.2 | 8,192 | XLA over 2 cores | 1.5 |" in text
    )
    assert (
        "| sb3-contrib, choosing its thread count | 10,240 | 12.0 | 1.0 (512) | 25.0 | 410 | "
        in text
    )
    assert "| sb3-contrib 2.9.2, torch 2.13.0 | 10,240 |" in text


def test_the_peer_runs_the_whole_budget_at_its_faster_probed_thread_count(monkeypatch):
    calls = []

    def fake_peer(python, steps, threads):
        calls.append((steps, threads))
        return {"seconds": steps / (100.0 if threads == 2 else 50.0), "threads": threads}

    monkeypatch.setattr(bench, "_peer", fake_peer)
    monkeypatch.setattr(bench, "_ours_child", lambda steps: {"steps": steps})
    results = bench.measure(None, bench.STEPS, 40_960, [1, 2])
    assert calls == [(bench.PROBE_STEPS, 1), (bench.PROBE_STEPS, 2), (bench.STEPS, 2)]
    assert [r["threads"] for r in results["peer"]] == [2]
    assert results["ours"] == results["ours_again"] == {"steps": 40_960}
    calls.clear()
    bench.measure(None, 2048, 10_240, [1, 2])  # a budget within the probe's: each count runs it
    assert calls == [(2048, 1), (2048, 2)]


def test_run_gives_a_section_with_its_command_and_table(monkeypatch, tmp_path):
    seen = {}

    def fake_measure(python, steps, ours_steps, threads):
        seen.update(steps=steps, ours_steps=ours_steps, threads=threads)
        return {
            "ours": _side(1.0, ours_steps, jax="0.9.2", cores=2),
            "ours_again": _side(1.0, ours_steps, jax="0.9.2", cores=2),
            "peer_probes": [],
            "peer": [_peer(steps / 500, steps, 1)],
        }

    monkeypatch.setattr(bench, "measure", fake_measure)
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    monkeypatch.setattr(bench, "__file__", str(tmp_path / "bench_recurrent_ppo_sb3.py"))
    text = bench.run(quick=True)
    assert seen == {
        "steps": bench.QUICK_STEPS,
        "ours_steps": bench.QUICK_OURS_STEPS,
        "threads": bench.default_threads(),
    }
    assert "`python -m bench recurrent_ppo_sb3 --quick`" in text and "**41.0x**" in text
    saved = json.loads((tmp_path / "results" / "recurrent_ppo_sb3.json").read_text())
    assert saved["peer"][0]["threads"] == 1


def test_run_says_why_when_the_peers_venv_cannot_be_built(monkeypatch):
    def unavailable():
        raise peers.PeersUnavailable("could not create the venv: no network")

    monkeypatch.setattr(peers, "ensure", unavailable)
    assert "not measured: could not create the venv: no network" in bench.run(quick=True)


def test_the_module_runs_as_a_script_with_help():
    done = subprocess.run(
        [sys.executable, "-m", "bench.bench_recurrent_ppo_sb3", "--help"],
        capture_output=True,
        text=True,
        cwd=bench.ROOT,
    )
    assert done.returncode == 0 and "--ours-steps" in done.stdout


@pytest.mark.slow  # compiles 40 iterations of recurrent PPO: ~20 s
def test_our_side_times_one_chunk():
    result = bench.ours(bench.CHUNK)
    assert result["env_steps"] == bench.CHUNK and result["warmup_steps"] == bench.CHUNK
    assert result["seconds"] > 0 and result["startup_s"] > 0


@pytest.mark.slow
@pytest.mark.skipif(not peers.ready(), reason="the peers' venv is not built")
def test_the_peer_times_one_rollout():
    command = bench.peer_command(peers.PYTHON, 256, 1)
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["env_steps"] == 256 and result["threads"] == 1
    assert result["warmup_steps"] == 2 * 256 and result["sb3_contrib"] == "2.9.2"
