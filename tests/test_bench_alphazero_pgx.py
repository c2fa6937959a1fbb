"""Our AlphaZero's self-play beside pgx's example (``bench.bench_alphazero_pgx``): both sides are
given the same settings, the search's defaults the example relies on are the ones ours sets, the
peer's MLP is ours in size, the example's copy is checked by digest, and the driver's order,
table and refusals; each side's self-play on a tiny game batch is a slow test."""

import ast
import inspect
import json
import subprocess
import sys
from pathlib import Path

import mctx
import pytest

from bench import bench_alphazero_pgx as bench
from bench import peers, pgx_alphazero
from rl_jax.agents import alphazero


def _peers_have_haiku() -> bool:
    return peers.ready() and any((peers.VENV / "lib").glob("python*/site-packages/haiku"))


def _example_at_hand() -> Path | None:
    try:
        return bench.check_example(bench.CACHE)
    except bench.ExampleUnavailable:
        return None


@pytest.mark.parametrize("quick", [False, True])
def test_both_sides_are_given_the_same_settings(quick):
    settings = bench.default_settings(quick)
    config = bench.our_config(settings)
    assert isinstance(config, alphazero.Config) and config.env_id == "pgx/connect_four"
    assert config.num_envs == settings["games"]
    assert config.num_simulations == settings["simulations"]
    assert config.max_game_length == settings["max_moves"] == 42  # a whole game at most
    assert config.hidden == bench.HIDDEN and config.conv_layers == ()
    command = bench.peer_command(Path("python"), Path("example"), settings)
    args = pgx_alphazero.parse_args(command[2:])
    assert (args.games, args.simulations, args.max_moves, args.calls) == (
        settings["games"],
        settings["simulations"],
        settings["max_moves"],
        settings["calls"],
    )
    assert args.network == "mlp" and args.hidden == config.hidden
    assert pgx_alphazero.example_argv(args)[1:5] == [
        "env_id=connect_four",
        f"selfplay_batch_size={config.num_envs}",
        f"num_simulations={config.num_simulations}",
        f"max_num_steps={config.max_game_length}",
    ]


def test_the_resnet_row_gives_each_side_its_conv_network():
    settings = bench.row_settings(bench.default_settings(False), "resnet")
    assert settings["calls"] == bench.CALLS // 3
    assert bench.our_config(settings).conv_layers == bench.CONV_LAYERS
    args = pgx_alphazero.parse_args(bench.peer_command(Path("p"), Path("e"), settings)[2:])
    assert (args.network, args.channels, args.blocks) == (
        "resnet",
        bench.RESNET_CHANNELS,
        bench.RESNET_BLOCKS,
    )
    argv = pgx_alphazero.example_argv(args)
    assert f"num_channels={bench.RESNET_CHANNELS}" in argv
    assert f"num_layers={bench.RESNET_BLOCKS}" in argv


def test_the_search_defaults_the_example_leaves_are_the_ones_ours_uses():
    """The example calls ``gumbel_muzero_policy`` without ``max_num_considered_actions`` and
    with the completed-by-mix-value transform, Gumbel scale 1; ours passes the config's count
    and leaves the transform to mctx, Gumbel scale 1 in self-play."""
    parameters = inspect.signature(mctx.gumbel_muzero_policy).parameters
    config = bench.our_config(bench.default_settings(False))
    assert parameters["max_num_considered_actions"].default == config.max_considered_actions
    assert parameters["qtransform"].default is mctx.qtransform_completed_by_mix_value
    assert inspect.signature(alphazero.search).parameters["gumbel_scale"].default == 1.0


@pytest.mark.skipif(_example_at_hand() is None, reason="pgx's example is not in the cache")
def test_the_example_argv_names_fields_of_the_examples_config():
    tree = ast.parse((bench.CACHE / "train.py").read_text())
    (config,) = [n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Config"]
    fields = {
        n.target.id
        for n in config.body
        if isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name)
    }
    for network in bench.NETWORKS:
        settings = bench.row_settings(bench.default_settings(False), network)
        args = pgx_alphazero.parse_args(bench.peer_command(Path("p"), Path("e"), settings)[2:])
        for pair in pgx_alphazero.example_argv(args)[1:]:
            assert pair.split("=")[0] in fields


def test_a_copy_of_the_example_with_another_digest_is_refused(tmp_path):
    with pytest.raises(bench.ExampleUnavailable, match="missing"):
        bench.check_example(tmp_path)
    for name in bench.EXAMPLE_FILES:
        (tmp_path / name).write_text("# not pgx's\n")
    with pytest.raises(bench.ExampleUnavailable, match="sha256"):
        bench.example_dir(tmp_path)


def test_a_failed_download_says_where_to_put_the_example(monkeypatch, tmp_path):
    def offline(url, timeout):
        raise OSError("no network")

    monkeypatch.setattr(bench, "CACHE", tmp_path / "cache")
    monkeypatch.setattr(bench.urllib.request, "urlopen", offline)
    with pytest.raises(bench.ExampleUnavailable, match="--pgx-example DIR"):
        bench.example_dir()


def _side(slots_per_s, moves_per_s, **extra):
    return {
        "params": 89_608,
        "move_slots": 26_880,
        "moves_played": 10_000,
        "startup_s": 15.0,
        "seconds": 26_880 / slots_per_s,
        "slots_per_s": slots_per_s,
        "moves_per_s": moves_per_s,
        "load": 1.0,
        "jax": "0.9.2",
        **extra,
    }


def _row(network="mlp"):
    settings = bench.row_settings(bench.default_settings(False), network)
    return {
        "settings": settings,
        "ours": _side(6_000.0, 2_500.0),
        "peer": _side(3_000.0, 3_000.0, jax="0.10.2", haiku="0.0.17"),
        "ours_again": _side(4_500.0, 2_000.0),
        "ours_peer_jax": _side(5_400.0, 2_200.0, jax="0.10.2"),
    }


def test_the_ratio_takes_the_slower_of_ours_over_the_peer():
    row = _row()
    assert bench.ratio(row) == pytest.approx(1.5)
    assert bench.ratio(row, "moves_per_s") == pytest.approx(2_000 / 3_000)
    assert bench.same_jax_ratio(row) == pytest.approx(1.8)
    text = "\n".join(bench.table([row, _row("resnet")]))
    assert "**1.50x**; per move played 0.67x" in text and "1.80x" in text
    assert "| MLP 256 x 256 | ours `self_play` again | 89,608 | 26,880 | 10,000 |" in text
    assert "pgx example `selfplay`, haiku MLP, jax 0.10.2, haiku 0.0.17" in text
    assert "AZNet 64 ch x 1 block" in text


def test_measure_runs_ours_the_peer_ours_again_and_ours_on_the_peers_jax(monkeypatch):
    calls = []
    monkeypatch.setattr(bench, "_peer", lambda python, d, s: calls.append(("peer", python)) or {})
    monkeypatch.setattr(
        bench,
        "_ours_child",
        lambda s, python=sys.executable: calls.append(("ours", python)) or {},
    )
    bench.measure(Path("peers-python"), Path("example"), bench.default_settings(True))
    assert calls == [
        ("ours", sys.executable),
        ("peer", Path("peers-python")),
        ("ours", sys.executable),
        ("ours", "peers-python"),
    ]


def test_run_gives_a_section_with_its_command_and_table(monkeypatch, tmp_path):
    seen = []

    def fake_measure(python, directory, settings):
        seen.append(settings)
        return _row(settings["network"])

    monkeypatch.setattr(bench, "measure", fake_measure)
    monkeypatch.setattr(peers, "ensure", lambda: tmp_path / "python")
    monkeypatch.setattr(bench, "example_dir", lambda given: tmp_path)
    monkeypatch.setattr(bench, "__file__", str(tmp_path / "bench_alphazero_pgx.py"))
    text = bench.run(quick=True)
    assert [s["network"] for s in seen] == ["mlp"]
    assert seen[0]["games"] == bench.QUICK_GAMES and seen[0]["calls"] == bench.QUICK_CALLS
    assert "`python -m bench alphazero_pgx --quick`" in text and "**1.50x**" in text
    saved = json.loads((tmp_path / "results" / "alphazero_pgx.json").read_text())
    assert saved[0]["settings"]["network"] == "mlp"


def test_run_says_why_when_the_example_cannot_be_had(monkeypatch):
    def unavailable(given):
        raise bench.ExampleUnavailable("could not download it")

    monkeypatch.setattr(peers, "ensure", lambda: Path("python"))
    monkeypatch.setattr(bench, "example_dir", unavailable)
    assert "not measured: could not download it" in bench.run(quick=True)


@pytest.mark.parametrize("argv", [["--games", "0"], ["--network", "transformer"]])
def test_bad_arguments_give_one_line_and_exit_2(argv, capsys):
    assert bench.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1


@pytest.mark.skipif(not _peers_have_haiku(), reason="the peers' venv has no dm-haiku")
def test_the_peers_mlp_has_our_networks_parameters_and_outputs():
    """The haiku MLP that replaces the example's network, built in the peers' venv, has our
    ``PolicyValueNet``'s parameter count and output shapes on Connect Four's observations."""
    import jax

    config = bench.our_config(bench.default_settings(True))
    assert isinstance(config, alphazero.Config)
    obs = jax.vmap(config.make_game().init)(jax.random.split(jax.random.key(0), 2)).observation
    ours = alphazero.make_network(config).init(jax.random.key(0), obs[:1])
    count = sum(x.size for x in jax.tree.leaves(ours))
    script = (
        "import sys, jax, jax.numpy as jnp\n"
        "sys.path.insert(0, 'bench'); import pgx_alphazero as p\n"
        f"f = p.mlp_forward(7, {config.hidden!r})\n"
        f"x = jnp.zeros((3, {', '.join(map(str, obs.shape[1:]))}), bool)\n"
        "params, state = f.init(jax.random.PRNGKey(0), x)\n"
        "(logits, value), _ = f.apply(params, state, x, is_eval=True)\n"
        "print(sum(a.size for a in jax.tree.leaves(params)), logits.shape, value.shape)\n"
    )
    done = subprocess.run(
        [str(peers.PYTHON), "-c", script], cwd=bench.ROOT, capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split("\n")[-2] == f"{count} (3, 7) (3,)"


@pytest.mark.slow  # compiles our self-play on Connect Four
def test_our_side_times_a_tiny_self_play():
    settings = bench.Settings(games=2, simulations=2, max_moves=4, calls=1, network="mlp")
    result = bench.ours(settings)
    assert result["move_slots"] == 8 and 0 < result["moves_played"] <= 8
    assert result["params"] == 89_608 and result["seconds"] > 0
    # continuous self-play restarts ended games: every slot is a move
    assert result["continuous_moves_played"] == 8 and result["continuous_slots_per_s"] > 0


@pytest.mark.slow  # loads pgx's example in the peers' venv and compiles its self-play
@pytest.mark.skipif(
    not _peers_have_haiku() or _example_at_hand() is None,
    reason="the peers' venv has no dm-haiku, or pgx's example is not in the cache",
)
def test_the_examples_self_play_runs_with_our_mlp():
    settings = bench.Settings(games=2, simulations=2, max_moves=4, calls=1, network="mlp")
    result = bench._peer(peers.PYTHON, bench.CACHE, settings)
    assert result["move_slots"] == result["moves_played"] == 8
    assert result["params"] == 89_608 and result["devices"] == 1
    assert result["train_py_sha256"] == bench.EXAMPLE_FILES["train.py"]
