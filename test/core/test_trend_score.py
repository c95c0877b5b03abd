"""The growth law beside the wear model: windows taken in, scored eight windows ahead."""

import math

import numpy as np
import pytest
from reducer_twin.core.trend_score import SCORE_AFTER, SCORE_LAG, TrendScore
from reducer_twin.core.units import ARCMIN

NOISE = 0.03 * ARCMIN


def _feed(score, windows, model_logpdf, start=0):
    """Step ``score`` through windows of a linear law; return the exposures used."""
    exposures = []
    for k in range(start, start + windows):
        a = 1e-8 * (k + 0.5)
        z = 0.6 * ARCMIN + 2.0 * ARCMIN * a / 1e-6
        score.add(a, z, NOISE ** 2, NOISE ** 2, 1.0, model_logpdf)
        score.after_window(True, dict)
        exposures.append(a)
    return exposures


def test_windows_are_scored_only_after_settling_and_against_lagged_predictions():
    calls = []

    def model(snap, z, R):
        calls.append(snap)
        return -1e3     # a wear model far off: every scored window favours the law

    score = TrendScore()
    _feed(score, SCORE_AFTER + SCORE_LAG + 5, model)
    # A snapshot is kept from the first window; the first is scored SCORE_LAG windows on,
    # once the law has SCORE_AFTER windows.
    assert score.scored == 5 + SCORE_AFTER
    assert len(calls) == score.scored and all(s['windows'] < score.law.windows for s in calls)
    assert score.probability(0.5) > 0.99
    assert score.probability(0.0) == 0.0 and score.probability(1.0) == 1.0


def test_a_restart_scores_nothing_until_new_predictions_are_old_enough():
    score = TrendScore()
    _feed(score, 20, lambda snap, z, R: 0.0)
    scored = score.scored
    score.restart()
    _feed(score, SCORE_AFTER + SCORE_LAG, lambda snap, z, R: 0.0, start=20)
    assert score.scored == scored       # the new snapshots are not yet SCORE_LAG old
    _feed(score, 2, lambda snap, z, R: 0.0, start=20 + SCORE_AFTER + SCORE_LAG)
    assert score.scored == scored + 2


def test_the_law_predicts_a_window_as_it_stood_when_the_snapshot_was_taken():
    # The score of a window is the law's density from the snapshot SCORE_LAG windows back:
    # today's sums less the windows added since.
    seen = {}

    def model(snap, z, R):
        seen['snap'] = snap
        return 0.0

    fed = SCORE_AFTER + SCORE_LAG
    score = TrendScore()
    _feed(score, fed, model)
    before = score.score
    # The oldest snapshot kept was taken after window fed - SCORE_LAG (its law had those
    # windows and that one).
    late = TrendScore()
    _feed(late, fed - SCORE_LAG + 1, lambda snap, z, R: 0.0)
    a = 1e-8 * (fed + 0.5)
    z = 0.6 * ARCMIN + 2.0 * ARCMIN * a / 1e-6
    score.add(a, z, NOISE ** 2, NOISE ** 2, 1.0, model)
    lw, mean, var = late.law.predictive(a, NOISE ** 2)
    expected = math.log(np.exp(lw) @ (np.exp(-0.5 * (z - mean) ** 2 / var) / np.sqrt(var)))
    assert seen['snap']['windows'] == late.law.windows
    assert score.score - before == pytest.approx(expected, rel=1e-9)
