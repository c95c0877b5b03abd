"""The growth law beside the wear model: windows taken in, scored eight windows ahead."""

import math

import numpy as np
import pytest
from reducer_twin.core.trend_score import FORECAST_ERROR_CAP, FORECAST_MEMORY
from reducer_twin.core.trend_score import FORECAST_PRIOR_WINDOWS
from reducer_twin.core.trend_score import SCORE_AFTER, SCORE_LAG, TrendScore
from reducer_twin.core.units import ARCMIN

NOISE = 0.03 * ARCMIN


def _lost_motion(a):
    """Return the windows' lost motion, linear in the exposure ``a`` [m]."""
    return 0.6 * ARCMIN + 2.0 * ARCMIN * a / 1e-6


def _scored_lost_motion(snap):
    """Return the lost motion of the window a snapshot's prediction is scored on."""
    return _lost_motion(1e-8 * (snap['windows'] + SCORE_LAG - 0.5))


def _feed(score, windows, model_predictive, start=0, p0=0.5):
    """Step ``score`` through windows of a linear law; return the exposures used."""
    exposures = []
    for k in range(start, start + windows):
        a = 1e-8 * (k + 0.5)
        score.add(a, _lost_motion(a), NOISE ** 2, NOISE ** 2, 1.0, model_predictive, p0)
        score.after_window(True, dict)
        exposures.append(a)
    return exposures


def test_windows_are_scored_only_after_settling_and_against_lagged_predictions():
    calls = []

    def model(snap):
        calls.append(snap)
        return 1.0, NOISE ** 2    # a wear model far off: every scored window favours the law

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
    model = lambda snap: (0.0, NOISE ** 2)     # noqa: E731
    _feed(score, 20, model)
    scored = score.scored
    score.restart()
    _feed(score, SCORE_AFTER + SCORE_LAG, model, start=20)
    assert score.scored == scored       # the new snapshots are not yet SCORE_LAG old
    _feed(score, 2, model, start=20 + SCORE_AFTER + SCORE_LAG)
    assert score.scored == scored + 2


def test_the_law_predicts_a_window_as_it_stood_when_the_snapshot_was_taken():
    # The score of a window is the law's density from the snapshot SCORE_LAG windows back:
    # today's sums less the windows added since.
    seen = {}

    def model(snap):
        seen['snap'] = snap
        return 0.6 * ARCMIN, NOISE ** 2

    fed = SCORE_AFTER + SCORE_LAG
    score = TrendScore()
    _feed(score, fed, model)
    before = score.score
    # The oldest snapshot kept was taken after window fed - SCORE_LAG (its law had those
    # windows and that one).
    late = TrendScore()
    _feed(late, fed - SCORE_LAG + 1, model)
    a = 1e-8 * (fed + 0.5)
    z = _lost_motion(a)
    score.add(a, z, NOISE ** 2, NOISE ** 2, 1.0, model, 0.5)
    lw, mean, var = late.law.predictive(a, NOISE ** 2)
    # Both means are scored under one variance, the mean of the two predictive variances.
    w = np.exp(lw)
    v_law = w @ (var + mean ** 2) - (w @ mean) ** 2
    v = 0.5 * (2.0 * NOISE ** 2 + v_law)
    # Each squared error counts up to the cap (this wear model is far off).
    law = math.log(w @ np.exp(-0.5 * np.minimum((z - mean) ** 2 / v, FORECAST_ERROR_CAP)))
    wear_model = -0.5 * min((z - 0.6 * ARCMIN) ** 2 / v, FORECAST_ERROR_CAP)
    assert seen['snap']['windows'] == late.law.windows
    assert score.score - before == pytest.approx(law - wear_model, rel=1e-9)


def test_a_wider_wear_model_of_the_same_mean_loses_nothing_to_the_law():
    # Both predict the windows' law; the wear model's variance is ten times the law's sd.
    # Under their own variances the law would win by about ln 10 a window; the choice
    # between two extrapolations is their means'.
    def exact_but_wide(snap):
        return _scored_lost_motion(snap), (10.0 * NOISE) ** 2

    score = TrendScore()
    _feed(score, SCORE_AFTER + SCORE_LAG + 20, exact_but_wide)
    assert score.scored == SCORE_AFTER + 20
    assert abs(score.score) < 0.05 * score.scored


def test_a_window_far_from_both_means_moves_the_score_no_more_than_the_cap():
    fed = SCORE_AFTER + SCORE_LAG
    score = TrendScore()
    model = lambda snap: (0.7 * ARCMIN, NOISE ** 2)     # noqa: E731
    _feed(score, fed, model)
    before = score.score
    a = 1e-8 * (fed + 0.5)
    # A window 10 arcmin off (a jump, a misread window): each squared error counts up to
    # the cap: both are capped, and the window tells neither law.
    score.add(a, _lost_motion(a) + 10.0 * ARCMIN, NOISE ** 2, NOISE ** 2, 1.0, model, 0.5)
    assert score.score == pytest.approx(before, abs=1e-9)


def test_lagged_predictions_that_hold_leave_the_forecast_scale_at_one():
    # A wear model that predicts the windows' law exactly, within the noise it claims.
    score = TrendScore()
    _feed(score, 60, lambda snap: (_scored_lost_motion(snap), 0.0), p0=0.0)
    assert score.scored > 30 and score.forecast_scale() == 1.0


def test_lagged_predictions_that_miss_by_three_sds_widen_by_their_squared_error():
    # Where neither model is the unit's growth, their predictions eight windows ahead
    # miss by more than they claim: the remaining life's rate variances are widened by the
    # forgotten mean of the squared errors (pipeline.EstimatorStage.record).
    score = TrendScore()
    miss = 3.0 * math.sqrt(2.0) * NOISE     # 3 sd of the prediction with the window's noise

    def model(snap):
        return _scored_lost_motion(snap) + miss, NOISE ** 2

    _feed(score, 200, model, p0=0.0)
    # Nine, shrunk towards 1 by the prior's windows against the memory's.
    steady = (FORECAST_PRIOR_WINDOWS + 9.0 * FORECAST_MEMORY) / (
        FORECAST_PRIOR_WINDOWS + FORECAST_MEMORY)
    assert score.forecast_scale() == pytest.approx(steady, rel=0.02)


def test_one_misread_window_counts_no_more_than_the_cap():
    score = TrendScore()
    k = 0
    while not score.scored:
        _feed(score, 1, lambda snap: (0.0, 0.0), start=k, p0=0.0)
        k += 1
    assert score.forecast_scale() <= (FORECAST_PRIOR_WINDOWS + FORECAST_ERROR_CAP) / (
        FORECAST_PRIOR_WINDOWS + 1.0)
