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
``spike``         one sample off its neighbours by more than the spike
                  threshold while the next one returns: dropped (this
                  costs one sample of delay)
================  ==========================================================

Counts of each reason are kept for the diagnostics.
"""

from dataclasses import dataclass
import math

import numpy as np

from .errors import InvalidInput
from .params import _Validated, spec

REASONS = ('non_finite', 'duplicate', 'out_of_order', 'clock_jump', 'gap', 'wrap', 'spike')
"""Reasons a sample is dropped or repaired, in the order of the table above."""


@dataclass(frozen=True)
class IngestConfig(_Validated):
    """Thresholds of the ingestion rules."""

    _prefix = 'ingest'
    max_gap_s: float = spec(0.05, 's', 0.0, 60.0, 'largest stamp gap bridged by interpolation',
                            lo_open=True)
    clock_jump_s: float = spec(1.0, 's', 0.0, 1e6,
                               'backward stamp jump treated as a clock reset', lo_open=True)
    link_spike_rad: float = spec(math.radians(0.5), 'rad', 0.0, 10.0,
                                 'deviation of a link sample that counts as a spike',
                                 lo_open=True)
    motor_spike_rad: float = spec(math.radians(0.5) * 81.0, 'rad', 0.0, 1000.0,
                                  'deviation of a motor sample that counts as a spike',
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


class StreamCleaner:
    """
    Apply the ingestion rules to angle streams, chunk by chunk.

    Several streams that share their stamps (all joints of one JointState
    message) are cleaned together as the columns of 2-D arrays: stamp rules
    act on rows, value rules (non-finite, wrap, spike) on each column, and
    a dropped value becomes NaN in its column only.

    Parameters
    ----------
    spike_rad : float or array_like
        Deviation from the neighbours that marks a spike [rad], per column.
    config : IngestConfig
        Thresholds.

    """

    def __init__(self, spike_rad, config=None):
        self.config = config or IngestConfig()
        self.spike_rad = np.asarray(spike_rad, dtype=float)
        self.counts = dict.fromkeys(REASONS, 0)
        self.accepted = 0
        self.missing = 0
        self.period_ns = None
        self._raw_prev_t = None
        self._diffs = []
        self._last_t = None
        self._max_t = None
        self._segment = 0
        self._unwrap = None     # per-column unwrap offset [rad]
        self._raw_last = None   # per-column last finite raw value
        self._held = None       # last row, waiting for its right neighbour
        self._prev = None       # (t, positions) of the last released row
        self._ndim = None

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
            Accepted samples, same dimensionality as ``position`` (the last
            row is held back until the next call or :meth:`flush` for the
            spike test).

        Raises
        ------
        InvalidInput
            If the arrays do not match in shape.

        """
        t = np.asarray(t_ns, dtype=np.int64).ravel()
        pos = np.asarray(position, dtype=float)
        n = t.size
        one_d = pos.ndim == 1
        if self._ndim is None:
            self._ndim = pos.ndim
        pos = pos.reshape(n, -1) if pos.size == n * max(1, pos.size // max(n, 1)) else pos
        if pos.ndim != 2 or pos.shape[0] != n:
            raise InvalidInput(f'position has shape {np.shape(position)} for {n} stamps')
        vel = _optional(velocity, pos.shape, 'velocity')
        eff = _optional(effort, pos.shape, 'effort')
        self._count_missing(t)
        finite = np.isfinite(pos)
        self.counts['non_finite'] += int(finite.size - np.count_nonzero(finite))
        pos = np.where(finite, pos, np.nan)
        t, pos, vel, eff, seg = self._order(t, pos, vel, eff)
        pos = self._unwrap_positions(pos)
        out = self._despike(t, pos, vel, eff, seg)
        return _squeeze(out) if one_d else out

    def _count_missing(self, t):
        """Count samples missing from the stream (stamp holes at the nominal period)."""
        if t.size == 0:
            return
        prev = t[0] if self._raw_prev_t is None else self._raw_prev_t
        d = np.diff(t, prepend=prev)
        d = d[d > 0]
        self._raw_prev_t = int(t[-1])
        if self.period_ns is None:
            self._diffs.extend(d[:64].tolist())
            if len(self._diffs) < 16:
                return
            self.period_ns = float(np.median(self._diffs))
        holes = d[(d > 1.5 * self.period_ns) & (d < self.config.max_gap_s * 1e9 * 200)]
        self.missing += int(np.sum(np.round(holes / self.period_ns) - 1))

    def flush(self):
        """
        Release the row held back for the spike test.

        Returns
        -------
        CleanStream
            Zero or one sample.

        """
        if self._held is None:
            return CleanStream.empty()
        t, p, v, e, s = self._held
        self._held = None
        self.accepted += 1
        out = CleanStream(np.array([t], np.int64), p[None, :], v[None, :], e[None, :],
                          np.array([s], np.int64))
        return _squeeze(out) if self._ndim == 1 else out

    def _order(self, t, pos, vel, eff):
        """Drop duplicate/out-of-order stamps, split segments at gaps and clock jumps."""
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
            return t, pos, vel, eff, seg
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
        return t[keep], pos[keep], vel[keep], eff[keep], seg[keep]

    def _unwrap_positions(self, pos):
        """Unwrap jumps of about 2·pi between finite neighbours (within and across calls)."""
        n, k = pos.shape
        if self._unwrap is None:
            self._unwrap = np.zeros(k)
            self._raw_last = np.full(k, np.nan)
        if n == 0:
            return pos
        finite = np.isfinite(pos)
        # Forward-fill each column so a dropped value does not hide a wrap.
        rows = np.where(finite, np.arange(n)[:, None], -1)
        rows = np.maximum.accumulate(rows, axis=0)
        filled = np.where(rows >= 0, pos[np.maximum(rows, 0), np.arange(k)], self._raw_last)
        prev = np.where(np.isfinite(self._raw_last), self._raw_last, filled[0])
        d = np.diff(filled, axis=0, prepend=prev[None, :])
        d = np.where(np.isfinite(d), d, 0.0)
        turns = np.round(d / (2.0 * math.pi))
        # A real move of pi in one sample is impossible at any robot speed; a jump of
        # about a whole turn is an encoder wrapping.
        wrapped = (np.abs(d) > math.pi) & (np.abs(d - turns * 2.0 * math.pi) < 0.5)
        self.counts['wrap'] += int(np.count_nonzero(wrapped))
        offset = self._unwrap - np.cumsum(np.where(wrapped, turns, 0.0), axis=0) * 2.0 * math.pi
        self._raw_last = np.where(np.isfinite(filled[-1]), filled[-1], self._raw_last)
        self._unwrap = offset[-1].copy()
        return pos + offset

    def _despike(self, t, pos, vel, eff, seg):
        """Drop single values off both neighbours; hold the newest row back one call."""
        if self._held is not None:
            h = self._held
            t = np.concatenate([[h[0]], t])
            pos = np.concatenate([h[1][None, :], pos])
            vel = np.concatenate([h[2][None, :], vel])
            eff = np.concatenate([h[3][None, :], eff])
            seg = np.concatenate([[h[4]], seg])
            self._held = None
        n = t.size
        if n == 0:
            return CleanStream.empty(pos.shape[1])
        if n >= 2:
            left_t = np.empty(n, np.int64)
            left_p = np.empty_like(pos)
            left_t[1:], left_p[1:] = t[:-1], pos[:-1]
            if self._prev is not None:
                left_t[0], left_p[0] = self._prev
            else:
                left_t[0], left_p[0] = t[0], np.nan
            span = (t[1:] - left_t[:-1]).astype(float)
            frac = np.where(span > 0, (t[:-1] - left_t[:-1]) / np.where(span > 0, span, 1.0),
                            0.5)[:, None]
            right_p = pos[1:]
            line = left_p[:-1] + frac * (right_p - left_p[:-1])
            with np.errstate(invalid='ignore'):
                dev = np.abs(pos[:-1] - line)
                agree = np.abs(right_p - left_p[:-1]) < self.spike_rad
                spike = (dev > self.spike_rad) & agree & (seg[:-1] == seg[1:])[:, None]
            if spike.any():
                self.counts['spike'] += int(np.count_nonzero(spike))
                pos = pos.copy()
                pos[:-1][spike] = np.nan
        self._held = (int(t[-1]), pos[-1].copy(), vel[-1].copy(), eff[-1].copy(), int(seg[-1]))
        rel = slice(0, n - 1)
        out = CleanStream(t[rel], pos[rel], vel[rel], eff[rel], seg[rel])
        if n >= 2:
            self._prev = (int(t[n - 2]), np.where(np.isfinite(pos[n - 2]), pos[n - 2],
                                                  self._prev[1] if self._prev else np.nan))
        self.accepted += n - 1
        return out


def _squeeze(stream):
    """Turn a one-column stream back into 1-D arrays, dropping its NaN rows."""
    ok = np.isfinite(stream.position[:, 0])
    return CleanStream(stream.t_ns[ok], stream.position[ok, 0], stream.velocity[ok, 0],
                       stream.effort[ok, 0], stream.segment[ok])


def _optional(values, shape, name):
    if values is None:
        return np.full(shape, np.nan)
    arr = np.asarray(values, dtype=float)
    if arr.size != int(np.prod(shape)):
        raise InvalidInput(f'{name} has {arr.size} values for positions of shape {shape}')
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


class Pairer:
    """
    Align a motor stream to a link stream of the same joint.

    The motor angle is interpolated linearly at each link stamp, from motor
    samples of the same segment no further than ``max_gap_s`` away on both
    sides. Link samples waiting for a later motor sample are held (up to
    ``max_gap_s``); link samples that cannot be paired are counted as
    ``unpaired``.

    Parameters
    ----------
    config : IngestConfig
        Thresholds.
    motor_scale : float
        Factor that turns reported motor angles into input angles (1 for
        raw motor angles, the ratio when the controller divides by it).

    """

    def __init__(self, config=None, motor_scale=1.0):
        self.config = config or IngestConfig()
        self.motor_scale = float(motor_scale)
        self.unpaired = 0
        self._motor = CleanStream.empty()
        self._link = CleanStream.empty()

    def add_motor(self, stream):
        """Append cleaned motor samples."""
        self._motor = _concat(self._motor, stream)

    def add_link(self, stream):
        """Append cleaned link samples."""
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
        if len(motor) == 0:
            if final:
                self.unpaired += len(link)
                self._link = CleanStream.empty()
            return PairedSamples.empty()
        horizon = motor.t_ns[-1]
        ready = link.t_ns <= horizon
        if not final:
            # Hold samples the motor stream may still cover, unless too old.
            ready |= link.t_ns < horizon - gap_ns
        else:
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
        self.unpaired += int(np.count_nonzero(~ok))
        good = idx[ok]
        out = PairedSamples(link.t_ns[good], m[ok] * self.motor_scale, link.position[good],
                            link.effort[good], link.velocity[good])
        self._link = _take(link, rest)
        # Keep the motor samples still needed for later link stamps (plus one before).
        keep_from = max(0, int(np.searchsorted(motor.t_ns, lt[-1] if lt.size else 0)) - 1)
        if final:
            keep_from = len(motor)
        self._motor = _take(motor, np.arange(keep_from, len(motor)))
        return out


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
