"""
Pairing by controller tick: whether a link and a motor sample of one tick belong together.

When the link and motor encoders of a joint arrive on topics of their own, the stamps of
one controller tick differ: by publish jitter (pair the samples as they are) or because
they are the true sample times (interpolate). :class:`TickPairing` decides from the data
and reports its evidence (:data:`PAIRING_FACTS`); :class:`.pairing.Pairer` and the TE
extraction follow its decision.
"""

import math

import numpy as np

from .stamp_clock import PERIOD_STEPS

TICK_TOLERANCE = 0.3
"""
Largest stamp difference of a link and a motor sample of one controller tick [periods].

A controller reads both encoders of a joint in the same cycle; the stamps it writes
differ by the publish jitter of each topic (tens of µs, a few percent of a 1 kHz period).
0.3 periods keeps every such pair and stays far from the neighbouring ticks (0.7 periods
away at least).
"""

TICK_RATE_TOLERANCE = 0.02
"""Largest relative difference of the two streams' nominal periods still taken as one rate."""

TICK_MIN_STEPS = 200
"""Differences of consecutive same-tick pairs needed before the pairing is decided."""

TICK_CONFIDENCE = 5.0
"""The slope must lie this many standard errors away from 1/2 for a decision."""

PAIRINGS = ('interpolate', 'tick')
"""How a motor sample is found for a link sample: interpolated at its stamp, or its own tick's."""

PAIRING_FACTS = ('pairing', 'tick_paired')
"""
Diagnostic values that report the pairing (:meth:`TickPairing.facts`), facts and no faults.

``pairing``: which pairing is in use and why; ``tick_paired``: link samples paired with
their tick's motor sample.
"""

SHARED_STAMPS = 'shared stamps: one message carries both encoders of a tick'
"""The pairing of the combined form (nothing to decide)."""


class TickPairing:
    """
    Decide from the data whether a link and a motor sample of one tick belong together.

    A controller (ros2_control) reads the link and motor encoders of a joint in the same
    cycle; when the stamps then differ, the difference ``d`` is either publish jitter (the
    samples were taken together: pair them as they are) or real timing (the stamps are
    the sample times: interpolate the motor angle at the link stamp). Interpolating
    jittered stamps adds ``omega·d`` to the TE (0.1 arcmin at 1 rad/s for 30 µs), noise
    that grows with speed; pairing true stamps by tick adds the same. The data say which:
    with ``D = (theta_motor(t_link) - theta_motor[k])/i`` the change the interpolation makes
    (the motor angle interpolated at the link stamp minus the tick's own sample, referred to
    the output), the interpolated TE's sample-to-sample change regresses on ``D``'s with
    slope ``-1`` when the stamps are jitter (the interpolation adds ``-D``) and ``0`` when
    they are true (the interpolated TE is the smooth one). ``beta`` is minus that slope; the
    pairing is decided once ``beta`` lies :data:`TICK_CONFIDENCE` standard errors from 1/2
    after at least :data:`TICK_MIN_STEPS` steps: by tick when ``0.5 < beta < 1.5``, else by
    interpolation. Until then, and whenever the streams are not candidates (different rates,
    no motor stamp within :data:`TICK_TOLERANCE` periods of a link stamp, no motion to tell
    them apart), the motor angle is interpolated as before.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i`` (input angles are divided by it).

    Attributes
    ----------
    decided : str or None
        One of :data:`PAIRINGS` once decided, else None.
    tick_paired : int
        Link samples paired with their tick's motor sample.

    """

    def __init__(self, ratio):
        self.ratio = float(ratio)
        self.decided = None
        self.tick_paired = 0
        self._sums = np.zeros(3)        # sum dx², dx·dy, dy² of the steps
        self._steps = 0
        self._periods = {'link': _PeriodLearner(), 'motor': _PeriodLearner()}
        self._last = None               # (t, x, y) of the last observed pair: steps across calls

    @property
    def pairing(self):
        """Return the pairing in use: ``'tick'`` or ``'interpolate'``."""
        return self.decided or 'interpolate'

    @property
    def beta(self):
        """Return the fraction of the stamp differences that is jitter, and its standard error."""
        sxx, sxy, syy = self._sums
        n = self._steps
        if n < 3 or sxx <= 0.0:
            return math.nan, math.nan
        beta = -sxy / sxx
        var = max(syy - sxy * sxy / sxx, 0.0) / (n - 1)
        return beta, math.sqrt(var / sxx)

    def reason(self):
        """
        Say which pairing is in use and why (for the diagnostics and the analysis summary).

        Returns
        -------
        str
            The pairing and the evidence behind it.

        """
        beta, se = self.beta
        fig = f'stamp-difference slope {beta:.2f} ± {se:.2f}' if np.isfinite(beta) else ''
        if self.decided == 'tick':
            return (f'tick: the stamps of one controller tick differ by jitter ({fig}); '
                    'link and motor samples of a tick are paired as they are')
        if self.decided == 'interpolate':
            return (f'interpolate: the stamps are the sample times ({fig}); the motor angle '
                    'is interpolated at each link stamp')
        periods = [p.period for p in self._periods.values()]
        if None not in periods and not _same_rate(*periods):
            return 'interpolate: the link and motor streams have different rates'
        return ('interpolate: not enough evidence to pair by controller tick'
                + (f' ({fig}, {self._steps} steps)' if fig else ''))

    def facts(self):
        """Return the :data:`PAIRING_FACTS` of the diagnostics and the analysis summary."""
        return {'pairing': self.reason(), 'tick_paired': int(self.tick_paired)}

    def learn(self, side, t):
        """
        Take stamps of one side into the estimate of its nominal period.

        Parameters
        ----------
        side : str
            ``'link'`` or ``'motor'``.
        t : ndarray
            New stamps in time order (any unit, the same for both sides).

        """
        self._periods[side].add(t)

    def match(self, t_link, t_motor):
        """
        Index of the motor sample of the same tick for each link stamp, -1 where none.

        Parameters
        ----------
        t_link, t_motor : ndarray
            Increasing stamps of the two sides (one unit).

        Returns
        -------
        ndarray of int64 or None
            None when the streams are no candidates (rates unknown or different).

        """
        p_link, p_motor = self._periods['link'].period, self._periods['motor'].period
        if p_link is None or p_motor is None or not _same_rate(p_link, p_motor):
            return None
        if t_link.size == 0 or t_motor.size == 0:
            return np.full(t_link.size, -1, dtype=np.int64)
        j = np.searchsorted(t_motor, t_link)
        lo = np.clip(j - 1, 0, t_motor.size - 1)
        hi = np.clip(j, 0, t_motor.size - 1)
        # Differences in the stamps' own type (ns as int64 keep their precision).
        d_lo = np.abs(t_link - t_motor[lo])
        d_hi = np.abs(t_motor[hi] - t_link)
        near = np.where(d_hi < d_lo, hi, lo)
        dist = np.minimum(d_lo, d_hi)
        ok = dist <= TICK_TOLERANCE * p_link
        out = np.where(ok, near, -1)
        # One motor sample per link sample: a motor sample claimed twice pairs neither.
        taken = out[ok]
        if taken.size > 1:
            dup = np.zeros(t_motor.size, dtype=np.int64)
            np.add.at(dup, taken, 1)
            out[ok & (dup[np.maximum(out, 0)] > 1)] = -1
        return out

    def observe(self, t_link, link, motor_interp, motor_tick, ok):
        """
        Take same-tick pairs into the evidence; decide when it suffices.

        Parameters
        ----------
        t_link : ndarray
            Link stamps (the unit of :meth:`learn`).
        link : ndarray
            Link angles [rad].
        motor_interp : ndarray
            Input-side motor angle interpolated at each link stamp [rad].
        motor_tick : ndarray
            Input-side angle of the tick's own motor sample [rad].
        ok : ndarray of bool
            Samples where both are known.

        """
        if self.decided is not None:
            return
        period = self._periods['link'].period
        rows = np.flatnonzero(ok)
        if rows.size == 0 or period is None:
            return
        t = t_link[rows]
        x = (motor_interp[rows] - motor_tick[rows]) / self.ratio
        y = link[rows] - motor_interp[rows] / self.ratio
        if self._last is not None:
            t = np.concatenate([[self._last[0]], t])
            x = np.concatenate([[self._last[1]], x])
            y = np.concatenate([[self._last[2]], y])
        self._last = (t[-1], float(x[-1]), float(y[-1]))
        step = np.diff(t) <= 1.5 * period
        dx, dy = np.diff(x)[step], np.diff(y)[step]
        if dx.size >= 16:
            # A torque reversal moves the TE by the lost motion within a few samples:
            # such steps say nothing about the stamps and are left out.
            dev = np.abs(dy - np.median(dy))
            mad = np.median(dev)
            if mad > 0.0:
                keep = dev <= 10.0 * 1.4826 * mad
                dx, dy = dx[keep], dy[keep]
        self._sums += (float(dx @ dx), float(dx @ dy), float(dy @ dy))
        self._steps += dx.size
        if self._steps >= TICK_MIN_STEPS:
            beta, se = self.beta
            if np.isfinite(beta) and abs(beta - 0.5) > TICK_CONFIDENCE * se:
                self.decided = 'tick' if 0.5 < beta < 1.5 else 'interpolate'


class _PeriodLearner:
    """The nominal period of a stream: median of its first :data:`PERIOD_STEPS` steps."""

    def __init__(self):
        self.period = None
        self._steps = []
        self._last = None

    def add(self, t):
        if self.period is not None or t.size == 0:
            return
        if self._last is not None:
            t = np.concatenate([[self._last], t])
        self._last = t[-1]
        steps = np.diff(t)
        self._steps.extend(steps[steps > 0].tolist())
        if len(self._steps) >= PERIOD_STEPS:
            self.period = np.median(self._steps[:PERIOD_STEPS])


def _same_rate(p_link, p_motor):
    return abs(p_link - p_motor) <= TICK_RATE_TOLERANCE * max(p_link, p_motor)
