"""PPO on MinAtar Breakout beside Stable-Baselines3 (``bench.bench_ppo_minatar_sb3``): the
settings it calls equal are our MinAtar recipe's, the peer's numpy Breakout is shaped as ours,
its arguments and table; our side for one iteration and SB3's script for one rollout are slow
tests."""

import json
import subprocess
import sys

import pytest

from bench import bench_ppo_minatar_sb3 as bench
from bench import peers, sb3_ppo_minatar
from rl_jax.agents.ppo import ppo


def test_the_recipe_is_what_the_peer_is_given():
    """``bench/sb3_ppo_minatar.py`` hard-codes the recipe's settings in SB3's terms: if the recipe
    changes, the comparison is no longer at equal work."""
    config = ppo.default_config(bench.ENV_ID)
    hparams = ppo.default_hyperparams(bench.ENV_ID)
    peer = sb3_ppo_minatar
    assert (config.num_envs, config.num_steps) == (peer.NUM_ENVS, peer.NUM_STEPS)
    assert config.batch_size == peer.ROLLOUT == bench.ROLLOUT
    assert (config.num_epochs, config.num_minibatches) == (peer.NUM_EPOCHS, peer.NUM_MINIBATCHES)
    assert config.batch_size // config.num_minibatches == peer.BATCH_SIZE
    # actor and critic MLPs of their own on the flattened grid: SB3's net_arch pi / vf
    assert config.conv_layers == () and config.hidden == peer.HIDDEN
    assert config.activation == peer.ACTIVATION
    assert not config.normalize_obs and not config.normalize_rewards  # no VecNormalize
    assert config.normalize_advantages and config.clip_value_loss  # SB3: clip_range_vf
    expected = {
        "learning_rate": peer.LEARNING_RATE,
        "lr_decay_steps": peer.DECAY_STEPS,
        "gamma": peer.GAMMA,
        "gae_lambda": peer.GAE_LAMBDA,
        "clip_eps": peer.CLIP_RANGE,
        "value_clip_eps": peer.CLIP_RANGE_VF,
        "ent_coef": peer.ENT_COEF,
        "vf_coef": 2 * peer.VF_COEF,  # ours halves the mean squared error, SB3 does not
        "max_grad_norm": peer.MAX_GRAD_NORM,
        "adam_eps": 1e-5,  # SB3's PPO default
    }
    for name, value in expected.items():
        assert float(getattr(hparams, name)) == pytest.approx(value), name


def test_the_peers_breakout_is_shaped_as_ours(monkeypatch):
    """Our venv has gymnasium and numpy MinAtar too: the wrapper's spaces are our env's, it has
    no sticky actions, and it truncates (not terminates) at ``MAX_EPISODE_STEPS``."""
    from rl_jax import envs

    ours = envs.make(bench.ENV_ID)
    env = sb3_ppo_minatar.make_env()
    assert env.observation_space.shape == ours.observation_space().shape
    assert env.action_space.n == ours.action_space().n == 3
    assert env.game.sticky_action_prob == 0.0
    obs, _ = env.reset(seed=0)
    assert obs.dtype.name == "float32" and obs.shape == (10, 10, 4)
    assert set(obs.ravel().tolist()) <= {0.0, 1.0}
    monkeypatch.setattr(sb3_ppo_minatar, "MAX_EPISODE_STEPS", 2)
    env.reset(seed=0)
    _, _, terminated, truncated, _ = env.step(0)
    assert not terminated and not truncated
    _, _, terminated, truncated, _ = env.step(0)
    assert truncated != terminated  # cut at the 2nd step unless the game ended right there


def test_the_peer_decays_as_ours_over_env_steps_before_the_rollout():
    decay = sb3_ppo_minatar.Decay(1e-3)
    assert decay(1.0) == 1e-3  # before the model exists (its optimizer's first rate)

    class Model:
        num_timesteps = sb3_ppo_minatar.ROLLOUT + 5_000_000

    decay.model = Model()
    assert decay(0.3) == pytest.approx(5e-4)
    Model.num_timesteps = 20_000_000
    assert decay(0.0) == 0.0


def test_steps_round_up_to_whole_rollouts():
    assert bench.round_up(1) == 8_192
    assert bench.round_up(16_384) == bench.STEPS == 16_384
    assert bench.OURS_STEPS % bench.ROLLOUT == 0
    with pytest.raises(ValueError, match=">= 1"):
        bench.round_up(0)


@pytest.mark.parametrize("argv", [["--steps", "0"], ["--sb3-steps", "0"], ["--sb3-threads", "a"]])
def test_bad_arguments_give_one_line_and_exit_2(argv, capsys):
    assert bench.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


def test_peer_script_refuses_a_bad_budget():
    with pytest.raises(SystemExit):
        sb3_ppo_minatar.parse_args(["--steps", "0"])


def _side(seconds, steps=16_384, **extra):
    side = {"env_steps": steps, "seconds": seconds, "env_steps_per_s": steps / seconds}
    return {**side, "startup_s": 12.0, "warmup_s": 1.0, "warmup_steps": 8_192, "load": 1.5, **extra}


def _peer(seconds, steps, threads):
    versions = {"stable_baselines3": "2.9.2", "torch": "2.13.0", "minatar": "1.0.15"}
    return _side(seconds, steps, threads=threads, **versions)


def test_table_compares_the_slower_of_ours_with_the_faster_peer():
    results = {
        "ours": _side(0.5, 327_680, jax="0.9.2", cores=2),  # 655,360/s
        "ours_again": _side(0.8, 327_680, jax="0.9.2", cores=2),  # 409,600/s
        "peer": [_peer(1.6, 16_384, 1), _peer(2.0, 16_384, 2)],  # 10,240/s and 8,192/s
    }
    text = "\n".join(bench.table(results))
    assert bench.ratio(results) == pytest.approx(40.0)
    assert "**40.0x** (goal: >= 30x, met)" in text
    assert "| ours again, XLA over 2 cores | 327,680 | 12.0 | 0.8 | 409,600 | 1.5 |" in text
    assert (
        "| SB3 2.9.2, torch 2.13.0 on 2 thread(s), numpy MinAtar 1.0.15 | 16,384 | 12.0 | 2.0 | "
        "8,192 | 1.5 |" in text
    )
    results["ours_again"] = _side(2.0, 327_680, jax="0.9.2", cores=2)
    assert "(goal: >= 30x, not met)" in "\n".join(bench.table(results))


def test_measure_runs_ours_the_peer_at_each_count_and_ours_again(monkeypatch):
    calls = []

    def fake_peer(python, steps, threads):
        calls.append(("peer", steps, threads))
        return {"threads": threads}

    def fake_ours(steps):
        calls.append(("ours", steps))
        return {"steps": steps}

    monkeypatch.setattr(bench, "_peer", fake_peer)
    monkeypatch.setattr(bench, "_ours_child", fake_ours)
    results = bench.measure(None, bench.STEPS, bench.OURS_STEPS, [1, 2])
    assert calls == [
        ("ours", bench.OURS_STEPS),
        ("peer", bench.STEPS, 1),
        ("peer", bench.STEPS, 2),
        ("ours", bench.OURS_STEPS),
    ]
    assert [r["threads"] for r in results["peer"]] == [1, 2]


def test_run_gives_a_section_with_its_command_and_table(monkeypatch, tmp_path):
    seen = {}

    def fake_measure(python, steps, ours_steps, threads):
        seen.update(steps=steps, ours_steps=ours_steps, threads=threads)
        return {
            "ours": _side(0.1, ours_steps, jax="0.9.2", cores=2),
            "ours_again": _side(0.1, ours_steps, jax="0.9.2", cores=2),
            "peer": [_peer(steps / 8_192, steps, 1)],
        }

    monkeypatch.setattr(bench, "measure", fake_measure)
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    monkeypatch.setattr(bench, "__file__", str(tmp_path / "bench_ppo_minatar_sb3.py"))
    text = bench.run(quick=True)
    assert seen == {
        "steps": bench.QUICK_STEPS,
        "ours_steps": bench.QUICK_OURS_STEPS,
        "threads": [1],
    }
    assert "`python -m bench ppo_minatar_sb3 --quick`" in text and "**40.0x**" in text
    saved = json.loads((tmp_path / "results" / "ppo_minatar_sb3.json").read_text())
    assert saved["peer"][0]["threads"] == 1


def test_run_says_why_when_the_peers_venv_cannot_be_built(monkeypatch):
    def unavailable():
        raise peers.PeersUnavailable("could not create the venv: no network")

    monkeypatch.setattr(peers, "ensure", unavailable)
    assert "not measured: could not create the venv: no network" in bench.run(quick=True)


def test_the_module_runs_as_a_script_with_help():
    done = subprocess.run(
        [sys.executable, "-m", "bench.bench_ppo_minatar_sb3", "--help"],
        capture_output=True,
        text=True,
        cwd=bench.ROOT,
    )
    assert done.returncode == 0 and "--sb3-steps" in done.stdout


@pytest.mark.slow  # compiles one PPO iteration on MinAtar and runs two
def test_our_side_times_one_rollout():
    result = bench.ours(bench.ROLLOUT)
    assert result["env_steps"] == bench.ROLLOUT and result["warmup_steps"] == bench.ROLLOUT
    assert result["seconds"] > 0 and result["startup_s"] > 0


@pytest.mark.slow
@pytest.mark.skipif(not peers.ready(), reason="the peers' venv is not built")
def test_the_peer_times_one_rollout():
    command = bench.peer_command(peers.PYTHON, bench.ROLLOUT, 1)
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["env_steps"] == bench.ROLLOUT and result["threads"] == 1
    assert result["warmup_steps"] == bench.ROLLOUT and result["minatar"] == "1.0.15"
