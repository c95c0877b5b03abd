"""
Transmission error from a motor/link encoder pair.

This is what runs on real robot data. :func:`compute_te` turns two encoder
streams into ``TE = theta_link - theta_motor/i`` [rad] (unwrapping, time
alignment, gaps) and :class:`TEExtractor` does it chunk by chunk, as the
samples arrive; the :mod:`.window_analysis` cuts the TE stream into windows
and reads the lost motion, the wear estimator's observation.
"""

from dataclasses import dataclass, replace
import math

import numpy as np

from .encoder_steps import EncoderSteps
from .errors import InvalidInput, InvalidParameter, out_of_range
from .held_encoders import HeldEncoders
from .stamp_clock import median_step
from .tick_pairing import TickPairing
from .travel_ratio import TravelRatio


TWO_PI = 2.0 * math.pi

CLOCK_RESET_S = 60.0
"""
A stamp this far [s] or more behind the newest one means the clock was reset.

Sim time reset, or a long bag played again: the stream starts over at that sample
(:class:`TEExtractor` and :class:`WindowAnalyzer` restart there). A stamp less far
back is a replay or a late sample, left out as before. The wear estimator tells a
replayed window from a reset by the same horizon (:data:`.pipeline.CLOCK_RESET_S`).
"""

TIME_OFFSET_LINEAR_S = 1e-3
"""
Largest time offset between the encoders [s] that is read as the TE's linear term ``omega·delta``.

An offset ``delta`` pairs each link sample with the motor ``delta`` away: the TE gains the
motor's travel over ``delta`` less the link's, ``omega·delta`` only while both move alike.
Through the play the motor moves and the link does not, and the TE's own change over
``delta`` enters the reversals that the lost motion is read from; the acceleration adds
``delta^2·alpha/2``. On the model's simulator (an unloaded joint, 60 s at 1 kHz, 2 %
effort noise, two seeds; a one-off sweep, the 10-20 ms cases kept in
``test/core/test_joint_twin.py``) the windows' pooled TE referred to the learnt offset by
the linear map read the lost motion within 0.2 % to 1 ms, +1.6 % at 2 ms, +5 % at 3 ms,
+17 % at 5 ms, +69 % at 10 ms. Beyond this the TE read before the offset was removed is
not used: its windows give no lost motion, the pool and the partial window are dropped when
the offset is learnt, and a jump of a window's mean is not said to be a step of the TE's
constant.
"""


@dataclass(frozen=True)
class TEStream:
    """
    TE at the link stamps; arrays index-aligned with the link input (length N).

    Attributes
    ----------
    t : ndarray
        Link stamps [s] as given.
    te : ndarray
        TE ``theta_link - theta_motor/i`` [rad], NaN where not valid. Its
        constant is reduced into ``(-pi/i, pi/i]`` at the first valid
        sample, since the turn counts of wrapped encoders are unknown.
    output_angle : ndarray
        Unwrapped link angle [rad], NaN where not valid (defined up to whole
        turns when the input was wrapped).
    valid : ndarray of bool
        Samples with a usable TE.
    max_gap_s : float
        Largest stamp spacing interpolated or unwrapped across [s].
    motor_nonfinite, motor_unordered : int
        Motor samples dropped for a NaN/inf stamp or angle, and for a stamp
        not later than every earlier one.
    link_nonfinite, link_unordered : int
        The same for link samples.
    link_uncovered : int
        Valid link samples outside the motor stream's span or inside a motor
        gap (never interpolated across).
    turn_corrections : int
        Gaps across which a turn count of a wrapped stream was restored.

    """

    t: np.ndarray
    te: np.ndarray
    output_angle: np.ndarray
    valid: np.ndarray
    max_gap_s: float
    motor_nonfinite: int = 0
    motor_unordered: int = 0
    link_nonfinite: int = 0
    link_unordered: int = 0
    link_uncovered: int = 0
    turn_corrections: int = 0

    def __len__(self):
        """Return the number of link samples."""
        return self.t.shape[0]

    @property
    def dropped(self):
        """Count the link samples without a TE."""
        return int(self.valid.size - np.count_nonzero(self.valid))

    def part(self, sl):
        """
        Return the samples ``sl`` of this stream (its counts kept whole).

        Parameters
        ----------
        sl : slice
            Which link samples.

        Returns
        -------
        TEStream
            Views of this stream's arrays.

        """
        return stream_slice(self, sl)


def _as_stream(t, angle, name):
    """Check one stamp/angle pair: 1-D float arrays of equal length."""
    try:
        t = np.asarray(t, dtype=float)
        angle = np.asarray(angle, dtype=float)
    except (TypeError, ValueError) as err:
        raise InvalidInput(f'{name} stamps and angles must be numeric arrays: {err}') from err
    if t.ndim != 1 or angle.ndim != 1:
        raise InvalidInput(f'{name} stamps and angles must be 1-D, got shapes '
                           f'{t.shape} and {angle.shape}')
    if t.shape != angle.shape:
        raise InvalidInput(f'{name} stamps and angles must have the same length, got '
                           f'{t.size} stamps and {angle.size} angles')
    return t, angle


def _usable(t, angle):
    """
    Find finite samples whose stamp is later than every earlier stamp.

    Returns the mask (None when every sample is usable) and the counts of
    non-finite and of out-of-order samples.
    """
    finite = np.isfinite(t) & np.isfinite(angle)
    if finite.all() and (t.size < 2 or (np.diff(t) > 0.0).all()):
        return None, 0, 0
    tf = np.where(finite, t, -np.inf)
    previous = np.concatenate([[-np.inf], np.maximum.accumulate(tf)[:-1]])
    ordered = tf > previous
    keep = finite & ordered
    return keep, int(np.count_nonzero(~finite)), int(np.count_nonzero(finite & ~ordered))


def reset_indices(t, newest=None):
    """
    Return the indices where the stamp falls :data:`CLOCK_RESET_S` behind the newest.

    Parameters
    ----------
    t : ndarray
        Stamps [s] (NaN ignored).
    newest : float, optional
        Newest stamp before ``t``.

    Returns
    -------
    list of int
        Each index starts a new stream; the newest stamp restarts there.

    """
    if t.size < 2 or (np.diff(t) > 0.0).all():
        # Increasing stamps (the common case) fall back only against ``newest``, if at all.
        return [0] if t.size and newest is not None and t[0] <= newest - CLOCK_RESET_S else []
    out, start = [], 0
    while start < t.size:
        head = np.nan if newest is None else newest
        before = np.fmax.accumulate(np.concatenate([[head], t[start:-1]]))
        back = np.flatnonzero(t[start:] <= before - CLOCK_RESET_S)
        if back.size == 0:
            break
        start += int(back[0])
        out.append(start)
        newest = None
    return out


def cut_pieces(n, cuts):
    """Slices of ``range(n)`` cut at ``cuts``."""
    bounds = [0, *cuts, n]
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]


def _join(streams):
    """Concatenate the TE streams of consecutive pieces of one chunk."""
    first = streams[0]
    if len(streams) == 1:
        return first
    counts = {name: sum(getattr(s, name) for s in streams) for name in (
        'motor_nonfinite', 'motor_unordered', 'link_nonfinite', 'link_unordered',
        'link_uncovered', 'turn_corrections')}
    return TEStream(*(np.concatenate([getattr(s, name) for s in streams])
                      for name in ('t', 'te', 'output_angle', 'valid')),
                    first.max_gap_s, **counts)


def _shared(t_motor, t_link):
    """Whether the motor and link samples share their stamps (one per row)."""
    try:
        tm, tl = np.asarray(t_motor, dtype=float), np.asarray(t_link, dtype=float)
    except (TypeError, ValueError):
        return False
    return tm.shape == tl.shape and (tm is tl or np.array_equal(tm, tl))


def _motor_at(t_motor, motor_angle, t_link):
    """
    Return the motor angle at the link stamps for :class:`.held_encoders.HeldEncoders`.

    None where the motor has fewer than two usable samples.

    Linear between the motor's own samples: a motor reading held on its own stamps stays held
    between them, and a link reading is judged against the motor's motion.
    """
    try:
        tm, am, tl = (np.asarray(a, dtype=float) for a in (t_motor, motor_angle, t_link))
    except (TypeError, ValueError):
        return None
    ok = np.isfinite(tm) & np.isfinite(am)
    if np.count_nonzero(ok) < 2 or tm.shape != am.shape:
        return None
    tm, am = tm[ok], am[ok]
    if not (np.diff(tm) > 0.0).all():
        order = np.argsort(tm, kind='stable')
        tm, am = tm[order], am[order]
    return np.interp(tl, tm, am)


def stream_slice(stream, sl):
    """Return the samples ``sl`` of a TE stream (counts kept whole)."""
    return TEStream(stream.t[sl], stream.te[sl], stream.output_angle[sl], stream.valid[sl],
                    stream.max_gap_s, stream.motor_nonfinite, stream.motor_unordered,
                    stream.link_nonfinite, stream.link_unordered, stream.link_uncovered,
                    stream.turn_corrections)


def _unwrap(t, angle, max_gap, predict=None):
    """
    Unwrap within runs of samples closer than ``max_gap``; never across a gap.

    Whole turns are counted as integers, so an already unwrapped stream
    comes back bit-identical. ``predict`` (optional) returns the angle the
    stream is expected to follow (the motor: the link angle times the ratio):
    once a step of half a turn or more is seen, every step holds as many turns
    as it departs from the expected step, so a fast motor that turns half a
    turn or more across a few lost samples (65 rad/s over 40 ms) is not
    unwrapped by a turn, and a wrapped one is unwrapped right. Expected steps
    of two turns or more (the expectation's own turn count unknown) are not
    used. Returns the angle and the run index per sample (None when there is
    no gap: one run).
    """
    if angle.size < 2:
        return angle, None
    step = np.diff(angle)
    gap = np.diff(t) > max_gap
    if np.abs(step).max() >= np.pi:
        expected = predict() if predict is not None else None
        if expected is not None:
            moved = np.diff(expected)
            step = step - np.where(np.abs(moved) < 2.0 * TWO_PI, moved, 0.0)
        jumps = np.where(gap, 0.0, np.round(step / TWO_PI)).astype(np.int64)
        angle = angle - TWO_PI * np.concatenate([[0], np.cumsum(jumps)])
    if not gap.any():
        return angle, None
    return angle, np.concatenate([[0], np.cumsum(gap)])


def _turns(delta, ratio):
    """Split a TE jump into whole link turns and whole motor turns (integers)."""
    link_turns = np.round(delta / TWO_PI)
    motor_turns = np.round((delta - TWO_PI * link_turns) * ratio / TWO_PI)
    return link_turns.astype(np.int64), motor_turns.astype(np.int64)


def _run_starts(sel, *runs):
    """Positions in ``sel`` where a run of any of ``runs`` (None: one run) begins, after 0."""
    change = np.zeros(max(sel.size - 1, 0), dtype=bool)
    for run in runs:
        if run is not None:
            change |= np.diff(run[sel]) != 0
    return np.flatnonzero(change) + 1


def compute_te(t_motor, motor_angle, t_link, link_angle, ratio, max_gap_s=0.005,
               link_time_offset_s=0.0, te_reference=None):
    """
    Compute the transmission error from motor and link encoder streams.

    ``TE(t) = theta_link(t) - theta_motor(t + delta)/i`` [rad], the motor
    angle interpolated linearly at each link stamp shifted by ``delta``.
    Angles may be multi-turn or wrapped (to ``[-pi, pi)``, ``[0, 2·pi)`` or
    any 2·pi range); each stream is unwrapped within runs of samples closer
    than ``max_gap_s`` (it must turn less than half a turn between such
    samples). Across a gap nothing is unwrapped or interpolated: the turn
    counts are restored by keeping the TE continuous, which holds because
    the true TE changes by far less than half a motor turn referred to the
    output (2.2 deg for i = 81).

    Linear interpolation errs by at most ``alpha·dt²/8`` [rad] at output
    acceleration ``alpha`` for motor spacing ``dt`` (0.2 arcsec at
    8 rad/s² and 1 kHz; zero when the streams share stamps).

    Parameters
    ----------
    t_motor, motor_angle : array_like, shape (M,)
        Motor stamps [s] and angles [rad] (input side).
    t_link, link_angle : array_like, shape (N,)
        Link stamps [s] and angles [rad] (output side).
    ratio : float
        Reduction ratio ``i`` (input turns per output turn), non-zero.
    max_gap_s : float
        Largest stamp spacing [s] that is interpolated or unwrapped across.
    link_time_offset_s : float
        The link sample stamped ``t`` was taken at ``t + delta`` [s]; the
        motor angle is read there (0: take stamps as exact).
    te_reference : float, optional
        TE just before this chunk [rad] (the last valid TE of the previous
        chunk): the TE's constant is chosen continuous with it instead of in
        ``(-pi/i, pi/i]``, so that chunks of one stream agree
        (:class:`TEExtractor` does this).

    Returns
    -------
    TEStream
        TE and the unwrapped output angle at the link stamps.

    Raises
    ------
    InvalidInput
        If an array is not 1-D numeric or stamps and angles differ in length.
    InvalidParameter
        If ``ratio``, ``max_gap_s`` or ``link_time_offset_s`` is out of range.

    Notes
    -----
    Samples with a NaN/inf stamp or angle, and samples whose stamp is not
    later than every earlier stamp of their stream (duplicates, reordering)
    are dropped and counted, not raised on: one bad message must not stop a
    stream.

    """
    tm, am = _as_stream(t_motor, motor_angle, 'motor')
    tl, al = _as_stream(t_link, link_angle, 'link')
    ratio = checked_float('ratio', ratio, '', 'finite and non-zero', lambda v: v != 0.0)
    max_gap_s = checked_float('max_gap_s', max_gap_s, 's', '> 0', lambda v: v > 0.0)
    offset = checked_float('link_time_offset_s', link_time_offset_s, 's', 'finite', lambda v: True)
    reference = 0.0 if te_reference is None else checked_float(
        'te_reference', te_reference, 'rad', 'finite', lambda v: True)

    keep_m, m_nonfinite, m_unordered = _usable(tm, am)
    keep_l, l_nonfinite, l_unordered = _usable(tl, al)
    if keep_m is not None:
        tm, am = tm[keep_m], am[keep_m]
    idx_l = np.arange(tl.size) if keep_l is None else np.flatnonzero(keep_l)
    tq, al_k = (tl, al) if keep_l is None else (tl[idx_l], al[idx_l])
    if offset != 0.0:
        tq = tq + offset
    al_u, run_l = _unwrap(tq, al_k, max_gap_s)
    am, run_m = _unwrap(tm, am, max_gap_s, lambda: ratio * np.interp(tm, tq, al_u)
                        if tq.size else None)

    if tm.size == 0 or idx_l.size == 0:
        empty = np.full(tl.size, np.nan)
        return TEStream(tl.copy(), empty, empty.copy(), np.zeros(tl.size, dtype=bool),
                        max_gap_s, m_nonfinite, m_unordered, l_nonfinite, l_unordered,
                        int(idx_l.size), 0)
    if tq.size == tm.size and np.array_equal(tq, tm):
        # Shared stamps (one JointState carries both encoders): nothing to interpolate.
        motor_at, run_at, ok = am, run_m, None
    else:
        motor_at, run_at, ok = _interpolate(tm, am, run_m, tq, max_gap_s,
                                            extrapolate_s=abs(offset) * (1.0 + 1e-9))
    raw = al_u - motor_at / ratio

    sel = np.arange(raw.size) if ok is None else np.flatnonzero(ok)
    corrections = 0
    if sel.size:
        raw_ok = raw if ok is None else raw[sel]
        # A new run of either stream may start with unknown whole turns: keep TE continuous.
        # The first sample only fixes the TE's constant; the output angle keeps its turns.
        starts = _run_starts(sel, run_l, run_at)
        lt, mt = _turns(np.concatenate([raw_ok[:1] - reference,
                                        raw_ok[starts] - raw_ok[starts - 1]]), ratio)
        corrections = int(np.count_nonzero((lt[1:] != 0) | (mt[1:] != 0)))
        if starts.size:
            lengths = np.diff(np.concatenate([[0], starts, [sel.size]]))
            link_turns = np.repeat(np.cumsum(lt), lengths)
            motor_turns = np.repeat(np.cumsum(mt), lengths)
        else:
            link_turns, motor_turns = lt[0], mt[0]
        te_ok = raw_ok - TWO_PI * link_turns - TWO_PI * motor_turns / ratio
        out_ok = (al_u if ok is None else al_u[sel]) - TWO_PI * (link_turns - lt[0])
    rows = idx_l[sel]
    if rows.size == tl.size:
        te, out, valid = te_ok, np.asarray(out_ok, dtype=float), np.ones(tl.size, dtype=bool)
    else:
        te, out = np.full(tl.size, np.nan), np.full(tl.size, np.nan)
        valid = np.zeros(tl.size, dtype=bool)
        if rows.size:
            te[rows], out[rows], valid[rows] = te_ok, out_ok, True
    return TEStream(tl.copy(), te, out, valid, max_gap_s, m_nonfinite, m_unordered,
                    l_nonfinite, l_unordered, int(idx_l.size - sel.size), corrections)


class TEExtractor:
    """
    Stateful :func:`compute_te` for a stream that arrives in chunks.

    Each chunk's TE constant is chosen continuous with the previous chunk's
    last valid TE, so a TE whose constant sits near ``±pi/i`` (an encoder
    zero offset) does not jump by ``2·pi/i`` between chunks. Angles should be
    multi-turn across chunks (as ros2_control reports them): the turn count
    of a wrapped link encoder is not carried from one chunk to the next. A
    chunk whose stamps jump back by :data:`CLOCK_RESET_S` or more (the clock
    was reset) is computed in pieces from there, so that the samples after the
    reset are not taken for late ones.

    Link and motor samples on stamps of their own go through the rule of
    :class:`~reducer_twin.core.tick_pairing.TickPairing` (the one ``encoder_ingest``
    and the bag analysis apply): once the data show that the stamps of one
    controller tick differ by jitter only, each link sample is paired with its
    tick's motor sample (the motor sample takes the link stamp) instead of the
    motor angle interpolated at the link stamp; ``link_time_offset_s`` then
    reads the motor angle that far from the tick along the motor's motion.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i``.
    max_gap_s : float
        Largest stamp spacing [s] interpolated or unwrapped across.
    link_time_offset_s : float
        Time offset of the link encoder behind its stamps [s].

    Attributes
    ----------
    ticks : TickPairing or None
        The pairing rule and its evidence (its ``reason()`` says which is in use).
    held : HeldEncoders or None
        Whether an encoder's reading is held between slower updates; its stale
        samples are left out of the TE (:mod:`.held_encoders`, :attr:`held_reason`).
    steps : EncoderSteps or None
        The smallest move each encoder reports at the output (:mod:`.encoder_steps`,
        :attr:`step_reason`).
    travel : TravelRatio or None
        The ratio of the motor's moves to the link's, against ``ratio``
        (:mod:`.travel_ratio`, :attr:`ratio_reason`).

    """

    def __init__(self, ratio, max_gap_s=0.005, link_time_offset_s=0.0):
        self.ratio = ratio
        self.max_gap_s = max_gap_s
        self.link_time_offset_s = link_time_offset_s
        self.last_te = None
        self._period_s = None
        self._motor_tail = None     # (stamps, angles) of the last chunk's end (negative offsets)
        try:
            self.ticks = TickPairing(ratio) if math.isfinite(ratio) and ratio != 0 else None
            self.held = HeldEncoders(ratio) if self.ticks is not None else None
            self.steps = EncoderSteps(ratio) if self.ticks is not None else None
            self.travel = TravelRatio(ratio) if self.ticks is not None else None
        except (TypeError, ValueError):
            self.ticks = self.held = self.steps = self.travel = None   # compute_te says why

    @property
    def held_reason(self):
        """Say when an encoder's reading is held between slower updates, else None."""
        if self.held is None or self._period_s is None:
            return None
        return self.held.reason(1.0 / self._period_s)

    @property
    def step_reason(self):
        """Say when an encoder reports the output angle too coarsely, else None."""
        return None if self.steps is None else self.steps.reason()

    @property
    def ratio_reason(self):
        """Say when the motor turns another number of times than ``ratio``, else None."""
        return None if self.travel is None else self.travel.reason()

    def update(self, t_motor, motor_angle, t_link, link_angle):
        """
        Compute the TE of the next chunk.

        Parameters
        ----------
        t_motor, motor_angle : array_like
            Motor stamps [s] and angles [rad].
        t_link, link_angle : array_like
            Link stamps [s] and angles [rad].

        Returns
        -------
        TEStream
            As :func:`compute_te`.

        """
        pieces = self._pieces(t_motor, t_link)
        if pieces is not None:
            try:
                tm, am, tl, al = (np.asarray(a, dtype=float)
                                  for a in (t_motor, motor_angle, t_link, link_angle))
            except (TypeError, ValueError):
                pieces = None   # compute_te says what is wrong
        if pieces is None:
            return self._compute(t_motor, motor_angle, t_link, link_angle)
        return _join([self._compute(tm[m], am[m], tl[k], al[k]) for m, k in pieces])

    def _compute(self, t_motor, motor_angle, t_link, link_angle):
        if self.steps is not None and not self.steps.decided:
            self.steps.observe(link_angle, motor_angle)     # each encoder's own readings
        if self.ticks is not None:
            t_motor, motor_angle = self._by_tick(t_motor, motor_angle, t_link, link_angle)
        tm, am = self._with_motor_tail(t_motor, motor_angle)
        stream = compute_te(tm, am, t_link, link_angle, self.ratio,
                            self.max_gap_s, self.link_time_offset_s, self.last_te)
        if self.held is not None and stream.t.size and self.held.watching:
            if self._period_s is None and stream.t.size > 16:
                self._period_s = median_step(stream.t[:4096])
            shared = _shared(t_motor, t_link)
            motor_at = motor_angle if shared else _motor_at(t_motor, motor_angle, t_link)
            stale = None if motor_at is None else self.held.stale_mask(link_angle, motor_at,
                                                                       shared)
            if stale is not None:
                valid = stream.valid & ~stale
                stream = replace(stream, valid=valid, te=np.where(valid, stream.te, np.nan),
                                 output_angle=np.where(valid, stream.output_angle, np.nan))
        if self.travel is not None and self.travel.measured is None:
            self.travel.observe(stream.t, stream.output_angle, stream.te)
        kept = np.flatnonzero(stream.valid)
        if kept.size:
            self.last_te = float(stream.te[kept[-1]])
        return stream

    def _with_motor_tail(self, t_motor, motor_angle):
        """
        Return the motor stream with the previous chunk's last samples before it.

        A link sample read ``delta`` before its stamp (``link_time_offset_s < 0``) needs the
        motor angle ``delta`` before it: at a chunk's start that lies in the previous
        chunk, and extrapolated along the first segment instead it errs by
        ``alpha·delta²/2`` (5 arcmin at 8 rad/s² and 20 ms). Beyond
        :data:`TIME_OFFSET_LINEAR_S` (microseconds err by far less) the motor samples
        within ``|delta|`` of a chunk's end are kept for the next: a joint of the model's
        simulator with its link read 20 ms early, fed in 0.1 s pieces as ``te_monitor``
        can be, read +19 % against the whole recording; now the same to the digit.
        """
        tail, self._motor_tail = self._motor_tail, None
        offset = self.link_time_offset_s
        if offset >= -TIME_OFFSET_LINEAR_S:
            return t_motor, motor_angle
        try:
            tm = np.asarray(t_motor, dtype=float)
            am = np.asarray(motor_angle, dtype=float)
        except (TypeError, ValueError):
            return t_motor, motor_angle     # compute_te says what is wrong
        if tm.ndim != 1 or tm.shape != am.shape or tm.size == 0:
            return t_motor, motor_angle
        good = np.isfinite(tm) & np.isfinite(am)
        keep = np.flatnonzero(good & (tm >= tm[-1] + offset - self.max_gap_s))
        if keep.size and np.all(np.diff(tm[keep]) > 0.0) and keep[-1] == tm.size - 1:
            self._motor_tail = (tm[keep].copy(), am[keep].copy())
        if tail is None or not (0.0 < tm[0] - tail[0][-1] <= self.max_gap_s):
            return tm, am
        return np.concatenate([tail[0], tm]), np.concatenate([tail[1], am])

    def _by_tick(self, t_motor, motor_angle, t_link, link_angle):
        """
        Return the motor stream to pair with: restamped to the link stamps where by tick.

        Streams that share their stamps, and chunks with a sample that ``compute_te``
        would drop, are returned as given.
        """
        try:
            tm, am, tl, al = (np.asarray(a, dtype=float)
                              for a in (t_motor, motor_angle, t_link, link_angle))
        except (TypeError, ValueError):
            return t_motor, motor_angle     # compute_te says what is wrong
        if (tm.ndim != 1 or tl.ndim != 1 or tm.shape != am.shape or tl.shape != al.shape
                or tm.size < 2 or tl.size < 2 or (tm.shape == tl.shape and np.array_equal(tm, tl))
                or _usable(tm, am)[0] is not None or _usable(tl, al)[0] is not None):
            return t_motor, motor_angle
        ticks = self.ticks
        ticks.learn('link', tl)
        ticks.learn('motor', tm)
        if ticks.decided == 'interpolate':
            return t_motor, motor_angle
        match = ticks.match(tl, tm)
        if match is None:
            return t_motor, motor_angle
        paired = match >= 0
        if ticks.decided is None:
            m_u, l_u = np.unwrap(am), np.unwrap(al)
            inside = paired & (tl >= tm[0]) & (tl <= tm[-1])
            ticks.observe(tl, l_u, np.interp(tl, tm, m_u), m_u[np.maximum(match, 0)], inside)
            if ticks.decided != 'tick':
                return t_motor, motor_angle
        rows = np.flatnonzero(paired)
        ticks.tick_paired += rows.size
        return tl[rows], am[match[rows]]

    @staticmethod
    def _pieces(t_motor, t_link):
        """``(motor slice, link slice)`` pieces between clock resets, or None (no reset)."""
        try:
            tm = np.asarray(t_motor, dtype=float)
            tl = np.asarray(t_link, dtype=float)
        except (TypeError, ValueError):
            return None     # compute_te says what is wrong
        if tm.ndim != 1 or tl.ndim != 1:
            return None
        cuts_l = reset_indices(tl)
        if not cuts_l:
            return None
        cuts_m = cuts_l if tm.shape == tl.shape and np.array_equal(tm, tl) else (
            reset_indices(tm))
        if len(cuts_m) != len(cuts_l):
            return None     # the streams disagree about the reset: as before, no pieces
        return list(zip(cut_pieces(tm.size, cuts_m), cut_pieces(tl.size, cuts_l)))


def _interpolate(tm, am, run_m, tq, max_gap_s, extrapolate_s=0.0):
    """
    Motor angle and run at the query stamps; ``ok`` where no gap is bridged.

    Queries up to ``extrapolate_s`` beyond either end of the motor stamps are
    extrapolated along the end segment: a link sample taken ``delta`` after
    its stamp needs the motor angle ``delta`` after the last motor sample of
    a chunk (error ``alpha·delta²/2``, 0.002 arcsec at 50 µs).
    """
    if tm.size == 1:
        i0 = np.zeros(tq.size, dtype=np.int64)
        i1 = i0
        on0 = on1 = tq == tm[0]
        bridged = np.zeros(tq.size, dtype=bool)
    else:
        i0 = _step_index(tm, tq)
        i1 = i0 + 1
        on0, on1 = tq == tm[i0], tq == tm[i1]
        bridged = ((tm[i1] - tm[i0] <= max_gap_s) & (tq >= tm[0] - extrapolate_s)
                   & (tq <= tm[-1] + extrapolate_s))
    ok = bridged | on0 | on1
    with np.errstate(divide='ignore', invalid='ignore'):
        # Where frac is not finite (coinciding stamps) ``ok`` is False: the value is unused.
        frac = np.where(on0 | on1, 0.0, (tq - tm[i0]) / (tm[i1] - tm[i0]))
        motor_at = np.where(on1 & ~on0, am[i1], am[i0] + frac * (am[i1] - am[i0]))
    # A run id per query: the motor run it reads from; a bridged gap always starts a new one.
    base = run_m if run_m is not None else np.zeros(tm.size, dtype=np.int64)
    run_at = np.where(on1 & ~on0, base[i1], base[i0])
    return motor_at, run_at, ok


def _step_index(tm, tq):
    """
    ``clip(searchsorted(tm, tq, 'right') - 1, 0, M - 2)`` for increasing stamps ``tm``.

    Query ``k`` of a stream shifted by less than a step (a link stream read at its
    stamps plus the time offset) lies in step ``k`` or ``k - 1``: that is checked
    with two comparisons per query instead of a binary search.
    """
    m = tm.size
    if tq.size == m and m > 2:
        if (tm[:-1] <= tq[:-1]).all() and (tq[:-1] < tm[1:]).all() and tq[-1] >= tm[-2]:
            i0 = np.arange(m)
            i0[-1] = m - 2
            return i0
        if tq[0] < tm[1] and (tm[:-1] <= tq[1:]).all() and (tq[1:] < tm[1:]).all():
            i0 = np.arange(-1, m - 1)
            i0[0] = 0
            return i0
    return np.clip(np.searchsorted(tm, tq, side='right') - 1, 0, m - 2)


def checked_float(name, value, unit, allowed, test):
    """Return ``value`` as a float if finite and ``test(value)``, else raise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameter(out_of_range(name, value, unit, allowed)) from None
    if isinstance(value, bool) or not math.isfinite(v) or not test(v):
        raise InvalidParameter(out_of_range(name, value, unit, allowed))
    return v
