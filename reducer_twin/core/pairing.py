"""
Pairing of a joint's motor and link samples (the ingestion stage's second step).

A joint's two cleaned angle streams (:class:`.ingest.CleanStream`) become time-aligned
samples (:class:`PairedSamples`): columns of one message per tick are paired row by row
(:func:`pair_columns`, :func:`pair_same_stamps`); a motor stream on a topic of its own is
aligned to the link stamps by :class:`Pairer`, interpolated or by controller tick as
:class:`.tick_pairing.TickPairing` decides. The torque is read where
:func:`.effort_source.choose_effort` says.
"""

from dataclasses import dataclass

import numpy as np

from .effort_source import choose_effort
from .ingest import CleanStream, IngestConfig
from .tick_pairing import TickPairing


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
    sides; given the ``ratio``, a :class:`.tick_pairing.TickPairing` decides
    from the data whether the samples of one controller tick are paired as they
    are instead (their stamps differ by jitter only). Link samples waiting for a later
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
        Where the torque is read (:data:`.effort_source.EFFORT_SOURCES`); the motor
        side's effort is interpolated at the link stamps like its angle.
    motor_effort_scale : float
        Factor that turns the motor entry's effort into output torque.
    ratio : float, optional
        Reduction ratio; None: always interpolate (no
        :class:`.tick_pairing.TickPairing`).
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
        Where the torque is read (:data:`.effort_source.EFFORT_SOURCES`).
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
