"""The peers comparison's pure parts: SAC's update FLOPs (``bench.sac_programs``) against a hand
count, its products' listing against that count, the tables with and without the PyTorch peer,
and SBX's SAC script run for a few updates where the peers' venv is built."""

import json
import subprocess

import pytest

from bench import bench_peers, peers, sac_programs
from rl_jax.agents.sac import sac

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

WIDTH, BATCH = 32, 16
OBS, ACTION = 3, 1  # Pendulum


def _config(**overrides):
    base = {"actor_hidden": (WIDTH, WIDTH), "critic_hidden": (WIDTH, WIDTH)}
    base |= {"batch_size": BATCH, "buffer_size": 1_000}
    return sac.default_config("rl_jax/Pendulum-v1", **{**base, **overrides})


def _dense(n_in, n_out):
    return 2 * BATCH * n_in * n_out


ACTOR = [(OBS, WIDTH), (WIDTH, WIDTH), (WIDTH, 2 * ACTION)]  # mean and log-std heads
CRITIC = [(OBS + ACTION, WIDTH), (WIDTH, WIDTH), (WIDTH, 1)]


@pytest.mark.slow  # compiles SAC's update to count its flops: ~11 s
def test_sac_update_flops_equal_a_hand_count():
    """Critic step: the actor forward on s' (the bootstrap action), both target critics
    forward, both critics forward and backward (weight gradients, and input gradients below
    the first layer, whose input is data). Actor step: the actor forward, both critics forward
    and back to their action input (input gradients of every layer, no weight gradients), the
    actor's weight gradients and its input gradients below the first layer."""
    actor = sum(_dense(*shape) for shape in ACTOR)
    critic = sum(_dense(*shape) for shape in CRITIC)
    critic_step = actor + 2 * critic + 2 * critic + 2 * critic + 2 * (critic - _dense(*CRITIC[0]))
    actor_step = actor + 2 * critic + 2 * critic + actor + (actor - _dense(*ACTOR[0]))
    counted = sac_programs.update_flops(_config())
    assert counted["critic_step"] == critic_step
    assert counted["actor_step"] == actor_step
    assert counted["per_update"] == critic_step + actor_step  # an actor step every update


def test_policy_delay_divides_the_actor_steps_share():
    counted = sac_programs.update_flops(_config(policy_delay=2))
    assert counted["per_update"] == counted["critic_step"] + counted["actor_step"] / 2


def test_the_listed_products_of_several_seeds_add_up_to_the_count():
    """``dots_program`` runs what ``update_dots`` lists: for 3 seeds vmapped, the same FLOPs as
    3 single-seed updates."""
    from bench.td3_programs import _dot_flops

    config = _config()
    dots = sac_programs.update_dots(config, 3)
    total = sum(weight * _dot_flops(equation) for equation, weight in dots)
    assert total == 3 * sac_programs.update_flops(config)["per_update"]


def test_learner_parts_name_the_learner_or_refuse():
    assert bench_peers.learner_parts("sac")[0] is sac
    with pytest.raises(ValueError, match="td3 or sac"):
        bench_peers.learner_parts("ppo")


def _ours(rate, load=1.0):
    side = {"updates_per_s": rate, "dots_alone_updates_per_s": 2 * rate, "load": load}
    return {"flops_per_update": 5e8, "matmul_1024_gflops": 200.0, **side}


def _case(peers_run):
    result = {"ours": {1: _ours(300.0), 2: _ours(280.0)}}
    result["ours_again"] = {1: _ours(290.0), 2: _ours(300.0)}
    for peer in peers_run:
        key = "updates_per_s" if peer == "sbx" else "learning_steps_per_s"
        result[peer] = [{key: 100.0, "load": 2.0}, {key: 120.0, "load": 3.0}]
    return result


def _rows(lines):
    return [line for line in lines if line.startswith("|")]


@pytest.mark.parametrize("algo", ["td3", "sac"])
def test_tables_have_one_column_per_peer_measured(algo):
    lines = bench_peers.table({"a case": _case(bench_peers.PEERS[algo])})
    rows = _rows(lines)
    first_table = rows[:3]  # header, rule, the case
    assert len({row.count("|") for row in first_table}) == 1
    assert ("PyTorch x2" in rows[0]) == (algo == "td3")
    cells = [cell.strip() for cell in first_table[2].split("|")]
    # ours: the better layout's worse timing (1 device: min(300, 290) = 290); SBX: 100 + 120
    assert "1.32x" in cells  # 290 / 220
    assert "500.0" in cells  # MFLOP per update


@pytest.mark.slow
@pytest.mark.skipif(not peers.ready(), reason="the peers' venv is not built")
def test_sbx_sac_runs_and_prints_its_rate():
    command = [str(peers.PYTHON), str(bench_peers.ROOT / "bench" / "sbx_sac.py")]
    command += ["--env-id", "Pendulum-v1", "--hidden", "16,16", "--batch-size", "32"]
    command += ["--updates", "20", "--warmup", "5", "--learning-starts", "100"]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["algo"] == "SAC" and result["updates"] == 20 and result["updates_per_s"] > 0


def test_peers_sac_reports_every_case_against_sbx_alone(monkeypatch, tmp_path):
    from bench import bench_peers_sac

    measured = []

    def fake_measure(case, python, quick, algo):
        measured.append((case, quick, algo))
        return _case(bench_peers.PEERS[algo])

    monkeypatch.setattr(bench_peers, "measure_case", fake_measure)
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    monkeypatch.setattr(bench_peers, "__file__", str(tmp_path / "bench_peers.py"))
    text = bench_peers_sac.run(quick=True)
    assert measured == [(case, True, "sac") for case in bench_peers.CASES]
    assert text.startswith(f"## {bench_peers_sac.TITLE}")
    assert "`python -m bench peers_sac --quick`" in text and "PyTorch" not in text
    assert set(json.loads((tmp_path / "results" / "peers_sac.json").read_text())) == set(
        bench_peers.CASES
    )
