"""
The wear and lost motion that explain a window's hysteresis widths.

The window analysis (:mod:`.window_analysis`) reads, per torque bin, the width
between the loaded flanks; :class:`LostMotionFit` finds the wear whose model
hysteresis :meth:`.transmission_error.ModelTables.hysteresis` explains them
(with a compliance correction), weighs it against a straight curve's reading,
and returns the lost motion at the catalogue's test torque with its standard
error.
"""

import numpy as np

_SHAPE_ERROR = 0.02
"""
Shape error of the hysteresis model: a fraction of the windup between a bin and the test torque.

The wear fit extrapolates the observed widths to the catalogue's test torque along the
model's curve ``H(|T|, w) + 2·|T|·c``. A reducer whose curve has another shape (a spring
straighter or stiffer than the model's, a play taken up at another torque) is read wrong
in proportion to how far the bins lie from the test torque: each bin's standard error gets
``_SHAPE_ERROR · 2·| |T|_b - T_test |/k_s`` added in quadrature, so bins near the test
torque decide the level where the window has them, and the reported standard error grows
with the reach of the extrapolation where it has not. 0.02 from bench/bench_lost_motion.py
(0.01-0.03 read alike; from 0.05 on, the noisier low bins near the takeup decide too much).
"""


class LostMotionFit:
    """
    Weighted least-squares reading of the lost motion from the hysteresis bins of windows.

    Parameters
    ----------
    tables : ModelTables
        The reducer's model tables (hysteresis, lost motion, series stiffness).
    centres : ndarray
        Centres of the torque bins [N·m] (where an unused bin is evaluated).
    takeup_torque : float
        The catalogue's lost-motion test torque [N·m].
    compliance_prior : float
        Prior sd of the compliance correction, a share of the series compliance.
    min_bins : int
        Usable bins a window needs for a reading.

    """

    def __init__(self, tables, centres, takeup_torque, compliance_prior, min_bins):
        self.tables = tables
        self.centres = centres
        self.takeup_torque = takeup_torque
        self.compliance_prior = compliance_prior
        self.min_bins = min_bins

    def fit(self, torque_b, h_b, sig_b, usable, chunk=128):
        """
        Weighted least-squares wear that explains the observed hysteresis, per window.

        Model: ``H_b = H(|T|_b, w) + 2·|T|_b·c`` with the table hysteresis
        :meth:`.transmission_error.ModelTables.hysteresis` and a compliance
        correction ``c`` [rad/(N·m)] with a Gaussian prior of
        ``compliance_prior/k_s``. ``c`` absorbs a stiffness that differs from
        the catalogue and the part of an unidentified 1x harmonic that is odd
        in torque (under gravity ``cos(theta)`` follows ``T``); wear is
        measured by the level of ``H``, not its slope. Each bin's standard
        error includes a shape error that grows with its distance from the
        test torque (:data:`_SHAPE_ERROR`): the level is read where the curve
        is observed nearest the test torque. The table is bilinear,
        so the model is linear in ``(w, c)`` between wear nodes: the weighted
        sum of squares is minimised exactly on every interval at once. The
        standard error is scaled by the reduced chi-square when above 1. The
        reading is then weighed against a straight curve's
        (:meth:`_or_straight`).

        Parameters
        ----------
        torque_b, h_b, sig_b : ndarray, shape (W, B)
            Bin torques [N·m], observed widths [rad] and their standard
            errors [rad].
        usable : ndarray of bool, shape (W, B)
            Bins that take part.
        chunk : int
            Windows per vectorised pass (bounds the memory).

        Returns
        -------
        tuple of ndarray, shape (W,)
            Wear [m], its std [m], lost motion [rad], its std [rad] and the
            compliance correction [rad/(N·m)]; NaN for windows with fewer
            than ``min_bins`` usable bins.

        """
        n_win = torque_b.shape[0]
        out = np.full((5, n_win), np.nan)
        todo = np.flatnonzero(usable.sum(axis=1) >= self.min_bins)
        for lo in range(0, todo.size, chunk):
            rows = todo[lo:lo + chunk]
            out[:, rows] = self._fit_rows(torque_b[rows], h_b[rows], sig_b[rows],
                                          usable[rows])
        return tuple(out)

    def _fit_rows(self, torque_b, h_b, sig_b, usable):
        """Vectorised body of :meth:`fit` for windows that all have enough bins."""
        grid = self.tables.wear
        step = np.diff(grid)
        torque_b = np.where(usable, torque_b, self.centres)
        # A bin far from the test torque says less about the lost motion there: its share of
        # the curve's shape between the two is the model's, and a reducer may differ.
        reach = 2.0 * np.abs(torque_b - self.takeup_torque) / self.tables.series_stiffness
        measured = np.where(usable, 1.0 / np.where(usable, sig_b, 1.0) ** 2, 0.0)
        sig_b = np.hypot(sig_b, _SHAPE_ERROR * reach)
        weight = np.where(usable, 1.0 / np.where(usable, sig_b, 1.0) ** 2, 0.0)[..., None]
        h_b = np.where(usable, h_b, 0.0)[..., None]
        model = self._hysteresis_table(torque_b.ravel()).reshape(torque_b.shape + grid.shape)
        slope = np.diff(model, axis=2) / step
        lever = 2.0 * torque_b[..., None]
        miss = h_b - model[..., :-1]
        prior = (self.compliance_prior / self.tables.series_stiffness) ** -2
        a11 = (weight * slope ** 2).sum(axis=1)
        a12 = (weight * slope * lever).sum(axis=1)
        a22 = (weight * lever ** 2).sum(axis=1) + prior
        b1 = (weight * slope * miss).sum(axis=1)
        b2 = (weight * lever * miss).sum(axis=1)
        det = a11 * a22 - a12 ** 2
        with np.errstate(invalid='ignore', divide='ignore'):
            move = np.where(det > 0.0, (a22 * b1 - a12 * b2) / det, 0.0)
        move = np.clip(move, 0.0, step)
        comp = (b2 - a12 * move) / a22
        chi2 = ((weight * (miss - slope * move[:, None] - lever * comp[:, None]) ** 2).sum(axis=1)
                + prior * comp ** 2)
        best = np.argmin(chi2, axis=1)
        pick = np.arange(best.size)
        wear = grid[best] + move[pick, best]
        m = usable.sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            scale = np.where(m > 1, np.maximum(1.0, chi2[pick, best] / (m - 1)), 1.0)
            wear_var = np.where(det[pick, best] > 0.0,
                                scale * a22[pick, 0] / det[pick, best], np.inf)
        wear_std = np.sqrt(wear_var)
        half = 0.5e-6
        lo, hi = np.maximum(wear - half, grid[0]), np.minimum(wear + half, grid[-1])
        dlm = (self.tables.lost_motion(hi) - self.tables.lost_motion(lo)) / (hi - lo)
        lm, lm_std = self.tables.lost_motion(wear), np.abs(dlm) * wear_std
        resid = (miss[pick, :, best] - slope[pick, :, best] * move[pick, best][:, None]
                 - lever[..., 0] * comp[pick, best][:, None])
        lm, lm_std = self._or_straight(torque_b, h_b[..., 0], weight[..., 0], measured, prior,
                                       (wear > grid[0]) & (m > 1), lm, lm_std,
                                       (measured * resid ** 2).sum(axis=1))
        return wear, wear_std, lm, lm_std, comp[pick, best]

    def _or_straight(self, torque_b, h_b, weight, measured, prior, open_, lm, lm_std, chi2):
        """
        Weigh the model's reading against a straight hysteresis curve's.

        Above its take-up a reducer's spring may be straighter than the model's, whose
        contacts stiffen with the load: read along the model's curve, a straight one is
        extrapolated to the test torque along a bend it does not have (5-6 % on units
        of 0.6-0.8 arcmin, whose model curve bends most; the sign depends on the bins'
        reach). The alternative is ``H_b = L + 2·|T|_b·(1/k_s + c)``, ``c`` with the
        compliance prior, whose lost motion is its level ``L`` (the width left when
        the windup of the fitted stiffness is taken off). The two readings are averaged
        with the weights of their likelihoods (equal prior odds; chi-square of the bins'
        measurement errors only, without the shape error, which is the model's), the
        variance including their spread. A fit on the table's lower bound (censored) or
        with a single bin keeps the model's reading.

        Parameters
        ----------
        torque_b, h_b : ndarray, shape (W, B)
            Bin torques [N·m] and widths [rad].
        weight, measured : ndarray, shape (W, B)
            Weights of the bins with and without the shape error [rad^-2], 0 where unused.
        prior : float
            Precision of the compliance prior [(N·m/rad)^2].
        open_ : ndarray of bool, shape (W,)
            Windows whose model reading may be weighed.
        lm, lm_std : ndarray, shape (W,)
            The model's lost motion and its standard error [rad].
        chi2 : ndarray, shape (W,)
            The model fit's chi-square under ``measured``.

        Returns
        -------
        tuple of ndarray
            Lost motion and its standard error [rad].

        """
        arm = 2.0 * torque_b
        rest = h_b - arm / self.tables.series_stiffness
        n11, n12 = weight.sum(axis=1), (weight * arm).sum(axis=1)
        n22 = (weight * arm ** 2).sum(axis=1) + prior
        r1, r2 = (weight * rest).sum(axis=1), (weight * arm * rest).sum(axis=1)
        det = n11 * n22 - n12 ** 2
        m = (weight > 0.0).sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            level = (n22 * r1 - n12 * r2) / det
            comp = (n11 * r2 - n12 * r1) / det
            resid = rest - level[:, None] - arm * comp[:, None]
            fit_chi2 = (weight * resid ** 2).sum(axis=1) + prior * comp ** 2
            var = np.maximum(1.0, fit_chi2 / np.maximum(m - 1, 1)) * n22 / det
            odds = np.exp(np.clip(0.5 * ((measured * resid ** 2).sum(axis=1) - chi2), -50.0, 50.0))
            share = 1.0 / (1.0 + odds)
        share = np.where(open_ & (det > 0.0) & np.isfinite(level) & np.isfinite(var), share, 0.0)
        level, var = np.where(share > 0.0, level, lm), np.where(share > 0.0, var, 0.0)
        mixed = (1.0 - share) * lm + share * level
        spread = share * (1.0 - share) * (lm - level) ** 2
        return mixed, np.sqrt((1.0 - share) * lm_std ** 2 + share * var + spread)

    def _hysteresis_table(self, torque_b):
        """Model hysteresis at ``|T|_b`` on every wear node of the table, shape (m, nodes)."""
        tab = self.tables
        t = np.clip(torque_b, tab.torque[0], tab.torque[-1])
        i = np.clip(np.searchsorted(tab.torque, t, side='right') - 1, 0, tab.torque.size - 2)
        f = ((t - tab.torque[i]) / (tab.torque[i + 1] - tab.torque[i]))[:, None]
        beta = (1.0 - f) * tab.beta[i] + f * tab.beta[i + 1]
        return 2.0 * (beta + (torque_b / tab.series_stiffness)[:, None])
