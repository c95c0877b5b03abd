"""
Persistent disagreement between the windows and the wear model: never gated out.

The wear estimator (:mod:`.estimator`) hands every update's normalised innovation,
as its normal score, to :class:`Disagreement`. When the scores keep one sign (their
exponential average beyond ±:data:`TREND_LIMIT` for two windows) while each is inside
the gate, the rate has drifted from the model's: the variance of ``θ`` is raised by
:data:`RATE_RELEASE_SD` squared (:func:`release_rate`) and the data move the rate.
When ``max_consecutive_rejections`` outliers come in a row, or the disagreement
includes outliers (a jump of the lost motion, a rate many times the model's), the
components are spread again over the prior range of ``θ``, weighted about the
current estimate, and the wear variance is raised so that the innovation is one
standard deviation (:func:`respread`); the data then move the rate and the wear.
Both count as a recovery.
"""

import math

import numpy as np

from .gaussian_sum import logsumexp

TREND_MEMORY = 0.7
"""Factor of the exponential average of the normalised innovations."""

TREND_LIMIT = 1.5
"""Average normalised innovation that, held for two windows, counts as disagreement."""

RATE_RELEASE_SD = 0.3
"""
Sd added to ``ln s`` when a disagreement within the gate is found (a third of the rate).

A re-spread of the whole prior range overshot there: with the wear variance
raised to the innovation, the next window moved the wear past the truth, the
rate fell to let the truth catch up, and the disagreement came back the other
way, every ten windows (a unit built 2 µm tight, whose rate the prior puts
1.5x too low: P50 35-44 % short at 60 % of life; with the release: 0-5 %).
"""


class Disagreement:
    """
    The exponential average of the normalised innovations, and how long it has held.

    Attributes
    ----------
    trend : float
        The average (memory :data:`TREND_MEMORY`).
    count : int
        Windows in a row it has been beyond :data:`TREND_LIMIT`.

    """

    def __init__(self, trend=0.0, count=0):
        self.trend = float(trend)
        self.count = int(count)

    def judge(self, score, outlier, consecutive, max_consecutive):
        """
        Take one window's normal score; say which recovery it calls for.

        Parameters
        ----------
        score : float
            The window's normalised innovation, as its normal score.
        outlier : bool
            Beyond the gate.
        consecutive : int
            Outliers in a row, this window's included.
        max_consecutive : int
            Outliers in a row that call for a respread.

        Returns
        -------
        str or None
            ``'release'`` (a drift within the gate: :func:`release_rate`),
            ``'respread'`` (a jump: :func:`respread`) or None.

        """
        self.trend = TREND_MEMORY * self.trend + (1.0 - TREND_MEMORY) * score
        self.count = self.count + 1 if abs(self.trend) > TREND_LIMIT else 0
        if self.count >= 2 and not outlier and consecutive == 0:
            return 'release'
        if self.count >= 2 or consecutive >= max_consecutive:
            return 'respread'
        return None

    def clear(self):
        """Start over (after a recovery or a reset)."""
        self.trend = 0.0
        self.count = 0


def release_rate(P):
    """
    Let the rate move after a disagreement the gate admits (a drift, not a jump).

    The rate's variance (state 1) of every component is raised by
    :data:`RATE_RELEASE_SD` squared, in place; wear, as-built offset and bias keep
    theirs, so the next windows move the rate and the wear follows it.
    """
    P[:, 1, 1] += RATE_RELEASE_SD ** 2


def respread(m, P, thetas, sd, wear_var):
    """
    Spread one moment-matched state again over the prior's rates.

    Parameters
    ----------
    m, P : ndarray, shapes (n,), (n, n)
        The mixture's mean and covariance; state 0 the wear, state 1 ``θ``.
    thetas : ndarray
        The prior's component rates ``θ``.
    sd : float
        Each component's sd of ``θ``.
    wear_var : float
        Variance added to the wear (so that the innovation is one sd) [m²].

    Returns
    -------
    tuple of ndarray
        ``(lw, m, P)``: one component per rate, ``θ`` uncorrelated with the rest,
        weighted by a broad bump about the current rate (sd the larger of three times
        its sd and 2), so that the data choose again.

    """
    offsets = thetas - m[1]
    base = P.copy()
    base[1, :] = 0.0
    base[:, 1] = 0.0
    base[1, 1] = sd ** 2
    base[0, 0] += wear_var
    means = np.tile(m, (offsets.size, 1))
    means[:, 1] = m[1] + offsets
    lw = -0.5 * (offsets / max(3.0 * math.sqrt(P[1, 1]), 2.0)) ** 2
    lw -= logsumexp(lw)
    return lw, means, np.tile(base, (offsets.size, 1, 1))
