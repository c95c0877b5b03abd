"""
A drive's torque filter undone: the load behind an effort published through a first-order filter.

A drive that low-pass filters its torque estimate publishes ``E`` with
``tau·dE/dt = T - E`` (``tau``: the filter's time constant, the twin's ``effort_lag_s``):
the load of about ``tau`` before. Read as published, the lagging effort puts samples of
each torque reversal on the wrong flank (an unloaded joint read half its lost motion
through a 50 ms filter). :class:`EffortLag` gives the window analysis
(:class:`.window_analysis.WindowAnalyzer`) the torque ``T = E + tau·dE/dt`` of the samples
it buffers, the rate taken within each run of samples between gaps of the stream (never
across one), and owns what that needs across the analysis's cuts: the samples just
before the buffer the rate reaches back to, and how many buffered samples already have
the samples after them that their rate reaches.
"""

import numpy as np

from .torque_smoothing import nominal_step


class EffortLag:
    """
    Undo a first-order filter of known time constant on the buffered effort.

    The effort's rate is taken over the torque average's half-width either side
    (:meth:`.torque_smoothing.TorqueSmoothing.half_width`: the average then quiets the
    noise the rate adds as it quiets the effort's), at least one sample.

    Parameters
    ----------
    lag_s : float
        Time constant of the drive's torque filter [s]; 0: the effort is read as
        published, and every method leaves it so.
    smoothing : TorqueSmoothing
        The torque average of the window analysis, whose half-width the rate spans.

    """

    def __init__(self, lag_s, smoothing):
        self.lag_s = lag_s
        self._smoothing = smoothing
        self._head = None       # (stamps [s], effort [N·m]) just before the buffer

    def reach(self, t, period_s):
        """
        Return the samples either side the effort's rate is taken over, and the step [s].

        ``period_s`` is the stream's sample period [s], None while unknown: then the
        nominal step of the stamps ``t`` [s] (:func:`.torque_smoothing.nominal_step`).
        """
        period = period_s or nominal_step(t)
        return max(1, self._smoothing.half_width(period)), period

    def complete(self, t, period_s):
        """
        Return how many of the buffered samples (stamps ``t`` [s]) have their torque.

        A sample's torque needs the effort's rate over the samples after it: those
        within :meth:`reach` of the latest stamp wait for samples that have not come.
        All of them without a lag.
        """
        if not self.lag_s or not t.size:
            return t.size
        half, period = self.reach(t, period_s)
        return int(np.searchsorted(t, t[-1] - half * period, side='right'))

    def torque(self, t, effort, gap, period_s):
        """
        Return the buffered samples' torque with the drive's filter undone [N·m].

        Parameters
        ----------
        t : ndarray, shape (N,)
            Stamps of the buffered samples [s].
        effort : ndarray, shape (N,)
            Their effort as published [N·m].
        gap : ndarray, shape (N,)
            Greater than 0 where a gap of the stream precedes a sample.
        period_s : float or None
            The stream's sample period [s] (:meth:`reach`).

        Returns
        -------
        ndarray, shape (N,)
            ``E + tau·dE/dt``, the rate one-sided at a run's ends; the samples before the
            buffer (:meth:`keep`) lend theirs to the first run when no gap parts them.
            ``effort`` itself without a lag.

        """
        if not self.lag_s:
            return effort
        size = t.size
        half = self.reach(t, period_s)[0]
        head = self._head
        if head is not None and size and not gap[0] > 0.0:
            # The samples before the buffer, of the windows cut already, in the same run.
            t, effort = np.concatenate([head[0], t]), np.concatenate([head[1], effort])
            gap = np.concatenate([np.zeros(head[0].size), gap])
        skip = t.size - size
        out = effort.copy()
        bounds = np.concatenate([[0], np.flatnonzero(gap[1:] > 0.0) + 1, [t.size]])
        for a, z in zip(bounds[:-1].tolist(), bounds[1:].tolist()):
            k = np.arange(a, z)
            lo, hi = np.maximum(k - half, a), np.minimum(k + half, z - 1)
            span = t[hi] - t[lo]
            with np.errstate(invalid='ignore', divide='ignore'):
                rate = np.where(span > 0.0, (effort[hi] - effort[lo]) / span, 0.0)
            out[a:z] += self.lag_s * rate
        return out[skip:]

    def keep(self, t, effort, end, period_s):
        """
        Keep the samples before ``end`` that the rate of the samples from ``end`` reaches.

        Called as the buffered samples (stamps ``t`` [s], effort [N·m]) before ``end`` are
        cut into windows and dropped; their copies are kept.
        """
        if self.lag_s:
            head = slice(max(0, end - self.reach(t, period_s)[0]), end)
            self._head = (t[head].copy(), effort[head].copy())

    def restart(self):
        """Forget the samples before the buffer: the stream starts over (a reset, a flush)."""
        self._head = None
