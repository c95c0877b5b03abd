"""
The observed growth law beside the wear model, and the score that weighs the two.

:class:`TrendScore` keeps the growth law (:class:`.growth.GrowthTrend`) of one reducer,
takes each usable window into it, and scores the window against the predictions both
models made :data:`SCORE_LAG` windows before (prequential log score, Dawid 1984): the
sum of the log predictive densities of the law less those of the wear model moves the
probability that the law, not the model's curve, holds
(:attr:`.estimator.WearEstimator.trend_probability`). The wear model's part of each
prediction is the estimator's own (it is given as a function).

Each window scores the two predicted means under one variance, the mean of the two
predictive variances: the choice is between two extrapolations, which their means decide.
Under each model's own variance the sharper of two predictions that both hold wins by the
ratio of their sds on every window, and the wear model predicts eight windows ahead
through its rate's uncertainty, which the law's fitted growth does not carry as widely. On
the model's own simulator, 300 h from new, both predicted the windows alike and both wider
than their errors (squared errors 0.3-0.6 and 0.5-0.8 of their variances), the law's sd
0.6 of the model's: the law won by about 0.2 nats a window, took the remaining life in 21
of 30 joints and put its P50 at a third of the truth (``bench_early_life.py``). On the
means, a law that predicts no better than the curve gains nothing; one whose means do
still wins by their squared errors. Each squared error counts up to
:data:`FORECAST_ERROR_CAP` variances: under one variance the score of a window far from
both means grows with its distance times the means' difference (a lost motion that jumped
by 10 µm of wear moved it by 6 nats a window), and a jump or a misread window tells
neither law.

The same lagged predictions say how well the two models extrapolate at all: the squared
error of their mixture, in its own predictive sds, has mean 1 when the predictions are
calibrated. Where neither model is the unit's growth (a run-in then a straight line, a
rate that steps), the lagged errors exceed what both claim, and :meth:`TrendScore.
forecast_scale` (their mean, forgotten over :data:`FORECAST_MEMORY` windows, at least 1)
is the factor by which the variance of the rate the remaining life extrapolates with is
widened (:meth:`.pipeline.EstimatorStage.record`). ``bench_accuracy.py`` prints it at the
end of each life (seed 1, median per unit): 1.00 on the model's simulator, 1.24 on the
independent generator, 2.52 on the third generator.
"""

import math

import numpy as np

from .gaussian_sum import logsumexp, mixture_moments
from .growth import GrowthTrend

SCORE_AFTER = 8
"""Usable windows both models have seen before their predictions are scored."""

SCORE_LAG = 8
"""
Windows between a model's prediction and the window it is scored on.

The remaining life is an extrapolation, so the two models are weighed by how well each
extrapolates: each usable window is scored against the prediction both made
``SCORE_LAG`` windows earlier, not the one-step prediction. The wear model follows a
lost motion that grows unlike its curve by moving its rate every window, which its
one-step predictions hide; eight windows ahead they show it. Measured on the independent
generator (bench_accuracy, 120 windows a life; lags of 4, 8 and 16 windows gave the same
figures within a unit): seed 1 RUL P50 within 30 % at 60 % of life 88 -> 92 %,
alpha-lambda 84/84 -> 88/88 %; seed 2 alpha-lambda 83/90 -> 86/90 %; the model generator
unchanged.
"""


FORECAST_MEMORY = 40.0
"""Scored windows over which the lagged errors' mean is forgotten (time constant)."""

FORECAST_PRIOR_WINDOWS = 8.0
"""Windows of squared error 1 the mean starts from (a few errors do not move it alone)."""

FORECAST_ERROR_CAP = 16.0
"""
Largest squared error counted [predictive variances] (4 sd, the estimator's outlier gate).

A misread window is the window analysis', not a sign that the growth is mispredicted;
beyond the cap it counts as the cap.
"""


class TrendScore:
    """
    A reducer's growth law and its score against the wear model.

    Parameters
    ----------
    new_probability : float
        Prior probability that the law counts from a new unit (:class:`.growth.GrowthTrend`).
    origin : float
        The law's exposure before the estimator started [m] (a service time's).

    Attributes
    ----------
    law : GrowthTrend
        The growth law.
    lagged : list of dict
        Snapshots the predictions start from, the oldest :data:`SCORE_LAG` windows back.
    recent : list of list
        ``[A, z, R]`` of the latest windows (their terms in ``recent_terms``): the law as
        a snapshot saw it is today's less them.
    score, scored : float, int
        The summed log-score difference (law less model) and the windows in it.
    forecast : list of float
        Forgotten sums ``[Σ 1, Σ e²]`` of the lagged predictions' squared errors ``e²``.
    settle : int
        Usable windows still to come before snapshots are kept again.

    """

    def __init__(self, new_probability=1.0, origin=0.0):
        self.law = GrowthTrend(new_probability, origin)
        self.lagged = []
        self.recent = []
        self.recent_terms = []
        self.score = 0.0
        self.scored = 0
        self.settle = 0
        self.forecast = [0.0, 0.0]

    def restart(self):
        """
        Score again only on predictions made :data:`SCORE_AFTER` usable windows from here.

        The predictions made before were of another reducer (the rate searched again);
        nor are those made while the data choose it again scored.
        """
        self.lagged = []
        self.settle = SCORE_AFTER + 1     # this window counts down the first

    def add(self, exposure, z, R_score, R, rho, model_predictive, p0):
        """
        Score both models' predictions of ``z``, then add it to the growth law.

        Parameters
        ----------
        exposure : float
            Archard exposure of the window's middle since the estimator started [m].
        z : float
            The window's lost motion [rad].
        R_score : float
            Its noise for the scores (the noise scale's and the growth within the window
            included, no Student-t weight: the same for both models) [rad²].
        R : float
            The noise the law takes it with (``rho`` and the Student-t weight in it); the
            law keeps ``R/rho`` and applies the latest ``rho`` to all its windows [rad²].
        rho : float
            The learnt noise scale.
        model_predictive : callable
            ``(snapshot)``: the wear model's predictive mean of ``z`` from a snapshot and
            its variance without the window's noise [rad, rad²].
        p0 : float
            Prior probability of the law (:meth:`probability`).

        """
        self.law.set_noise_scale(rho)
        if len(self.lagged) == SCORE_LAG and self.law.windows >= SCORE_AFTER:
            snap = self.lagged[0]
            m_model, v_model = model_predictive(snap)
            v_model = v_model + R_score
            lw, mean, var = self._law_predictive(snap, exposure, R_score)
            m_law, v_law = mixture_moments(lw, mean[:, None], var[:, None, None])
            # Both models' means, under one variance (the module's docstring).
            v_score = 0.5 * (v_model + float(v_law[0, 0]))
            log_model = -0.5 * min((z - m_model) ** 2 / v_score, FORECAST_ERROR_CAP)
            log_law = logsumexp(lw - 0.5 * np.minimum((z - mean) ** 2 / v_score,
                                                      FORECAST_ERROR_CAP))
            # The error of the two models' mixture, as it stood, in its own sds.
            p = self.probability(p0)
            with np.errstate(divide='ignore'):     # p of 0 or 1: one model alone
                m_mix, v_mix = mixture_moments(np.log([1.0 - p, p]), np.array([[m_model], m_law]),
                                               np.array([[[v_model]], v_law]))
            self._count_forecast(float((z - m_mix[0]) ** 2 / v_mix[0, 0]))
            self.score += log_law - log_model
            self.scored += 1
        terms = self.law.terms(exposure, z, R / rho)
        self.law.add_terms(terms)
        self.recent = (self.recent + [[exposure + self.law.origin, z, R / rho]])[-SCORE_LAG:]
        self.recent_terms = (self.recent_terms + [terms])[-SCORE_LAG:]

    def _law_predictive(self, snap, exposure, R):
        """Return the law's predictive mixture ``(log_weights, means, variances)`` at ``snap``."""
        since = self.law.windows - snap['windows']
        law = self.law.rolled_back(self.recent_terms[len(self.recent_terms) - since:],
                                   snap['growth_exposure'])
        return law.predictive(exposure, R)

    def _count_forecast(self, e2):
        """Take one lagged squared error (in predictive variances) into the forgotten mean."""
        keep = 1.0 - 1.0 / FORECAST_MEMORY
        e2 = min(e2, FORECAST_ERROR_CAP) if math.isfinite(e2) else FORECAST_ERROR_CAP
        self.forecast = [keep * self.forecast[0] + 1.0, keep * self.forecast[1] + e2]

    def forecast_scale(self):
        """
        Return the factor (>= 1) by which the lagged predictions' variance fell short.

        The forgotten mean of their squared errors, from :data:`FORECAST_PRIOR_WINDOWS`
        windows of 1; never below 1 (the lagged errors tell a growth the models cannot
        follow, not that the rest of the interval is too wide).
        """
        n, total = self.forecast
        return max(1.0, (FORECAST_PRIOR_WINDOWS + total) / (FORECAST_PRIOR_WINDOWS + n))

    def after_window(self, usable, snapshot):
        """
        Count a window down while settling, then keep a snapshot of where it ends.

        ``usable``: the window gave a lost motion; ``snapshot()``: the wear model's part
        (:meth:`.estimator.WearEstimator._snapshot`), to which the law's is added.
        """
        if self.settle and usable:
            self.settle -= 1
        if not self.settle:
            snap = snapshot()
            snap.update(windows=self.law.windows, growth_exposure=self.law.exposure)
            self.lagged = (self.lagged + [snap])[-SCORE_LAG:]

    def probability(self, p0):
        """Return the probability the law holds: prior ``p0`` moved by the score."""
        if p0 in (0.0, 1.0):
            return p0
        logit = math.log(p0 / (1.0 - p0)) + self.score
        return 1.0 / (1.0 + math.exp(-logit)) if logit > -700.0 else 0.0
