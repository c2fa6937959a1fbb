"""The MinAtar benchmark's smoke run (``bench/bench_minatar``): its table has a row per
implementation and size, every rate positive and finite, and ours set against gymnax's."""

import math

from bench import bench_minatar


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


def test_tiny_run_makes_the_side_by_side_table():
    section = bench_minatar.run(
        games=("Breakout",), sizes=(2,), min_time=0.01, rounds=1, blocks={2: 5}
    )
    rows = [_cells(line) for line in section.splitlines() if line.startswith("| Breakout |")]
    implementations = [(row[1], row[2]) for row in rows]
    assert implementations == [
        (bench_minatar.NUMPY, "1"),
        (bench_minatar.GYMNAX, "2"),
        (bench_minatar.OURS, "2"),
    ]
    for row in rows:
        rate, versus_numpy = float(row[3].replace(",", "")), float(row[4].removesuffix("x"))
        assert math.isfinite(rate) and rate > 0, row
        assert math.isfinite(versus_numpy) and versus_numpy > 0, row
    assert rows[0][4] == "1.0x"
    assert [row[5] for row in rows[:2]] == ["-", "-"]
    ours_vs_gymnax = float(rows[2][5].removesuffix("x"))
    assert math.isfinite(ours_vs_gymnax) and ours_vs_gymnax > 0


def test_small_ratios_keep_two_significant_digits():
    assert [bench_minatar.times(r) for r in (24.04, 1.0, 0.96, 0.5, 0.048, 0.0012)] == [
        "24.0x",
        "1.0x",
        "1.0x",
        "0.5x",
        "0.048x",
        "0.0012x",
    ]


def test_numpy_minatar_runs_every_game_without_sticky_actions():
    for game in bench_minatar.GAMES:
        once = bench_minatar.numpy_rollout(game, block=50)
        assert once() == 50
