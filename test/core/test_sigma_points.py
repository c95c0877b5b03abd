"""
The scaled sigma points' weights (``reducer_twin.core.sigma_points``) are filterpy's.

The estimator computes Van der Merwe's weights itself (importing filterpy's package
costs half a second of scipy imports); they must be the very numbers filterpy's
``MerweScaledSigmaPoints`` gives, and sum to one.
"""

from filterpy.kalman import MerweScaledSigmaPoints
import numpy as np
import pytest
from reducer_twin.core.sigma_points import merwe_weights
from reducer_twin.core.wear_mixture import N_FILTER, SIGMA_ALPHA, SIGMA_BETA, SIGMA_KAPPA


@pytest.mark.parametrize('n, alpha, beta, kappa', [
    (N_FILTER, SIGMA_ALPHA, SIGMA_BETA, SIGMA_KAPPA),      # the estimator's points
    (3, 1e-3, 2.0, 0.0), (2, 0.5, 2.0, 1.0), (7, 0.1, 0.0, 3.0 - 7),
])
def test_the_weights_are_filterpys_to_the_last_bit(n, alpha, beta, kappa):
    points = MerweScaledSigmaPoints(n, alpha=alpha, beta=beta, kappa=kappa)
    Wm, Wc = merwe_weights(n, alpha, beta, kappa)
    np.testing.assert_array_equal(Wm, points.Wm)
    np.testing.assert_array_equal(Wc, points.Wc)
    assert Wm.shape == Wc.shape == (2 * n + 1,)
    assert np.sum(Wm) == pytest.approx(1.0, abs=1e-9)
