"""
Lost-motion growth learnt from the window history: the observed-trend model.

The wear model (:mod:`.estimator`) predicts how lost motion grows with the
Archard exposure ``A`` (``Σ duty.archard_increment``: run-in-free Archard
wear at rate scale 1). A reducer may not follow it: its lost motion may grow
linearly in the exposure, or be more concave than the model's curve (wear
modes the model leaves out, a lost-motion mechanism other than flank wear).
This module learns the growth law from the observations instead::

    z = β + k·(A/A_now)^g + v        v ~ N(0, R)

``β`` the unit's new lost motion, ``k`` the growth so far (at ``A_now``,
the exposure of the latest window), ``g`` the exponent (``g = 1``: linear in
the exposure). The physics is the prior: ``g ~ N(0.7, 0.3²)`` (the model's
lost motion grows close to ``A^0.65-0.7`` once run in), ``β`` from the
as-built range (0.3-1.0 arcmin), ``k ~ N(0, (3 arcmin)²)`` cut to ``k >= 0``
(wear never takes lost motion away) once the windows place ``k`` within
:data:`TRUNCATE_BELOW` of its prior sd. Without the cut, windows that read
lower as a recording went on (a fit's bias settling, not wear) were taken for
negative growth, and the law, following them down, won over the wear model.

Given ``g`` the model is linear in ``(β, k)``, so the posterior is exact:
the weighted sums ``Σ w·x xᵀ``, ``Σ w·z·x``, ``Σ w·z²`` with
``x = [1, A^g]`` are kept for every ``g`` of a grid (0.2 .. 1.6 in steps of
0.02), which makes an update O(grid) and the state a few hundred numbers,
whatever the length of the history. The exposure is rescaled to ``A_now``
only when the posterior is formed (a factor ``A_now^-g`` per ``g``). Each
window's noise is the one the wear estimator used for it (Student-t weight
included), so the two models see the same data, with one difference: the
learnt noise scale ``ρ`` (:attr:`GrowthTrend.noise_scale`, the ratio of
observed to reported variance) is applied to every window when the
posterior is formed, not frozen into each window's weight when it came.
The estimator learns ``ρ`` over its first tens of windows; frozen, the
earliest windows (weighed with ``ρ = 1``) outweighed the later ones by the
``ρ`` learnt since, up to 25 times, and a few early windows read high
bent the law (measured: a unit whose windows scatter 3x their reported sd
had its P50 at 60 % of life +68 % long; with ``ρ`` applied to all, +22 %).

The law takes its windows with ``max(ρ, ρ_law)``, ``ρ_law`` its own residual
scatter (:meth:`GrowthTrend.residual_scale`). ``ρ`` is learnt from the
differences of successive innovations, which see only the noise that changes
from one window to the next; a slow error of the window readings (the load of
a duty's phase, a fit settling over a recording) is invisible to it, but not
to a law fitted over the whole history. Measured on 300-h recordings from new
of the independent generator (seeds 3-16): ``ρ`` 0.055 on a forearm whose
windows scatter about the best law at 0.6 of their reported variance, its
exponent read 0.75 ± 0.04 where the truth is 0.56 (with ``ρ_law``: ± 0.07; the
early-life interval holds 69-82 % of the true lives against 67-78 %, README
Figures).

:meth:`GrowthTrend.predictive` gives the one-step-ahead predictive density
of a window, which the estimator compares with its own (prequential log
score, Dawid 1984) to weigh the two models.
"""

import math

import numpy as np

from .noise_scale import NOISE_PRIOR_WINDOWS
from .normal_cdf import log_ndtr
from .units import ARCMIN, UM

EXPONENTS = np.round(np.arange(0.2, 1.6 + 1e-9, 0.02), 10)
"""Grid of growth exponents ``g``."""

EXPONENT_PRIOR = (0.7, 0.3)
"""Mean and sd of the prior on ``g`` (the model's curve, once run in)."""

NEW_PRIOR = (0.65 * ARCMIN, 0.25 * ARCMIN)
"""Mean and sd of the prior on ``β``, the unit's new lost motion [rad]."""

START_PRIOR = (1.65 * ARCMIN, 3.0 * ARCMIN)
"""
Mean and sd of the prior on ``β`` of a unit used before the twin started [rad].

The law's exposure counts from the twin's start, so ``β`` is the lost motion then:
anywhere from a new unit's (0.3 arcmin) to beyond the usual limit (3 arcmin), a
broad prior the first windows replace.
"""

START_EXPONENT_PRIOR = (1.0, 0.1)
"""
Mean and sd of the prior on ``g`` of a unit used before the twin started.

A law ``A_total^g0`` seen from an origin ``A_s`` mid-life grows as
``(A_s + A)^g0 - A_s^g0``: linear in ``A`` while ``A`` is small against ``A_s``,
towards ``A^g0`` only once the twin has seen more exposure than the unit had
before. A steep start from the twin's start is not the reducer's: it is the
window analysis settling (its first windows of a recording read low while its
pooled fits converge: 0.04-0.05 arcmin over the first 20-30 windows of a 150-h
recording of the independent generator, base joint at half its life), and with a
looser prior (0.3) the law took that start for a concave growth and won, its
remaining life 10 times the truth (15 600 h against 1 490). Read with the new
unit's prior (``β`` at 0.65 arcmin, ``g`` at 0.7), a unit met at 2 arcmin was bent
into a steep start that flattens, and its remaining life came out long: twins
started without state at 25-75 % of life on the independent generator had P10-P90
holding 62 % and 57 % of the true lives after 30 % of a life (seeds 1, 2), 30 % and
33 % of them below P10 (``bench_accuracy.py``, mid-life starts).
"""

GROWTH_PRIOR_SD = 3.0 * ARCMIN
"""Sd of the zero-mean prior on ``k``, the growth to date [rad]."""

TRUNCATE_BELOW = 0.05
"""Posterior sd of ``k``, in prior sds, below which ``k >= 0`` is imposed.

While the windows hardly place ``k`` the cut would only move the prior's half-normal mean
(2.4 arcmin) into the law."""

_MASS_NEGLIGIBLE_BEYOND = 8.3
"""Sds of ``k`` above zero beyond which the truncation's lost mass is taken as none."""

EXPOSURE_UNIT = UM
"""Unit of the exposure inside the sums [m] (keeps ``A^g`` and its square in range)."""


class GrowthTrend:
    """
    Bayesian power law of lost motion in Archard exposure (see the module).

    The sums are over windows with weight ``1/R``; the state is
    :meth:`state` / :meth:`from_state`.
    """

    def __init__(self, new_probability=1.0, origin=0.0):
        n = EXPONENTS.size
        self.new_probability = float(new_probability)   # prior odds of the law's origin
        # Exposure of a unit's service before the twin started [m], where known (its
        # service time at the duty seen since): the law then counts from new.
        self.origin = float(origin)
        self.sxx = np.zeros((n, 3))   # Σw, Σw·a, Σw·a² with a = A^g
        self.sxz = np.zeros((n, 2))   # Σw·z, Σw·z·a
        self.szz = 0.0                # Σw·z²
        self.windows = 0
        self.exposure = 0.0           # A_now [m], from the origin
        self.noise_scale = 1.0        # ρ, applied to every window's R
        self._cached = None

    # -- data ----------------------------------------------------------------------------

    def add(self, exposure, z, R):
        """
        Take one window into the sums.

        Parameters
        ----------
        exposure : float
            Archard exposure of the window's middle since the estimator started [m].
        z : float
            Observed lost motion [rad].
        R : float
            Its noise variance before the noise scale ``ρ`` [rad²] (> 0).

        """
        self.add_terms(self.terms(exposure, z, R))

    def terms(self, exposure, z, R):
        """Return a window's :func:`window_terms`, its exposure counted from the origin."""
        return window_terms(exposure + self.origin, z, R)

    def add_terms(self, terms):
        """Take one window's terms (:func:`window_terms`) into the sums."""
        xx, xz, zz = terms
        self.sxx += xx
        self.sxz += xz
        self.szz += zz
        self.windows += 1
        self._cached = None

    def rolled_back(self, terms, exposure):
        """
        Return the law as it was before the latest windows (a copy).

        Parameters
        ----------
        terms : sequence
            The latest windows' :func:`window_terms`, oldest first.
        exposure : float
            ``A_now`` then [m].

        Returns
        -------
        GrowthTrend
            The sums less those windows' terms (to rounding), at ``exposure``.

        """
        out = self.copy()
        for xx, xz, zz in reversed(terms):
            out.sxx -= xx
            out.sxz -= xz
            out.szz -= zz
        out.windows -= len(terms)
        out.exposure = float(exposure)
        out._cached = None
        return out

    def copy(self):
        """Return an independent duplicate: the sums and the exposure now."""
        out = GrowthTrend(self.new_probability, self.origin)
        out.sxx, out.sxz, out.szz = self.sxx.copy(), self.sxz.copy(), self.szz
        out.windows, out.exposure, out.noise_scale = self.windows, self.exposure, self.noise_scale
        out._cached = self._cached
        return out

    def set_noise_scale(self, rho):
        """Set ``ρ``, the factor on every window's noise variance (> 0)."""
        rho = float(rho)
        if rho != self.noise_scale:
            self.noise_scale = rho
            self._cached = None

    def advance(self, exposure):
        """Set the exposure now [m] since the estimator started (the end of the latest window)."""
        exposure = max(float(exposure) + self.origin, self.exposure)
        if exposure != self.exposure:
            self.exposure = exposure
            self._cached = None

    # -- posterior -----------------------------------------------------------------------

    def _posterior(self):
        """Return :meth:`_compute` at ``A_now``, kept until the sums or ``A_now`` change."""
        if self._cached is None:
            self._cached = self._compute()
        return self._cached

    def _compute(self, exposure=None):
        """
        Posterior of ``(β, k)`` for every ``g`` and origin, with ``a`` rescaled to ``A_ref``.

        Two origins of the law, weighed by their evidence from
        ``new_probability`` on: a unit new when the twin started (``β`` its new
        lost motion, :data:`NEW_PRIOR`, :data:`EXPONENT_PRIOR`) and one used
        before (``β`` the lost motion at the start, :data:`START_PRIOR`,
        :data:`START_EXPONENT_PRIOR`). Rows ``[0, G)`` are the first, ``[G, 2G)``
        the second; :meth:`_exponents` gives each row's ``g``.

        Returns
        -------
        tuple
            ``(log_weights (R,), means (R, 2), covariances (R, 2, 2), A_ref)``.

        """
        a_ref = (exposure if exposure is not None else self.exposure) / EXPOSURE_UNIT
        scale = a_ref ** -EXPONENTS if a_ref > 0.0 else np.ones_like(EXPONENTS)
        inv_rho = 1.0 / max(self.noise_scale, self.residual_scale())
        s0, s1, s2 = self.sxx.T * inv_rho
        z0, z1 = self.sxz.T * inv_rho
        parts = []
        for p, (beta0, beta_sd), (g0, g_sd) in (
                (self.new_probability, NEW_PRIOR, EXPONENT_PRIOR),
                (1.0 - self.new_probability, START_PRIOR, START_EXPONENT_PRIOR)):
            if p <= 0.0:
                continue
            prec_beta, prec_k = 1.0 / beta_sd ** 2, 1.0 / GROWTH_PRIOR_SD ** 2
            # The 2x2 precision L = [[l00, l01], [l01, l11]] per g, inverted in closed form.
            l00 = s0 + prec_beta
            l01 = s1 * scale
            l11 = s2 * scale * scale + prec_k
            det = l00 * l11 - l01 * l01
            r0 = z0 + prec_beta * beta0
            r1 = z1 * scale
            cov = np.empty((EXPONENTS.size, 2, 2))
            cov[:, 0, 0] = l11 / det
            cov[:, 0, 1] = cov[:, 1, 0] = -l01 / det
            cov[:, 1, 1] = l00 / det
            mean = np.empty((EXPONENTS.size, 2))
            mean[:, 0] = (l11 * r0 - l01 * r1) / det
            mean[:, 1] = (l00 * r1 - l01 * r0) / det
            quad = (self.szz * inv_rho + prec_beta * beta0 ** 2
                    - mean[:, 0] * r0 - mean[:, 1] * r1)
            logdet = np.log(det)
            # The evidence of each (origin, g): the priors' normalisations differ by origin.
            lw = (math.log(p) - math.log(beta_sd * g_sd) - 0.5 * quad - 0.5 * logdet
                  - 0.5 * ((EXPONENTS - g0) / g_sd) ** 2)
            half = EXPONENTS.size // 2     # the grid is odd: the median is its middle value
            if np.partition(cov[:, 1, 1], half)[half] < (TRUNCATE_BELOW * GROWTH_PRIOR_SD) ** 2:
                lw += _truncate_growth(mean, cov)
            parts.append((lw, mean, cov))
        if len(parts) == 1:
            lw, mean, cov = parts[0]
        else:
            lw, mean, cov = (np.concatenate(x) for x in zip(*parts))
        lw -= lw.max()
        lw -= math.log(np.exp(lw).sum())
        return lw, mean, cov, a_ref

    def residual_scale(self):
        """
        Return the law's own residual scatter, as a scale on the windows' noise.

        The smallest weighted residual sum of squares over the exponent grid, with
        ``β`` and ``k`` fitted freely (no prior), per degree of freedom, shrunk towards
        the learnt ``ρ`` with the weight its own prior has in it
        (:data:`.noise_scale.NOISE_PRIOR_WINDOWS` windows)::

            ρ_law = (n0·ρ + min_g RSS_g) / (n0 + n - 2)

        The posterior takes ``max(ρ, ρ_law)`` (see the module). 0 with fewer than three
        windows.

        Returns
        -------
        float
            ``ρ_law``.

        """
        n = self.windows
        if n < 3:
            return 0.0
        s0, s1, s2 = self.sxx.T
        z0, z1 = self.sxz.T
        det = s0 * s2 - s1 * s1
        fit = det > 1e-12 * s0 * s2
        if not fit.any():
            return 0.0
        rss = self.szz - (s2 * z0 * z0 - 2.0 * s1 * z0 * z1 + s0 * z1 * z1)[fit] / det[fit]
        best = max(float(rss.min()), 0.0)
        n0 = NOISE_PRIOR_WINDOWS
        return (n0 * self.noise_scale + best) / (n0 + n - 2)

    def _exponents(self, rows):
        """Return the ``g`` of each row of the posterior (one or both origins)."""
        return EXPONENTS if rows == EXPONENTS.size else np.concatenate([EXPONENTS, EXPONENTS])

    def predictive(self, exposure, R):
        """
        One-step-ahead predictive density of a window at ``exposure``.

        Parameters
        ----------
        exposure : float
            Archard exposure of the window's middle since the estimator started [m].
        R : float
            Noise variance of the window, ``ρ`` included [rad²].

        Returns
        -------
        tuple of ndarray
            ``(log_weights, means, variances)`` of the Gaussian mixture over ``g``.

        """
        lw, mean, cov, a_ref = self._posterior()
        g = self._exponents(lw.size)
        a = (max(exposure + self.origin, 0.0) / EXPOSURE_UNIT) ** g
        if a_ref > 0.0:
            a = a * a_ref ** -g
        x = np.stack([np.ones_like(a), a], axis=1)
        m = np.einsum('gi,gi->g', x, mean)
        v = np.einsum('gi,gij,gj->g', x, cov, x) + R
        return lw, m, v

    def summary(self):
        """
        Moment-matched posterior of ``(β, k, g)`` at ``A_now``.

        Returns
        -------
        tuple of ndarray
            Mean ``[β [rad], k [rad], g]`` and its 3x3 covariance.

        """
        lw, mean, cov, _ = self._posterior()
        w = np.exp(lw)
        full = np.concatenate([mean, self._exponents(lw.size)[:, None]], axis=1)
        m = w @ full
        d = full - m
        P = np.einsum('g,gi,gj->ij', w, d, d)
        P[:2, :2] += np.einsum('g,gij->ij', w, cov)
        return m, 0.5 * (P + P.T)

    # -- persistence ---------------------------------------------------------------------

    def state(self):
        """Return the sums as plain JSON-able data."""
        return {'sxx': [[float(v) for v in row] for row in self.sxx],
                'sxz': [[float(v) for v in row] for row in self.sxz],
                'szz': float(self.szz), 'windows': int(self.windows),
                'exposure': float(self.exposure), 'noise_scale': float(self.noise_scale),
                'new_probability': self.new_probability, 'origin': self.origin}

    @classmethod
    def from_state(cls, d, legacy_scale=1.0):
        """
        Restore from :meth:`state` output.

        Parameters
        ----------
        d : mapping
            The state.
        legacy_scale : float
            ``ρ`` to take for a state written before the sums were kept free
            of it (no ``noise_scale``): their windows' weights held the ``ρ``
            of their time, taken as this one, so the law is restored as it was.

        Raises
        ------
        ValueError
            If the sums do not fit the exponent grid, are not finite, or the
            noise scale is not a positive number.

        """
        # A state from before the law had two origins: it was placed as from new.
        out = cls(float(d.get('new_probability', 1.0)), float(d.get('origin', 0.0)))
        if not (0.0 <= out.new_probability <= 1.0 and math.isfinite(out.origin)
                and out.origin >= 0.0):
            raise ValueError(f'growth new_probability must lie in [0, 1] and origin be a '
                             f'finite number >= 0 m, got {out.new_probability!r} and '
                             f'{out.origin!r}')
        sxx = np.array(d['sxx'], dtype=float)
        sxz = np.array(d['sxz'], dtype=float)
        if sxx.shape != out.sxx.shape or sxz.shape != out.sxz.shape:
            raise ValueError(f'growth sums must have shapes {out.sxx.shape} and '
                             f'{out.sxz.shape}, got {sxx.shape} and {sxz.shape}')
        out.sxx, out.sxz = sxx, sxz
        out.szz = float(d['szz'])
        out.windows = int(d['windows'])
        out.exposure = float(d['exposure'])
        if not (np.all(np.isfinite(sxx)) and np.all(np.isfinite(sxz))
                and math.isfinite(out.szz) and math.isfinite(out.exposure)):
            raise ValueError('growth sums must be finite')
        if 'noise_scale' in d:
            out.noise_scale = float(d['noise_scale'])
        else:
            out.noise_scale = float(legacy_scale)
            out.sxx, out.sxz, out.szz = (v * out.noise_scale for v in (sxx, sxz, out.szz))
        if not (math.isfinite(out.noise_scale) and out.noise_scale > 0.0):
            raise ValueError(f'growth noise_scale must be a finite number > 0, got '
                             f'{out.noise_scale!r}')
        return out


def window_terms(exposure, z, R):
    """
    Return one window's terms of the sums ``Σ w·x xᵀ``, ``Σ w·z·x``, ``Σ w·z²``.

    Parameters
    ----------
    exposure : float
        Archard exposure of the window's middle [m].
    z : float
        Observed lost motion [rad].
    R : float
        Its noise variance before the noise scale ``ρ`` [rad²] (> 0).

    Returns
    -------
    tuple
        ``(xx (G, 3), xz (G, 2), zz)`` over the exponent grid.

    """
    a = (max(exposure, 0.0) / EXPOSURE_UNIT) ** EXPONENTS
    w = 1.0 / R
    xx = np.empty((EXPONENTS.size, 3))
    xx[:, 0] = w
    xx[:, 1] = w * a
    xx[:, 2] = w * (a * a)
    xz = np.empty((EXPONENTS.size, 2))
    xz[:, 0] = w * z
    xz[:, 1] = w * z * a
    return xx, xz, w * z * z


def _truncate_growth(mean, cov):
    """
    Restrict the growth ``k`` to ``k >= 0``: wear never takes lost motion away.

    The prior on ``k`` is the half-normal of :data:`GROWTH_PRIOR_SD`, so the
    posterior of ``(β, k)`` given ``g`` is its Gaussian truncated to
    ``k >= 0``. Its moments replace ``mean`` and ``cov`` in place (``β``
    follows ``k`` through their regression), and the log of the posterior
    mass kept, ``ln Φ(m_k/s_k)``, is returned to weigh the exponents.

    Parameters
    ----------
    mean : ndarray, shape (G, 2)
        Untruncated posterior means of ``(β, k)``, changed in place.
    cov : ndarray, shape (G, 2, 2)
        Their covariances, changed in place.

    Returns
    -------
    ndarray, shape (G,)
        ``ln Φ(m_k/s_k)`` per exponent.

    """
    s = np.sqrt(cov[:, 1, 1])
    a = -mean[:, 1] / s
    # Beyond 8.3 sd the mass cut off is below 6e-17: ln Φ rounds to 0 against the weights.
    log_mass = np.zeros_like(a)
    near = -a < _MASS_NEGLIGIBLE_BEYOND
    log_mass[near] = log_ndtr(-a[near])
    lam = np.exp(-0.5 * a * a - 0.5 * math.log(2.0 * math.pi) - log_mass)
    shift = s * lam
    shrink = 1.0 + a * lam - lam * lam
    gain = cov[:, 0, 1] / cov[:, 1, 1]
    mean[:, 1] += shift
    mean[:, 0] += gain * shift
    var_k = cov[:, 1, 1] * shrink
    cov[:, 0, 0] += gain * gain * (var_k - cov[:, 1, 1])
    cov[:, 0, 1] = cov[:, 1, 0] = gain * var_k
    cov[:, 1, 1] = var_k
    return log_mass
