"""The log of the standard normal distribution function, against scipy's."""

import math

import numpy as np
import pytest
from reducer_twin.core.normal_cdf import ASYMPTOTIC_BELOW, log_ndtr
from scipy.special import log_ndtr as scipy_log_ndtr


@pytest.mark.parametrize('lo, hi, rtol', [(-60.0, ASYMPTOTIC_BELOW, 1e-15),
                                          (ASYMPTOTIC_BELOW, -5.0, 1e-15), (-5.0, 0.0, 1e-15),
                                          (0.0, 8.0, 3e-15)])
def test_log_ndtr_equals_scipys(lo, hi, rtol):
    """
    On each branch (asymptotic series, lower tail, centre, upper side) the values agree.

    Above 0, ``ln Φ(x) ≈ -Q(x)`` carries the relative error of ``erfc(x/sqrt 2)``, in
    which the rounding of ``x/sqrt 2`` is amplified ``2·(x/sqrt 2)²``-fold, in scipy's
    value as in this one: the two agree to 3e-15 up to x = 8 (|ln Φ| > 6e-16).
    """
    x = np.concatenate([np.linspace(lo, hi, 20_001),
                        np.random.default_rng(7).uniform(lo, hi, 5_000)])
    np.testing.assert_allclose(log_ndtr(x), scipy_log_ndtr(x), rtol=rtol, atol=0.0)


def test_log_ndtr_is_continuous_where_the_series_takes_over():
    """Either side of -20 the two forms give the same slope, ``-x`` to first order."""
    x = np.array([ASYMPTOTIC_BELOW - 1e-9, ASYMPTOTIC_BELOW])
    step = np.diff(log_ndtr(x))[0] / 1e-9
    assert step == pytest.approx(20.05, rel=1e-3)    # d/dx ln Φ = φ/Φ ≈ -x + 1/(-x)


def test_log_ndtr_far_in_the_upper_tail_is_minus_the_tail_mass():
    """``ln Φ(x) = ln(1 - Q(x)) ≈ -Q(x)``: no cancellation to 0 where Q is above 1e-300."""
    x = 30.0
    q = 0.5 * math.erfc(x / math.sqrt(2.0))
    assert log_ndtr(x) == pytest.approx(-q, rel=1e-15)


@pytest.mark.parametrize('x, expected', [(math.inf, 0.0), (-math.inf, -math.inf),
                                         (0.0, math.log(0.5))])
def test_log_ndtr_at_special_arguments(x, expected):
    """``Φ(+inf) = 1``, ``Φ(-inf) = 0`` and ``Φ(0) = 1/2``."""
    assert log_ndtr(x) == expected


def test_log_ndtr_keeps_the_shape_and_passes_nan_on():
    """Elementwise over any shape; NaN in, NaN out."""
    x = np.array([[0.0, np.nan], [-30.0, 3.0]])
    out = log_ndtr(x)
    assert out.shape == (2, 2)
    assert np.isnan(out[0, 1])
    np.testing.assert_allclose(out[[0, 1, 1], [0, 0, 1]],
                               scipy_log_ndtr(x[[0, 1, 1], [0, 0, 1]]), rtol=3e-15)
