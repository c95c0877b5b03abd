"""
The flanks of a window's hysteresis, with the harmonics fitted jointly with them.

The samples of a window fall into ``(|T| bin, torque sign)`` groups; each group is a
flank, a straight line in ``|T|``. The manufacturing harmonics (functions of the output
angle) and the encoder time offset are fitted jointly with those lines, by least squares
pooled over recent windows (:class:`FlankPool`), so that the joint meeting the same load
at different positions tells the harmonics from the hysteresis. The width between a
bin's two flank lines, the harmonics taken out, is its hysteresis
(:meth:`FlankPool.hysteresis`), from which :mod:`.wear_fit` reads the lost motion.
"""

import math

import numpy as np

from .te_extraction import TIME_OFFSET_LINEAR_S, TWO_PI
from .window_ops import solve_identifiable_many

_MODEL_SIGMA = 3e-6
"""
Model error of one bin's hysteresis width [rad] (0.6 arcsec), added in quadrature.

What the period-mean table leaves out: mesh ripple (below 0.3 arcsec peak to
peak) and interpolation (below 0.1 arcsec), and harmonics that leak into a
bin when they cannot be separated from the torque lines. Without it, bins
with many samples would claim a precision the model does not have.
"""

_POOL_EXPOSURE_S = 100.0 * 3600.0
"""Operation [s] over which the pooled flank levels fade (the lost motion moves little)."""

_POOL_FRICTION_JUMP = 0.01
"""
Change of the friction taken out of the effort [fraction of rated torque] for which the
pooled fit restarts: its flank groups were formed with another torque.

The change is that of the map from effort to torque, both maps evaluated at this window's
RMS speed and RMS load: ``|ΔFc + ½·Δ(1/η − η)·T_rms| + |ΔFv|·ω_rms`` (the fit may trade
a Coulomb friction for an efficiency's loss, which at the window's load take out the same
torque). A window whose load differs from the pool's first (a joint loaded by its
accelerations, a payload changed) under the same friction and efficiency keeps the pool:
its samples are placed in their flank groups by the same map. (The pool's map was taken at
its first window's load and this window's at its own, so a steady efficiency under a
changing load restarted the pool of a third-generator base, loaded by its accelerations
alone, at about every other window: 8 of its 153 windows read a lost motion, counted once.)
"""

_POOL_JUMP = 0.003
"""
Change of a window's mean TE [rad], less the offset's and windup's shares: a new TE constant.

The pooled fit restarts there: a motor turn count lost across a gap (``2·pi/i``), a link
encoder re-homed or its offset changed. The pool refers each window to one level through
its mean, which does not carry its flank lines over such a step: a link re-homed by
0.005 rad (17 arcmin) halfway through a recording read a forearm's lost motion 24 % high
(independent generator), with or without a gap at the step, while the threshold was
0.01 rad; from 3 mrad (10 arcmin) it reads within 0.3 %. The play's growth over a life
moves a window's mean by less (1 mrad).

A time offset ``delta`` between the encoders adds ``omega·delta`` to the TE, so the
windows' means also follow their mean speed: at 10 ms a base's moved by 50 arcmin from one
window to the next. Taken for new constants, they restarted the pool on every window, no
window alone could tell the offset from the flanks, and the offset was never learnt: the
joint was refused as "the effort has the opposite sign" (independent generator, link and
motor topics stamped 10 ms apart). The latest offset the pool identified, times each
window's mean speed, is taken out of the mean before it is compared, as is the windup
under the window's mean load at the model's stiffness (4 arcmin at rated torque: windows
under loads of opposite signs differ by twice that; without it, a few windows of the
model's simulator restarted the pool, its NEES 0.15 moved to 0.14).
"""

_NO_FRICTION = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
"""``friction_taken`` of a window from which no friction is taken out."""


class FlankPool:
    """
    The flank lines of one joint's windows and the harmonics, pooled over recent windows.

    Parameters
    ----------
    orders : tuple of int
        Harmonic orders per output revolution.
    edges : ndarray
        Edges of the log-spaced ``|T|`` bins [N·m].
    rated_torque : float
        The reducer's rated torque [N·m].
    min_bins : int
        Usable bins a window needs for a lost motion.
    memory : float
        Factor by which the pool fades per window (0: this window only).

    """

    def __init__(self, orders, edges, rated_torque, min_bins, memory):
        self.orders = orders
        self.edges = edges
        self.centres = np.sqrt(edges[1:] * edges[:-1])
        self.torque_bins = edges.size - 1
        self.rated_torque = rated_torque
        self.min_bins = min_bins
        self._memory = memory
        n_par = 2 * len(orders) + 1
        n_groups = 2 * self.torque_bins
        self._te_ref = None
        self._level_ref = None      # the restart window's mean less its offset's share
        self._offset = None         # the latest time offset identified [s]
        self.steps = []             # (window of the last batch, step [rad]) of the TE's constant
        self._pool_friction = np.array([0.0, 0.0, 1.0])   # Coulomb, viscous, efficiency
        self._pool = {'moments': np.zeros((n_par + 1, n_par + 1)), 'count': np.zeros(n_groups),
                      'su': np.zeros(n_groups), 'suu': np.zeros(n_groups),
                      'st': np.zeros(n_groups), 'stt': np.zeros(n_groups),
                      'sut': np.zeros(n_groups), 's0': np.zeros((n_groups, n_par + 1)),
                      's1': np.zeros((n_groups, n_par + 1)),
                      'stz': np.zeros((n_groups, n_par + 1))}

    def harmonics(self, theta):
        """
        ``sin(k·theta), cos(k·theta)`` of the regressors' orders and of orders 1 and 2.

        Only order 1 takes sines and cosines (of the angle wrapped to a turn): every
        other order comes from it by the angle-addition formulas, one above an order
        already known, or twice one (the double-angle formulas), so order ``Zc`` takes
        about ``2·log2(Zc)`` products instead of two trigonometric passes. The
        friction's load model uses orders 1 and 2 of the same table.

        Returns
        -------
        dict of int to tuple of ndarray
            ``order -> (sin, cos)``.

        """
        phi = theta - TWO_PI * np.round(theta / TWO_PI)
        done = {1: (np.sin(phi), np.cos(phi))}
        wanted = {1, 2, *self.orders}
        for order in sorted(wanted):
            _harmonic(order, done)
        return {order: done[order] for order in wanted}

    def regressors(self, harmonics, speed, y):
        """Stack ``sin(k·theta), cos(k·theta)`` per order, ``omega`` (time offset), then ``y``."""
        n_ord = len(self.orders)
        z = np.empty((2 * n_ord + 2, y.size))
        for j, order in enumerate(self.orders):
            z[2 * j], z[2 * j + 1] = harmonics[order]
        z[-2] = speed
        z[-1] = y
        return z

    def bins(self, z, torque):
        """
        Place the samples in the ``|T|`` bins: what the group sums share whatever they exclude.

        Returns
        -------
        tuple of ndarray
            Bin index (clipped), outside-the-bins mask, ``u = |T| - bin centre`` and
            ``u·z`` per sample.

        """
        size = np.abs(torque)
        b = np.searchsorted(self.edges, size, side='right') - 1
        beyond = (b < 0) | (b >= self.torque_bins)
        b = np.clip(b, 0, self.torque_bins - 1)
        u = size - self.centres[b]
        return b, beyond, u, u * z

    def group_stats(self, z, torque, bins, win, starts, ends, exclude=None, normal=True):
        """
        Sum the regressors per group ``(window, |T| bin, torque sign)`` and per window.

        Each group gets a straight line in ``u = |T| - bin centre``; its
        projection is eliminated from the normal equations algebraically
        (``Z^T Z - Σ_g S_g^T M_g^-1 S_g``), so no residual array is formed.
        Samples outside the bins take no part. With ``normal=False`` only the
        group sums are formed (the hysteresis needs no normal equations).
        """
        n_win = starts.size
        n_groups = n_win * 2 * self.torque_bins
        b, beyond, u, uz = bins
        outside = beyond | exclude if exclude is not None else beyond
        gid = np.where(outside, n_groups, (win * self.torque_bins + b) * 2 + (torque < 0.0))
        # The smoothed torque stays in one bin for tens of samples: sum over those runs of
        # one group first (contiguous), then add the runs of each group.
        first = np.flatnonzero(np.concatenate([[True], gid[1:] != gid[:-1]]))
        g_run = gid[first]

        def group_sums(rows):
            runs = np.add.reduceat(rows, first, axis=-1)
            if runs.ndim == 1:
                return np.bincount(g_run, runs, n_groups + 1)[:-1]
            return np.stack([np.bincount(g_run, r, n_groups + 1)[:-1] for r in runs], axis=1)
        count = np.bincount(g_run, np.diff(np.append(first, gid.size)), n_groups + 1)[:-1]
        s0 = group_sums(z)
        s1 = group_sums(uz)
        su, suu = group_sums(u), group_sums(u * u)
        with np.errstate(invalid='ignore', divide='ignore'):
            u_mean = np.where(count > 0, su / count, 0.0)
            s_uu = suu - count * u_mean ** 2
            sloped = (count >= 3) & (s_uu > 1e-12 * count * self.centres.max() ** 2)
            s1c = s1 - u_mean[:, None] * s0
        groups = {'count': count, 'u_mean': u_mean, 's_uu': s_uu, 'sloped': sloped,
                  's0': s0, 's1c': s1c, 'su': su, 'suu': suu, 's1': s1}
        if not normal:
            return groups
        with np.errstate(invalid='ignore', divide='ignore'):
            proj0 = np.where(count[:, None] > 0, s0 / np.sqrt(count)[:, None], 0.0)
            proj1 = np.where(sloped[:, None], s1c / np.sqrt(np.where(sloped, s_uu, 1.0))[:, None],
                             0.0)
        n_par = z.shape[0]
        shape = (n_win, 2 * self.torque_bins, n_par)
        proj0, proj1 = proj0.reshape(shape), proj1.reshape(shape)
        correction = (np.matmul(proj0.transpose(0, 2, 1), proj0)
                      + np.matmul(proj1.transpose(0, 2, 1), proj1))
        # Second moments per window, less those of the samples outside the bins.
        out_idx = np.flatnonzero(outside)
        z_out = z[:, out_idx]
        out_bounds = np.searchsorted(out_idx, np.concatenate([starts, ends[-1:]]))
        moments = np.empty((n_win, n_par, n_par))
        for k in range(n_win):
            zk = z[:, starts[k]:ends[k]]
            moments[k] = zk @ zk.T
            if out_bounds[k + 1] > out_bounds[k]:
                zo = z_out[:, out_bounds[k]:out_bounds[k + 1]]
                moments[k] -= zo @ zo.T
        group_params = (count > 0).astype(float) + sloped
        inside = (ends - starts) - np.diff(out_bounds)
        return {
            **groups,
            'moments': moments,
            'reduced': moments - correction,
            'energy': np.einsum('wii->wi', moments)[:, :-1],
            'dof': inside - group_params.reshape(n_win, -1).sum(axis=1),
        }

    def fit_harmonics(self, stats, n_win, te_mean, exposure, friction_taken, speed_mean=None,
                      windup_mean=None):
        """
        Pooled least squares of the harmonics and time offset.

        The normal equations are those of the pool (:meth:`_level_correction`:
        flank lines shared by its windows), referred to one TE level through
        the windows' means ``te_mean`` [rad]; ``exposure`` [s] of operation per
        window shortens the pool where the lost motion moves (time-compressed
        recordings). The residual variance is each window's own, under its
        own flank lines. ``friction_taken`` (per window ``(Coulomb, viscous,
        RMS speed, efficiency, RMS load)`` of what :meth:`.friction_fit.FrictionFit.fit`
        took out of the effort, or None) restarts the pool where it changed
        (:data:`_POOL_FRICTION_JUMP`). Where a jump of the TE's constant is looked for
        (:data:`_POOL_JUMP`), ``te_mean`` is taken without the identified time offset's
        share (times ``speed_mean`` [rad/s] per window) and ``windup_mean`` [rad], the
        windup the window's mean load gives (None: 0 for either); :attr:`steps` lists
        the windows of this batch where it jumped.

        Returns
        -------
        tuple
            Coefficients per window (0 where not identifiable), the
            identifiable mask, the residual TE variance per window [rad²], and
            the pool's flank groups after each window (``count``, ``su``,
            ``suu``, ``s0``, ``s1``, and the TE ``shift`` to each window's
            level) for :meth:`_borrow_flanks`.

        """
        reduced, dof = stats['reduced'], stats['dof']
        normal, rhs = reduced[:, :-1, :-1], reduced[:, :-1, -1]
        shape = (n_win, 2 * self.torque_bins)
        raw = {'moments': stats['moments'], 'count': stats['count'].reshape(shape),
               'su': stats['su'].reshape(shape), 'suu': stats['suu'].reshape(shape),
               's0': stats['s0'].reshape(shape + (-1,)), 's1': stats['s1'].reshape(shape + (-1,))}
        pool = self._pool
        self.steps = []
        # The pool after each window; its flank lines are projected out of all at once.
        after = {key: np.empty((n_win,) + value.shape) for key, value in pool.items()}
        groups = {key: after[key] for key in ('count', 'su', 'suu', 's0', 's1')}
        groups['shift'] = np.empty(n_win)
        for k in range(n_win):
            # The windows' TE is centred on each one's mean: refer it to one level for the
            # pool (a jump of the TE's constant, where a turn count was lost, starts afresh).
            # The torque that placed the samples in their flank groups is the effort less the
            # friction taken out: where that changed by more than the flanks can absorb (the
            # friction identified, a window after the first ones that carried all of it), the
            # pooled groups mix two torques and start afresh too.
            friction = friction_taken[k] if friction_taken is not None else _NO_FRICTION
            fc, fv, speed, eta, load = friction
            fc0, fv0, eta0 = self._pool_friction
            moved = (abs(fc - fc0 + 0.5 * ((1.0 / eta - eta) - (1.0 / eta0 - eta0)) * load)
                     + abs(fv - fv0) * speed)
            level = te_mean[k] - (0.0 if speed_mean is None or self._offset is None
                                  else self._offset * float(speed_mean[k]))
            level -= 0.0 if windup_mean is None else float(windup_mean[k])
            stepped = self._te_ref is not None and abs(level - self._level_ref) > _POOL_JUMP
            if stepped and (speed_mean is None or self._offset is not None
                            and abs(self._offset) <= TIME_OFFSET_LINEAR_S):
                # Before an offset is identified, or while one too large to be a linear
                # term is not yet removed, a mean that follows the speed is no step.
                self.steps.append((k, level - self._level_ref))
            if self._te_ref is None or stepped or \
                    moved > _POOL_FRICTION_JUMP * self.rated_torque:
                self._te_ref, self._level_ref = te_mean[k], level
                self._pool_friction = np.array([fc, fv, eta])
                for value in pool.values():
                    value[...] = 0.0
            d = te_mean[k] - self._te_ref
            add = {key: value[k].copy() for key, value in raw.items()}
            total = add['s0'].sum(axis=0)
            add['moments'][-1, :] += d * total
            add['moments'][:, -1] += d * total
            add['moments'][-1, -1] += d * d * add['count'].sum()
            add['s0'][:, -1] += d * add['count']
            add['s1'][:, -1] += d * add['su']
            # The flank levels are shared while the lost motion holds still: over
            # memory_windows windows, or _POOL_EXPOSURE_S of operation if that is shorter
            # (a time-compressed recording wears visibly from one window to the next).
            memory = min(self._memory, math.exp(-exposure[k] / _POOL_EXPOSURE_S))
            for key, value in pool.items():
                value *= memory
            # The pooled windows' index tau counts back from this one (0): one step older.
            pool['stt'] += pool['count'] - 2.0 * pool['st']
            pool['st'] -= pool['count']
            pool['sut'] -= pool['su']
            pool['stz'] -= pool['s0']
            for key, value in add.items():
                pool[key] += value
            for key, value in after.items():
                value[k] = pool[key]
            groups['shift'][k] = d
        red = after['moments'] - self._level_correction(after)
        pool_n, pool_r = red[:, :-1, :-1], red[:, :-1, -1]
        pool_raw = np.diagonal(after['moments'], axis1=1, axis2=2)[:, :-1]
        beta, ident = solve_identifiable_many(pool_n, pool_r, pool_raw)
        known = np.flatnonzero(ident[:, -1])
        if known.size:
            self._offset = float(beta[known[-1], -1])
        noise = np.full(n_win, np.nan)
        free = dof - np.count_nonzero(ident, axis=1)
        for k in np.flatnonzero(free > 0).tolist():
            b = beta[k]
            rss = reduced[k, -1, -1] - 2.0 * b @ rhs[k] + b @ normal[k] @ b
            noise[k] = max(rss, 0.0) / free[k]
        return beta, ident, noise, groups

    def restart(self):
        """Start the pool afresh at the next window (its windows read a TE since found wrong)."""
        self._te_ref = None

    def retime(self, delta_s):
        """
        Refer the pooled windows' TE to link stamps ``delta_s`` later.

        A time offset ``delta`` adds ``omega·delta`` to the TE, so the TE of the pooled
        windows, had the link encoder's stamps been ``delta_s`` later, is
        ``y - delta_s·omega``: a linear map of the regressors, which the pooled moments
        and group sums follow exactly (``A·M·A^T`` and ``A·s``). Without it, the pool
        mixes windows of two offsets once the calibration is applied, and no single
        coefficient fits both: measured on the model's simulator (1-4 kHz, 30 joints),
        the pool's offset took 15-30 windows to fade and the fifth to tenth windows read
        their lost motion 0.01-0.12 arcmin high (+0.08 in every joint's sixth window).

        Parameters
        ----------
        delta_s : float
            Time added to the link encoder's stamps [s].

        """
        if self._offset is not None:
            self._offset -= delta_s
        pool = self._pool
        moments = pool['moments']
        moments[-1, :] -= delta_s * moments[-2, :]
        moments[:, -1] -= delta_s * moments[:, -2]
        for key in ('s0', 's1', 'stz'):
            pool[key][:, -1] -= delta_s * pool[key][:, -2]

    def _level_correction(self, pool):
        """
        Projection of the pooled flank lines out of the pooled moments, ``(..., P+1, P+1)``.

        The pool's groups are ``(|T| bin, torque sign)`` over all its windows:
        each a level with a slope in ``u`` and a drift over the windows (the
        lost motion grows, quickly in a time-compressed recording), shared by
        the windows, so that the harmonics are told from the hysteresis by the
        positions at which the joint meets the same load in different moves,
        not only within one window. ``pool`` holds one pool or a stack of them (a
        leading axis of windows).
        """
        n = pool['count']
        has = n > 0
        with np.errstate(invalid='ignore', divide='ignore'):
            inv_n = np.where(has, 1.0 / np.where(has, n, 1.0), 0.0)
            u_m, t_m = pool['su'] * inv_n, pool['st'] * inv_n
            c_uu = pool['suu'] - n * u_m ** 2
            c_tt = pool['stt'] - n * t_m ** 2
            c_ut = pool['sut'] - n * u_m * t_m
            b_u = pool['s1'] - u_m[..., None] * pool['s0']
            b_t = pool['stz'] - t_m[..., None] * pool['s0']
        use_u = has & (n >= 3) & (c_uu > 1e-12 * n * self.centres.max() ** 2)
        use_t = has & (n >= 3) & (c_tt > 1e-6 * n)
        c_uu, c_tt, c_ut = (np.where(use_u, c_uu, 1.0), np.where(use_t, c_tt, 1.0),
                            np.where(use_u & use_t, c_ut, 0.0))
        b_u = np.where(use_u[..., None], b_u, 0.0)
        b_t = np.where(use_t[..., None], b_t, 0.0)
        det = c_uu * c_tt - c_ut ** 2
        ok = det > 1e-9 * c_uu * c_tt
        # Inverse of the centred (u, tau) Gram matrix; a nearly collinear pair keeps u only.
        i_uu = np.where(ok, c_tt / np.where(ok, det, 1.0), 1.0 / c_uu)
        i_tt = np.where(ok, c_uu / np.where(ok, det, 1.0), 0.0)
        i_ut = np.where(ok, -c_ut / np.where(ok, det, 1.0), 0.0)
        i_uu, i_tt, i_ut = (np.where(use_u, i_uu, 0.0), np.where(use_t, i_tt, 0.0),
                            np.where(use_u & use_t, i_ut, 0.0))
        i_tt = np.where(use_t & ~use_u, 1.0 / c_tt, i_tt)
        s0 = pool['s0']

        def gram(a, weight, b):
            return np.swapaxes(a * weight[..., None], -1, -2) @ b
        return (gram(s0, inv_n, s0) + gram(b_u, i_uu, b_u) + gram(b_t, i_tt, b_t)
                + gram(b_u, i_ut, b_t) + gram(b_t, i_ut, b_u))

    def hysteresis(self, stats, beta, noise, pooled, needed):
        """
        Observed hysteresis ``(|T|, H, std, usable, odd, fewest)`` per window and bin.

        ``needed`` is the samples a flank needs
        (:meth:`.window_analysis.WindowAnalyzer.flank_samples`). ``fewest`` is the
        samples of the window's own flank with fewer of them, per bin (whether or not
        the bin's flanks were taken from the pool): :class:`.soft_zone.SoftZoneCheck`
        compares bins at the lost-motion test torque from fewer samples than a lost
        motion needs.
        """
        n_win, n_par = beta.shape
        b_group = np.repeat(beta, 2 * self.torque_bins, axis=0)
        s0, s1c = stats['s0'], stats['s1c']
        count, u_mean, s_uu, sloped = (stats[k] for k in ('count', 'u_mean', 's_uu', 'sloped'))
        with np.errstate(invalid='ignore', divide='ignore'):
            level = (s0[:, -1] - np.einsum('gi,gi->g', s0[:, :-1], b_group)) / count
            slope = np.where(sloped, (s1c[:, -1] - np.einsum('gi,gi->g', s1c[:, :-1], b_group))
                             / np.where(sloped, s_uu, 1.0), 0.0)
            first = self._first_order_means(s0, count)
        shape = (n_win, self.torque_bins, 2)
        count, u_mean, s_uu, sloped, level, slope, sin1, cos1 = (
            a.reshape(shape) for a in (count, u_mean, s_uu, sloped, level, slope, *first))
        own = count >= needed
        fewest = count.min(axis=2)
        count, u_mean, s_uu, sloped, level, slope, sin1, cos1 = self._borrow_flanks(
            own, beta, (count, u_mean, s_uu, sloped, level, slope, sin1, cos1), pooled,
            needed)
        usable = (count >= needed).all(axis=2) & own.any(axis=2)
        with np.errstate(invalid='ignore', divide='ignore'):
            u_eval = (count * u_mean).sum(axis=2) / count.sum(axis=2)
            lever = u_eval[..., None] - u_mean
            at_eval = level + slope * lever
            spread = np.where(sloped, lever ** 2 / np.where(sloped, s_uu, 1.0), 0.0)
            var = noise[:, None] * (1.0 / count + spread).sum(axis=2)
        width = at_eval[..., 1] - at_eval[..., 0]
        std = np.sqrt(var + _MODEL_SIGMA ** 2)
        usable &= np.isfinite(width) & np.isfinite(std)
        odd = np.stack([sin1[..., 1] - sin1[..., 0], cos1[..., 1] - cos1[..., 0]], axis=-1)
        return u_eval + self.centres, width, std, usable, np.nan_to_num(odd), fewest

    def _first_order_means(self, s0, count):
        """Per flank group, the mean ``sin(theta)`` and ``cos(theta)`` (zeros without order 1)."""
        if 1 not in self.orders:
            return np.zeros_like(count, dtype=float), np.zeros_like(count, dtype=float)
        j = 2 * self.orders.index(1)
        return s0[..., j] / count, s0[..., j + 1] / count

    def first_order(self, ident):
        """Whether the window fit identified the ``sin`` and ``cos`` of order 1, ``(W, 2)``."""
        if 1 not in self.orders:
            return np.zeros((ident.shape[0], 2), dtype=bool)
        j = 2 * self.orders.index(1)
        return ident[:, j:j + 2]

    def _borrow_flanks(self, own, beta, flanks, groups, needed):
        """
        Flank lines from the pool for a window without a hysteresis of its own.

        A window that met its loads under one sign only (the reversal fell into the
        window before or after, as a 2 s window of a slow cycle often does) has too
        few bins for a lost motion. The pool holds every ``(|T| bin, torque sign)``
        flank of the recent windows (this one included) beyond the lost-motion test
        torque, referred to one TE level: in such a window, a bin that the window met
        under one sign and the pool under both takes both flank lines from the pool,
        with this window's harmonics removed and moved to this window's TE level.
        Both flanks then come from the same samples, so harmonics left in them
        cancel as in a window's own bins; the pooled samples are older (the pool's
        memory), over which the lost motion holds still as the pooled harmonic fit
        already assumes. A window with enough bins of its own keeps them.

        Parameters
        ----------
        own : ndarray of bool, shape (W, bins, 2)
            Flanks with enough samples in the window itself.
        beta : ndarray, shape (W, P)
            Harmonic and time-offset coefficients per window.
        flanks : tuple of ndarray, shape (W, bins, 2)
            ``count, u_mean, s_uu, sloped, level, slope`` of the window's flanks and the
            means of ``sin(theta)`` and ``cos(theta)`` over their samples.
        groups : dict of ndarray
            The pool's flank groups after each window (:meth:`fit_harmonics`).
        needed : int
            Samples a flank needs (:meth:`.window_analysis.WindowAnalyzer.flank_samples`).

        Returns
        -------
        tuple of ndarray
            ``flanks`` with the pooled ones where they are taken.

        """
        shape = own.shape
        n = groups['count'].reshape(shape)
        with np.errstate(invalid='ignore', divide='ignore'):
            s0 = groups['s0'].reshape(shape + (-1,))
            s1 = groups['s1'].reshape(shape + (-1,))
            u_mean = groups['su'].reshape(shape) / n
            s_uu = groups['suu'].reshape(shape) - n * u_mean ** 2
            s1c = s1 - u_mean[..., None] * s0
            b = beta[:, None, None, :]
            level = ((s0[..., -1] - (s0[..., :-1] * b).sum(axis=-1)) / n
                     - groups['shift'][:, None, None])
            sloped = (n >= 3) & (s_uu > 1e-12 * n * self.centres.max() ** 2)
            slope = np.where(sloped, (s1c[..., -1] - (s1c[..., :-1] * b).sum(axis=-1))
                             / np.where(sloped, s_uu, 1.0), 0.0)
            first = self._first_order_means(s0, n)
        pooled = ((n >= needed) & np.isfinite(level)).all(axis=2)
        blind = own.all(axis=2).sum(axis=1) < self.min_bins
        take = (pooled & own.any(axis=2) & blind[:, None])[..., None]
        if not take.any():
            return flanks
        return tuple(np.where(take, p, f)
                     for p, f in zip((n, u_mean, s_uu, sloped, level, slope, *first), flanks))


def _harmonic(order, done):
    """
    Return ``(sin, cos)`` of ``order`` times the angle, kept in ``done`` with what it needs.

    From order ``k - 1`` and order 1 (angle addition) when ``k - 1`` is known or ``k`` is
    odd, else from order ``k/2`` (double angle); ``done`` holds order 1.
    """
    if order not in done:
        if order - 1 in done or order % 2:
            (s_a, c_a), (s_1, c_1) = _harmonic(order - 1, done), done[1]
            done[order] = (s_a * c_1 + c_a * s_1, c_a * c_1 - s_a * s_1)
        else:
            s_h, c_h = _harmonic(order // 2, done)
            done[order] = (2.0 * s_h * c_h, (c_h - s_h) * (c_h + s_h))
    return done[order]
