"""``bench.results`` summarises a row's run into RESULTS.md only once the run has ended: a run
stopped early (SIGTERM checkpoints and exits 0, and a long row is made in sittings) writes no
row, and says how to continue it."""

import json

import pytest

from bench import results


def _run(directory, total_steps, last_step, seeds=5):
    directory.mkdir()
    (directory / "config.json").write_text(json.dumps({"total_steps": total_steps}))
    lines = [
        json.dumps({"step": step, "seed": seed, "eval_return": step + seed, "wall_time": 1.0})
        for step in range(5_000, last_step + 1, 5_000)
        for seed in range(seeds)
    ]
    (directory / "metrics.jsonl").write_text("\n".join(lines) + "\n")
    return directory


@pytest.fixture
def runs(tmp_path, monkeypatch):
    monkeypatch.setattr(results, "RUNS", tmp_path / "results")
    return tmp_path


@pytest.mark.parametrize("where", ["the row's own directory", "elsewhere"])
def test_a_run_stopped_early_writes_no_row_and_says_how_to_continue(runs, where):
    results.RUNS.mkdir()
    own = where == "the row's own directory"
    run = _run((results.RUNS if own else runs) / "td3-humanoid", 300_000, last_step=35_000)
    with pytest.raises(SystemExit) as stopped:
        results.regenerate("td3-humanoid", from_run=run, write=False)
    message = str(stopped.value)
    assert "stopped at step 35,000 of 300,000" in message
    again = (
        "python -m bench.results td3-humanoid" if own else f"experiments/train.py --resume {run}"
    )
    assert again in message
    assert not (results.RUNS / "td3-humanoid.json").exists()


def test_a_finished_run_is_summarised_and_judged(runs):
    run = _run(runs / "td3-humanoid", total_steps=10_000, last_step=10_000)
    record = results.regenerate("td3-humanoid", from_run=run, write=False)
    assert record["summary"]["env_steps"] == 10_000
    assert record["summary"]["final"] == [10_000.0 + seed for seed in range(5)]
    assert record["goal_met"]  # Humanoid's goal is on time alone; the logged time is 1 s
    assert json.loads((results.RUNS / "td3-humanoid.json").read_text())["row"] == "td3-humanoid"


def test_a_match_row_scores_each_seed_by_its_wins_in_the_match(runs):
    run = _run(runs / "td3-humanoid", total_steps=10_000, last_step=10_000, seeds=3)
    summary = results.summarize(run)
    match = {
        "seeds": [  # in another order than the run's seeds: matched by seed, not position
            {"seed": 2, "wins": 19, "games": 20},
            {"seed": 0, "wins": 18, "games": 20},
            {"seed": 1, "wins": 10, "games": 20},
        ]
    }
    scored = results.with_match_scores(summary, match)
    assert scored["final"] == [90.0, 50.0, 95.0]
    assert scored["final_mean"] == pytest.approx(235 / 3)
    assert scored["best"] == summary["best"]  # the run's own evaluation stays beside it
    ok, cell = results.goal_met(results.Goal(90.0, 3), scored, None)
    assert not ok and "2/3 reach it" in cell
    with pytest.raises(SystemExit, match=r"no games of seeds \[1\]"):
        results.with_match_scores(summary, {"seeds": match["seeds"][:2]})


def test_a_mean_goal_below_100_keeps_its_decimals_and_a_near_miss_reads_as_one():
    goal = results.Goal(61.2, 5, "final", mean=True)
    ok, cell = results.goal_met(goal, {"final": [61.19] * 5}, None)
    assert not ok and cell == "final, mean of 5 >= 61.2: 61.190, **not met**"
    ok, cell = results.goal_met(goal, {"final": [61.24] * 5}, None)
    assert ok and cell == "final, mean of 5 >= 61.2: 61.2, met"
    ok, cell = results.goal_met(results.Goal(159.0, 5, mean=True), {"final": [170.4] * 5}, None)
    assert ok and cell == "final, mean of 5 >= 159: 170, met"
