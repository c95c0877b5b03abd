"""
Validation of encoder streams (the ingestion stage's cleaner).

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
                  message arrived) are re-timed on it
                  (:class:`.stamp_clock.StampClock`)
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
================  ==========================================================

Counts of each reason are kept for the diagnostics. This module owns the stage's
thresholds (:class:`IngestConfig`), the cleaned stream (:class:`CleanStream`) and the
cleaner (:class:`StreamCleaner`). The rest of the stage lives beside it: the stamp clock
(:mod:`.stamp_clock`), the pairing of motor and link samples (:mod:`.pairing`, by
controller tick or interpolated as :mod:`.tick_pairing` decides; the torque read as
:mod:`.effort_source` says) and the spike filter of the paired samples (:mod:`.spikes`).
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import InvalidInput
from .params import _Validated, spec
from .stamp_clock import FAST_ROWS, PERIOD_STEPS, StampClock

REASONS = ('non_finite', 'duplicate', 'out_of_order', 'clock_jump', 'gap', 'wrap')
"""Reasons a stream sample is dropped or repaired (per encoder stream)."""

VALUE_REASONS = ('non_finite', 'wrap')
"""The rules that act on one column's values (the others act on whole rows)."""

WRAP_PERIODS = 3
"""Neighbours further apart than this many nominal periods are not tested for a wrap."""


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


def stream_cleaners(config, split):
    """
    Return the cleaners of a robot's link stream and of its motor stream (None if one).

    Only a stream that carries both encoders of its joints may be re-timed
    (:class:`.stamp_clock.StampClock`): two topics keep their stamps.
    """
    if split:
        return StreamCleaner(config, retime=False), StreamCleaner(config, retime=False)
    return StreamCleaner(config), None


class StreamCleaner:
    """
    Apply the ingestion rules to angle streams, chunk by chunk.

    Several streams that share their stamps (all joints of one JointState
    message) are cleaned together as the columns of 2-D arrays: stamp rules
    act on rows, value rules (non-finite, wrap) on each column, and
    a dropped value becomes NaN in its column only.

    Parameters
    ----------
    config : IngestConfig
        Thresholds.
    retime : bool
        Whether stamps that scatter about a clock may be re-timed
        (:class:`.stamp_clock.StampClock`: a stream that carries both encoders of its joints).

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
