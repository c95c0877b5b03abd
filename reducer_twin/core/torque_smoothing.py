"""
The effort as the reducer's torque inside each window: smoothed, its noise, and the load model.

A motor-current torque estimate carries white noise of a few % of rated torque; the
reducer's torque changes with the robot's dynamics, far slower. :class:`TorqueSmoothing`
averages the effort over a centred window, sized per window to quiet its noise beside
the lost-motion test torque (:meth:`TorqueSmoothing.quiet_half`), gives each sample its
noise band, and draws the result toward the rigid-body load model where that explains
the effort (:meth:`TorqueSmoothing.toward_model`). Used by
:class:`.window_analysis.WindowAnalyzer`.
"""

import math

import numpy as np

from .window_ops import window_mean, window_medians

SMOOTHING_NOISE = 0.1
"""Noise of the smoothed torque, as a fraction of the lost-motion test torque, sought."""

SMOOTHING_MAX_S = 0.15
"""Longest torque average [s] (five times the default ``torque_smoothing_s``)."""

CORRELATED_RATIO = 2.0
"""
Noise of the averages, over what white noise of the effort's scatter gives, that is read.

Below it the averages' own figure is not taken: over a 2 s window the fourth
differences of 30 ms means are some 60 independent values, whose median absolute
value scatters by about 20 % (white noise of 5 % of rated torque on the project's
simulator: 1.8 in 1 window of 144 at 1.5); the simulator's effort, quiet and
white, reads 1.6-2.1 from the load's own change at that scale (its averages then
keep 0.5-0.7 N·m, below the sought :data:`SMOOTHING_NOISE` of the test torque, which
they must also pass); the independent generator reads 1.0.
"""

_FOURTH = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / math.sqrt(70.0)
"""Fourth difference normalised to keep the variance of uncorrelated values."""


def nominal_step(t):
    """
    Stamp step a stream's clock keeps [s]: the median step to three significant digits.

    The averages' half-widths are whole numbers of steps and sit on whole numbers at
    round rates (0.15 s at 200 Hz: 15 steps either way of a 5 ms step); a jittered
    stream's median step over one batch of windows was 4.99988 ms, over another
    5.00011 ms, and the half-width 15 or 14 samples with how the stream was cut.
    """
    if t.size < 2:
        return 0.0
    step = float(np.median(np.diff(t)))
    return float(f'{step:.3g}') if step > 0.0 else step


class TorqueSmoothing:
    """
    Smoothing of the effort within windows, for one reducer and analysis settings.

    Parameters
    ----------
    smoothing_s : float
        Length of the centred moving average before it is lengthened [s].
    sign_sigmas : float
        Half-width of the noise band, in standard deviations of the smoothed torque.
    takeup_torque : float
        The lost-motion test torque [N·m].
    rated_torque : float
        The reducer's rated torque [N·m].

    """

    def __init__(self, smoothing_s, sign_sigmas, takeup_torque, rated_torque):
        self.smoothing_s = smoothing_s
        self.sign_sigmas = sign_sigmas
        self.takeup_torque = takeup_torque
        self.rated_torque = rated_torque
        self.correlated_windows = 0
        """Windows whose effort noise was read from its averages (:meth:`mean_noise`)."""
        self.correlated_ratio = None
        """The last such window's noise over the white figure."""

    def half_width(self, period):
        """Half-width in samples of the ``smoothing_s`` average at a stamp step [s]."""
        return int(round(0.5 * self.smoothing_s / period)) if period > 0 else 0

    def smooth(self, torque, half, t, period, model, win, starts, ends, hold=1):
        """
        Centred moving average of the effort inside each window, and its noise band.

        The noise of the raw effort is estimated per window from second
        differences (robustly, by their median absolute value), so the
        smoothed torque's noise is ``sigma/sqrt(m)`` for an average of ``m``
        samples; of an effort held over ``h`` samples (:mod:`.held_effort`),
        from second differences ``h`` samples apart, and ``sigma/sqrt(m/h)``.
        Where the averages themselves are noisier than that (noise correlated
        over samples: :meth:`mean_noise`), ``sigma`` is the white noise that
        would give their noise.
        Samples whose smoothed torque is within ``sign_sigmas`` of that noise
        from zero (or from the torque with the viscous friction
        left in) are ambiguous: their flank is unknown. ``half`` is the
        average's half-width in samples (:meth:`half_width`), lengthened
        for a noisy effort by :meth:`quiet_half`; ``hold`` the samples per update of
        a held effort (1: fresh on every sample).

        Returns
        -------
        tuple of ndarray
            Smoothed torque [N·m] and ``sign_sigmas`` times its noise [N·m],
            both like ``torque``.

        """
        # A held effort changes every h samples: its noise shows between its updates, and
        # an average of m samples holds m/h of them (:mod:`.held_effort`).
        h = hold
        sigma = 1.4826 * window_medians(
            np.abs(torque[h:-h] - 0.5 * (torque[:-2 * h] + torque[2 * h:])), starts,
            ends - 2 * h) / math.sqrt(1.5)
        sigma = self.mean_noise(torque, sigma, half, win, starts, ends, h)
        half = self.quiet_half(sigma, half, t, period, model, win, starts, ends, h)
        smooth, count = window_mean(torque, half, win, starts, ends)
        return smooth, self.sign_sigmas * sigma[win] / np.sqrt(np.maximum(count / h, 1.0))

    def mean_noise(self, torque, sigma, half, win, starts, ends, hold=1):
        """
        Noise of the effort as white noise that gives its averages' noise, per window.

        A torque estimate's noise correlated over many samples (a current loop's
        ripple of a few tens of Hz) hides from differences between neighbours: 2 %
        of rated torque in 5-50 Hz at 1 kHz read 2.0 N·m of its 15.7, the 30 ms
        average was not lengthened and kept 7.6 N·m of noise against a band of
        1 N·m, and a new unit's wear read 67-80 % low, with nothing said.

        The noise ``s_m`` of the ``m = 2·half + 1``-sample averages is read from
        their fourth differences ``m`` samples apart (averages that share no
        sample; the load's own change cancels up to its cubic term), robustly,
        over the samples whose averages are whole. Where ``s_m·sqrt(m/h)``
        exceeds ``sigma`` by :data:`CORRELATED_RATIO` and ``s_m`` is more than
        :data:`SMOOTHING_NOISE` of the test torque (a noise the average must
        quiet), it replaces ``sigma``: the averages are then taken to fall as
        ``1/sqrt(length)`` beyond ``m``, as for noise correlated over fewer
        samples than an average.

        Parameters
        ----------
        torque : ndarray
            The effort [N·m].
        sigma : ndarray
            Its noise per window from neighbouring samples [N·m].
        half, win, starts, ends, hold
            As for :meth:`quiet_half`.

        Returns
        -------
        ndarray
            ``sigma``, or the white-noise equivalent of the averages' noise where larger.

        """
        m = 2 * half + 1
        if half <= 0 or torque.size < 4 * m + 1:
            return sigma
        mean, _ = window_mean(torque, half, win, starts, ends)
        n = torque.size - 4 * m
        fourth = sum(c * mean[k * m:k * m + n] for k, c in enumerate(_FOURTH))
        lo = starts + half
        hi = np.maximum(ends - half - 4 * m, lo)
        s_m = 1.4826 * window_medians(np.abs(fourth), lo, hi)
        white = s_m * math.sqrt(m / hold)
        found = ((white > CORRELATED_RATIO * sigma) & (hi > lo)
                 & (s_m > SMOOTHING_NOISE * self.takeup_torque))
        if not found.any():
            return sigma
        self.correlated_windows += int(found.sum())
        self.correlated_ratio = float(white[found][-1] / max(sigma[found][-1], 1e-12))
        return np.where(found, white, sigma)

    def quiet_half(self, sigma, half, t, period, model, win, starts, ends, hold=1):
        """
        Half-width of the torque average that quiets the effort's noise beside the test torque.

        The smoothed torque places each sample in its ``|T|`` bin and flank. Where
        its noise ``sigma/sqrt(m)`` is a sizeable part of the lost-motion test
        torque, samples near it land in the wrong bins and flanks: the flank
        levels no longer follow the true torque, and on a joint whose load
        follows its position (a base rotation: accelerating at one end of a move,
        braking at the other) the harmonics of the output angle take up part of
        the lost motion. Measured on a base rotation with an effort noise of 2 %
        of rated torque at 1 kHz and a 0.03 s average: 6.5 % low, 12 % low in its
        last windows, 1 % with the true torque. The average is lengthened until
        its noise is :data:`SMOOTHING_NOISE` of the test torque, but no longer
        than half the time the load takes to pass the test torque (an average
        over the passage mixes the two flanks: a 0.15 s average read an
        unloaded joint whose load passes it in 17 ms 12 % low) nor than
        :data:`SMOOTHING_MAX_S`. The passage is timed on the rigid-body load
        of :meth:`.friction_fit.FrictionFit.fit` (noise-free); without it, or in a
        window where the load does not pass the test torque, the average keeps
        ``half``. Each window is judged on its own noise and passage: one
        half-width for a batch of windows (their median noise and slope) made
        the result depend on how the stream was cut into batches (a remaining
        life moved 12 % between chunkings of one recording).

        Parameters
        ----------
        sigma : ndarray
            Noise of the raw effort per window [N·m].
        half : int
            Half-width of the ``torque_smoothing_s`` average [samples].
        t : ndarray
            Stamps of the samples [s].
        period : float
            Their median step [s].
        model : ndarray or None
            The rigid-body load as :meth:`.friction_fit.FrictionFit.fit` explains the effort [N·m].
        win, starts, ends : ndarray
            Window of each sample; first and end sample of each window.
        hold : int
            Samples per update of a held effort (1: fresh on every sample).

        Returns
        -------
        ndarray of int
            Half-width of each window [samples], at least ``half``.

        """
        halves = np.full(sigma.size, half, dtype=np.int64)
        if half <= 0 or model is None or not period > 0.0:
            return halves
        samples = hold * (sigma / (SMOOTHING_NOISE * self.takeup_torque)) ** 2
        size = np.abs(model)
        near = np.flatnonzero((size > 0.5 * self.takeup_torque)
                              & (size < 1.5 * self.takeup_torque))
        # The slope over the average's own span, within the sample's window: the load
        # model carries the noise of the speed (its acceleration and drag terms), which a
        # slope between neighbours multiplies.
        lag = 2 * half
        w = win[near]
        near, w = (a[(near - lag >= starts[w]) & (near + lag < ends[w])] for a in (near, w))
        with np.errstate(invalid='ignore'):
            slope = (np.abs(model[near + lag] - model[near - lag])
                     / (t[near + lag] - t[near - lag]))
        ok = np.isfinite(slope)
        slope, w = slope[ok], w[ok]
        if slope.size == 0:
            return halves
        # The median slope of each window that has one.
        order = np.lexsort((slope, w))
        slope, w = slope[order], w[order]
        first = np.flatnonzero(np.r_[True, w[1:] != w[:-1]])
        count = np.diff(np.r_[first, w.size])
        middle = 0.5 * (slope[first + (count - 1) // 2] + slope[first + count // 2])
        passage = self.takeup_torque / np.maximum(middle, 1e-12)
        longest = np.minimum(0.5 * passage, SMOOTHING_MAX_S)
        with np.errstate(invalid='ignore'):
            quiet = np.minimum(np.ceil(0.5 * (samples[w[first]] - 1.0)),
                               np.floor(0.5 * longest / period))
        quiet = np.where(np.isfinite(quiet), quiet, 0.0)
        halves[w[first]] = np.maximum(half, quiet).astype(np.int64)
        return halves

    def toward_model(self, torque, band, model, win, starts):
        """
        Combine the smoothed torque with the rigid-body load model, weighted by their errors.

        The load model (:meth:`.friction_fit.FrictionFit.fit`'s fit, pooled over many windows) has
        almost no noise but misses what a single joint's rigid-body terms
        cannot explain (other joints' motion, payloads); the smoothed torque
        has the effort's noise ``sigma`` (``band/sign_sigmas``). Per window,
        the model's own error ``s_m^2`` is the mean square of their
        difference less ``sigma^2``; the torque becomes
        ``model + g*(T_s - model)`` with ``g = s_m^2/(s_m^2 + sigma^2)`` and
        its noise ``sqrt(g)*sigma``: near the model where it explains the
        effort, the smoothed torque where it does not.

        Returns
        -------
        tuple of ndarray
            Torque [N·m] and its ``sign_sigmas`` band [N·m], like ``torque``.

        """
        sigma2 = (band / self.sign_sigmas) ** 2 if self.sign_sigmas > 0 else band * 0.0
        diff = torque - model
        ok = np.isfinite(diff)
        n_ok = np.add.reduceat(ok, starts)
        with np.errstate(invalid='ignore', divide='ignore'):
            miss = (np.add.reduceat(np.where(ok, diff ** 2 - sigma2, 0.0), starts)
                    / np.maximum(n_ok, 1))
        miss = np.maximum(miss, 1e-6 * self.rated_torque ** 2)
        miss = np.where(n_ok > 0, miss, np.inf)
        with np.errstate(invalid='ignore'):
            gain = np.where(ok, miss[win] / (miss[win] + sigma2), 1.0)
        gain = np.where(np.isfinite(gain), gain, 1.0)
        out = np.where(ok, model + gain * np.where(ok, diff, 0.0), torque)
        return out, band * np.sqrt(gain)
