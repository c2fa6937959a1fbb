"""The Elo difference of a match and its interval, against numbers worked by hand."""

import math

import pytest

from rl_jax.envs.games.elo import elo_difference, elo_estimate


def test_elo_difference_at_scores_worked_by_hand():
    assert elo_difference(0.5) == 0.0
    assert math.copysign(1.0, elo_difference(0.5)) == 1.0  # no "-0" in a table
    # s = 10/11: 1/s - 1 = 0.1, log10 0.1 = -1, d = +400; and symmetric below one half
    assert elo_difference(10 / 11) == pytest.approx(400.0)
    assert elo_difference(1 / 11) == pytest.approx(-400.0)
    # s = 0.76: 1/s - 1 = 0.24/0.76 = 0.315789..., log10 = -0.500602, d = +200.24
    assert elo_difference(0.76) == pytest.approx(200.24, abs=0.01)
    assert elo_difference(1.0) == math.inf
    assert elo_difference(0.0) == -math.inf


def test_interval_of_60_wins_20_draws_20_losses():
    # s = (60 + 10) / 100 = 0.7, d = 400 log10(0.7 / 0.3) = 147.19;
    # var = (60 * 0.3^2 + 20 * 0.2^2 + 20 * 0.7^2) / 100 = (5.4 + 0.8 + 9.8) / 100 = 0.16,
    # se = sqrt(0.16 / 100) = 0.04, z(95%) = 1.95996: s in [0.62160, 0.77840],
    # d in [400 log10(0.62160 / 0.37840), 400 log10(0.77840 / 0.22160)] = [86.22, 218.25]
    estimate = elo_estimate(60, 20, 20)
    assert estimate.score == pytest.approx(0.7)
    assert estimate.score_low == pytest.approx(0.62160, abs=1e-5)
    assert estimate.score_high == pytest.approx(0.77840, abs=1e-5)
    assert estimate.difference == pytest.approx(147.19, abs=0.01)
    assert estimate.low == pytest.approx(86.22, abs=0.01)
    assert estimate.high == pytest.approx(218.25, abs=0.01)
    assert estimate.confidence == 0.95


def test_a_wider_confidence_widens_the_interval_and_the_view_flips_the_sign():
    narrow, wide = elo_estimate(60, 20, 20, 0.9), elo_estimate(60, 20, 20, 0.99)
    assert wide.low < narrow.low < narrow.difference < narrow.high < wide.high
    mirrored = elo_estimate(20, 20, 60)
    assert mirrored.difference == pytest.approx(-147.19, abs=0.01)
    assert (mirrored.low, mirrored.high) == pytest.approx((-218.25, -86.22), abs=0.01)


def test_one_sided_matches():
    # all draws: no spread, the point itself
    assert elo_estimate(0, 10, 0)[:3] == (0.0, 0.0, 0.0)
    # a clean sweep: the score's interval is [1, 1], every end infinite
    sweep = elo_estimate(10, 0, 0)
    assert sweep.difference == sweep.low == sweep.high == math.inf
    # 9 wins and a loss: s = 0.9, se = sqrt(0.09 / 10) = 0.0949, s + 1.96 se > 1 is clipped
    nearly = elo_estimate(9, 0, 1)
    assert nearly.score_high == 1.0 and nearly.high == math.inf
    assert nearly.low == pytest.approx(400 * math.log10(0.71406 / 0.28594), abs=0.05)


@pytest.mark.parametrize("counts", [(0, 0, 0), (-1, 2, 3)], ids=["no games", "negative count"])
def test_bad_counts_are_refused(counts):
    with pytest.raises(ValueError):
        elo_estimate(*counts)
