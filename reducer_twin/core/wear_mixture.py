"""
The wear estimator's Gaussian sum of unscented filters on ``[w, θ, b, c]``.

:class:`WearMixture` holds the components (log weights, means, covariances) and
moves them: the prediction through the process model of :mod:`.state_space`, the
correction by one window's lost motion ``z = h(w + b) + c + v`` (Student-t ``v``),
the projection onto the physical ranges, pruning and merging, a search of the
rate again over the prior's range, and the moment-matched estimate. What the
observations are judged by (the noise scale, the growth law, disagreement, the
service time) is :class:`.estimator.WearEstimator`'s, which holds one.

Why a Gaussian sum: the rate is known from the physics within a factor of a
few at best, and a reducer can wear 10 000 times faster than the model says
(lubrication lost, contamination, or simply a time-compressed recording read
as real time). One unscented filter cannot move ``θ`` that far (its sigma
points through ``exp(θ)`` blow the wear up), so the prior on ``θ`` is a
sum of Gaussian components (Alspach & Sorenson 1972), 0.5 apart over
``ln s0 - 6 .. ln s0 + 14`` with sd 0.3 each and weights from the prior
``N(ln s0, σ_θ²)`` (default sd 2: the Janakiraman coefficient moves 1 % for a
0.14 % change of the pressure-viscosity coefficient, physics notes section
2). Each component is an unscented filter on the full state (Julier &
Uhlmann 1997; scaled points of Wan & van der Merwe 2000,
``α = 1, β = 2, κ = 0``: all mean weights positive, points at ±2σ, the
weights of :func:`~.sigma_points.merwe_weights`, filterpy's numbers) whose weight follows its
predictive likelihood. Components whose weight falls below ``exp(-23)`` of
the best are dropped and components whose means come within a third of a
standard deviation are merged (moment matching), so a few filters run once
the rate is known. The numerics of the sum (points, moments, the update,
pruning and merging) are :mod:`.gaussian_sum`'s.
The estimate is the moment-matched mixture.

A wide prior (a reducer of unknown history) makes the first update strongly
nonlinear: the update is iterated by posterior linearisation
(García-Fernández et al. 2015) while the prior sd of ``w + b`` exceeds 1 µm.
"""

from dataclasses import dataclass
import math

import numpy as np

from .gaussian_sum import logsumexp as _logsumexp
from .gaussian_sum import mixture_moments, tidy, UnscentedTransform
from .recovery import release_rate, respread
from .service_time import service_update
from .state_space import lost_motion_curve, run_in_free_wear, unit_lost_motion
from .state_space import wear_from_run_in_free
from .units import UM
from .wear import run_in_factor

N_FILTER = 4
"""Dimension of the filter's state: the reducer's and the window fit's bias ``c``."""

SIGMA_ALPHA, SIGMA_BETA, SIGMA_KAPPA = 1.0, 2.0, 0.0
"""Scaled sigma-point parameters (Wan & van der Merwe 2000) for ``n = 4``."""

RATE_GRID = (-6.0, 14.0, 0.5, 0.3)
"""Components of the prior on ``θ``: from, to (relative to ln s0), spacing and sd."""


PRIOR_REACH = 4.0
"""Sds of their priors beyond which the as-built offset and the fit's bias are not taken."""

BIAS_SEPARATION = 0.01
"""Lost-motion growth across a window, in the window's sd, below which ``c`` is not updated."""


def prior_components(config, new_unit_probability=None):
    """
    Return the Gaussian-sum prior: log weights, means and covariances.

    Parameters
    ----------
    config : EstimatorConfig
        Estimator tuning.
    new_unit_probability : float, optional
        Overrides ``config.new_unit_probability`` (1 after a reducer is replaced).

    Returns
    -------
    tuple of ndarray
        ``(log_weights (C,), means (C, 4), covariances (C, 4, 4))`` over
        ``[w, ln s, b, c]``, weights normalised.

    """
    p_new = config.new_unit_probability if new_unit_probability is None else new_unit_probability
    lo, hi, step, sd = RATE_GRID
    theta0, sd0 = math.log(config.initial_rate_scale), config.initial_log_rate_scale_std
    if sd0 <= sd:
        thetas, comp_sd = np.array([theta0]), sd0
    else:
        thetas, comp_sd = theta0 + np.arange(lo, hi + 0.5 * step, step), sd
    log_prior = -0.5 * ((thetas - theta0) / sd0) ** 2
    hypotheses = [(p, w, s) for p, w, s in (
        (p_new, config.initial_wear, config.initial_wear_std),
        (1.0 - p_new, config.used_wear, config.used_wear_std)) if p > 0.0]
    lw, means, covs = [], [], []
    for p, wear, wear_sd in hypotheses:
        for theta, lp in zip(thetas, log_prior):
            lw.append(math.log(p) + lp)
            means.append([wear, theta, 0.0, 0.0])
            covs.append(np.diag([wear_sd ** 2, comp_sd ** 2, config.as_built_std ** 2,
                                 config.fit_bias_std ** 2]))
    lw = np.array(lw)
    return lw - _logsumexp(lw), np.array(means), np.array(covs)


@dataclass(frozen=True)
class Innovation:
    """
    What one window's lost motion said against the mixture's prediction of it.

    Attributes
    ----------
    y : float
        ``z - E[z]`` over the mixture [rad].
    variance : float
        Predicted variance of ``z`` without the window's noise, the growth within the
        window included [rad²].
    nis : float
        ``y²/(variance + ρ·σ²)``.
    spread : float
        The growth within the window over the mixture (weighted smear) [rad²].

    """

    y: float
    variance: float
    nis: float
    spread: float


class WearMixture:
    """
    Gaussian sum of unscented filters on ``x = [w, ln s, b, c]`` (see the module).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (process and observation model).
    config : EstimatorConfig
        Tuning (priors, process noise, robustness).
    new_unit_probability : float
        Weight of the new-unit hypothesis in the prior (:func:`prior_components`).

    """

    def __init__(self, params, config, new_unit_probability):
        self.params = params
        self.config = config
        self.h = lost_motion_curve(params)
        # The scaled sigma points (filterpy's MerweScaledSigmaPoints' weights, same numbers).
        self.ut = UnscentedTransform(N_FILTER, SIGMA_ALPHA, SIGMA_BETA, SIGMA_KAPPA)
        self.assign(*prior_components(config, new_unit_probability))

    def assign(self, lw, m, P):
        """Take components ``(log weights (C,), means (C, 4), covariances (C, 4, 4))``."""
        self.lw, self.m, self.P = lw, m, P
        self._moments = None

    @property
    def size(self):
        """Return the number of components."""
        return int(self.lw.size)

    # model functions -------------------------------------------------------------------

    def fx(self, X, increment):
        """Propagate sigma points: ``w' = W(S(w) + e^θ·Δa)``, the rest unchanged."""
        wp = self.params.wear
        out = X.copy()
        free = run_in_free_wear(X[..., 0], wp) + np.exp(X[..., 1]) * increment
        out[..., 0] = wear_from_run_in_free(free, wp)
        return out

    def hx(self, X):
        """Observe sigma points: the unit's lost motion plus the window fit's bias."""
        return unit_lost_motion(X[..., 0], X[..., 2], self.h) + X[..., 3]

    # steps -----------------------------------------------------------------------------

    def predict(self, exposure, increment):
        """
        Propagate every component over ``exposure`` operating seconds and ``increment``.

        ``increment`` is the run-in-free Archard wear at rate scale 1 [m]; the process
        noise ``diag(q_w, q_θ, 0, 0)·exposure`` is added.
        """
        if exposure == 0.0 and increment == 0.0:
            return
        m, P = self._propagated(self.m, self.P, increment, exposure)
        self.m, self.P = m, P
        self.project()

    def _propagated(self, m, P, increment, exposure):
        """Return components ``(m, P)`` predicted over ``increment`` and ``exposure``."""
        X = self.fx(self.ut.points(m, P), increment)
        m, P = self.ut.moments(X)
        c = self.config
        P[:, 0, 0] += c.wear_noise_density * exposure
        P[:, 1, 1] += c.log_rate_scale_noise_density * exposure
        return m, 0.5 * (P + np.swapaxes(P, 1, 2))

    def smear(self, increment):
        """
        Variance each component's wear growth within a window adds to its lost motion [rad²].

        A window's fit mixes samples from the start to the end of its exposure:
        with the lost motion growing by ``ΔLM`` over the window (the component's
        rate and slope times the window's Archard increment ``increment``), the
        spread of a uniform growth, ``ΔLM²/12``. Negligible for a real-time window,
        a large share of the noise for a time-compressed one.
        """
        if not increment:
            return np.zeros(self.lw.size)
        m = self.m
        step = 0.05 * UM
        u = m[:, 0] + m[:, 2]
        slope = (self.h(u + step) - self.h(u - step)) / (2 * step)
        wp = self.params.wear
        g = run_in_factor(np.maximum(m[:, 0], 0.0), wp) ** wp.roughness_exponent
        growth = slope * g * np.exp(m[:, 1]) * increment
        return growth * growth / 12.0

    def update(self, z, rho, sigma2, increment):
        """
        Correct every component with one window's lost motion.

        Parameters
        ----------
        z : float
            The window's lost motion [rad].
        rho : float
            The learnt noise scale (:class:`.noise_scale.NoiseScale`).
        sigma2 : float
            The window's reported variance [rad²] (floored by the caller).
        increment : float
            The window's Archard increment [m] (its growth: :meth:`smear`); 0 for none.

        Returns
        -------
        Innovation
            What the window said against the prediction.

        """
        nu = self.config.robust_dof
        smear = self.smear(increment)
        R = rho * sigma2 + smear
        m0, P0 = self.m, self.P
        X = self.ut.points(m0, P0)
        zc, szz, cxz = self.ut.observed(self.hx(X), X - self.ut.mean(X)[:, None, :])
        S = szz + R
        d2 = (z - zc) ** 2 / S
        w = np.exp(self.lw - self.lw.max())
        w /= w.sum()
        z_mix = float(w @ zc)
        v_mix = float(w @ (szz + smear + (zc - z_mix) ** 2))
        R = rho * sigma2
        y = z - z_mix
        nis = y * y / (v_mix + R)
        loglik = -0.5 * np.log(S) - 0.5 * (nu + 1.0) * np.log1p(d2 / nu)
        R_eff = (R + smear) * np.maximum(1.0, (nu + d2) / (nu + 1.0))
        # A window across which the lost motion does not grow adds nothing that tells the
        # fit's bias from the as-built offset: the bias is a consider state for it (Schmidt
        # 1966: its mean and variance stay, its covariances are updated). ``c`` and ``b``
        # are seen only as h(w + b) + c; the unscented update, whose slope changes as ``b``
        # moves, lent the pair a spurious separate identity, and a long recording at one
        # wear walked them along their ridge (measured: ``c`` from 0 to 4 prior sd and the
        # lost motion 30 % low under steady windows).
        consider = 12.0 * smear < (BIAS_SEPARATION ** 2) * sigma2
        # A component whose w + b spans over 1 µm (where h bends across it) is relinearised
        # about its posterior.
        wide = (P0[:, 0, 0] + P0[:, 2, 2] + 2.0 * P0[:, 0, 2]) > UM ** 2
        m, P = self.ut.posterior(m0, P0, z, R_eff, zc, szz, cxz, self.hx, wide, (consider, 3))
        lw = self.lw + loglik
        self.assign(lw - _logsumexp(lw), m, P)
        self.project()
        return Innovation(y, v_mix, nis, float(w @ smear))

    def predictive(self, m, P, increment, exposure):
        """
        Predictive mean and variance of ``z`` from one component ``(m (4,), P (4, 4))``.

        Predicted through ``increment`` [m] and ``exposure`` [s] with the process noise;
        the variance is without the window's noise [rad²].
        """
        m, P = self._propagated(m[None, :], P[None, :, :], increment, exposure)
        zc, szz = self.ut.observed(self.hx(self.ut.points(m, P)))
        return float(zc[0]), float(szz[0])

    def release_rate(self):
        """Release the rate of every component (:func:`.recovery.release_rate`)."""
        release_rate(self.P)
        self._moments = None

    def respread(self, y, s_mix):
        """
        Spread the components over the prior's range of ``θ`` again (:func:`.recovery.respread`).

        The wear's variance is raised so that the innovation ``y`` (of predicted
        variance ``s_mix``) is one sd.
        """
        m, P = mixture_moments(self.lw, self.m, self.P)
        lo, hi, step, sd = RATE_GRID
        theta0 = math.log(self.config.initial_rate_scale)
        thetas = theta0 + np.arange(lo, hi + 0.5 * step, step)
        step_w = 0.05 * UM
        slope = abs(float(self.h(m[0] + m[2] + step_w) - self.h(m[0] + m[2] - step_w))) / (
            2 * step_w)
        self.assign(*respread(m, P, thetas, sd, max(y * y - s_mix, 0.0) / max(slope, 1e-6) ** 2))

    def serviced(self, past, total, log_std):
        """
        Take a service time as one pseudo-observation (:func:`.service_time.service_update`).

        ``past`` and ``total`` the Archard exposure before the twin and in all [m],
        ``log_std`` the sd of the implied ``ln s``.
        """
        wp = self.params.wear
        self.assign(*service_update(self.ut, self.lw, self.m, self.P,
                                    lambda w: run_in_free_wear(w, wp), past, total, log_std))
        self.project()

    def project(self):
        """
        Project each component's mean onto the physical ranges (Simon & Chia 2002).

        ``w >= 0``; the as-built offset ``b`` and the fit's bias ``c`` within
        :data:`PRIOR_REACH` of their priors' sd. Without the bounds a
        component of the new-unit hypothesis could explain a worn unit by an
        as-built offset of 11 µm and a bias of 0.27 arcmin (11 and 5 sd): its
        Student-t weights keep it alive, and the mixture swung to it.
        """
        c = self.config
        np.maximum(self.m[:, 0], 0.0, out=self.m[:, 0])
        reach_b = PRIOR_REACH * c.as_built_std
        reach_c = PRIOR_REACH * c.fit_bias_std
        np.clip(self.m[:, 2], -reach_b, reach_b, out=self.m[:, 2])
        np.clip(self.m[:, 3], -reach_c, reach_c, out=self.m[:, 3])
        self._moments = None

    def tidy(self):
        """Drop negligible components, merge converged ones (:func:`.gaussian_sum.tidy`)."""
        self.assign(*tidy(self.lw, self.m, self.P, order_by=1))

    # the estimate ----------------------------------------------------------------------

    def estimate(self):
        """Return the moment-matched ``(x (4,), P (4, 4))``, computed when first read."""
        if self._moments is None:
            self._moments = mixture_moments(self.lw, self.m, self.P)
        return self._moments

    def lost_motion(self):
        """
        Return the mean and variance of the unit's own lost motion ``h(w + b)`` [rad, rad²].

        Over the mixture (without the fit's bias ``c``).
        """
        X = self.ut.points(self.m, self.P)
        zc, szz = self.ut.observed(unit_lost_motion(X[..., 0], X[..., 2], self.h))
        w = np.exp(self.lw - self.lw.max())
        w /= w.sum()
        mean = float(w @ zc)
        return mean, max(float(w @ (szz + (zc - mean) ** 2)), 0.0)
