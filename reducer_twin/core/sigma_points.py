"""
Weights of Van der Merwe's scaled sigma points, for the wear estimator's unscented filters.

With ``λ = α²(n + κ) − n`` the ``2n + 1`` points carry the mean weights
``Wm₀ = λ / (n + λ)``, ``Wmᵢ = 1 / (2(n + λ))`` and the covariance weights
``Wc₀ = Wm₀ + 1 − α² + β``, ``Wcᵢ = Wmᵢ`` (R. van der Merwe, *Sigma-Point Kalman
Filters for Probabilistic Inference in Dynamic State-Space Models*, PhD thesis, OGI
2004, section 3.2.2; R. Labbe, *Kalman and Bayesian Filters in Python*, ch. 10). The
arithmetic is filterpy's ``MerweScaledSigmaPoints._compute_weights``, term for term,
so the weights are the same numbers (``test/core/test_sigma_points.py`` checks them
against filterpy), without importing filterpy's package and the scipy.stats and
scipy.ndimage it pulls in.
"""

import numpy as np


def merwe_weights(n, alpha, beta, kappa):
    """
    Return the mean and covariance weights of ``2n + 1`` scaled sigma points.

    Parameters
    ----------
    n : int
        State dimension.
    alpha : float
        Spread of the points around the mean.
    beta : float
        Prior knowledge of the distribution (2 is optimal for a Gaussian).
    kappa : float
        Secondary scaling.

    Returns
    -------
    Wm, Wc : ndarray, shape (2n + 1,)
        Weights of the mean and of the covariance.

    """
    lambda_ = alpha ** 2 * (n + kappa) - n
    c = .5 / (n + lambda_)
    Wc = np.full(2 * n + 1, c)
    Wm = np.full(2 * n + 1, c)
    Wc[0] = lambda_ / (n + lambda_) + (1 - alpha ** 2 + beta)
    Wm[0] = lambda_ / (n + lambda_)
    return Wm, Wc
