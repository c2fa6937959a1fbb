"""``python -m bench.figures``: its statistics (against known answers, and rliable's where
installed), the figures it draws from run directories made here (fake metrics files in the run
layer's format, and a tiny run of the fake learner for a GIF), the one-line skips and errors, and
the size limit of every committed image."""

import json
from pathlib import Path

import numpy as np
import pytest
from run_helpers import fake_run

from bench import figure_data, figure_plots, figure_stats, figures

ROOT = Path(__file__).resolve().parents[1]
IMAGE_SUFFIXES = {".png", ".gif", ".jpg", ".jpeg", ".svg", ".webp"}


# ---- statistics -----------------------------------------------------------------------------


def test_iqm_drops_a_quarter_at_each_end_of_the_pooled_scores():
    scores = [np.array([0.0, 1.0, 2.0, 100.0]), np.array([3.0, 4.0, 5.0, -50.0])]
    # pooled and sorted: -50 0 1 2 | 3 4 ... 8 values, 2 dropped at each end -> 1 2 3 4
    assert figure_stats.iqm(scores) == pytest.approx(2.5)


def test_stratified_bootstrap_keeps_every_env_in_every_resample():
    # Each env's scores are constant: any resample within envs gives back the same pool, so the
    # interval has no width (a bootstrap over the pooled runs would mix the envs and spread).
    scores = [np.zeros(4), np.ones(4)]
    assert figure_stats.iqm_ci(scores, resamples=500) == (0.5, 0.5, 0.5)
    fraction, low, high = figure_stats.profile_ci(scores, np.array([-1.0, 0.5, 2.0]), resamples=500)
    np.testing.assert_array_equal(fraction, [1.0, 0.5, 0.0])
    np.testing.assert_array_equal(low, fraction)
    np.testing.assert_array_equal(high, fraction)


def test_profile_weighs_each_env_alike_whatever_its_seed_count():
    scores = [np.array([1.0]), np.array([0.0, 0.0, 0.0])]
    np.testing.assert_array_equal(figure_stats.profile(scores, np.array([0.5])), [0.5])


def test_mean_band_of_one_seed_has_no_width_and_skips_missing_evals():
    mean, low, high = figure_stats.mean_ci(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_array_equal(mean, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(low, mean)
    np.testing.assert_array_equal(high, mean)
    mean, low, high = figure_stats.mean_ci(np.array([[1.0, np.nan], [3.0, 5.0]]))
    assert mean[1] == 5.0 and low[0] >= 1.0 and high[0] <= 3.0


def test_normalize_maps_low_to_0_and_high_to_1():
    np.testing.assert_allclose(
        figure_stats.normalize([-1500, -200, -850], -1500, -200), [0, 1, 0.5]
    )
    with pytest.raises(ValueError):
        figure_stats.normalize([1.0], 2.0, 2.0)


@pytest.fixture(scope="module")
def rliable():
    try:
        from rliable import library, metrics
    except Exception:  # noqa: BLE001 - absent, or its dependencies break on import
        pytest.skip("rliable is not installed (pip install rliable to compare with it)")
    return library, metrics


def _within(ours, theirs, tolerance):
    """Two bootstrap intervals with different RNGs agree to ``tolerance`` of the scores' scale."""
    np.testing.assert_allclose(np.asarray(ours, float), np.asarray(theirs, float), atol=tolerance)


def test_iqm_and_its_interval_match_rliable(rliable):
    library, metrics = rliable
    rng = np.random.default_rng(3)
    matrix = rng.normal(1.0, 0.4, size=(10, 4))  # [runs, tasks]
    points, intervals = library.get_interval_estimates(
        {"x": matrix}, lambda x: np.array([metrics.aggregate_iqm(x)]), reps=2000
    )
    center, low, high = figure_stats.iqm_ci(list(matrix.T), resamples=2000)
    assert center == pytest.approx(float(points["x"][0]), abs=1e-12)
    _within([low, high], intervals["x"][:, 0], 0.05)


def test_profile_and_its_band_match_rliable_with_unequal_seed_counts(rliable):
    library, _ = rliable
    rng = np.random.default_rng(4)
    matrix = rng.uniform(0, 1.5, size=(8, 3))
    taus = np.linspace(0, 1.5, 7)
    profiles, bands = library.create_performance_profile({"x": matrix}, taus, reps=2000)
    fraction, low, high = figure_stats.profile_ci(list(matrix.T), taus, resamples=2000)
    np.testing.assert_allclose(fraction, profiles["x"], atol=1e-12)
    _within(low, bands["x"][0], 0.1)  # fractions of 24 runs: steps of 1/24
    _within(high, bands["x"][1], 0.1)
    # unequal seed counts: rliable bootstraps each env's array alone (independent strata)
    envs = [rng.uniform(0, 1, 5), rng.uniform(0.5, 1.5, 9)]
    pooled = lambda *arrays: np.array([metrics_iqm(np.concatenate(arrays))])
    points, intervals = library.get_interval_estimates({"x": envs}, pooled, reps=2000)
    center, low, high = figure_stats.iqm_ci(envs, resamples=2000)
    assert center == pytest.approx(float(points["x"][0]), abs=1e-12)
    _within([low, high], intervals["x"][:, 0], 0.06)


def metrics_iqm(values):
    import scipy.stats

    return scipy.stats.trim_mean(values, 0.25, axis=None)


# ---- run directories in the run layer's format ------------------------------------------------


def write_run(directory: Path, algorithm: str, env_id: str, returns: np.ndarray, every=1000):
    """A run directory as the run layer writes it: config.json and metrics.jsonl rows."""
    directory.mkdir(parents=True)
    identity = {
        "algorithm": algorithm, "env_id": env_id, "config": {"env_id": env_id}, "hparams": [{}],
        "seeds": len(returns), "base_seed": 0,
    }  # fmt: skip
    (directory / "config.json").write_text(json.dumps({"identity": identity}))
    rows = [
        {"step": every * (t + 1), "seed": s, "eval_return": float(value), "train_return": 0.0}
        for t in range(returns.shape[1])
        for s, value in enumerate(returns[:, t])
    ]
    (directory / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return directory


@pytest.fixture
def runs(tmp_path):
    rng = np.random.default_rng(0)
    steps = np.arange(1, 31)
    cheetah = steps * 150 + rng.normal(0, 200, size=(3, 30))
    return {
        "cheetah_td3": write_run(tmp_path / "td3", "td3", "rl_jax/HalfCheetah-v5", cheetah, 10_000),
        "cheetah_sac": write_run(tmp_path / "sac", "sac", "rl_jax/HalfCheetah-v5", cheetah * 1.1),
        "cartpole": write_run(tmp_path / "cp", "ppo", "rl_jax/CartPole-v1", np.full((4, 5), 500.0)),
    }


def _manifest(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_figures_from_a_manifest_with_a_missing_run_skipped_in_one_line(runs, tmp_path, capsys):
    bench_md = tmp_path / "BENCH.md"
    bench_md.write_text(
        "## Speed\n\ntext\n\n| env | theirs | ours |\n|---|---:|---:|\n"
        "| A | 1,000 | 2,500 |\n| B | 300 | skipped (compile > 90 s) |\n"
    )
    manifest = _manifest(
        tmp_path / "manifest.toml",
        f"""
[curves.cheetah]
runs = ["{runs["cheetah_td3"]}", "{runs["cheetah_sac"]}", "{tmp_path / "not_yet"}"]
reference = ["td3_paper", "sac_simbav2"]
[curves.gone]
runs = ["{tmp_path / "no_such_run"}"]
[aggregate.suite]
runs = ["{runs["cheetah_td3"]}", "{runs["cheetah_sac"]}", "{runs["cartpole"]}"]
[aggregate.suite.normalize]
"rl_jax/HalfCheetah-v5" = {{ reference = "td3_paper", step = 300000 }}
"rl_jax/CartPole-v1" = {{ low = 0, high = 500 }}
[speed.bench]
source = "{bench_md}"
heading = "Speed"
label = "env"
bars = ["theirs", "ours"]
baseline = "theirs"
log = true
""",
    )
    out = tmp_path / "figures"
    assert figures.main(["--manifest", str(manifest), "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert (
        f"skipped curves_gone.png: run directory {tmp_path / 'no_such_run'} is missing" in printed
    )
    made = sorted(p.name for p in out.iterdir())
    assert made == ["aggregate_suite.png", "curves_cheetah.png", "speed_bench.png"]
    assert all(0 < (out / name).stat().st_size <= figure_plots.MAX_BYTES for name in made)
    cheetah = next(line for line in printed if "curves_cheetah.png" in line)
    assert "against TD3 paper, SAC (SimbaV2 baseline)" in cheetah
    assert cheetah.endswith(f"(left out, missing: {tmp_path / 'not_yet'})")
    assert any(line.startswith("wrote") and "TD3 IQM" in line for line in printed)


def test_run_dirs_on_the_command_line_make_one_curves_figure_per_env(runs, tmp_path, capsys):
    out = tmp_path / "out"
    arguments = [str(runs["cheetah_td3"]), str(runs["cartpole"]), str(tmp_path / "nothing")]
    assert figures.main([*arguments, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "curves_CartPole-v1.png",
        "curves_HalfCheetah-v5.png",
    ]
    assert "is missing" in capsys.readouterr().out


def test_a_curves_legend_below_the_axes_and_only_the_figures_named(runs, tmp_path, capsys):
    from PIL import Image

    manifest = _manifest(
        tmp_path / "manifest.toml",
        f"""
[curves.inside]
runs = ["{runs["cheetah_td3"]}", "{runs["cheetah_sac"]}"]
reference = []
[curves.below]
runs = ["{runs["cheetah_td3"]}", "{runs["cheetah_sac"]}"]
reference = []
legend = "below"
[curves.corner]
runs = ["{runs["cartpole"]}"]
legend = "lower right"
""",
    )
    out = tmp_path / "figures"
    only = ["curves_inside", "curves_below.png"]
    assert figures.main(["--manifest", str(manifest), "--out", str(out), *("--only", *only)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["curves_below.png", "curves_inside.png"]
    with (
        Image.open(out / "curves_inside.png") as inside,
        Image.open(out / "curves_below.png") as below,
    ):
        assert below.width == inside.width and below.height > inside.height
    assert (
        figures.main(["--manifest", str(manifest), "--out", str(out), "--only", "curves_corner"])
        == 0
    )
    assert (out / "curves_corner.png").stat().st_size > 0
    assert "1 figures written" in capsys.readouterr().out.splitlines()[-1]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[plots.x]\nruns = []\n", "unknown figure kind [plots]"),
        ("[curves.x]\ntitle = 'no runs'\n", "[curves.x] lacks ['runs']"),
        ("[curves.x]\nruns = []\nlabel = 'a typo'\n", "has unknown keys ['label']"),
        ("[curves.x\n", "is not readable TOML"),
    ],
)
def test_a_bad_manifest_is_one_line_and_status_2(tmp_path, capsys, text, message):
    manifest = _manifest(tmp_path / "m.toml", text)
    assert figures.main(["--manifest", str(manifest), "--out", str(tmp_path / "o")]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error


def test_a_malformed_entry_is_one_line(tmp_path, capsys):
    manifest = _manifest(tmp_path / "m.toml", "[curves.x]\nruns = [1]\n")
    assert figures.main(["--manifest", str(manifest), "--out", str(tmp_path / "o")]) == 2
    assert "[curves.x] runs must be a list of paths" in capsys.readouterr().err


def test_an_out_that_cannot_be_a_folder_is_one_line(tmp_path, capsys):
    manifest = _manifest(tmp_path / "m.toml", "[curves.x]\nruns = []\n")
    (tmp_path / "a_file").write_text("")
    assert figures.main(["--manifest", str(manifest), "--out", str(tmp_path / "a_file")]) == 2
    assert capsys.readouterr().err.startswith("error: cannot write to --out")


def test_an_unknown_figure_name_is_one_line(tmp_path, capsys):
    manifest = _manifest(tmp_path / "m.toml", "[curves.x]\nruns = []\n")
    assert figures.main(["--manifest", str(manifest), "--only", "curves_y"]) == 2
    assert "no figure 'curves_y'" in capsys.readouterr().err


def test_figures_that_cannot_be_made_say_why(runs, tmp_path):
    entry = {"runs": [str(runs["cheetah_td3"]), str(runs["cartpole"])]}
    with pytest.raises(figure_data.FigureError, match="different envs"):
        figures.make_curves(entry, tmp_path / "c.png")
    with pytest.raises(figure_data.FigureError, match="unknown reference 'nope'"):
        figures.make_curves({"runs": entry["runs"][:1], "reference": "nope"}, tmp_path / "c.png")
    with pytest.raises(figure_data.FigureError, match="no normalize entry for rl_jax/"):
        figures.make_aggregate({"runs": entry["runs"], "normalize": {}}, tmp_path / "a.png")
    with pytest.raises(figure_data.FigureError, match="non-empty list"):
        figures.make_curves({"runs": []}, tmp_path / "c.png")
    speed = {"source": "BENCHMARKS.md", "heading": "no such heading", "label": "x", "bars": []}
    with pytest.raises(figure_data.FigureError, match="has no heading"):
        figures.make_speed(speed, tmp_path / "s.png")


def test_the_suite_aggregate_reads_its_rows_per_seed_from_results_md(tmp_path):
    rows = figure_data.result_rows()
    assert rows["sac-hopper"].env_id == "rl_jax/Hopper-v5"
    assert rows["sac-hopper"].total_steps == 300_000 and rows["sac-hopper"].finals.size == 5
    assert rows["dqn-cartpole"].finals.size == 30  # "500 (x8) / 499 / 500 (x21)"
    entry = figures.read_manifest(figures.MANIFEST)["aggregate"]["suite"]
    note = figures.make_aggregate(entry, tmp_path / "a.png")
    assert all(f"{label} IQM" in note for label in entry["rows"]), note
    uneven = {**entry, "rows": {"A": ["sac-hopper", "sac-ant"], "B": ["sac-hopper"]}}
    with pytest.raises(figure_data.FigureError, match="not the same envs"):
        figures.make_aggregate(uneven, tmp_path / "b.png")


def test_cells_of_benchmark_tables_read_as_numbers():
    assert figure_data.cell_number("1,029,909") == 1029909
    assert figure_data.cell_number("296, 294") == 294
    assert figure_data.cell_number("**1.21x**") == 1.21
    assert figure_data.cell_number("skipped (compile > 180 s)") is None
    assert figure_data.cell_number("") is None


# ---- GIFs -----------------------------------------------------------------------------------


def test_gif_of_a_trained_run_is_rendered_and_small(tmp_path, capsys):
    run_dir = fake_run(tmp_path / "run", total_steps=40)
    manifest = _manifest(tmp_path / "m.toml", f'[gifs.point]\nrun = "{run_dir}"\n')
    assert figures.main(["--manifest", str(manifest), "--out", str(tmp_path / "o")]) == 0
    gif = tmp_path / "o" / "policy_point.gif"
    assert 0 < gif.stat().st_size <= figure_plots.MAX_BYTES
    assert "wrote" in capsys.readouterr().out


def test_shrink_gif_fits_the_limit_and_keeps_the_playing_time(tmp_path):
    import imageio.v2 as imageio
    from PIL import Image, ImageSequence

    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 255, (48, 64, 3), dtype=np.uint8) for _ in range(24)]
    source = tmp_path / "noise.gif"
    imageio.mimsave(source, frames, duration=50, loop=0)
    limit = source.stat().st_size // 6  # more than smaller frames can give: frames go too
    size = figure_plots.shrink_gif(source, tmp_path / "small.gif", limit=limit)
    assert size == (tmp_path / "small.gif").stat().st_size <= limit
    with Image.open(tmp_path / "small.gif") as image:
        durations = [frame.info["duration"] for frame in ImageSequence.Iterator(image)]
    assert len(durations) < 24 and sum(durations) == pytest.approx(24 * 50, rel=0.05)


# ---- what is committed ------------------------------------------------------------------------


def _committed_images() -> list[Path]:
    """Images git tracks (or would: untracked, not ignored); without git, those under docs/."""
    import subprocess

    listed = subprocess.run(
        ["git", "-C", str(ROOT), "ls-files", "--cached", "--others", "--exclude-standard"],
        capture_output=True,
        text=True,
    )
    if listed.returncode != 0:
        return [p for p in (ROOT / "docs").rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES]
    paths = [ROOT / line for line in listed.stdout.splitlines()]
    return [p for p in paths if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]


def test_every_committed_image_is_at_most_150_kb():
    images = _committed_images()
    assert any(p.parent == ROOT / "docs" / "figures" for p in images)
    too_big = [
        f"{p.relative_to(ROOT)}: {p.stat().st_size:,} B"
        for p in images
        if p.stat().st_size > figure_plots.MAX_BYTES
    ]
    assert not too_big, too_big


def test_reference_curves_record_their_source_and_fit_their_steps():
    for path in figure_data.REFERENCES.glob("*.json"):
        data = json.loads(path.read_text())
        assert {"repository", "files", "commit"} <= set(data["source"]), path
        assert data["env_version"] and data["evaluation"], path
        for env_id, entry in data["envs"].items():
            returns = np.asarray(entry["returns"])
            assert returns.shape[1] == len(entry.get("steps", data["steps"])), (path, env_id)
    cheetah = figure_data.read_reference("td3_paper", "rl_jax/HalfCheetah-v5")
    assert cheetah.returns.shape == (10, 101) and 9000 < cheetah.mean_at(1_000_000) < 10_000
    # CrossQ's runs give the 300k anchors the SAC and PPO issue quotes from the same files.
    anchors = {"HalfCheetah": 10_012, "Hopper": 2_644, "Walker2d": 5_941, "Ant": 5_712}
    for name, anchor in anchors.items():
        crossq = figure_data.read_reference("crossq_simbav2", f"rl_jax/{name}-v5")
        assert crossq.returns.shape == (10, 101), name
        assert round(crossq.mean_at(300_000)) == anchor, name
        assert crossq.returns_at(300_000).shape == (10,)
    # SAC on Ant-v5 itself: 10 runs every 25,000 steps to 1M; their mean at 300k is the figure
    # RESULTS.md quotes beside the v4 curve's.
    ant_v5 = figure_data.read_reference("sac_sb3_v5", "rl_jax/Ant-v5")
    assert ant_v5.returns.shape == (10, 40) and ant_v5.source_env == "Ant-v5"
    assert round(ant_v5.mean_at(300_000)) == 2_226


def test_the_manifest_names_only_kinds_and_keys_the_command_knows():
    manifest = figures.read_manifest(figures.MANIFEST)
    assert set(manifest) <= set(figures.KINDS)
