"""
Validation and pairing of encoder streams (the ingestion stage).

Robot data arrive as two angle streams per joint, the motor (input) side
and the link (output) side, either in one message per tick or on separate
topics at their own rates. Before any TE is computed, every stream goes
through the same rules, applied identically by the live ``encoder_ingest``
node and by the offline bag analysis (arrays in, arrays out, state carried
across calls):

================  ==========================================================
reason            what happens
================  ==========================================================
(stamps)          stamps that scatter about a regular clock (taken when a
                  message arrived) are re-timed on it (:class:`StampClock`)
``non_finite``    NaN/inf position or stamp: the sample is dropped
``duplicate``     same stamp as the previous sample: dropped
``out_of_order``  stamp earlier than the newest seen (by less than
                  ``clock_jump_s``): dropped
``clock_jump``    stamp jumps back by ``clock_jump_s`` or more (a bag
                  played in a loop, sim time reset): the stream restarts
                  (new segment), the sample is kept
``gap``           stamps further apart than ``max_gap_s``: a new segment
                  starts; nothing is interpolated across it
``wrap``          a jump of about a multiple of 2·pi between neighbours
                  (an encoder that wraps): repaired by unwrapping
``spike``         a paired sample whose TE (``link - motor/i``) is further
                  than ``spike_te_rad`` from the last accepted TE: dropped
                  (TE is smooth, so a glitch of either encoder shows; the
                  test is causal and adds no delay)
``step``          a second consecutive sample that agrees with the dropped
                  one: the jump is real (re-homing), it is accepted
================  ==========================================================

Counts of each reason are kept for the diagnostics.
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import InvalidInput
from .params import _Validated, spec

FAST_ROWS = 8
"""Chunks of at most this many rows try the plain-Python path first."""

PERIOD_STEPS = 16
"""The nominal period of a stream is the median of its first this many stamp steps."""

REASONS = ('non_finite', 'duplicate', 'out_of_order', 'clock_jump', 'gap', 'wrap')
"""Reasons a stream sample is dropped or repaired (per encoder stream)."""

VALUE_REASONS = ('non_finite', 'wrap')
"""The rules that act on one column's values (the others act on whole rows)."""

WRAP_PERIODS = 3
"""Neighbours further apart than this many nominal periods are not tested for a wrap."""

SPIKE_REASONS = ('spike', 'step')
"""Reasons a sample is dropped or repaired, in the order of the table above."""

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


@dataclass(frozen=True)
class IngestConfig(_Validated):
    """Thresholds of the ingestion rules."""

    _prefix = 'ingest'
    max_gap_s: float = spec(0.05, 's', 0.0, 60.0, 'largest stamp gap bridged by interpolation',
                            lo_open=True)
    clock_jump_s: float = spec(1.0, 's', 0.0, 1e6,
                               'backward stamp jump treated as a clock reset', lo_open=True)
    spike_te_rad: float = spec(math.radians(0.5), 'rad', 0.0, 1.0,
                               'TE jump from the last accepted sample that marks a spike',
                               lo_open=True)


@dataclass
class CleanStream:
    """
    Accepted samples of one stream, or of several streams sharing stamps.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (N,)
        Stamps [ns].
    position : ndarray, shape (N,) or (N, K)
        Unwrapped positions [rad]; NaN where a column's sample was dropped.
    velocity, effort : ndarray, same shape as ``position``
        Velocity [rad/s] and effort [N·m] (NaN where not reported).
    segment : ndarray of int64, shape (N,)
        Segment number of each sample (a gap or clock jump starts a new one).

    """

    t_ns: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    segment: np.ndarray

    @classmethod
    def empty(cls, columns=None):
        """Return a stream with no samples (``columns`` given: 2-D arrays)."""
        shape = (0,) if columns is None else (0, columns)
        return cls(np.zeros(0, np.int64), np.zeros(shape), np.zeros(shape), np.zeros(shape),
                   np.zeros(0, np.int64))

    def __len__(self):
        return self.t_ns.size

    def column(self, k):
        """
        Return column ``k`` as a 1-D stream without its dropped samples.

        Parameters
        ----------
        k : int
            Column index.

        Returns
        -------
        CleanStream
            The column's valid samples.

        """
        if self.position.ndim == 1:
            return self
        ok = np.isfinite(self.position[:, k])
        return CleanStream(self.t_ns[ok], self.position[ok, k], self.velocity[ok, k],
                           self.effort[ok, k], self.segment[ok])


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


def stream_cleaners(config, split):
    """
    Return the cleaners of a robot's link stream and of its motor stream (None if one).

    Only a stream that carries both encoders of its joints may be re-timed
    (:class:`StampClock`): two topics keep their stamps.
    """
    if split:
        return StreamCleaner(config, retime=False), StreamCleaner(config, retime=False)
    return StreamCleaner(config), None


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


class StreamCleaner:
    """
    Apply the ingestion rules to angle streams, chunk by chunk.

    Several streams that share their stamps (all joints of one JointState
    message) are cleaned together as the columns of 2-D arrays: stamp rules
    act on rows, value rules (non-finite, wrap, spike) on each column, and
    a dropped value becomes NaN in its column only.

    Parameters
    ----------
    config : IngestConfig
        Thresholds.
    retime : bool
        Whether stamps that scatter about a clock may be re-timed (:class:`StampClock`:
        a stream that carries both encoders of its joints).

    """

    def __init__(self, config=None, retime=True):
        self.config = config or IngestConfig()
        self.counts = dict.fromkeys(REASONS, 0)
        self.accepted = 0
        self.missing = 0
        self.period_ns = None
        self._raw_prev_t = None
        self._diffs = []
        self._rows = 0          # rows that arrived so far
        self._period_row = None  # the row from which the wrap rule knows the period
        self._last_t = None
        self._max_t = None
        self._segment = 0
        self._unwrap = None     # per-column unwrap offset [rad]
        self._raw_last = None   # per-column last finite raw value
        self._wrap_prev = None  # (stamp, segment) of the last row seen by the wrap rule
        self.column_counts = None   # per-column counts of the value rules
        self._ndim = None
        self.clock = StampClock(retime)   # re-times stamps that scatter about a clock

    def process(self, t_ns, position, velocity=None, effort=None):
        """
        Clean a chunk of samples.

        Parameters
        ----------
        t_ns : array_like of int, shape (N,)
            Stamps [ns] in arrival order.
        position : array_like, shape (N,) or (N, K)
            Positions [rad], wrapped or multi-turn.
        velocity, effort : array_like, optional
            Velocity [rad/s] and effort [N·m] of the same shape; NaN allowed.

        Returns
        -------
        CleanStream
            Accepted samples, same dimensionality as ``position``.

        Raises
        ------
        InvalidInput
            If the arrays do not match in shape.

        """
        undecided = self.clock.active is None
        t = self.clock.retime(np.asarray(t_ns, dtype=np.int64).ravel())
        pos = np.asarray(position, dtype=float)
        n = t.size
        base = self._rows
        one_d = pos.ndim == 1
        if one_d and pos.shape[0] == n:
            pos = pos.reshape(n, 1)
        if pos.ndim != 2 or pos.shape[0] != n:
            raise InvalidInput(f'position has shape {np.shape(position)} for {n} stamps, '
                               f'expected ({n},) or ({n}, columns)')
        if self._raw_last is not None and pos.shape[1] != self._raw_last.size:
            raise InvalidInput(f'position has {pos.shape[1]} columns, the stream has '
                               f'{self._raw_last.size}')
        if self._ndim is None:
            self._ndim = 1 if one_d else 2
        vel = _optional(velocity, pos.shape, 'velocity')
        eff = _optional(effort, pos.shape, 'effort')
        self._rows += n        # arrived (the rows of this batch count from ``base``)
        if n == 0:
            out = CleanStream(t, pos, vel, eff, np.zeros(0, np.int64))
            return _squeeze(out) if one_d else out
        if n <= FAST_ROWS and not undecided:
            out = self._fast(t, pos, vel, eff)
            if out is not None:
                return _squeeze(out) if one_d else out
        if undecided and self.clock.active:
            # The deciding stamps scattered: their holes are those of the clock's line,
            # the later ones those of the re-timed stamps.
            head = self.clock.raw_head
            self.missing, self.period_ns, self._diffs = self.clock.window_missing, \
                self.clock.period_ns, []
            self._period_row = base
            self._raw_prev_t = int(t[head - 1])
            self._count_missing(t[head:], base + head)
        else:
            self._count_missing(t, base)
        finite = np.isfinite(pos)
        self.counts['non_finite'] += int(finite.size - np.count_nonzero(finite))
        if self.column_counts is None:
            self.column_counts = {r: np.zeros(pos.shape[1], np.int64) for r in VALUE_REASONS}
        per_column = np.count_nonzero(finite, axis=0)
        self.column_counts['non_finite'] += pos.shape[0] - per_column
        all_finite = bool((per_column == pos.shape[0]).all())
        if not all_finite:
            pos = np.where(finite, pos, np.nan)
        t, pos, vel, eff, seg, kept = self._order(t, pos, vel, eff)
        pos = self._unwrap_positions(pos, t, seg, base + kept, all_finite)
        self.accepted += t.size
        out = CleanStream(t, pos, vel, eff, seg)
        return _squeeze(out) if one_d else out

    def _fast(self, t, pos, vel, eff):
        """
        Clean a few rows in plain Python when no rule fires (the live common case).

        Returns None, having changed nothing, when any rule would act (a
        stamp out of order or across a gap, a non-finite value, a wrap) or
        the stream is still starting: the vectorised path then handles the
        chunk. When it returns, the result and the state are exactly what
        the vectorised path produces (a test checks this).
        """
        if self._last_t is None or self.period_ns is None:
            return None
        gap_ns = int(self.config.max_gap_s * 1e9)
        stamps = t.tolist()
        last = self._last_t
        for ti in stamps:
            if ti <= last or ti - last > gap_ns:
                return None
            last = ti
        prev_raw = self._raw_last.tolist()
        for row in pos.tolist():
            for j, x in enumerate(row):
                if not (-math.pi < x - prev_raw[j] < math.pi):  # also catches NaN/inf
                    return None
            prev_raw = row
        period = self.period_ns
        d_prev = self._raw_prev_t
        for ti in stamps:
            d = ti - d_prev
            if d > 1.5 * period:
                self.missing += int(round(d / period) - 1)
            d_prev = ti
        self._raw_prev_t = stamps[-1]
        self._wrap_prev = (stamps[-1], self._segment)
        self._last_t = self._max_t = stamps[-1]
        self._raw_last = pos[-1].copy()
        self.accepted += len(stamps)
        return CleanStream(t, pos + self._unwrap, vel, eff,
                           np.full(len(stamps), self._segment, dtype=np.int64))

    def counts_for(self, columns):
        """
        Return the counts of some columns: row rules whole, value rules of those columns.

        Parameters
        ----------
        columns : sequence of int
            Column indices (e.g. the link and motor columns of one joint).

        Returns
        -------
        dict
            Reason to count.

        """
        out = dict(self.counts)
        if self.column_counts is not None:
            for reason, per_column in self.column_counts.items():
                out[reason] = int(per_column[list(columns)].sum())
        return out

    def _count_missing(self, t, first_row):
        """
        Count samples missing from the stream (stamp holes at the nominal period).

        Holes are measured from the newest stamp so far (since the last clock
        jump): a sample that arrives late, and is dropped as out of order, leaves
        one hole, not one before it and another after it. ``first_row`` is the
        arrival index of ``t[0]`` in the stream.
        """
        if t.size == 0:
            return
        prev = t[0] if self._raw_prev_t is None else self._raw_prev_t
        if t[0] >= prev and (t.size < 2 or bool((np.diff(t) > 0).all())):
            d = np.diff(t, prepend=prev)
            rows = np.arange(t.size)
            self._raw_prev_t = int(t[-1])
        else:
            d, rows, self._raw_prev_t = self._steps_past_newest(t, int(prev))
        rows = rows[d > 0]
        d = d[d > 0]
        if self.period_ns is None:
            # Steps seen before the period is known are kept, and their holes counted once
            # it is: the count and the period do not depend on how the stream is chunked.
            kept = len(self._diffs)
            d = np.concatenate([np.asarray(self._diffs, dtype=d.dtype), d])
            if d.size < PERIOD_STEPS:
                self._diffs = d.tolist()
                return
            self.period_ns = float(np.median(d[:PERIOD_STEPS]))
            # The wrap rule knows the period from the row whose step completed them on,
            # however the stream is chunked.
            self._period_row = first_row + int(rows[PERIOD_STEPS - 1 - kept])
            self._diffs = []
        holes = d[(d > 1.5 * self.period_ns) & (d < self.config.max_gap_s * 1e9 * 200)]
        self.missing += int(np.sum(np.round(holes / self.period_ns) - 1))

    def _steps_past_newest(self, t, newest):
        """Return the steps by which stamps pass the newest one, their rows, and the newest."""
        jump_ns = int(self.config.clock_jump_s * 1e9)
        steps, rows = [], []
        for k, tk in enumerate(t.tolist()):
            if tk <= newest - jump_ns:     # the clock was reset: the stream starts over
                newest = tk
            elif tk > newest:
                steps.append(tk - newest)
                rows.append(k)
                newest = tk
        return np.array(steps, dtype=np.int64), np.array(rows, dtype=np.int64), newest

    def flush(self):
        """
        Return what is still held (nothing: the rules are causal).

        Returns
        -------
        CleanStream
            An empty stream.

        """
        return CleanStream.empty(None if self._ndim == 1 else
                                 (0 if self._raw_last is None else self._raw_last.size))

    def _order(self, t, pos, vel, eff):
        """
        Drop duplicate/out-of-order stamps, split segments at gaps and clock jumps.

        Returns the rows kept, their segments and their indices in the chunk.
        """
        cfg = self.config
        jump_ns = int(cfg.clock_jump_s * 1e9)
        gap_ns = int(cfg.max_gap_s * 1e9)
        n = t.size
        keep = np.ones(n, dtype=bool)
        seg = np.empty(n, dtype=np.int64)
        last, max_t, segment = self._last_t, self._max_t, self._segment
        # Vectorised fast path: strictly increasing stamps, no clock jump.
        if n and (last is None or t[0] > max_t) and np.all(np.diff(t) > 0):
            d = np.diff(t, prepend=t[0] if last is None else last)
            breaks = d > gap_ns
            if last is None:
                breaks[0] = False
            self.counts['gap'] += int(np.count_nonzero(breaks))
            seg[:] = segment + np.cumsum(breaks)
            self._last_t = self._max_t = int(t[-1])
            self._segment = int(seg[-1])
            return t, pos, vel, eff, seg, np.arange(n)
        for k in range(n):
            tk = int(t[k])
            if last is not None:
                if tk == last:
                    self.counts['duplicate'] += 1
                    keep[k] = False
                    continue
                if tk <= max_t - jump_ns:
                    self.counts['clock_jump'] += 1
                    segment += 1
                    max_t = tk
                elif tk <= max_t:
                    self.counts['out_of_order'] += 1
                    keep[k] = False
                    continue
                elif tk - last > gap_ns:
                    self.counts['gap'] += 1
                    segment += 1
            last = tk
            max_t = tk if max_t is None else max(max_t, tk)
            seg[k] = segment
        self._last_t, self._max_t, self._segment = last, max_t, segment
        return t[keep], pos[keep], vel[keep], eff[keep], seg[keep], np.flatnonzero(keep)

    def _unwrap_positions(self, pos, t, seg, arrival, all_finite=False):
        """
        Unwrap jumps of about 2·pi between close neighbours (within and across calls).

        Only neighbours of one segment and at most :data:`WRAP_PERIODS` nominal
        periods apart are compared: across a longer hole a fast motor may move
        about a whole turn, and the turn count is restored downstream by
        keeping the TE continuous. Until the period is known (``arrival`` gives each
        sample's arrival index in the stream) neighbours up to ``max_gap_s`` apart are:
        the same rows whether the stream came in one chunk or many (a 4-period hole
        among a stream's first steps was unwrapped when it came in small pieces, a
        turn apart from the one piece). ``all_finite`` says that ``pos`` holds no NaN
        (nothing to forward-fill).
        """
        n, k = pos.shape
        if self._unwrap is None:
            self._unwrap = np.zeros(k)
            self._raw_last = np.full(k, np.nan)
        if n == 0:
            return pos
        prev_t, prev_seg = self._wrap_prev if self._wrap_prev else (t[0], seg[0])
        self._wrap_prev = (int(t[-1]), int(seg[-1]))
        if all_finite:
            filled = pos
        else:
            # Forward-fill each column so a dropped value does not hide a wrap.
            rows = np.where(np.isfinite(pos), np.arange(n)[:, None], -1)
            rows = np.maximum.accumulate(rows, axis=0)
            filled = np.where(rows >= 0, pos[np.maximum(rows, 0), np.arange(k)], self._raw_last)
        prev = np.where(np.isfinite(self._raw_last), self._raw_last, filled[0])
        d = np.diff(filled, axis=0, prepend=prev[None, :])
        # The common case: no neighbours a half turn apart, so nothing wrapped (NaN never is).
        if not (np.abs(d) > math.pi).any():
            self._raw_last = np.where(np.isfinite(filled[-1]), filled[-1], self._raw_last)
            return pos + self._unwrap
        dt = np.diff(t, prepend=prev_t)
        span = self.config.max_gap_s * 1e9
        if self.period_ns:
            span = np.where(arrival >= self._period_row, WRAP_PERIODS * self.period_ns, span)
        close = ((dt <= span) & (seg == np.concatenate([[prev_seg], seg[:-1]])))[:, None]
        d = np.where(np.isfinite(d), d, 0.0)
        turns = np.round(d / (2.0 * math.pi))
        # A real move of pi in one sample is impossible at any robot speed; a jump of
        # about a whole turn is an encoder wrapping.
        wrapped = close & (np.abs(d) > math.pi) & (np.abs(d - turns * 2.0 * math.pi) < 0.5)
        self.counts['wrap'] += int(np.count_nonzero(wrapped))
        self.column_counts['wrap'] += np.count_nonzero(wrapped, axis=0)
        offset = self._unwrap - np.cumsum(np.where(wrapped, turns, 0.0), axis=0) * 2.0 * math.pi
        self._raw_last = np.where(np.isfinite(filled[-1]), filled[-1], self._raw_last)
        self._unwrap = offset[-1].copy()
        return pos + offset


class SpikeFilter:
    """
    Drop paired samples whose TE jumps away from the last accepted TE.

    TE (``link - motor/i``) changes by far less than ``spike_te_rad``
    between samples of a working reducer (lost motion is a few arc minutes,
    traversed over many samples), so a larger jump is an encoder glitch of
    either side. A second consecutive sample that agrees with the dropped one
    (within the threshold) means the jump is real (e.g. re-homing): it is
    accepted and counted as a ``step``. Causal: no sample is held back.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``.
    config : IngestConfig
        Thresholds.

    """

    def __init__(self, ratio, config=None):
        self.ratio = float(ratio)
        self.threshold = (config or IngestConfig()).spike_te_rad
        self.counts = dict.fromkeys(SPIKE_REASONS, 0)
        self._last = None       # last accepted TE
        self._rejected = None   # TE of the sample dropped just before

    def keep(self, motor, link):
        """
        Return the mask of samples to keep.

        Parameters
        ----------
        motor, link : ndarray
            Motor (input) and link angles of paired samples [rad].

        Returns
        -------
        ndarray of bool
            True for samples that are not spikes.

        """
        return self.keep_te(link - motor / self.ratio)

    def keep_te(self, te):
        """
        Return the mask of samples to keep, given their TE.

        Parameters
        ----------
        te : ndarray
            TE ``link - motor/i`` of paired samples [rad].

        Returns
        -------
        ndarray of bool
            True for samples that are not spikes.

        """
        n = te.size
        keep = np.ones(n, dtype=bool)
        if n == 0:
            return keep
        prev = np.empty(n)
        prev[0] = te[0] if self._last is None else self._last
        prev[1:] = te[:-1]
        suspects = np.flatnonzero(np.abs(te - prev) > self.threshold)
        if suspects.size == 0 and self._rejected is None:
            self._last = float(te[-1])
            return keep
        # Rare: walk from the first suspect with the true "last accepted" TE.
        start = int(suspects[0]) if suspects.size else 0
        last = self._last if start == 0 else float(te[start - 1])
        # Samples before ``start`` were accepted, which clears a rejection of the last call.
        rejected = self._rejected if start == 0 else None
        thr = self.threshold
        for k in range(start, n):
            x = float(te[k])
            if last is None or abs(x - last) <= thr:
                last, rejected = x, None
            elif rejected is not None and abs(x - rejected) <= thr:
                self.counts['step'] += 1
                last, rejected = x, None
            else:
                keep[k] = False
                self.counts['spike'] += 1
                rejected = x
        self._last, self._rejected = last, rejected
        return keep


class SpikeFilterBank:
    """
    :class:`SpikeFilter` for several joints at once (one column each).

    The common case, no jump anywhere, costs a few array operations for all
    joints together; a column with a suspect goes through its own filter.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``.
    columns : int
        Number of joints.
    config : IngestConfig
        Thresholds.

    """

    def __init__(self, ratio, columns, config=None):
        self.ratio = float(ratio)
        self.filters = [SpikeFilter(ratio, config) for _ in range(columns)]
        self.threshold = self.filters[0].threshold
        # Last accepted TE of every column while no filter has a rejection pending (the
        # common case, kept here as one array); None otherwise, the filters then hold it.
        self._last = None

    def keep(self, motor, link, valid):
        """
        Return the mask of paired samples to keep.

        Parameters
        ----------
        motor, link : ndarray, shape (N, K)
            Motor (input) and link angles [rad].
        valid : ndarray of bool, shape (N, K)
            Which entries are paired samples at all.

        Returns
        -------
        ndarray of bool, shape (N, K)
            ``valid`` without the spikes: ``valid`` itself when no sample is
            dropped.

        """
        with np.errstate(invalid='ignore'):
            te = link - motor / self.ratio
        last = self._last
        if last is not None and valid.all():
            if te.shape[0] == 1:
                jumps = np.abs(te[0] - last) > self.threshold
            else:
                jumps = np.abs(np.diff(te, axis=0, prepend=last[None, :])) > self.threshold
            if not jumps.any():
                self._last = te[-1].copy()
                return valid
        filters = self.filters
        if last is not None:
            for f, x in zip(filters, last.tolist()):
                f._last = x
        keep = valid.copy()
        for k, f in enumerate(filters):
            rows = np.flatnonzero(valid[:, k])
            keep[rows, k] = f.keep_te(te[rows, k])
        if all(f._last is not None and f._rejected is None for f in filters):
            self._last = np.array([f._last for f in filters])
        else:
            self._last = None
        return keep

    def counts(self, k):
        """Return the spike/step counts of joint ``k``."""
        return dict(self.filters[k].counts)


def _squeeze(stream):
    """Turn a one-column stream back into 1-D arrays, dropping its NaN rows."""
    ok = np.isfinite(stream.position[:, 0])
    return CleanStream(stream.t_ns[ok], stream.position[ok, 0], stream.velocity[ok, 0],
                       stream.effort[ok, 0], stream.segment[ok])


def _optional(values, shape, name):
    if values is None:
        return np.full(shape, np.nan)
    arr = np.asarray(values, dtype=float)
    if arr.shape != shape and not (shape[1] == 1 and arr.shape == shape[:1]):
        raise InvalidInput(f'{name} has shape {arr.shape} for positions of shape {shape}')
    return arr.reshape(shape)


@dataclass
class PairedSamples:
    """
    Time-aligned motor and link samples of one joint.

    Attributes
    ----------
    t_ns : ndarray of int64
        Link stamps [ns].
    motor_angle : ndarray
        Motor (input) angle at the link stamps [rad], multi-turn.
    link_angle : ndarray
        Link (output) angle [rad], multi-turn.
    effort : ndarray
        Output torque [N·m] (NaN where unknown).
    link_velocity : ndarray
        Link velocity [rad/s] (NaN where unknown).

    """

    t_ns: np.ndarray
    motor_angle: np.ndarray
    link_angle: np.ndarray
    effort: np.ndarray
    link_velocity: np.ndarray

    def __len__(self):
        return self.t_ns.size

    @classmethod
    def empty(cls):
        """Return a batch with no samples."""
        z = np.zeros(0)
        return cls(np.zeros(0, np.int64), z, z.copy(), z.copy(), z.copy())

    def as_rows(self, t0_ns=0):
        """
        Return the samples as rows of the ``encoder_pairs`` layout.

        Parameters
        ----------
        t0_ns : int
            Stamp subtracted before the conversion to seconds.

        Returns
        -------
        ndarray, shape (N, 5)
            ``stamp_s, motor_angle_rad, link_angle_rad, effort_nm,
            link_velocity_rad_s``.

        """
        return np.column_stack([(self.t_ns - t0_ns) * 1e-9, self.motor_angle, self.link_angle,
                                self.effort, self.link_velocity])


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


class Pairer:
    """
    Align a motor stream to a link stream of the same joint.

    The motor angle is interpolated linearly at each link stamp, from motor
    samples of the same segment no further than ``max_gap_s`` away on both
    sides; given the ``ratio``, a :class:`TickPairing` decides from the data
    whether the samples of one controller tick are paired as they are instead
    (their stamps differ by jitter only). Link samples waiting for a later
    motor sample are held while the link stream runs on for up to
    ``max_gap_s``; link samples that cannot be paired are counted as
    ``unpaired``.

    Parameters
    ----------
    config : IngestConfig
        Thresholds.
    motor_scale : float
        Factor that turns reported motor angles into input angles (1 for
        raw motor angles, the ratio when the controller divides by it).
    hold_s : float, optional
        How long [s of link stream] a link sample waits for the motor stream
        to cover it before it counts as unpaired (default ``max_gap_s``: live, a
        stalled motor topic must not hold the link). Offline, where a bag's
        link and motor messages can lie seconds apart in the file, a longer
        hold keeps every sample whose partner comes in a later chunk.
    effort : str
        Where the torque is read (:data:`EFFORT_SOURCES`); the motor side's
        effort is interpolated at the link stamps like its angle.
    motor_effort_scale : float
        Factor that turns the motor entry's effort into output torque.
    ratio : float, optional
        Reduction ratio; None: always interpolate (no :class:`TickPairing`).
    effort_scale : float
        Output torque per unit of the effort read (after ``motor_effort_scale``).

    Attributes
    ----------
    unpaired : int
        Link samples that could not be paired.
    ticks : TickPairing or None
        The pairing rule and its evidence.

    """

    def __init__(self, config=None, motor_scale=1.0, hold_s=None, effort='link',
                 motor_effort_scale=1.0, ratio=None, effort_scale=1.0):
        self.config = config or IngestConfig()
        self.effort_scale = float(effort_scale)
        self.motor_scale = float(motor_scale)
        self.hold_ns = int((self.config.max_gap_s if hold_s is None else hold_s) * 1e9)
        self.effort = effort
        self.motor_effort_scale = float(motor_effort_scale)
        self.unpaired = 0
        self.ticks = None if ratio is None else TickPairing(ratio)
        self._motor = CleanStream.empty()
        self._link = CleanStream.empty()

    def add_motor(self, stream):
        """Append cleaned motor samples."""
        if self.ticks is not None:
            self.ticks.learn('motor', stream.t_ns)
        self._motor = _concat(self._motor, stream)

    def add_link(self, stream):
        """Append cleaned link samples."""
        if self.ticks is not None:
            self.ticks.learn('link', stream.t_ns)
        self._link = _concat(self._link, stream)

    def pop(self, final=False):
        """
        Return every link sample that can be paired now.

        Parameters
        ----------
        final : bool
            Pair or drop everything that is left (end of data).

        Returns
        -------
        PairedSamples
            Paired samples in time order.

        """
        link, motor = self._link, self._motor
        if len(link) == 0:
            return PairedSamples.empty()
        gap_ns = int(self.config.max_gap_s * 1e9)
        # A link sample the motor stream has not covered while the link stream ran on for
        # max_gap_s is given up: a stalled motor topic must not hold the link for ever.
        stale = link.t_ns < link.t_ns[-1] - max(gap_ns, self.hold_ns)
        if len(motor) == 0:
            drop = np.ones(len(link), bool) if final else stale
            self.unpaired += int(np.count_nonzero(drop))
            self._link = _take(link, np.flatnonzero(~drop))
            return PairedSamples.empty()
        horizon = motor.t_ns[-1]
        # Hold samples the motor stream may still cover, unless too old.
        ready = (link.t_ns <= horizon) | stale
        if final:
            ready[:] = True
        idx = np.flatnonzero(ready)
        rest = np.flatnonzero(~ready)
        lt = link.t_ns[idx]
        j = np.searchsorted(motor.t_ns, lt, side='left')
        exact = (j < len(motor)) & (motor.t_ns[np.minimum(j, len(motor) - 1)] == lt)
        lo = np.clip(j - 1, 0, len(motor) - 1)
        hi = np.clip(j, 0, len(motor) - 1)
        lo = np.where(exact, hi, lo)
        t_lo, t_hi = motor.t_ns[lo], motor.t_ns[hi]
        ok = (exact | ((t_lo <= lt) & (t_hi >= lt) & (t_hi - t_lo <= 2 * gap_ns)
                       & (motor.segment[lo] == motor.segment[hi])))
        span = (t_hi - t_lo).astype(float)
        frac = np.where(span > 0, (lt - t_lo) / np.where(span > 0, span, 1.0), 0.0)
        m = motor.position[lo] + frac * (motor.position[hi] - motor.position[lo])
        tick = self._tick(lt, link.position[idx], m, motor, hi, ok)
        if tick is not None:
            m = np.where(tick >= 0, motor.position[np.maximum(tick, 0)], m)
        self.unpaired += int(np.count_nonzero(~ok))
        good = idx[ok]
        torque = link.effort[good]
        if self.effort != 'link':
            me = motor.effort[lo] + frac * (motor.effort[hi] - motor.effort[lo])
            if tick is not None:
                me = np.where(tick >= 0, motor.effort[np.maximum(tick, 0)], me)
            torque = choose_effort(torque, me[ok], self.effort, self.motor_effort_scale)
        if self.effort_scale != 1.0:
            torque = torque * self.effort_scale
        out = PairedSamples(link.t_ns[good], m[ok] * self.motor_scale, link.position[good],
                            torque, link.velocity[good])
        self._link = _take(link, rest)
        # Keep the motor samples still needed for later link stamps (plus one before).
        keep_from = max(0, int(np.searchsorted(motor.t_ns, lt[-1] if lt.size else 0)) - 1)
        if final:
            keep_from = len(motor)
        self._motor = _take(motor, np.arange(keep_from, len(motor)))
        return out

    def _tick(self, lt, link, m, motor, after, ok):
        """
        Return the tick's motor sample of each link stamp (-1: interpolated), or None.

        ``after`` is the first motor sample at or after each link stamp (clipped to the
        stream), whose segment a partner must share. Same-tick pairs feed the evidence
        of :attr:`ticks` until it decides.
        """
        ticks = self.ticks
        if ticks is None or ticks.decided == 'interpolate' or lt.size == 0:
            return None
        match = ticks.match(lt, motor.t_ns)
        if match is None:
            return None
        # Only a partner of the same segment (no gap or clock jump between them).
        near = np.maximum(match, 0)
        match = np.where((match >= 0) & (motor.segment[near] == motor.segment[after]), match, -1)
        if ticks.decided is None:
            scale = self.motor_scale
            ticks.observe(lt, link, m * scale, motor.position[near] * scale, ok & (match >= 0))
            if ticks.decided != 'tick':
                return None
        match = np.where(ok, match, -1)
        ticks.tick_paired += int(np.count_nonzero(match >= 0))
        return match


EFFORT_SOURCES = ('auto', 'link', 'motor')
"""Where the joint torque is read: the link entry, the motor entry, or the link where known."""

MOTOR_EFFORT_UNITS = ('auto', 'motor', 'joint')
"""What the motor entry's effort is: motor torque, output torque, or as its angles say."""


def motor_effort_scale(units, motor_angles, ratio):
    """
    Factor that turns the motor entry's effort into output torque.

    Parameters
    ----------
    units : str
        One of :data:`MOTOR_EFFORT_UNITS`; ``'auto'``: a motor torque unless the
        motor angles are reported divided by the ratio (then joint units).
    motor_angles : str
        ``'raw'``, ``'output'`` or ``'auto'`` (taken as raw).
    ratio : float
        Reduction ratio.

    Returns
    -------
    float
        ``ratio`` for a motor torque, 1 for joint units.

    """
    if units == 'auto':
        units = 'joint' if motor_angles == 'output' else 'motor'
    return ratio if units == 'motor' else 1.0


def motor_torque_seen(link_effort, motor_effort, ratio, lowest_bin, largest_torque):
    """
    Tell from the data a motor torque on the motor entry beside motor angles in output form.

    With ``motor_effort_units`` left to ``auto``, an effort on the motor entry beside
    motor angles divided by the ratio is read in joint units. A drive that reports the
    joint's angle but its motor's torque then gives efforts ``ratio`` times too small:
    the lowest torque bin the lost motion is read from is never reached, and the joint
    is not observed. Such an effort is taken for a motor torque when the link entry
    carries none (the motor entry's is the one read), the motor entry's stays below
    ``lowest_bin`` (read as output torque, it gives no lost motion either way), and
    ``ratio`` times it reaches ``lowest_bin`` without passing ``largest_torque``.

    Parameters
    ----------
    link_effort, motor_effort : ndarray
        The entries' efforts over the samples seen so far [as published] (NaN: none).
    ratio : float
        The reduction ratio.
    lowest_bin : float
        The lower edge of the lowest torque bin the lost motion is read from [N*m].
    largest_torque : float
        The largest output torque a reducer takes [N*m].

    Returns
    -------
    float or None
        The motor entry's largest effort (its 99.9th percentile of ``|effort|``) when it
        is a motor torque, else None (the configured rule stands).

    """
    if np.isfinite(link_effort).any():
        return None
    effort = np.abs(motor_effort[np.isfinite(motor_effort)])
    if effort.size < 100:
        return None
    peak = float(np.percentile(effort, 99.9))
    if peak < lowest_bin <= ratio * peak <= largest_torque:
        return peak
    return None


def choose_effort(link_effort, motor_effort, source='link', motor_effort_scale=1.0,
                  effort_scale=1.0):
    """
    Output torque from the link side, the motor side, or the link side where it is known.

    Parameters
    ----------
    link_effort, motor_effort : ndarray
        Effort of the link and motor entries at the same samples.
    source : str
        One of :data:`EFFORT_SOURCES`.
    motor_effort_scale : float
        Factor that turns the motor entry's effort into output torque (the ratio
        for a motor torque, 1 when the controller reports it in joint units).
    effort_scale : float
        Output torque per unit of the effort so chosen (-1 for an effort of the other
        sign; a torque constant for a current).

    Returns
    -------
    ndarray
        Output torque [N·m], NaN where unknown.

    """
    if effort_scale != 1.0:
        return effort_scale * choose_effort(link_effort, motor_effort, source,
                                            motor_effort_scale)
    if source == 'link':
        return link_effort
    if source != 'motor':
        known = np.isfinite(link_effort)
        if known.all():
            return link_effort
    motor = motor_effort * motor_effort_scale if motor_effort_scale != 1.0 else motor_effort
    if source == 'motor':
        return motor
    return np.where(known, link_effort, motor)


def pair_columns(stream, link_col, motor_col, motor_scale=1.0, effort='link',
                 motor_effort_scale=1.0, effort_scale=1.0):
    """
    Pair two columns of a stream cleaned together (one message per tick).

    Parameters
    ----------
    stream : CleanStream
        2-D stream holding both columns.
    link_col, motor_col : int
        Column indices of the link and motor sides.
    motor_scale : float
        Factor that turns reported motor angles into input angles.
    effort : str
        Where the torque is read (:data:`EFFORT_SOURCES`).
    motor_effort_scale : float
        Factor that turns the motor entry's effort into output torque.
    effort_scale : float
        Output torque per unit of the effort so chosen.

    Returns
    -------
    tuple
        ``(rows, unpaired)``: rows ``(stamp_ns, motor, link, effort,
        velocity)`` where both sides are valid, as float64 with the stamp in
        the first column, and the number of rows with only one side.

    """
    link = stream.position[:, link_col]
    motor = stream.position[:, motor_col]
    ok = np.isfinite(link) & np.isfinite(motor)
    unpaired = int(np.count_nonzero(np.isfinite(link) ^ np.isfinite(motor)))
    torque = choose_effort(stream.effort[:, link_col], stream.effort[:, motor_col], effort,
                           motor_effort_scale, effort_scale)
    if ok.all():
        return (stream.t_ns, motor * motor_scale, link, torque,
                stream.velocity[:, link_col]), unpaired
    return (stream.t_ns[ok], motor[ok] * motor_scale, link[ok], torque[ok],
            stream.velocity[ok, link_col]), unpaired


def pair_same_stamps(link, motor, motor_scale=1.0):
    """
    Pair streams that share their stamps (one message per tick).

    Parameters
    ----------
    link, motor : CleanStream
        Cleaned streams; only stamps present in both are paired.
    motor_scale : float
        Factor that turns reported motor angles into input angles.

    Returns
    -------
    tuple
        ``(PairedSamples, unpaired_count)``.

    """
    if len(link) == len(motor) and np.array_equal(link.t_ns, motor.t_ns):
        return PairedSamples(link.t_ns, motor.position * motor_scale, link.position,
                             link.effort, link.velocity), 0
    common, li, mi = np.intersect1d(link.t_ns, motor.t_ns, assume_unique=True,
                                    return_indices=True)
    unpaired = len(link) + len(motor) - 2 * common.size
    return PairedSamples(common, motor.position[mi] * motor_scale, link.position[li],
                         link.effort[li], link.velocity[li]), unpaired


def _concat(a, b):
    if len(a) == 0:
        return b
    if len(b) == 0:
        return a
    return CleanStream(*(np.concatenate([x, y]) for x, y in
                         ((a.t_ns, b.t_ns), (a.position, b.position), (a.velocity, b.velocity),
                          (a.effort, b.effort), (a.segment, b.segment))))


def _take(s, idx):
    return CleanStream(s.t_ns[idx], s.position[idx], s.velocity[idx], s.effort[idx],
                       s.segment[idx])
