"""
The friction and the drive's efficiency that a motor-current effort carries.

A motor-current torque includes the friction of the motor and the first stage,
which the cycloid mesh does not transmit, and a drive reports ``T/eta`` while it
drives the load and ``T*eta`` while the load drives it back. :class:`FrictionFit`
explains the effort, by least squares pooled over recent windows, as the rigid
body load plus Coulomb and viscous friction at the efficiency that fits best,
and takes what the reducer does not carry out of the torque
(:class:`.window_analysis.WindowAnalyzer` runs it on every window batch).
"""

import math

import numpy as np

from .window_ops import shifted, solve_identifiable_many, window_mean

_FRICTION_TERMS = 8
"""Regressors of the friction identification (load: 6, Coulomb, viscous)."""


_FRICTION_SUMS = 20
"""Pooled regressors: the load's six, times the driving and driven-back shares, then 2."""


_EFFICIENCIES = (1.0, 0.95, 0.9, 0.85, 0.8, 0.75, 0.7, 0.65)
"""Efficiencies of the drive weighed by the friction fit (1: a constant Coulomb friction)."""


def _efficiency_maps():
    """Map the pooled sums' regressors to the friction fit's at each efficiency, (E, 8, 20)."""
    eye = np.eye(6)
    maps = np.zeros((len(_EFFICIENCIES), _FRICTION_TERMS, _FRICTION_SUMS))
    for m, eta in zip(maps, _EFFICIENCIES):
        m[:6, :6] = eye
        m[:6, 6:12] = (1.0 / eta - 1.0) * eye
        m[:6, 12:18] = -(1.0 - eta) * eye
        m[6, 18] = m[7, 19] = 1.0
    return maps


_EFFICIENCY_MAPS = _efficiency_maps()


_FRICTION_SPEED = 0.01
"""Speed [rad/s] over which Coulomb friction changes sign (``tanh(omega/omega_s)``)."""


_FRICTION_FLOOR = 0.005
"""
Friction [fraction of rated torque, at the window's RMS speed] below which none is taken out.

Far below the lowest torque bin (2 %) and the effort noise band: it cannot change a
flank, while subtracting a fitted near-zero friction would only move samples between bins.
"""


class FrictionFit:
    """
    The friction and efficiency of one joint's drive, pooled over recent windows.

    Parameters
    ----------
    rated_torque : float
        The reducer's rated torque [N·m] (the floor below which no friction is taken out
        is a share of it, :data:`_FRICTION_FLOOR`).
    memory_windows : float
        Memory of the pooled sums in windows (> 0).

    Attributes
    ----------
    coulomb_friction, viscous_friction : float
        The friction last taken out [N·m] and [N·m·s/rad] (0 while not significant).
    efficiency : float
        The drive's efficiency last fitted (1: read as a constant Coulomb friction).

    """

    def __init__(self, rated_torque, memory_windows):
        self.rated_torque = rated_torque
        self._memory = math.exp(-1.0 / memory_windows)
        self._normal = np.zeros((_FRICTION_SUMS, _FRICTION_SUMS))
        self._rhs = np.zeros(_FRICTION_SUMS)
        self._energy = np.zeros(_FRICTION_SUMS)
        self._yy = 0.0
        self._samples = 0.0
        self._directions = np.zeros(2)
        self.coulomb_friction = 0.0
        self.viscous_friction = 0.0
        self.efficiency = 1.0

    def fit(self, torque, t, harmonics, speed, win, starts, ends, half):
        """
        Take the friction the effort carries out of the torque, per window.

        A motor-current torque includes the friction of the motor and the first
        stage, which the cycloid mesh does not transmit: near a reversal it gives
        the effort the sign of the motion, not of the load. The effort is
        explained, by least squares pooled over recent windows
        (``friction_memory_windows``), as the rigid-body load (a constant,
        ``cos``/``sin`` of the output angle and of twice it, the output
        acceleration) plus Coulomb ``Fc·tanh(omega/omega_s)`` and viscous
        ``Fv·omega`` friction; ``Fc`` and ``Fv`` (each at least 0, 0 while not
        identifiable: a joint that never reversed) are subtracted when they
        amount to :data:`_FRICTION_FLOOR` of rated torque or more. Velocity-
        proportional drag downstream of the mesh (cables, seals of the link)
        is taken out with ``Fv`` too, although the reducer carries it: the
        effort cannot tell the two apart, so the caller treats a sample whose
        torque changes sign with ``Fv·omega`` put back as ambiguous. The
        acceleration is taken over ``half`` samples either side (at least 1;
        :meth:`.torque_smoothing.TorqueSmoothing.half_width`).

        Returns
        -------
        tuple of ndarray
            Torque at the reducer output [N·m]; the velocity-proportional part
            taken out of it [N·m] (which may be drag of the link that the
            reducer does carry); the effort as the fit explains it [N·m] (NaN
            at the windows' edges); per window the friction taken out
            ``(Coulomb [N·m], viscous [N·m·s/rad], RMS speed [rad/s], efficiency,
            RMS load [N·m])``; and per window whether the fit
            could not yet tell friction from the load (too few samples of one
            direction of motion).

        """
        n = torque.size
        drag = np.zeros(n)
        model = np.full(n, np.nan)
        half = max(1, half)
        speed_s, count = window_mean(speed, half, win, starts, ends)
        effort_s, _ = window_mean(torque, half, win, starts, ends)
        # The acceleration from the smoothed speed over the averaging length (a two-sample
        # difference would add the speed's noise, amplified, to the load model), where the
        # averages at both ends are whole and in the same window.
        whole = count == 2 * half + 1
        inner = (shifted(whole, -half) & shifted(whole, half)
                 & (shifted(win, -half) == shifted(win, half)))
        accel = np.where(inner, (shifted(speed_s, half) - shifted(speed_s, -half))
                         / np.maximum(shifted(t, half) - shifted(t, -half), 1e-12), 0.0)
        # The regressors written in place: [1, cos, sin, cos 2theta, sin 2theta, accel,
        # Coulomb shape, speed].
        x = np.empty((_FRICTION_TERMS, n))
        x[0] = 1.0
        (x[2], x[1]), (x[4], x[3]) = harmonics[1], harmonics[2]
        x[5] = accel
        coulomb_shape = np.tanh(np.divide(speed, _FRICTION_SPEED, out=x[6]), out=x[6])
        x[7] = speed
        use = inner & np.isfinite(effort_s) & np.isfinite(accel)
        out = torque.copy()
        taken = np.zeros((starts.size, 5))
        unknown = np.zeros(starts.size, dtype=bool)
        # The drive's efficiency: the load regressors also times the share of the
        # Coulomb shape where the effort drives the load and where it is driven back.
        moving = np.abs(coulomb_shape)
        power = effort_s * speed
        driving, back = np.where(power > 0.0, moving, 0.0), np.where(power < 0.0, moving, 0.0)
        # Written row by row into one C-ordered array: the per-window products below read
        # contiguous rows (a Fortran-ordered gather joined by concatenate took 14x longer).
        used = np.flatnonzero(use)
        z = np.empty((_FRICTION_SUMS, used.size))
        np.take(x[:6], used, axis=1, out=z[:6])
        np.multiply(z[:6], driving[used], out=z[6:12])
        np.multiply(z[:6], back[used], out=z[12:18])
        np.take(x[6:], used, axis=1, out=z[18:])
        pooled = self._pooled_sums(z, effort_s[used], speed[used], used, starts, ends)
        sums = [np.array([p[j] for p in pooled]) for j in range(4)]
        betas, idents, etas, picked = self._efficiency_fits(
            *sums, np.array([p[4] for p in pooled]) / (2 * half + 1))
        for k, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
            (self._normal, self._rhs, self._energy, self._yy, self._samples,
             self._directions) = pooled[k]
            beta, ident, eta = betas[k], idents[k], float(etas[k])
            fc, fv, known = self._significant(beta, ident, picked[0][k], picked[1][k])
            unknown[k] = not known
            self.coulomb_friction, self.viscous_friction = fc, fv
            self.efficiency = eta
            load = beta[:6] @ x[:6, a:b]
            rms_speed = float(np.sqrt(np.mean(speed[a:b] ** 2)))
            gain = 1.0 + (1.0 / eta - 1.0) * driving[a:b] - (1.0 - eta) * back[a:b]
            taken[k] = (fc, fv, rms_speed, eta, float(np.sqrt(np.mean(load ** 2))))
            if fc + fv * rms_speed < _FRICTION_FLOOR * self.rated_torque:
                fc = fv = 0.0
                taken[k, :2] = 0.0
            # The effort as the fit explains it, where its acceleration is whole (the
            # window's edges keep NaN), taken as the torque is: its friction terms less
            # what is taken out, the efficiency divided out of all.
            rest = ((beta[6] - fc) * coulomb_shape[a:b] + (beta[7] - fv) * speed[a:b]) / gain
            model[a:b] = np.where(inner[a:b], load + rest, np.nan)
            if not (fc or fv or eta < 1.0):
                continue    # nothing significant to take out
            out[a:b] = (torque[a:b] - fc * coulomb_shape[a:b] - fv * speed[a:b]) / gain
            drag[a:b] = fv * speed[a:b] / gain
        return out, drag, model, taken, unknown

    def _efficiency_fits(self, normal, rhs, energy, yy, samples):
        """
        Fit the friction at the efficiency of :data:`_EFFICIENCIES` that explains the effort.

        A drive reports ``T/eta`` while it drives the load and ``T*eta`` while the load
        drives it back: the load regressors ``x`` become ``x*(1 + (1/eta - 1)*D -
        (1 - eta)*B)`` (``D``, ``B`` the Coulomb shape where the smoothed effort and the
        speed have the same or opposite signs), a linear map of the pooled sums of
        ``[x, x*D, x*B, Coulomb shape, speed]``, per window (on its pool). One below 1
        is taken where it lowers the residual by more than 9 residual variances
        (three standard errors of one more parameter) over the independent samples
        (``samples``: the smoothed effort's residuals are correlated over its averaging
        length); otherwise the effort is read as before (a constant Coulomb friction).

        Returns
        -------
        tuple
            Coefficients and identifiable masks of the fits at the chosen efficiency
            (``(W, 8)``), the efficiency per window and the normal equations and
            right-hand sides (for :meth:`_significant`).

        """
        maps = _EFFICIENCY_MAPS
        # The residual at every efficiency, per window (energy-scaled, a small ridge
        # where a regressor is not identifiable: only to rank the efficiencies).
        # (W, E, 8, 8) by stacked products: each window's the same whatever the batch.
        n_all = maps[None] @ normal[:, None] @ maps.transpose(0, 2, 1)[None]
        r_all = (maps[None] @ rhs[:, None, :, None])[..., 0]
        energy_all = np.einsum('weii->wei', n_all)
        scale = 1.0 / np.sqrt(np.maximum(energy_all, 1e-300))
        a = n_all * scale[..., :, None] * scale[..., None, :] + 1e-9 * np.eye(_FRICTION_TERMS)
        b_all = np.linalg.solve(a, (r_all * scale)[..., None])[..., 0] * scale
        rss = (yy[:, None] - 2.0 * np.einsum('wei,wei->we', b_all, r_all)
               + np.einsum('wei,weij,wej->we', b_all, n_all, b_all))
        best = np.argmin(rss, axis=1)
        pick = np.arange(best.size)
        free = np.maximum(samples - _FRICTION_TERMS, 1.0)
        take = (best > 0) & (rss[:, 0] - rss[pick, best] > 9.0 * rss[pick, best] / free)
        best = np.where(take, best, 0)
        n_e, r_e = n_all[pick, best], r_all[pick, best]
        betas, idents = solve_identifiable_many(n_e, r_e, energy_all[pick, best])
        return betas, idents, np.asarray(_EFFICIENCIES)[best], (n_e, r_e)

    def _pooled_sums(self, x_used, y_used, speed_used, used, starts, ends):
        """
        Return the friction fit's pooled sums after each window, from the last batch's.

        Each window adds the normal equations of its samples (regressors ``x_used``,
        effort ``y_used`` and speed ``speed_used`` at the sample indices ``used``) to
        the sums forgotten by ``friction_memory_windows``; the sums do not depend on the
        fits, so they are formed first and the fits solved together.

        Returns
        -------
        list of tuple
            Per window ``(normal, rhs, energy, yy, samples, directions)``, as
            ``_fric_n``, ``_fric_r``, ``_fric_e``, ``_fric_yy``, ``_fric_m`` and
            ``_fric_dir`` stand after it.

        """
        lo, hi = np.searchsorted(used, starts).tolist(), np.searchsorted(used, ends).tolist()
        memory = self._memory
        n, r, e = self._normal, self._rhs, self._energy
        yy, m, direction = self._yy, self._samples, self._directions
        pooled = []
        for a, b in zip(lo, hi):
            xk, yk, moving = x_used[:, a:b], y_used[a:b], speed_used[a:b]
            n = memory * n + xk @ xk.T
            r = memory * r + xk @ yk
            e = memory * e + np.einsum('ij,ij->i', xk, xk)
            yy = memory * yy + float(yk @ yk)
            m = memory * m + yk.size
            direction = memory * direction + np.array(
                [np.count_nonzero(moving > _FRICTION_SPEED),
                 np.count_nonzero(moving < -_FRICTION_SPEED)])
            pooled.append((n, r, e, yy, m, direction))
        return pooled

    def _significant(self, beta, ident, normal, rhs):
        """
        Coulomb and viscous friction of the pooled fit, 0 unless 3 standard errors above 0.

        The third value says whether the fit could tell friction from the load at all.
        """
        free = self._samples - np.count_nonzero(ident)
        # Both directions of motion, each in a fifth of the samples: otherwise the sign of
        # the speed is a constant and Coulomb friction cannot be told from the load.
        if free <= 0 or self._directions.min() < 0.2 * self._samples:
            return 0.0, 0.0, False
        rss = self._yy - 2.0 * beta @ rhs + beta @ normal @ beta
        idx = np.flatnonzero(ident)
        try:
            cov = np.linalg.inv(normal[np.ix_(idx, idx)]) * max(rss, 0.0) / free
        except np.linalg.LinAlgError:
            return 0.0, 0.0, False
        se = dict(zip(idx.tolist(), np.sqrt(np.maximum(np.diag(cov), 0.0)).tolist()))
        out = []
        for j in (6, 7):
            value = float(beta[j]) if ident[j] else 0.0
            out.append(value if value > 3.0 * se.get(j, math.inf) else 0.0)
        return out[0], out[1], True
