"""The Elo difference that a match's wins, draws and losses imply, with a confidence interval.

A player who scores ``s`` per game (win 1, draw 1/2, loss 0) against another is, under the Elo
model ``s = 1 / (1 + 10 ** (-d / 400))``, ``d`` points stronger:

    d(s) = -400 * log10(1 / s - 1).

The interval is the normal approximation of the mean score over ``n`` games, mapped through
``d`` (which is increasing, so the ends map to the ends). Each game scores 1, 1/2 or 0, so the
per-game variance is the trinomial one, with the observed fractions ``w, l`` of wins and losses
and the draws in between:

    var = w (1 - s)^2 + (1 - w - l) (1/2 - s)^2 + l s^2,     se = sqrt(var / n),
    s_low, s_high = s -/+ z * se    (clipped to [0, 1]),    z = Phi^-1((1 + confidence) / 2).

A score of 0 or 1 (or an end clipped there) maps to an infinite difference: no finite match
bounds how much stronger a player who never dropped a point is. When all games end alike the
variance is 0 and the interval is the point itself; read such a match as a bound on one side.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import NamedTuple


class EloEstimate(NamedTuple):
    """The Elo difference of a match, from the first player's view, with its interval."""

    difference: float  # d(s): positive when the first player scored more than half
    low: float  # d at the low end of the score's interval
    high: float  # d at the high end
    score: float  # s: points per game, a win 1 and a draw 1/2
    score_low: float
    score_high: float
    confidence: float  # e.g. 0.95


def elo_difference(score: float) -> float:
    """The Elo difference ``-400 log10(1/s - 1)`` that a score ``s`` per game implies
    (``-inf`` at 0, ``inf`` at 1)."""
    if not 0.0 <= score <= 1.0:
        raise ValueError(f"a score per game lies in [0, 1], got {score}")
    if score == 0.0:
        return -math.inf
    if score == 1.0:
        return math.inf
    return 0.0 - 400.0 * math.log10(1.0 / score - 1.0)  # 0.0 -: no "-0" at an even score


def elo_estimate(wins: int, draws: int, losses: int, confidence: float = 0.95) -> EloEstimate:
    """The Elo difference of ``wins``, ``draws`` and ``losses`` and its interval at
    ``confidence``, by the normal approximation of the score (this module's formulas)."""
    games = wins + draws + losses
    if min(wins, draws, losses) < 0 or games == 0:
        raise ValueError(f"need non-negative counts and at least one game: {wins, draws, losses}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence lies strictly between 0 and 1, got {confidence}")
    score = (wins + 0.5 * draws) / games
    variance = (wins * (1.0 - score) ** 2 + draws * (0.5 - score) ** 2 + losses * score**2) / games
    z = NormalDist().inv_cdf(0.5 + confidence / 2.0)
    half_width = z * math.sqrt(variance / games)
    score_low = max(0.0, score - half_width)
    score_high = min(1.0, score + half_width)
    return EloEstimate(
        difference=elo_difference(score),
        low=elo_difference(score_low),
        high=elo_difference(score_high),
        score=score,
        score_low=score_low,
        score_high=score_high,
        confidence=confidence,
    )
