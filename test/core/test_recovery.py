"""
Persistent disagreement (``reducer_twin.core.recovery``): never gated out.

A drift of one sign within the gate releases the rate once its average has held beyond
the limit for two windows; scores that change sign never do; outliers in a row, or a
held drift with outliers, spread the rate again over the prior's range, with the wear
free to follow and the weights about the current rate.
"""

import math

import numpy as np
import pytest
from reducer_twin.core.gaussian_sum import mixture_moments
from reducer_twin.core.recovery import (
    Disagreement, RATE_RELEASE_SD, release_rate, respread, TREND_LIMIT, TREND_MEMORY)


def _judge(scores, outliers=None, max_consecutive=3):
    d, consecutive, said = Disagreement(), 0, []
    for k, score in enumerate(scores):
        outlier = bool(outliers and outliers[k])
        consecutive = consecutive + 1 if outlier else 0
        said.append(d.judge(score, outlier, consecutive, max_consecutive))
    return said, d


def test_a_drift_within_the_gate_releases_the_rate_after_two_windows_beyond_the_limit():
    said, d = _judge([3.0] * 3)
    # Averages 0.9, 1.53, 1.97: beyond the limit from the second window on.
    assert (1 - TREND_MEMORY) * 3.0 < TREND_LIMIT < (1 - TREND_MEMORY ** 2) * 3.0
    assert said == [None, None, 'release'] and d.count == 2


def test_scores_that_change_sign_never_call_for_a_recovery():
    said, _ = _judge([2.5, -2.5] * 20)
    assert said == [None] * 40


def test_outliers_in_a_row_call_for_a_respread():
    said, _ = _judge([0.0, 0.0, 0.0], outliers=[True, True, True])
    assert said == [None, None, 'respread']


def test_a_held_drift_that_includes_an_outlier_calls_for_a_respread_not_a_release():
    said, _ = _judge([3.0, 3.0, 6.0], outliers=[False, False, True])
    assert said[-1] == 'respread'


def test_clear_starts_over():
    _, d = _judge([3.0] * 3)
    d.clear()
    assert d.trend == 0.0 and d.count == 0


def test_release_raises_the_rates_variance_only():
    P = np.tile(np.eye(3), (2, 1, 1))
    release_rate(P)
    np.testing.assert_array_equal(P[:, 1, 1], [1.0 + RATE_RELEASE_SD ** 2] * 2)
    np.testing.assert_array_equal(P[:, 0, 0], [1.0, 1.0])
    assert P[0, 0, 1] == 0.0


def test_respread_covers_the_prior_rates_lets_the_wear_follow_and_weighs_about_now():
    m = np.array([2e-6, 1.0, 0.1e-6])
    P = np.array([[1e-14, 1e-8, 0.0], [1e-8, 0.01, 0.0], [0.0, 0.0, 1e-14]])
    thetas = np.arange(-6.0, 14.0 + 0.25, 0.5)
    lw, means, covs = respread(m, P, thetas, 0.3, 4e-14)
    assert lw.size == thetas.size and np.exp(lw).sum() == pytest.approx(1.0)
    np.testing.assert_allclose(means[:, 1], thetas)
    np.testing.assert_array_equal(means[:, [0, 2]], np.tile(m[[0, 2]], (thetas.size, 1)))
    assert np.all(covs[:, 1, 1] == 0.09) and np.all(covs[:, 0, 1] == 0.0)
    assert np.all(covs[:, 0, 0] == 1e-14 + 4e-14)
    assert thetas[np.argmax(lw)] == pytest.approx(1.0)
    mean, _ = mixture_moments(lw, means, covs)
    assert mean[1] == pytest.approx(1.0, abs=0.5)
    # A bump of sd max(3 sqrt(P_θθ), 2) = 2 about the current rate.
    assert lw[np.argmax(lw)] - lw[np.searchsorted(thetas, 3.0)] == pytest.approx(
        0.5 * (2.0 / 2.0) ** 2)
    assert math.isfinite(lw.min())
