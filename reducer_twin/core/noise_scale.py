"""
The observation noise of the wear estimator, learnt from its innovations.

The window fit reports a standard error for each lost motion it reads; the
window-to-window scatter may be larger (a noisy effort) or smaller (the reported
sd carries the fit's shape allowance, an error common to a unit's windows).
:class:`NoiseScale` learns the ratio ``ρ`` of the observed to the reported
variance from the estimator's recent innovations (covariance matching in the
manner of Mehra 1972, made robust), as :class:`.estimator.WearEstimator` uses it.
"""

import math

import numpy as np

NOISE_MEMORY = 41
"""Innovations kept to learn the observation-noise scale ``ρ``."""

NOISE_PRIOR_WINDOWS = 3.0
"""Weight, in innovations, of the prior ``ρ = 1`` in the noise-scale estimate."""

NOISE_SCALE_RANGE = (1.0 / 25.0, 25.0)
"""
Bounds of the learnt noise scale ``ρ``: the reported sd is trusted within a factor 5 either way.

The ceiling keeps a trend the model misses from drowning the data in noise. The floor
was 0.5 until measured: the window fit's reported sd overstates the window-to-window
scatter on many units (bench_accuracy prints the learnt value: 0.05-0.9 on the model
generator, median 0.10-0.19; 0.05-7.4 on the independent one, median 0.37-0.87, seeds
1-2: the reported sd carries the fit's shape allowance, an error common to a unit's
windows). With
0.5, R was up to 10x too large: the model generator's NIS mean 0.26 (median 0.08), the
independent generator's P10-P90 coverage 81-88 % (seeds 1-4). With the floor at 1/25 (and
the differences weighted, :meth:`NoiseScale.fit`): NIS 0.84-0.85 on the model
generator, coverage 76-85 % with each tail 6-14 % on the independent one.
"""

_CHI2_1_MEDIAN = 0.454936423119572
"""Median of the χ² distribution with one degree of freedom."""


class NoiseScale:
    """
    The learnt ratio ``ρ`` of the observed to the reported lost-motion variance.

    Parameters
    ----------
    innovations : list of list, optional
        Recent innovations ``[y, V, σ²]`` (as :meth:`state` gives them); default none.

    """

    def __init__(self, innovations=None):
        self.innovations = list(innovations or [])

    def add(self, y, v, sigma2):
        """Keep one innovation ``y`` [rad], its predicted variance ``V`` and reported ``σ²``."""
        self.innovations = (self.innovations + [[y, v, sigma2]])[-NOISE_MEMORY:]

    def state(self):
        """Return the innovations kept, as plain lists of floats."""
        return [[float(v) for v in row] for row in self.innovations]

    @property
    def value(self):
        """Return ``ρ`` (:meth:`fit`)."""
        return self.fit()[0]

    def fit(self):
        """
        Return ``ρ`` and its weight in innovations, the prior's included.

        From differences of successive innovations ``d = y_k - y_(k-1)``,
        whose variance for white innovations is
        ``V_k + V_(k-1) + ρ·(σ_k² + σ_(k-1)²)`` (``V`` the predicted variance
        of the lost motion, ``σ`` the reported sd): the ``ρ`` that puts the
        median of the normalised ``d²`` over the last :data:`NOISE_MEMORY`
        innovations at the median of χ²₁. A bias the model misses
        (innovations of one sign) cancels in the differences and is left to
        the disagreement test, not taken for noise. Each difference counts
        with the weight ``(ρs/(V + ρs))²``, ``s = σ_k² + σ_(k-1)²`` and ``V``
        its predicted part (a weighted median, the weights at ``ρ = 1``, then
        at the ``ρ`` they gave; their sum is the differences' effective
        number): where the prediction is far less certain than the window (a
        reducer's first windows) the difference says next to nothing about
        ``ρ``. The estimate is shrunk
        towards 1 in log with the weight of :data:`NOISE_PRIOR_WINDOWS`
        innovations and kept in :data:`NOISE_SCALE_RANGE`: a trend the model
        misses for long raises the differences too, and must not drown the data
        in noise; a reported sd larger than the scatter is learnt down as far.

        Returns
        -------
        tuple of float
            ``(ρ, weight)``.

        """
        if len(self.innovations) < 3:
            return 1.0, NOISE_PRIOR_WINDOWS
        y, v, s2 = np.array(self.innovations).T
        d2 = np.diff(y) ** 2
        v2 = v[1:] + v[:-1]
        s22 = s2[1:] + s2[:-1]
        # d²/(V + ρ·σ²) exceeds the χ²₁ median exactly while ρ is below
        # (d²/median - V)/σ²: the ρ that puts the median there is their (weighted) median.
        limits = (d2 / _CHI2_1_MEDIAN - v2) / s22
        order = np.argsort(limits)
        limits, v2, s22 = limits[order], v2[order], s22[order]
        rho = 1.0
        for _ in range(2):   # the weights at ρ = 1, then at the ρ they gave
            cum = np.cumsum((rho * s22 / (v2 + rho * s22)) ** 2)
            n = float(cum[-1])
            rho = float(limits[np.searchsorted(cum, 0.5 * n)])
            rho = min(max(rho, NOISE_SCALE_RANGE[0]), NOISE_SCALE_RANGE[1])
        return math.exp(n * math.log(rho) / (n + NOISE_PRIOR_WINDOWS)), n + NOISE_PRIOR_WINDOWS
