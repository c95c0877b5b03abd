"""
The stamp clock of unstamped or jittery publishers, and the stamp steps' statistics.

A driver that stamps a message when it arrives, not when its encoders were read, gives
stamps that scatter about the controller's regular clock. :class:`StampClock` tells such
stamps from the true times of an irregular sampling and re-times them on that clock; the
cleaner of a stream that carries both encoders of its joints
(:class:`.ingest.StreamCleaner`) runs one, and the offline reader says what it did
(:func:`retimed_message`) or that a publisher leaves its stamps at zero
(:func:`unstamped_message`).

This module also owns what every step of the ingestion stage reads from stamp steps: the
nominal period (the median of the first :data:`PERIOD_STEPS` steps), the steps' scatter
about it (:func:`step_scatter`), and the chunk size up to which a step tries its
plain-Python path first (:data:`FAST_ROWS`).
"""

import math

import numpy as np

FAST_ROWS = 8
"""Chunks of at most this many rows try the plain-Python path first (cleaner and clock)."""

PERIOD_STEPS = 16
"""The nominal period of a stream is the median of its first this many stamp steps."""

CLOCK_STEPS = 256
"""Stamp steps (in arrival order) from which a stream's clock is judged (:class:`StampClock`)."""

CLOCK_SCATTER = 0.25
"""
Scatter of the stamp steps (robust sd over the period) from which stamps may be re-timed.

A controller that stamps when its encoders are read keeps its period to a few %; stamps taken
when a message arrives scatter with the transport. Measured on a 1 kHz recording stamped with
0.3 ms sd (the steps' scatter 42-47 %): each window's lost motion 3.5 times noisier, the wear
21-35 % low; with 0.17 ms (26 %) within 4-7 %.
"""

CLOCK_CORRELATION = -0.25
"""
Correlation of successive stamp steps at or below which the stamps scatter about a clock.

Stamps ``t_k = k·P + e_k`` with independent errors ``e`` give steps ``P + e_k - e_(k-1)``
whose neighbours correlate by -0.5; stamps that are the true times of an irregular
sampling give independent steps (0). Over :data:`CLOCK_STEPS` steps the estimate's sd is
about 0.06.
"""

CLOCK_MEDIAN = 31
"""Stamps of the trailing median that follows the clock's phase (drift, missed ticks)."""

CLOCK_REBASE = 3.0
"""A stamp this many periods off the clock's phase restarts it (a gap or a clock reset)."""

CLOCK_BLOCK = 4096
"""Stamps re-timed per pass (bounds the work a restart repeats)."""


def step_scatter(steps):
    """
    Return the period of stamp steps and their scatter about it.

    Parameters
    ----------
    steps : ndarray
        Differences of successive stamps [ns].

    Returns
    -------
    tuple of float
        The median step and the robust sd of the steps about it (1.4826 x MAD) [ns].

    """
    period = float(np.median(steps))
    return period, 1.4826 * float(np.median(np.abs(steps - period)))


def median_step(t):
    """Return the median of the positive steps between the stamps ``t`` [s], None without one."""
    steps = np.diff(t)
    steps = steps[steps > 0.0]
    return float(np.median(steps)) if steps.size else None


class StampClock:
    """
    Re-time stamps that scatter about a regular controller clock (stamped on arrival).

    A driver that stamps a message when it is received, not when its encoders
    were read, gives stamps ``t_k = t_0 + k·P + e_k``: the transport's delay
    ``e`` scatters them (a few tenths of a millisecond on a loaded computer),
    the messages still arrive in the order the controller sent them. The first
    :data:`CLOCK_STEPS` steps in arrival order decide: when their robust scatter
    is at least :data:`CLOCK_SCATTER` of their median period ``P`` and successive
    steps correlate by :data:`CLOCK_CORRELATION` or less (the signature of
    errors about a clock; an irregular sampling whose stamps are true has
    independent steps), every later stamp is replaced by
    ``t_0 + k·P + median(r)``, ``r_k = t_k - t_0 - k·P`` over the last
    :data:`CLOCK_MEDIAN` stamps: the clock's tick in arrival order, its phase
    following drift and missed ticks (a missed tick moves ``r`` by ``P``; the
    median takes the new level after half its length). A stamp
    :data:`CLOCK_REBASE` periods off the phase (a pause, a clock reset)
    restarts the clock there. Otherwise stamps pass unchanged. Causal, and the
    same however the stream is cut into calls.

    Only a stream that carries both encoders of a joint is re-timed: its TE does not
    depend on the stamps. The stamps of two topics (link and motor apart) are each
    re-timed with their own wander (the median's tenth of a millisecond), which the
    interpolation between them turns into TE. Measured on the independent generator at
    1 kHz with 0.3 ms of scatter (4 recordings of two topics, 12 joints): re-timed, the
    lost motion moved by up to 3 % either way against raw; with a median of 63 stamps
    one joint read 10 % high.

    Parameters
    ----------
    enabled : bool
        Whether the stream may be re-timed (False: its stamps always pass).

    Attributes
    ----------
    active : bool or None
        Whether stamps are re-timed (None until decided).
    retimed : int
        Stamps re-timed so far.
    window_missing : int
        Ticks missing from the deciding stamps (their span against the clock's period).
    raw_head : int
        Stamps of the call that decided which were returned as they came.
    period_ns, scatter_ns, correlation : float or None
        The deciding steps' median, robust sd and lag-1 correlation.

    """

    def __init__(self, enabled=True):
        self.active = None if enabled else False
        self.retimed = self.window_missing = self.raw_head = 0
        self.period_ns = self.scatter_ns = self.correlation = None
        self._first = []        # raw stamps until the decision
        self._t0 = None         # stamp of clock index 0 [ns]
        self._k = 0             # clock index of the next stamp
        self._recent = np.zeros(0)  # latest residuals [ns] (at most CLOCK_MEDIAN - 1)
        self._last_raw = self._last_out = None   # the latest stamp as it came, as given

    def retime(self, t):
        """
        Return the stamps of a chunk, re-timed when the stream's clock is active.

        Parameters
        ----------
        t : ndarray of int64
            Stamps [ns] in arrival order.

        Returns
        -------
        ndarray of int64
            Stamps [ns]: ``t`` itself unless re-timed.

        """
        if self.active is False or t.size == 0:
            return t
        if self.active is None:
            need = CLOCK_STEPS + 1 - len(self._first)
            self._first.extend(t[:need].tolist())
            if len(self._first) <= CLOCK_STEPS:
                return t
            self._decide(np.array(self._first, dtype=np.int64))
            self._first = []
            self.raw_head = need
            if not self.active:
                return t
            head, rest = t[:need], t[need:]
            self._t0, self._k, self._recent = int(head[-1]), 1, np.zeros(1)
            self._last_raw = self._last_out = int(head[-1])
            return np.concatenate([head, self._with_repeats(rest)]) if rest.size else t
        return self._with_repeats(t)

    def _with_repeats(self, t):
        """Re-time ``t``; a stamp that repeats the one before keeps the stamp given before."""
        repeat = t == np.concatenate([[self._last_raw], t[:-1]])
        if repeat.any():    # a message logged twice: the cleaner drops it as a duplicate
            fresh = np.flatnonzero(~repeat)
            given = self._retimed(t[fresh]) if fresh.size else t[:0]
            last = np.maximum.accumulate(np.where(repeat, -1, np.arange(t.size)))
            out = np.where(last >= 0, np.concatenate([given, [0]])[
                np.searchsorted(fresh, np.maximum(last, 0))], self._last_out)
        else:
            out = self._retimed(t)
        self._last_raw, self._last_out = int(t[-1]), int(out[-1])
        return out

    def _retimed(self, t):
        if t.size <= FAST_ROWS and self._recent.size == CLOCK_MEDIAN - 1:
            out = self._retime_few(t)
            if out is not None:
                return out
        return self._retime(t)

    def _retime_few(self, t):
        """Re-time a few stamps in plain Python (the live case): as :meth:`_retime` does."""
        recent = self._recent.tolist()
        period, t0, k = self.period_ns, self._t0, self._k
        middle = sorted(recent)[CLOCK_MEDIAN // 2 - 1:CLOCK_MEDIAN // 2 + 1]
        before = (middle[0] + middle[1]) / 2.0
        out = []
        for tk in t.tolist():
            r = float(tk - t0) - period * k
            if abs(r - before) > CLOCK_REBASE * period:
                return None     # a restart: the vectorised path takes the chunk
            recent.append(r)
            before = sorted(recent)[CLOCK_MEDIAN // 2]
            out.append(t0 + int(round(period * k + before)))
            del recent[0]
            k += 1
        self._recent, self._k = np.array(recent), k
        self.retimed += t.size
        return np.array(out, dtype=np.int64)

    def _decide(self, stamps):
        # A message logged twice repeats the stamp before: not a step of the clock.
        stamps = stamps[np.concatenate([[True], stamps[1:] != stamps[:-1]])]
        steps = np.diff(stamps).astype(float)
        if steps.size < PERIOD_STEPS:   # a clock that stands: nothing to re-time on
            self.active = False
            return
        period, scatter = step_scatter(steps)
        self.period_ns, self.scatter_ns = period, scatter
        clipped = np.clip(steps, period - 3.0 * scatter, period + 3.0 * scatter) - period
        a, b = clipped[1:], clipped[:-1]
        norm = math.sqrt(float(a @ a) * float(b @ b))
        self.correlation = float(a @ b) / norm if norm > 0.0 else 0.0
        self.active = bool(period > 0.0 and scatter >= CLOCK_SCATTER * period
                           and self.correlation <= CLOCK_CORRELATION)
        if self.active:
            # The clock's period from the line through the stamps (the median step is
            # a few tenths of a percent off: its phase would drift and the trailing
            # median lag behind it).
            k = np.arange(stamps.size) - 0.5 * (stamps.size - 1)
            line = float(k @ (stamps - stamps[0]).astype(float)) / float(k @ k)
            if abs(line - period) <= 3.0 * scatter:
                self.period_ns = line
            span = float(stamps[-1] - stamps[0]) / self.period_ns
            self.window_missing = max(0, int(round(span)) - (stamps.size - 1))

    def _retime(self, t):
        out = np.empty_like(t)
        self.retimed += t.size
        done = 0
        while done < t.size:
            part = t[done:done + CLOCK_BLOCK]
            ticks = self._k + np.arange(part.size)
            r = (part - self._t0).astype(float) - self.period_ns * ticks
            keep = self._recent
            series = np.concatenate([keep, r])
            # The trailing median at each stamp: the first ones after a (re)start over
            # fewer stamps.
            pad = min(CLOCK_MEDIAN - 1 - keep.size, part.size)
            phase = np.empty(part.size)
            for i in range(pad):
                phase[i] = np.median(series[:keep.size + i + 1])
            if part.size > pad:
                windows = np.lib.stride_tricks.sliding_window_view(series, CLOCK_MEDIAN)
                phase[pad:] = np.median(windows, axis=1)
            # The phase before each stamp: a stamp far off it restarts the clock there.
            before = np.concatenate([[np.median(keep) if keep.size else r[0]], phase[:-1]])
            off = np.flatnonzero(np.abs(r - before) > CLOCK_REBASE * self.period_ns)
            stop = part.size if not off.size else int(off[0])
            if stop == 0:   # restart at this stamp
                self._t0, self._k, self._recent = int(part[0]), 1, np.zeros(1)
                out[done] = part[0]
                done += 1
                continue
            out[done:done + stop] = self._t0 + np.round(
                self.period_ns * ticks[:stop] + phase[:stop]).astype(np.int64)
            self._recent = series[:keep.size + stop][-(CLOCK_MEDIAN - 1):]
            self._k += stop
            done += stop
        return out


def unstamped_message(topic, instead):
    """
    Say that a topic's publisher does not stamp its messages, and which times stand in.

    Parameters
    ----------
    topic : str
        The JointState topic.
    instead : str
        The times taken, e.g. ``'the recorder received them (log times)'``.

    Returns
    -------
    str
        The line (for a ``WARNING``, a node's log).

    """
    return (f'every header stamp on {topic} is zero (its publisher does not stamp its '
            f'messages): the times {instead} are taken instead; they carry the '
            "delivery's delays, and a link and a motor topic received apart read as "
            'stamped apart')


def retimed_message(topic, clock):
    """
    Say that the stamps of ``topic`` were re-timed on the clock they scatter about.

    Parameters
    ----------
    topic : str
        The stream's topic.
    clock : StampClock
        Its clock, active.

    Returns
    -------
    str
        One sentence with the scatter, the period and the steps' correlation.

    """
    return (f'the header stamps on {topic} scatter by {clock.scatter_ns * 1e-6:.3g} ms about '
            f'their {clock.period_ns * 1e-6:.3g} ms period '
            f'({100 * clock.scatter_ns / clock.period_ns:.0f} %): stamped when a message '
            'arrived rather than when the encoders were read; their steps alternate '
            f'(correlation {clock.correlation:.2f}), as about a regular clock: the samples '
            'were re-timed on it, in the order they arrived')
