"""
Transmission error and health indicators from a motor/link encoder pair.

This is what runs on real robot data. :func:`compute_te` turns two encoder
streams into ``TE = theta_link - theta_motor/i`` [rad] (unwrapping, time
alignment, gaps); :class:`WindowAnalyzer` cuts the TE stream into windows and
reports, per window, the paper's Table 5 figures, the manufacturing-error
orders, the encoder time offset, the duty the reducer saw, and the lost
motion observed at torque reversals (physics notes section 4), which is the
observation of the wear estimator.

Lost motion model (physics notes sections 3-4): the loaded mesh makes
``TE = -(sign(T)·beta(|T|, w) + T/k_s)``, so at equal ``|T|`` the TE under a
negative torque minus the TE under a positive torque is the hysteresis
``H(|T|, w) = 2·(beta + |T|/k_s)``, which grows with the wear ``w``. On top
the encoders see the manufacturing harmonics (functions of the output angle),
``omega·delta`` from a time offset ``delta`` between the encoders, and an
unknown constant offset. One linear least-squares fit removes the harmonics
and the time offset jointly with a straight line in ``|T|`` per torque bin
and torque sign; ``H`` at each bin follows from the two lines, and the wear
that explains all bins through
:meth:`.transmission_error.ModelTables.hysteresis` gives the lost motion.

Two things the data cannot do are handled explicitly. A harmonic or the time
offset that the window's motion cannot separate from the torque dependence
(at constant speed ``omega`` is a constant; under gravity ``cos(theta)``
follows ``T``) is reported as NaN and left to the bin lines. What such a 1x
harmonic leaves in ``H`` is odd in torque and grows with ``|T|``, like a
stiffness error, so the wear fit carries a compliance correction with a prior
and reads the wear from the level of ``H``, not its slope.
"""

from dataclasses import dataclass, field
import math

import numpy as np

from .errors import InvalidInput, InvalidParameter, out_of_range
from .ingest import TickPairing
from .transmission_error import model_tables
from .wear import wear_rate

TWO_PI = 2.0 * math.pi

CLOCK_RESET_S = 60.0
"""
A stamp this far [s] or more behind the newest one means the clock was reset.

Sim time reset, or a long bag played again: the stream starts over at that sample
(:class:`TEExtractor` and :class:`WindowAnalyzer` restart there). A stamp less far
back is a replay or a late sample, left out as before. The wear estimator tells a
replayed window from a reset by the same horizon (:data:`.pipeline.CLOCK_RESET_S`).
"""

_MODEL_SIGMA = 3e-6
"""
Model error of one bin's hysteresis width [rad] (0.6 arcsec), added in quadrature.

What the period-mean table leaves out: mesh ripple (below 0.3 arcsec peak to
peak) and interpolation (below 0.1 arcsec), and harmonics that leak into a
bin when they cannot be separated from the torque lines. Without it, bins
with many samples would claim a precision the model does not have.
"""

_MIN_IDENTIFIABILITY = 3e-3
"""
Smallest fraction of a regressor's energy left after the other regressors.

Below it, a harmonic or the time offset cannot be told apart from the torque
dependence (e.g. the 1x order when gravity makes ``T`` proportional to
``cos(theta)`` at constant speed) and is reported as NaN. 0.3 %: at 0.1 % a
weakly identified 2x order absorbed the hysteresis of an unloaded joint whose
load sign follows its position (-48 % at 5 % effort noise); at 1 % the 1x order
was left in the torque lines of a gravity-loaded joint at 100 Hz (+4 %).
"""


_HARMONIC_FIT_TORQUE = 0.5
"""
Share of the lost-motion test torque beyond which samples enter the harmonics' fit.

Near zero torque the flank's level follows the load steeply, and an unloaded joint's
position in the move mirrors its load: those samples bend the harmonics (all samples
whose flank is sure: an unloaded base given its exact torque read 5-9 % low). Beyond
the whole test torque, an unloaded joint that swings between two points meets each
flank only where it starts and brakes, at one end of the move, and a 1x harmonic reads
as lost motion (independent generator, 120-window lives: bases 1022, 2008 and 4013 read
0.15, 0.13 and 0.18 arcmin high; with half the test torque -0.00, 0.07 and 0.11).
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
        return _slice(self, sl)


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


def _clock_resets(t, newest=None):
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


def _pieces(n, cuts):
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


def _slice(stream, sl):
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
    ratio = _finite('ratio', ratio, '', 'finite and non-zero', lambda v: v != 0.0)
    max_gap_s = _finite('max_gap_s', max_gap_s, 's', '> 0', lambda v: v > 0.0)
    offset = _finite('link_time_offset_s', link_time_offset_s, 's', 'finite', lambda v: True)
    reference = 0.0 if te_reference is None else _finite(
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
    :class:`~reducer_twin.core.ingest.TickPairing` (the one ``encoder_ingest``
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

    """

    def __init__(self, ratio, max_gap_s=0.005, link_time_offset_s=0.0):
        self.ratio = ratio
        self.max_gap_s = max_gap_s
        self.link_time_offset_s = link_time_offset_s
        self.last_te = None
        try:
            self.ticks = TickPairing(ratio) if math.isfinite(ratio) and ratio != 0 else None
        except (TypeError, ValueError):
            self.ticks = None   # compute_te says what is wrong

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
        if self.ticks is not None:
            t_motor, motor_angle = self._by_tick(t_motor, motor_angle, t_link, link_angle)
        stream = compute_te(t_motor, motor_angle, t_link, link_angle, self.ratio,
                            self.max_gap_s, self.link_time_offset_s, self.last_te)
        kept = np.flatnonzero(stream.valid)
        if kept.size:
            self.last_te = float(stream.te[kept[-1]])
        return stream

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
        cuts_l = _clock_resets(tl)
        if not cuts_l:
            return None
        cuts_m = cuts_l if tm.shape == tl.shape and np.array_equal(tm, tl) else (
            _clock_resets(tm))
        if len(cuts_m) != len(cuts_l):
            return None     # the streams disagree about the reset: as before, no pieces
        return list(zip(_pieces(tm.size, cuts_m), _pieces(tl.size, cuts_l)))


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


def _first_index(test, start, stop, block, default):
    """
    First index in ``[start, stop)`` where ``test(a, b)`` (a mask of ``[a, b)``) holds.

    Blocks of ``block`` samples, four times longer each time, are tested in turn, so a
    hit near ``start`` does not cost a test of the whole span; ``default`` if none.
    """
    a = start
    while a < stop:
        b = min(stop, a + block)
        hit = np.flatnonzero(test(a, b))
        if hit.size:
            return a + int(hit[0])
        a, block = b, 4 * block
    return default


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


def _finite(name, value, unit, allowed, test):
    """Return ``value`` as a float if finite and ``test(value)``, else raise."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InvalidParameter(out_of_range(name, value, unit, allowed)) from None
    if isinstance(value, bool) or not math.isfinite(v) or not test(v):
        raise InvalidParameter(out_of_range(name, value, unit, allowed))
    return v


@dataclass(frozen=True)
class DutySummary:
    """
    What the reducer went through in one window (run-in-free wear exposure).

    Attributes
    ----------
    duration_s : float
        Stream time covered by the window's samples [s] (gaps excluded).
    exposure_s : float
        Operating seconds of wear exposure, ``duration_s·aging_factor`` [s].
    archard_increment : float
        ``aging·∫ wear_rate(T, omega, 0) dt`` [m]: Archard wear at rate
        scale 1 without run-in (the estimator applies both itself).
    mean_abs_torque : float
        Time mean of ``|T|`` [N·m].
    mean_abs_speed : float
        Time mean of ``|omega|`` [rad/s]: the mean speed ``Nm`` of the
        catalogue life formula.
    cubic_mean_torque : float
        ``Tm = (∫|omega|·|T|^(10/3) dt / ∫|omega| dt)^(3/10)`` [N·m], the
        catalogue's equivalent torque (exponent ``rating.life_exponent``);
        NaN when the joint did not move.
    max_abs_torque : float
        Largest ``|T|`` [N·m].

    """

    duration_s: float
    exposure_s: float
    archard_increment: float
    mean_abs_torque: float
    mean_abs_speed: float
    cubic_mean_torque: float
    max_abs_torque: float

    @property
    def mean_speed(self):
        """Mean speed ``Nm`` of the catalogue life formula, ``mean_abs_speed`` [rad/s]."""
        return self.mean_abs_speed


@dataclass(frozen=True)
class WindowFeatures:
    """
    Features of one window of the TE stream.

    Attributes
    ----------
    t_start, t_end : float
        Stamps of the first and last sample [s].
    samples : int
        Samples used.
    end_reason : str
        Why the window ended: ``'revolution'``, ``'duration'``, ``'motion'``
        (continuous turning stopped after ``window_s``), ``'max'``,
        ``'gap'`` or ``'flush'``.
    te_max, te_min, te_pp, te_mean : float
        Maximum, minimum, peak-to-peak and mean TE [rad] (paper Table 5
        format; raw, including the encoders' constant offset).
    loaded_mean_te : float
        Mean TE over samples with ``T > 10 %`` of rated torque [rad], after
        removing the fitted harmonics and time-offset term; NaN if none.
    orders : dict
        Order per output revolution -> amplitude [rad] of the TE harmonic,
        fitted against the output angle; NaN where not identifiable.
    time_offset_s : float
        Fitted time offset of the link encoder behind its stamps [s]
        (coefficient of ``omega`` in the TE); NaN at constant speed.
    lost_motion, lost_motion_std : float
        Lost motion at the catalogue test torque for the fitted wear, and
        its standard error [rad]; NaN without usable torque reversals.
    wear_fit, wear_fit_std : float
        Combined wear that explains the observed hysteresis, and its
        standard error [m]; NaN like ``lost_motion``.
    compliance_fit : float
        Compliance correction ``c`` fitted with the wear [rad/(N·m)]: the
        observed widths are modelled as ``H(|T|, w) + 2·|T|·c``; NaN like
        ``lost_motion``.
    hysteresis_torque : ndarray
        Torque of each usable bin [N·m]: mean ``|T|`` of its samples.
    hysteresis : ndarray
        Observed width ``TE(-|T|) - TE(+|T|)`` at those torques [rad].
    hysteresis_std : ndarray
        Standard errors of ``hysteresis`` [rad].
    duty : DutySummary
        Load and speed history of the window.
    implausible : bool
        The encoders did not measure the same motion in it (no lost motion read:
        :data:`PLAUSIBLE_TE_SPAN_RAD`, :data:`PLAUSIBLE_LOST_MOTION_RAD`).

    """

    t_start: float
    t_end: float
    samples: int
    end_reason: str
    te_max: float
    te_min: float
    te_pp: float
    te_mean: float
    loaded_mean_te: float
    orders: dict
    time_offset_s: float
    lost_motion: float
    lost_motion_std: float
    wear_fit: float
    wear_fit_std: float
    compliance_fit: float
    hysteresis_torque: np.ndarray = field(repr=False)
    hysteresis: np.ndarray = field(repr=False)
    hysteresis_std: np.ndarray = field(repr=False)
    duty: DutySummary = None
    implausible: bool = False


WINDOW_MODES = ('auto', 'revolution', 'duration')
"""How windows are cut (see :class:`WindowAnalyzer`)."""


class WindowAnalyzer:
    """
    Streaming analysis of a TE stream in windows.

    Windows never span a gap of the stream. ``window='duration'`` cuts
    every ``window_s`` of stream; ``'revolution'`` after each output
    revolution of net travel (or ``max_window_s``); ``'auto'`` (default)
    after one revolution while the joint turns continuously in one
    direction, otherwise after ``window_s`` (a window that turned
    continuously past ``window_s`` ends when continuous motion stops).

    Manufacturing orders and the time offset are hardware constants: they
    are fitted to recent windows pooled with an exponential memory of
    ``memory_windows`` windows, each ``(|T| bin, torque sign)`` flank line
    shared by the pool (with a drift over its windows), so that the joint
    meeting the same load at different positions in different moves tells
    the harmonics from the hysteresis, and windows that cover part of a
    revolution still separate them from the torque dependence. They are
    fitted only on samples whose load surely exceeds the catalogue's
    lost-motion test torque (noise band and viscous friction counted
    against it): below it the play is still being taken up, the flank's
    level follows the load, and an unloaded joint's load follows its
    position in the move, which the harmonics would then absorb at the cost
    of the hysteresis.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (rated torque, model tables, wear rate).
    window : str
        ``'auto'``, ``'revolution'`` or ``'duration'``.
    window_s : float
        Window length in stream time [s].
    max_window_s : float
        Longest window [s].
    aging_factor : float
        Seconds of wear exposure per second of stream (1 for a real robot).
    orders : sequence of int, optional
        Harmonic orders per output revolution (default 1, 2, Zc, Zp).
    torque_bins : int
        Number of log-spaced ``|T|`` bins.
    bin_range : tuple of float
        Lowest and highest bin edge as fractions of rated torque.
    min_bin_samples : int
        Samples needed under each torque sign for a bin to count, at
        :data:`FLANK_RATE_HZ` and above; below it, those of the same stream time
        (at least :data:`LOW_RATE_MIN_FLANK_SAMPLES`; see :meth:`flank_samples`).
    min_bins : int
        Usable bins needed for a lost-motion value.
    memory_windows : float
        Memory of the pooled harmonic fit in windows (0: this window only).
    min_speed : float
        Slowest output speed counted as turning [rad/s].
    compliance_prior : float
        Prior standard deviation of the compliance correction of the wear
        fit, as a fraction of the series compliance ``1/k_s``.
    min_window_samples : int
        Fewest samples in a window that ends by revolution, duration or
        motion: at 100 Hz a 2 s window holds too few samples per torque bin
        and sign, so the window is lengthened (up to ``max_window_s``).
    torque_smoothing_s : float
        Length of the centred moving average applied to the effort inside
        each window before it is binned [s] (0: none). A motor-current torque
        estimate carries white noise of a few % of rated torque; the
        reducer's torque changes with the robot's dynamics, far slower. The
        average is lengthened where the effort is noisier than it can quiet
        (:meth:`WindowAnalyzer._quiet_half`), up to
        :data:`_SMOOTHING_MAX_S`.
    sign_sigmas : float
        Samples whose smoothed torque lies within this many standard
        deviations of its noise from zero take no part in the hysteresis:
        there the noise, not the load, would pick the flank (standstill of
        an unloaded joint, torque reversals).
    friction : bool
        Identify the friction the effort carries and the reducer's output does
        not see, and take it out of the torque (see :meth:`_friction`).
    friction_memory_windows : float
        Memory of the pooled friction identification in windows.

    Raises
    ------
    InvalidParameter
        If a setting is out of range.

    """

    def __init__(self, params, window='auto', window_s=2.0, max_window_s=20.0, aging_factor=1.0,
                 orders=None, torque_bins=16, bin_range=(0.02, 1.5), min_bin_samples=20,
                 min_bins=2, memory_windows=10.0, min_speed=0.01, compliance_prior=0.3,
                 min_window_samples=1000, torque_smoothing_s=0.03, sign_sigmas=3.0,
                 friction=True, friction_memory_windows=30.0):
        if window not in WINDOW_MODES:
            raise InvalidParameter(out_of_range(
                'window', window, '', 'one of ' + ', '.join(repr(m) for m in WINDOW_MODES)))
        self.window = window
        self.window_s = _finite('window_s', window_s, 's', '> 0', lambda v: v > 0.0)
        self.max_window_s = _finite('max_window_s', max_window_s, 's', f'>= window_s = {window_s}',
                                    lambda v: v >= self.window_s)
        self.aging_factor = _finite('aging_factor', aging_factor, '', '>= 0', lambda v: v >= 0.0)
        self.memory_windows = _finite('memory_windows', memory_windows, 'windows', '>= 0',
                                      lambda v: v >= 0.0)
        self.min_speed = _finite('min_speed', min_speed, 'rad/s', '>= 0', lambda v: v >= 0.0)
        self.compliance_prior = _finite('compliance_prior', compliance_prior, '', '> 0',
                                        lambda v: v > 0.0)
        self.torque_bins = _whole('torque_bins', torque_bins, 1, 200)
        self.min_bin_samples = _whole('min_bin_samples', min_bin_samples, 3, 10 ** 9)
        self.min_bins = _whole('min_bins', min_bins, 1, 200)
        self.min_window_samples = _whole('min_window_samples', min_window_samples, 1, 10 ** 9)
        self.torque_smoothing_s = _finite('torque_smoothing_s', torque_smoothing_s, 's',
                                          '>= 0', lambda v: v >= 0.0)
        self.sign_sigmas = _finite('sign_sigmas', sign_sigmas, '', '>= 0', lambda v: v >= 0.0)
        self.friction = bool(friction)
        self._friction_memory = math.exp(-1.0 / _finite(
            'friction_memory_windows', friction_memory_windows, 'windows', '> 0',
            lambda v: v > 0.0))
        self._fric_n = np.zeros((_FRICTION_SUMS, _FRICTION_SUMS))
        self._fric_r = np.zeros(_FRICTION_SUMS)
        self._fric_e = np.zeros(_FRICTION_SUMS)
        self.efficiency = 1.0
        self._fric_yy = 0.0
        self._fric_m = 0.0
        self._fric_dir = np.zeros(2)
        self.coulomb_friction = 0.0
        self.viscous_friction = 0.0
        try:
            lo, hi = (float(v) for v in bin_range)
        except (TypeError, ValueError):
            raise InvalidParameter(out_of_range('bin_range', bin_range, '',
                                                '(low, high) fractions of rated torque')) from None
        if not (0.0 < lo < hi and math.isfinite(hi)):
            raise InvalidParameter(out_of_range('bin_range', bin_range, '', '0 < low < high'))
        g = params.geometry
        self.orders = tuple(int(k) for k in (orders or (1, 2, g.z_cycloid, g.z_pins)))
        if not self.orders or min(self.orders) < 1:
            raise InvalidParameter(out_of_range('orders', orders, '', 'whole numbers >= 1'))
        self.params = params
        self.tables = model_tables(params)
        self.rated_torque = params.rating.rated_torque
        self.takeup_torque = params.rating.lost_motion_torque_fraction * self.rated_torque
        self.edges = np.geomspace(lo, hi, self.torque_bins + 1) * self.rated_torque
        self.centres = np.sqrt(self.edges[1:] * self.edges[:-1])
        n_par = 2 * len(self.orders) + 1
        self._memory = math.exp(-1.0 / self.memory_windows) if self.memory_windows > 0 else 0.0
        n_groups = 2 * self.torque_bins
        self._te_ref = None
        self._pool_friction = np.zeros(2)
        self._pool = {'moments': np.zeros((n_par + 1, n_par + 1)), 'count': np.zeros(n_groups),
                      'su': np.zeros(n_groups), 'suu': np.zeros(n_groups),
                      'st': np.zeros(n_groups), 'stt': np.zeros(n_groups),
                      'sut': np.zeros(n_groups), 's0': np.zeros((n_groups, n_par + 1)),
                      's1': np.zeros((n_groups, n_par + 1)),
                      'stz': np.zeros((n_groups, n_par + 1))}
        self._buf = {name: np.empty(0) for name in _BUFFER}
        self._last_t = None
        self._last_theta = None
        self._aliased = False
        self.ignored_samples = 0
        self.clock_resets = 0
        self.samples_without_effort = 0
        self.largest_effort = 0.0
        self.derived_velocity = 0
        self.samples_seen = 0
        self.windows_emitted = 0
        self.windows_observed = 0
        self.windows_censored = 0       # of those, fits on the table's lower bound
        self.windows_friction_unknown = 0
        self.windows_implausible = 0
        self.largest_te_span = 0.0
        self.gaps = 0                   # holes longer than max_gap_s between samples
        self.gap_time_s = 0.0           # the stream time they span [s]
        self.effort_fault = None        # why the effort is not the output torque
        self.windows_effort_fault = 0
        self._effort_checks = []        # (width [rad], slope ratio) of the latest windows
        self._offset_checks = []        # (near, far [rad], step [N·m]) of the latest windows
        self.last_observed_t = None     # end of the last window with a lost motion [s]
        self.latest_t = None            # latest stamp fed [s]
        self._since = dict.fromkeys(_SINCE, 0)
        self._recent_t = (_EMPTY, _EMPTY)  # fresh and effortless stamps of the last update
        self._period_s = None

    def update(self, stream, effort, velocity):
        """
        Feed the next chunk of the stream; return the windows it completes.

        Parameters
        ----------
        stream : TEStream
            Next chunk of TE (later than every earlier chunk).
        effort : array_like, shape (N,)
            Output torque at the same stamps [N·m].
        velocity : array_like, shape (N,)
            Output (link) velocity at the same stamps [rad/s].

        Returns
        -------
        list of WindowFeatures
            Completed windows, oldest first.

        Raises
        ------
        InvalidInput
            If effort or velocity does not match the stream's length.

        Notes
        -----
        Samples stamped no later than the newest one seen are left out
        (``ignored_samples``), unless they lie :data:`CLOCK_RESET_S` or more
        back: the clock was reset, so the partial window is closed (as at a gap)
        and the stream starts over there (``clock_resets``).

        """
        effort = np.asarray(effort, dtype=float)
        velocity = np.asarray(velocity, dtype=float)
        if effort.shape != stream.t.shape or velocity.shape != stream.t.shape:
            raise InvalidInput(
                f'effort and velocity must match the {stream.t.size} TE samples, got '
                f'shapes {effort.shape} and {velocity.shape}')
        resets = _clock_resets(np.where(stream.valid, stream.t, np.nan), self._last_t)
        if resets:
            found = []
            for k, sl in enumerate(_pieces(stream.t.size, resets)):
                if k:
                    found += self._emit(final=True)
                    self._last_t = None
                    self.clock_resets += 1
                found += self._update(_slice(stream, sl), effort[sl], velocity[sl])
            return found
        return self._update(stream, effort, velocity)

    def _update(self, stream, effort, velocity):
        """Feed a chunk without a clock reset."""
        fresh = stream.valid if self._last_t is None else stream.valid & (stream.t > self._last_t)
        n_fresh = int(np.count_nonzero(fresh))
        self.samples_seen += n_fresh
        self._since['seen'] += n_fresh
        if n_fresh:
            latest = float(np.max(stream.t[fresh]))
            self.latest_t = latest if self.latest_t is None else max(self.latest_t, latest)
        self._recent_t = (stream.t[fresh], _EMPTY)
        if self._period_s is None and np.count_nonzero(fresh) > 16:
            steps = np.diff(stream.t[fresh][:4096])
            steps = steps[steps > 0]
            if steps.size:
                self._period_s = float(np.median(steps))
        use = fresh & np.isfinite(effort)
        without = int(np.count_nonzero(fresh & ~use))
        self.samples_without_effort += without
        self._since['without_effort'] += without
        if without:
            self._recent_t = (self._recent_t[0], stream.t[fresh & ~use])
        unknown = use & ~np.isfinite(velocity)
        if unknown.any():
            velocity = self._derive_velocity(stream, use, velocity, unknown)
        self.ignored_samples += int(np.count_nonzero(stream.valid & ~use))
        if use.all():
            def pick(a):
                return a
        else:
            def pick(a):
                return a[use]
        t = pick(stream.t)
        if t.size:
            previous = np.concatenate([[np.nan if self._last_t is None else self._last_t],
                                       t[:-1]])
            step = t - previous
            gap = step > stream.max_gap_s
            dt = np.where(step <= stream.max_gap_s, step, 0.0)
            if gap.any():      # stream time without samples: not counted as operation
                self.gaps += int(np.count_nonzero(gap))
                self.gap_time_s += float(step[gap].sum())
            self._last_t = float(t[-1])
            self._last_theta = float(pick(stream.output_angle)[-1])
            new = {'t': t, 'te': pick(stream.te), 'theta': pick(stream.output_angle),
                   'torque': pick(effort), 'speed': pick(velocity), 'dt': dt,
                   'gap': gap.astype(float)}
            self.largest_effort = max(self.largest_effort,
                                      float(np.max(np.abs(new['torque']))))
            self._buf = {k: np.concatenate([self._buf[k], new[k]]) if self._buf[k].size
                         else new[k] for k in _BUFFER}
            self._aliased = True
        return self._emit(final=False)

    @property
    def windows_read(self):
        """
        Windows whose lost motion tells the wear: observed, their fit above the table's bound.

        A fit on the lower bound (no play beyond a new nominal unit's) is censored by the
        estimator, not used (:meth:`.estimator.WearEstimator.update`).
        """
        return self.windows_observed - self.windows_censored

    @property
    def rate_hz(self):
        """Sample rate of the stream [Hz] (median stamp step), NaN before 17 samples."""
        return 1.0 / self._period_s if self._period_s else math.nan

    def not_observed_reason(self, effort_source='the joint states'):
        """
        Say why no window has given a lost motion the wear is read from, or None once one has.

        An effort found not to be the output torque (:attr:`effort_fault`) is said
        even after windows gave lost motions: they were read with that effort. Encoders
        that do not measure the same motion are said first (they distort the check).

        Parameters
        ----------
        effort_source : str
            Where the effort was expected (a topic name), for the message.

        Returns
        -------
        str or None
            One line a maintenance engineer can act on.

        """
        fault = self.effort_fault
        if fault is None and self.windows_read:
            return None
        if fault is not None and not self.windows_implausible:
            return fault
        seen = self.samples_seen
        if seen == 0:
            return 'no encoder samples with a transmission error (no motor/link pairs)'
        if self.samples_without_effort >= 0.99 * seen:
            return (f'no effort on {effort_source} ({self.samples_without_effort} of {seen} '
                    'samples): the lost motion needs the torque')
        if self.windows_emitted == 0:
            return f'no complete analysis window yet ({seen} samples)'
        if self.windows_implausible:
            return (f'the motor and link encoders do not measure the same motion: the '
                    f'transmission error spans up to {math.degrees(self.largest_te_span):.3g} '
                    f'deg in {self.windows_implausible} of {self.windows_emitted} windows '
                    f"(a reducer's moves by arcminutes; at most "
                    f'{math.degrees(PLAUSIBLE_TE_SPAN_RAD):g} deg and a lost motion of '
                    f'{math.degrees(PLAUSIBLE_LOST_MOTION_RAD) * 60:g} arcmin are read): a '
                    'frozen encoder, a motor encoder that counts against the link, or a '
                    'wrong reduction ratio or motor_angles')
        if fault is not None:
            return fault
        if self.windows_observed:       # every one censored
            return (f'none of its {self.windows_observed} windows with a lost motion read a '
                    "play beyond a new nominal unit's (their wear fits lie on the table's "
                    "lower bound, and the estimate would be the prior's alone): a unit built "
                    'tighter than nominal, read once its play has grown past that, or an '
                    'effort whose zero lies beyond the loads (an offset from the torque)')
        rate = self.rate_hz
        if math.isfinite(rate) and rate < LOW_RATE_HZ:
            return (f'{rate:.0f} Hz: too few samples per torque reversal in '
                    f'{self.windows_emitted} windows')
        if self.largest_effort < self.edges[0]:
            # Nothing reaches the lowest torque bin: a joint that carries no load, or an
            # effort in other units (a motor torque taken for the output torque).
            return (f'the effort on {effort_source} stays within +-{self.largest_effort:.3g} '
                    f'N*m in {self.windows_emitted} windows, below the {self.edges[0]:.3g} N*m '
                    f'({100.0 * self.edges[0] / self.rated_torque:.0f} % of the rated torque) '
                    'from which the lost motion is read: a joint without load, or an effort '
                    'in other units (a motor torque: set motor_effort_units to motor)')
        if self.largest_effort > EFFORT_PLAUSIBLE_RATED * self.rated_torque:
            return (f'the effort on {effort_source} reaches {self.largest_effort:.3g} N*m, '
                    f'{self.largest_effort / self.rated_torque:.3g} times the rated torque '
                    f'(a reducer takes at most about {EFFORT_PLAUSIBLE_RATED:g} times, '
                    'momentarily): not the output torque in N*m (a torque in joint units '
                    'on the motor entry, taken for a motor torque and multiplied by the '
                    'ratio: motor_effort_units joint; or other units: effort_scale, '
                    'twin.effort_scale in --config)')
        if self.windows_friction_unknown:
            return (f'the friction in the effort could not yet be told from the load: '
                    f'{self.windows_friction_unknown} of {self.windows_emitted} windows had '
                    'torque reversals, but the joint has not yet moved both ways in a fifth '
                    'of the samples each, and a motor friction in the effort would pick the '
                    'flank')
        return (f'no torque reversal at equal |T| above the effort noise in '
                f'{self.windows_emitted} windows (the joint did not reverse under load)')

    def stale_reason(self, after_s, effort_source='the joint states'):
        """
        Say why an observed reducer's lost motion stopped, once ``after_s`` of stream passed.

        Parameters
        ----------
        after_s : float
            Stream time [s] after the last window with a lost motion from which it counts.
        effort_source : str
            Where the effort was expected (a topic name), for the message.

        Returns
        -------
        tuple of (float, str, bool) or None
            Stream seconds since the last lost motion, the cause (one line), and whether
            the stream is faulty (effort missing, encoders that do not measure the same
            motion) rather than only without a torque reversal; None while the lost
            motion is current or was never read (:meth:`not_observed_reason` says why).

        """
        if self.last_observed_t is None or self.latest_t is None:
            return None
        gap = self.latest_t - self.last_observed_t
        if gap < after_s:
            return None
        since = self._since
        if since['without_effort'] >= 0.1 * max(since['seen'], 1):
            return gap, (f'no effort on {effort_source} in {since["without_effort"]} of '
                         f'{since["seen"]} samples since (their operating time is not '
                         'counted)'), True
        if since['implausible']:
            return gap, (f'in {since["implausible"]} of {since["windows"]} windows since, the '
                         f'transmission error spans up to '
                         f'{math.degrees(self.largest_te_span):.3g} deg (a frozen encoder?)'), True
        return gap, (f'no torque reversal under load in {since["windows"]} windows since'), False

    def _derive_velocity(self, stream, use, velocity, unknown):
        """
        Output speed from the unwrapped output angle where the stream has none.

        Central differences over the samples in use (one-sided at the ends; the
        chunk's first sample reaches back to the last sample of the previous chunk
        when it lies within ``max_gap_s``). Counted in ``derived_velocity``.
        """
        idx = np.flatnonzero(use)
        t, theta = stream.t[idx], stream.output_angle[idx]
        back = self._last_t is not None and t.size and t[0] - self._last_t <= stream.max_gap_s
        if back:
            t = np.concatenate([[self._last_t], t])
            theta = np.concatenate([[self._last_theta], theta])
        if t.size >= 2:
            derived = np.gradient(theta, t)
        else:
            derived = np.zeros(t.size)
        if back:
            derived = derived[1:]
        out = np.array(velocity, dtype=float, copy=True)
        fill = unknown[idx]
        out[idx[fill]] = derived[fill]
        self.derived_velocity += int(np.count_nonzero(fill))
        return out

    def flush(self):
        """
        Close the current partial window.

        Returns
        -------
        list of WindowFeatures
            The partial window, if it holds samples.

        """
        return self._emit(final=True)

    # -- windows ----------------------------------------------------------------------------

    def _emit(self, final):
        cuts = self._cut(final)
        if not cuts:
            if self._aliased:
                # The buffer must not alias arrays the caller may reuse.
                self._buf = {k: v.copy() for k, v in self._buf.items()}
                self._aliased = False
            return []
        out, first = [], 0
        # Batches of windows of about _BATCH_SAMPLES samples keep the temporaries small.
        while first < len(cuts):
            base = cuts[first][0]
            last = first + 1
            while last < len(cuts) and cuts[last][1] - base <= _BATCH_SAMPLES:
                last += 1
            end = cuts[last - 1][1]
            part = {k: v[base:end] for k, v in self._buf.items()}
            found = self._analyze(part, [(a - base, b - base, r) for a, b, r in cuts[first:last]])
            self.windows_emitted += len(found)
            self.windows_observed += sum(math.isfinite(f.lost_motion) for f in found)
            self.windows_censored += sum(math.isfinite(f.lost_motion) and f.wear_fit <= 0.0
                                         for f in found)
            for f in found:
                if math.isfinite(f.lost_motion):
                    self.last_observed_t = f.t_end
                    # The samples of the last update after it (the update that cut it).
                    seen, without = self._recent_t
                    self._since = {'seen': int(np.count_nonzero(seen > f.t_end)),
                                   'without_effort': int(np.count_nonzero(without > f.t_end)),
                                   'implausible': 0, 'windows': 0}
                else:
                    self._since['windows'] += 1
                    self._since['implausible'] += int(f.implausible)
            out += found
            first = last
        end = cuts[-1][1]
        self._buf = {k: v[end:].copy() for k, v in self._buf.items()}
        self._aliased = False
        return out

    def _cut(self, final):
        """Return ``[(start, end, reason)]`` of the windows complete in the buffer."""
        t, theta, speed = self._buf['t'], self._buf['theta'], self._buf['speed']
        n = t.size
        gaps = np.flatnonzero(self._buf['gap'])
        cuts, s = [], 0
        while s < n:
            g = gaps[np.searchsorted(gaps, s, side='right')] if gaps.size and gaps[-1] > s else n
            x = min(int(np.searchsorted(t, t[s] + self.max_window_s)), g)
            d = int(np.searchsorted(t, t[s] + self.window_s))
            cand = [(g, 'gap'), (x, 'max')]
            if self.window == 'duration':
                cand.append((d, 'duration'))
            else:
                # Searched in growing blocks from about one window; the turn only up to
                # where the window ends anyway: a revolution found later is never the end.
                shortest = s + self.min_window_samples
                block = max(d, shortest) - s + 2
                turn_until = x
                if self.window == 'auto':
                    direction = np.sign(speed[s])

                    def stopped(a, b):
                        v = speed[a:b]
                        return ~((np.abs(v) >= self.min_speed) & (np.sign(v) == direction))
                    c = _first_index(stopped, s, x, block, n)
                    last = (d, 'duration') if c <= d else (c, 'motion')
                    turn_until = min(x, max(last[0], shortest) + 1)
                start_theta = theta[s]
                r = _first_index(lambda a, b: np.abs(theta[a:b] - start_theta) >= TWO_PI,
                                 s, turn_until, block, n)
                cand.append((r, 'revolution'))
                if self.window == 'auto':
                    cand.append(last)
            # Too few samples (a low rate) for the torque bins: the window goes on.
            shortest = s + self.min_window_samples
            cand = [(c if r in ('gap', 'max') else max(c, shortest), r) for c, r in cand]
            end, reason = min(cand, key=lambda item: item[0])
            if end >= n:
                if not final:
                    break
                end, reason = n, 'flush'
            cuts.append((s, end, reason))
            s = end
        return cuts

    # -- analysis ---------------------------------------------------------------------------

    def _analyze(self, buf, cuts):
        """Compute the features of the windows ``cuts`` of ``buf`` (vectorised over windows)."""
        starts = np.array([c[0] for c in cuts])
        ends = np.array([c[1] for c in cuts])
        n_win = starts.size
        t, y, torque, speed, dt = (buf[k] for k in ('t', 'te', 'torque', 'speed', 'dt'))
        win = np.repeat(np.arange(n_win), ends - starts)
        drag = model = taken = unknown = None
        period = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        half = self._smoothing_half(period)
        harmonics = self._harmonics(buf['theta'])
        if self.friction:
            torque, drag, model, taken, unknown = self._friction(torque, t, harmonics, speed,
                                                                 win, starts, ends, half)
        torque, band = self._smooth_torque(torque, half, t, period, model, win, starts, ends)
        if model is not None:
            torque, band = self._toward_model(torque, band, model, win, starts)
        # Viscous friction of the motor side and drag of the link both follow the speed;
        # the effort cannot tell them apart: the torque lies between the two readings
        # (all of it subtracted, or none; the same without friction taken out).
        kept = torque + drag if drag is not None else torque
        low = np.where(torque * kept > 0.0, np.minimum(np.abs(torque), np.abs(kept)), 0.0) - band
        # Where the load may be inside the band, the noise or the friction picks the flank;
        # nor is the level known where the drag decides whether the load is beyond the
        # lost-motion test torque (the play taken up) or below it.
        high = np.maximum(np.abs(torque), np.abs(kept))
        ambiguous = (low <= 0.0) | ((high - np.abs(kept - torque) < self.takeup_torque)
                                    & (high > self.takeup_torque))
        te_mean = np.add.reduceat(y, starts) / (ends - starts)
        z = self._regressors(harmonics, speed, y - te_mean[win])
        x = z[:-1]
        bins = self._bins(z, torque)
        stats = self._group_stats(z, torque, bins, win, starts, ends, ambiguous, normal=False)
        # The harmonics and the time offset come from samples whose load surely takes most
        # of the play up (:data:`_HARMONIC_FIT_TORQUE`).
        taken_up = low > _HARMONIC_FIT_TORQUE * self.takeup_torque
        fit_stats = self._group_stats(z, torque, bins, win, starts, ends, ~taken_up)
        exposure = np.add.reduceat(dt, starts) * self.aging_factor
        beta, ident, noise, pooled = self._fit_harmonics(fit_stats, n_win, te_mean, exposure,
                                                         taken)
        torque_h, width, std, usable, odd = self._hysteresis(stats, beta, noise, pooled)
        if unknown is not None:
            # Before the friction can be told from the load (the joint has not yet moved
            # both ways), the effort still carries the motor's friction, which gives the
            # torque near a reversal the sign of the motion: no lost motion is read.
            # Measured on the independent generator (seeds 1-2): 41 of 61 units read their
            # first lost motion before the friction was known; windows read then were off
            # by 0.04 arcmin median, 0.28 at the 90th percentile, first windows read after
            # by 0.01 and 0.10. Withheld (bench_accuracy, seeds 1-4), a unit's first usable
            # window's error at the 90th percentile went from 0.22-0.55 to 0.09-0.14 arcmin.
            withheld = unknown & (usable.sum(axis=1) >= self.min_bins)
            self.windows_friction_unknown += int(withheld.sum())
            usable &= ~unknown[:, None]
        te_max = np.maximum.reduceat(y, starts)
        te_min = np.minimum.reduceat(y, starts)
        implausible = (te_max - te_min) > PLAUSIBLE_TE_SPAN_RAD
        usable &= ~implausible[:, None]
        # From the window where the effort is found not to be the torque, none is read.
        faulty = self._check_effort(torque_h, width, std, usable,
                                    odd * ~self._first_order(ident)[:, None, :])
        usable &= ~faulty[:, None]
        self.windows_effort_fault += int(faulty.sum())
        fit = self._fit_wear(torque_h, width, std, usable)
        # A lost motion no reducer has is an encoder or configuration fault.
        beyond = fit[2] > PLAUSIBLE_LOST_MOTION_RAD
        for k in (0, 1, 2, 3, 4):
            fit[k][beyond] = np.nan
        implausible |= beyond
        if implausible.any():
            self.windows_implausible += int(implausible.sum())
            self.largest_te_span = max(self.largest_te_span,
                                       float(np.max((te_max - te_min)[implausible])))
        fit = [a.tolist() for a in fit]
        # Mean TE under load, harmonics and time-offset term removed.
        # Per window: sum of TE minus the fitted terms' sums (the coefficients are constant
        # within a window), over the loaded samples.
        loaded = torque > 0.1 * self.rated_torque
        x_sums = np.add.reduceat(np.where(loaded, x, 0.0), starts, axis=1)
        y_sums = np.add.reduceat(np.where(loaded, y, 0.0), starts)
        with np.errstate(invalid='ignore', divide='ignore'):
            loaded_mean = ((y_sums - np.einsum('wj,jw->w', beta, x_sums))
                           / np.add.reduceat(loaded, starts))
        duty = self._duty(torque, speed, dt, starts)
        n_ord = len(self.orders)
        amp = np.hypot(beta[:, 0:2 * n_ord:2], beta[:, 1:2 * n_ord:2])
        amp = np.where(ident[:, 0:2 * n_ord:2] & ident[:, 1:2 * n_ord:2], amp, np.nan)
        offset = np.where(ident[:, -1], beta[:, -1], np.nan)
        out = []
        for k in range(n_win):
            use = usable[k]
            out.append(WindowFeatures(
                t_start=float(t[starts[k]]), t_end=float(t[ends[k] - 1]),
                samples=int(ends[k] - starts[k]), end_reason=cuts[k][2],
                te_max=float(te_max[k]), te_min=float(te_min[k]),
                te_pp=float(te_max[k] - te_min[k]), te_mean=float(te_mean[k]),
                loaded_mean_te=float(loaded_mean[k]),
                orders=dict(zip(self.orders, amp[k].tolist())),
                time_offset_s=float(offset[k]),
                wear_fit=fit[0][k], wear_fit_std=fit[1][k], lost_motion=fit[2][k],
                lost_motion_std=fit[3][k], compliance_fit=fit[4][k],
                hysteresis_torque=torque_h[k, use], hysteresis=width[k, use],
                hysteresis_std=std[k, use],
                duty=duty[k], implausible=bool(implausible[k])))
        return out

    def _check_effort(self, torque_b, width, std, usable, odd):
        """
        Check, window by window, that the effort is the output torque in N·m.

        Beyond the play the loaded flanks part as ``H = L + 2·|T|/k``: the width is
        positive (the twist follows the torque) and grows with the model's series
        compliance ``1/k_s``. Per window with two or more usable bins beyond twice
        the lost-motion test torque: the median width and the weighted slope of the
        width on ``2·|T|`` times ``k_s`` (where the bins determine it,
        :data:`EFFORT_SLOPE_PRECISION`). Over the latest :data:`EFFORT_CHECK_MEMORY`
        such windows (at least :data:`EFFORT_CHECK_WINDOWS`), a median width beyond
        :data:`PLAUSIBLE_LOST_MOTION_RAD` is encoders in other units (degrees), a
        negative one an effort of the opposite sign, a median slope ratio outside
        :data:`EFFORT_SLOPE_RANGE` an effort in other units, and a play that shows
        only far from zero effort an effort with an offset (:meth:`_offset_check`):
        :attr:`effort_fault` says which, once, and that window and every later one
        give no lost motion.

        A 1x error of the output angle that the window fit could not identify is left
        in the width: under gravity, where the torque follows ``cos(theta)``, it is odd
        in the torque and its slope adds to the ratio. Its share is bounded by the
        slope of the flanks' ``sin/cos(theta)`` difference (``odd``) times
        :data:`FIRST_ORDER_ALLOWANCE_RAD`; a ratio below the range is an effort in
        other units only if it stays below with that share added (:meth:`_effort_fault`).

        Parameters
        ----------
        torque_b, width, std : ndarray, shape (W, B)
            Bin torques [N·m], widths and their standard errors [rad].
        usable : ndarray of bool, shape (W, B)
            Bins that take part.
        odd : ndarray, shape (W, B, 2)
            Per bin, the difference between the flanks' mean ``sin(theta)`` and
            ``cos(theta)``, as the width takes them; zero for a term the fit removed.

        Returns
        -------
        ndarray of bool, shape (W,)
            Windows from which on the effort is known not to be the torque.

        """
        n_win = usable.shape[0]
        if self.effort_fault is not None:
            return np.ones(n_win, dtype=bool)
        faulty = np.zeros(n_win, dtype=bool)
        beyond = usable & (np.nan_to_num(torque_b) >= 2.0 * self.takeup_torque)
        level = np.full(n_win, np.nan)
        ratio = np.full(n_win, np.nan)
        share = np.zeros(n_win)
        rows = np.flatnonzero(beyond.sum(axis=1) >= 2)
        if rows.size:
            b = beyond[rows]
            w = np.where(b, 1.0 / np.where(b, std[rows], 1.0) ** 2, 0.0)
            x = np.where(b, 2.0 * torque_b[rows], 0.0)
            sw = w.sum(axis=1)
            x0 = (w * x).sum(axis=1) / sw
            sxx = (w * (x - x0[:, None]) ** 2).sum(axis=1)
            k_s = self.tables.series_stiffness

            def slope(y):   # weighted slope of y on 2|T| over the bins, per window
                y = np.where(b, y, 0.0)
                y0 = (w * y).sum(axis=1) / sw
                return (w * (x - x0[:, None]) * (y - y0[:, None])).sum(axis=1) / sxx
            with np.errstate(invalid='ignore', divide='ignore'):
                found = slope(width[rows]) * k_s
                # Bins close together leave the slope to the noise: not judged by it.
                error = k_s / np.sqrt(sxx)
                share[rows] = FIRST_ORDER_ALLOWANCE_RAD * k_s * np.hypot(
                    slope(odd[rows, :, 0]), slope(odd[rows, :, 1]))
            ratio[rows] = np.where(error <= EFFORT_SLOPE_PRECISION * np.abs(found), found,
                                   np.nan)
            level[rows] = np.nanmedian(np.where(b, width[rows], np.nan), axis=1)
        offsets = self._offset_check(torque_b, width, beyond)
        for row in np.flatnonzero(np.isfinite(level) | np.isfinite(offsets[0])).tolist():
            fault = self._effort_window(level[row], ratio[row], share[row], offsets[:, row])
            if fault is not None:
                self.effort_fault = fault
                faulty[row:] = True
                break
        return faulty

    def _effort_window(self, level, slope, share, offset):
        """Add one window to the effort checks; return the fault they find, or None."""
        fault = None
        checks = self._effort_checks
        if math.isfinite(level):
            checks.append((level, slope, share))
            del checks[:-EFFORT_CHECK_MEMORY]
            if len(checks) >= EFFORT_CHECK_WINDOWS:
                levels, slopes, shares = np.array(checks).T
                judged = np.isfinite(slopes)
                slope = reach = math.nan
                if judged.sum() >= EFFORT_CHECK_WINDOWS:
                    slope = float(np.median(slopes[judged]))
                    reach = float(np.median(slopes[judged] + shares[judged]))
                fault = self._effort_fault(float(np.median(levels)), slope, len(checks),
                                           reach)
        offsets = self._offset_checks
        if fault is None and np.isfinite(offset).all():
            offsets.append(offset.tolist())
            del offsets[:-EFFORT_CHECK_MEMORY]
            if len(offsets) >= EFFORT_CHECK_WINDOWS:
                fault = self._offset_fault(*np.median(np.array(offsets), axis=0).tolist(),
                                           len(offsets))
        return fault

    def _offset_check(self, torque_b, width, beyond):
        """
        Where each window's play shows: the residual width near and far from zero effort.

        The width less the model's windup, ``r = H - 2·|T|/k_s``, is the lost motion
        wherever the play is taken up on both flanks, plus ``2·|T|`` times the unit's
        compliance error (its stiffness within tolerance of the catalogue's); larger
        in a soft zone. An effort whose zero is ``δ`` away from the torque's puts both
        flanks of a bin below ``|δ|`` on one side of the play: there ``r`` is the
        compliance error's alone, and the lost motion appears at ``|T| ≈ |δ|``. Per
        window: a straight line ``r = L + s·|T|`` through the bins from
        :data:`EFFORT_OFFSET_FAR` test torques on (``s = 0`` with one bin), its level
        ``L``, the median of ``r - s·|T|`` over the bins at :data:`EFFORT_OFFSET_NEAR`
        test torques, and the effort where ``r - s·|T|`` first reaches ``L/2``
        (interpolated between bins).

        Returns
        -------
        ndarray, shape (3, W)
            The near play, ``L`` [rad] and the step's effort [N·m]; NaN where a window
            lacks near or far bins.

        """
        n_win = width.shape[0]
        out = np.full((3, n_win), np.nan)
        torque = np.nan_to_num(torque_b)
        lo, hi = EFFORT_OFFSET_NEAR
        near = beyond & (torque <= hi * self.takeup_torque) & (torque >= lo * self.takeup_torque)
        far = beyond & (torque >= EFFORT_OFFSET_FAR * self.takeup_torque)
        rows = np.flatnonzero(near.any(axis=1) & far.any(axis=1))
        if rows.size == 0:
            return out
        t, m = torque[rows], far[rows]
        r = np.where(beyond[rows], width[rows] - 2.0 * t / self.tables.series_stiffness, 0.0)
        n = m.sum(axis=1)
        t0 = (m * t).sum(axis=1) / n
        r0 = (m * r).sum(axis=1) / n
        stt = (m * (t - t0[:, None]) ** 2).sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            slope = np.where(stt > 0.0, (m * (t - t0[:, None]) * (r - r0[:, None])).sum(axis=1)
                             / np.where(stt > 0.0, stt, 1.0), 0.0)
        level = r0 - slope * t0
        r = r - slope[:, None] * t
        out[0, rows] = np.nanmedian(np.where(near[rows], r, np.nan), axis=1)
        out[1, rows] = level
        half = 0.5 * level
        for k, row in enumerate(rows.tolist()):
            bins = np.flatnonzero(beyond[row])
            above = np.flatnonzero(r[k, bins] >= half[k])
            if above.size == 0:
                continue
            i = bins[above[0]]
            step = t[k, i]
            if above[0] > 0:
                j = bins[above[0] - 1]
                share = (half[k] - r[k, j]) / (r[k, i] - r[k, j])
                step = t[k, j] + share * (t[k, i] - t[k, j])
            out[2, row] = step
        return out

    def _effort_fault(self, level, slope, windows, reach=math.nan):
        """
        Say how the effort differs from the torque (medians of the check), or None.

        ``reach`` is the median slope ratio with the share an unidentified 1x error of
        the output angle may have taken off it: a slope below the plausible range counts
        unless that share could lift it to :data:`EFFORT_SLOPE_REACH` (half the
        torsional stiffness the model gives; 0.68 is the lowest ratio measured at the
        torque's own scale). Above the range the share is not taken: it grows as the
        effort shrinks against the torque (a motor current in A reads far below it), so
        it would hide exactly that fault, and at the torque's own scale it stays far
        below the 3 it would need (1.1 for a forearm with 35 arcsec under 178 N·m of
        gravity).
        """
        beyond = f'{2.0 * self.takeup_torque:.3g} N*m'
        if abs(level) > PLAUSIBLE_LOST_MOTION_RAD:     # a width no reducer has
            return (f'the encoders do not read radians at the output: in {windows} windows '
                    f'the hysteresis beyond {beyond} is {math.degrees(abs(level)) * 60:.4g} '
                    f'arcmin wide and grows {slope:.3g} times as fast with the torque as the '
                    "reducer's torsional stiffness gives (a reducer's lost motion is below "
                    f'{math.degrees(PLAUSIBLE_LOST_MOTION_RAD) * 60:g} arcmin): positions in '
                    'degrees (57.3 times radians) or in counts, or a wrong reduction ratio')
        if level < 0.0:
            return (f'the effort has the opposite sign of the torque the reducer carries: '
                    f'in {windows} windows the transmission error under positive effort '
                    f'beyond {beyond} lies {math.degrees(-level) * 60:.3g} arcmin below the '
                    'one under negative effort, where a twist follows its torque (a drive '
                    'that reports its effort with the other sign): set effort_scale '
                    '(twin.effort_scale in --config) to -1')
        lo, hi = EFFORT_SLOPE_RANGE
        if not math.isfinite(slope) or lo <= slope <= hi:
            return None     # (NaN: too few windows measure the slope)
        if slope < lo and reach >= EFFORT_SLOPE_REACH:
            return None     # an unidentified 1x error of the angle may have lowered it
        if slope <= 0.0:
            return None     # a width that does not grow: no verdict on the units
        return (f'the effort is not the output torque in N*m: in {windows} windows the '
                f'transmission error grows with it {slope:.3g} times as fast as the '
                "reducer's torsional stiffness gives (plausible "
                f'{lo:g}-{hi:g}), so the effort reads about {1.0 / slope:.3g} times the '
                'torque (a motor current in A, or a motor torque taken for joint units or '
                'the other way round: motor_effort_units): set effort_scale '
                '(twin.effort_scale in --config) to the torque per unit of effort')

    def _offset_fault(self, near, far, step, windows):
        """Say that the effort is offset from the torque (medians of the check), or None."""
        if not (far >= EFFORT_OFFSET_MIN_RAD and near < EFFORT_OFFSET_NEAR_MAX_RAD
                and near < EFFORT_OFFSET_SHARE * far):
            return None
        arcmin = math.degrees(1.0) * 60.0
        return (f'the effort is offset from the torque the reducer carries: in {windows} '
                f'windows the hysteresis shows a play of {far * arcmin:.2g} arcmin beyond '
                f'{EFFORT_OFFSET_FAR * self.takeup_torque:.3g} N*m of effort but '
                f'{near * arcmin:.2g} arcmin at {EFFORT_OFFSET_NEAR[0] * self.takeup_torque:.3g}'
                f'-{EFFORT_OFFSET_NEAR[1] * self.takeup_torque:.3g} N*m, where a reducer has '
                f"taken its play up (at {self.takeup_torque:.3g} N*m): the effort's zero lies "
                f"about {step:.3g} N*m from the torque's (a drive's current or torque sensor "
                'offset, or a load taken off the effort); zero the effort at the drive')

    def _harmonics(self, theta):
        """
        ``sin(k·theta), cos(k·theta)`` of the regressors' orders and of orders 1 and 2.

        Only order 1 takes sines and cosines (of the angle wrapped to a turn): every
        other order comes from it by the angle-addition formulas, one above an order
        already known, or twice one (the double-angle formulas), so order ``Zc`` takes
        about ``2·log2(Zc)`` products instead of two trigonometric passes. The
        friction's load model uses orders 1 and 2 of the same table.

        Returns
        -------
        dict of int to tuple of ndarray
            ``order -> (sin, cos)``.

        """
        phi = theta - TWO_PI * np.round(theta / TWO_PI)
        done = {1: (np.sin(phi), np.cos(phi))}
        wanted = {1, 2, *self.orders}
        for order in sorted(wanted):
            _harmonic(order, done)
        return {order: done[order] for order in wanted}

    def _regressors(self, harmonics, speed, y):
        """Stack ``sin(k·theta), cos(k·theta)`` per order, ``omega`` (time offset), then ``y``."""
        n_ord = len(self.orders)
        z = np.empty((2 * n_ord + 2, y.size))
        for j, order in enumerate(self.orders):
            z[2 * j], z[2 * j + 1] = harmonics[order]
        z[-2] = speed
        z[-1] = y
        return z

    def _friction(self, torque, t, harmonics, speed, win, starts, ends, half):
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
        :meth:`_smoothing_half`).

        Returns
        -------
        tuple of ndarray
            Torque at the reducer output [N·m]; the velocity-proportional part
            taken out of it [N·m] (which may be drag of the link that the
            reducer does carry); the effort as the fit explains it [N·m] (NaN
            at the windows' edges); per window the friction taken out
            ``(Coulomb, viscous, RMS speed)``; and per window whether the fit
            could not yet tell friction from the load (too few samples of one
            direction of motion).

        """
        n = torque.size
        drag = np.zeros(n)
        model = np.full(n, np.nan)
        half = max(1, half)
        speed_s, count = _window_mean(speed, half, win, starts, ends)
        effort_s, _ = _window_mean(torque, half, win, starts, ends)
        # The acceleration from the smoothed speed over the averaging length (a two-sample
        # difference would add the speed's noise, amplified, to the load model), where the
        # averages at both ends are whole and in the same window.
        whole = count == 2 * half + 1
        inner = (_shifted(whole, -half) & _shifted(whole, half)
                 & (_shifted(win, -half) == _shifted(win, half)))
        accel = np.where(inner, (_shifted(speed_s, half) - _shifted(speed_s, -half))
                         / np.maximum(_shifted(t, half) - _shifted(t, -half), 1e-12), 0.0)
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
        taken = np.zeros((starts.size, 3))
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
        pooled = self._pooled_friction_sums(z, effort_s[used], speed[used], used, starts, ends)
        sums = [np.array([p[j] for p in pooled]) for j in range(4)]
        betas, idents, etas, picked = self._efficiency_fits(
            *sums, np.array([p[4] for p in pooled]) / (2 * half + 1))
        for k, (a, b) in enumerate(zip(starts.tolist(), ends.tolist())):
            (self._fric_n, self._fric_r, self._fric_e, self._fric_yy, self._fric_m,
             self._fric_dir) = pooled[k]
            beta, ident, eta = betas[k], idents[k], float(etas[k])
            fc, fv, known = self._significant_friction(beta, ident, picked[0][k],
                                                       picked[1][k])
            unknown[k] = not known
            self.coulomb_friction, self.viscous_friction = fc, fv
            self.efficiency = eta
            load = beta[:6] @ x[:6, a:b]
            rms_speed = float(np.sqrt(np.mean(speed[a:b] ** 2)))
            gain = 1.0 + (1.0 / eta - 1.0) * driving[a:b] - (1.0 - eta) * back[a:b]
            # The efficiency counts as Coulomb friction at the window's RMS load when the
            # pool decides whether the torque moved.
            loss = 0.5 * (1.0 / eta - eta) * float(np.sqrt(np.mean(load ** 2))) \
                if eta < 1.0 else 0.0
            taken[k] = (fc + loss, fv, rms_speed)
            if fc + fv * rms_speed < _FRICTION_FLOOR * self.rated_torque:
                fc = fv = 0.0
                taken[k, :2] = (loss, 0.0)
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
            right-hand sides (for :meth:`_significant_friction`).

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
        betas, idents = _solve_identifiable_many(n_e, r_e, energy_all[pick, best])
        return betas, idents, np.asarray(_EFFICIENCIES)[best], (n_e, r_e)

    def _pooled_friction_sums(self, x_used, y_used, speed_used, used, starts, ends):
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
        memory = self._friction_memory
        n, r, e = self._fric_n, self._fric_r, self._fric_e
        yy, m, direction = self._fric_yy, self._fric_m, self._fric_dir
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

    def _toward_model(self, torque, band, model, win, starts):
        """
        Combine the smoothed torque with the rigid-body load model, weighted by their errors.

        The load model (:meth:`_friction`'s fit, pooled over many windows) has
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

    def _significant_friction(self, beta, ident, normal, rhs):
        """
        Coulomb and viscous friction of the pooled fit, 0 unless 3 standard errors above 0.

        The third value says whether the fit could tell friction from the load at all.
        """
        free = self._fric_m - np.count_nonzero(ident)
        # Both directions of motion, each in a fifth of the samples: otherwise the sign of
        # the speed is a constant and Coulomb friction cannot be told from the load.
        if free <= 0 or self._fric_dir.min() < 0.2 * self._fric_m:
            return 0.0, 0.0, False
        rss = self._fric_yy - 2.0 * beta @ rhs + beta @ normal @ beta
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

    def _smooth_torque(self, torque, half, t, period, model, win, starts, ends):
        """
        Centred moving average of the effort inside each window, and its noise band.

        The noise of the raw effort is estimated per window from second
        differences (robustly, by their median absolute value), so the
        smoothed torque's noise is ``sigma/sqrt(m)`` for an average of ``m``
        samples. Samples whose smoothed torque is within ``sign_sigmas`` of
        that noise from zero (or from the torque with the viscous friction
        left in) are ambiguous: their flank is unknown. ``half`` is the
        average's half-width in samples (:meth:`_smoothing_half`), lengthened
        for a noisy effort by :meth:`_quiet_half`.

        Returns
        -------
        tuple of ndarray
            Smoothed torque [N·m] and ``sign_sigmas`` times its noise [N·m],
            both like ``torque``.

        """
        sigma = 1.4826 * _window_medians(np.abs(torque[1:-1] - 0.5 * (torque[:-2] + torque[2:])),
                                         starts, ends - 2) / math.sqrt(1.5)
        half = self._quiet_half(sigma, half, t, period, model)
        smooth, count = _window_mean(torque, half, win, starts, ends)
        return smooth, self.sign_sigmas * sigma[win] / np.sqrt(count)

    def _quiet_half(self, sigma, half, t, period, model):
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
        its noise is :data:`_SMOOTHING_NOISE` of the test torque, but no longer
        than half the time the load takes to pass the test torque (an average
        over the passage mixes the two flanks: a 0.15 s average read an
        unloaded joint whose load passes it in 17 ms 12 % low) nor than
        :data:`_SMOOTHING_MAX_S`. The passage is timed on the rigid-body load
        of :meth:`_friction` (noise-free); without it the average keeps
        ``half``.

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
            The rigid-body load as :meth:`_friction` explains the effort [N·m].

        Returns
        -------
        int
            Half-width [samples], at least ``half``.

        """
        noise = float(np.median(sigma)) if sigma.size else 0.0
        if half <= 0 or model is None or not noise > 0.0:
            return half
        samples = (noise / (_SMOOTHING_NOISE * self.takeup_torque)) ** 2
        size = np.abs(model)
        near = np.flatnonzero((size > 0.5 * self.takeup_torque)
                              & (size < 1.5 * self.takeup_torque))
        # The slope over the average's own span: the load model carries the noise of the
        # speed (its acceleration and drag terms), which a slope between neighbours
        # multiplies.
        lag = 2 * half
        near = near[(near >= lag) & (near < model.size - lag)]
        if not period > 0.0 or near.size == 0:
            return half
        with np.errstate(invalid='ignore'):
            slope = (np.abs(model[near + lag] - model[near - lag])
                     / (t[near + lag] - t[near - lag]))
        slope = slope[np.isfinite(slope)]
        if slope.size == 0:
            return half
        passage = self.takeup_torque / max(float(np.median(slope)), 1e-12)
        longest = min(0.5 * passage, _SMOOTHING_MAX_S)
        return max(half, min(math.ceil(0.5 * (samples - 1.0)),
                             int(0.5 * longest / period)))

    def _smoothing_half(self, period):
        """Half-width in samples of the ``torque_smoothing_s`` average at a stamp step [s]."""
        return int(round(0.5 * self.torque_smoothing_s / period)) if period > 0 else 0

    def _bins(self, z, torque):
        """
        Place the samples in the ``|T|`` bins: what the group sums share whatever they exclude.

        Returns
        -------
        tuple of ndarray
            Bin index (clipped), outside-the-bins mask, ``u = |T| - bin centre`` and
            ``u·z`` per sample.

        """
        size = np.abs(torque)
        b = np.searchsorted(self.edges, size, side='right') - 1
        beyond = (b < 0) | (b >= self.torque_bins)
        b = np.clip(b, 0, self.torque_bins - 1)
        u = size - self.centres[b]
        return b, beyond, u, u * z

    def _group_stats(self, z, torque, bins, win, starts, ends, exclude=None, normal=True):
        """
        Sum the regressors per group ``(window, |T| bin, torque sign)`` and per window.

        Each group gets a straight line in ``u = |T| - bin centre``; its
        projection is eliminated from the normal equations algebraically
        (``Z^T Z - Σ_g S_g^T M_g^-1 S_g``), so no residual array is formed.
        Samples outside the bins take no part. With ``normal=False`` only the
        group sums are formed (the hysteresis needs no normal equations).
        """
        n_win = starts.size
        n_groups = n_win * 2 * self.torque_bins
        b, beyond, u, uz = bins
        outside = beyond | exclude if exclude is not None else beyond
        gid = np.where(outside, n_groups, (win * self.torque_bins + b) * 2 + (torque < 0.0))
        # The smoothed torque stays in one bin for tens of samples: sum over those runs of
        # one group first (contiguous), then add the runs of each group.
        first = np.flatnonzero(np.concatenate([[True], gid[1:] != gid[:-1]]))
        g_run = gid[first]

        def group_sums(rows):
            runs = np.add.reduceat(rows, first, axis=-1)
            if runs.ndim == 1:
                return np.bincount(g_run, runs, n_groups + 1)[:-1]
            return np.stack([np.bincount(g_run, r, n_groups + 1)[:-1] for r in runs], axis=1)
        count = np.bincount(g_run, np.diff(np.append(first, gid.size)), n_groups + 1)[:-1]
        s0 = group_sums(z)
        s1 = group_sums(uz)
        su, suu = group_sums(u), group_sums(u * u)
        with np.errstate(invalid='ignore', divide='ignore'):
            u_mean = np.where(count > 0, su / count, 0.0)
            s_uu = suu - count * u_mean ** 2
            sloped = (count >= 3) & (s_uu > 1e-12 * count * self.centres.max() ** 2)
            s1c = s1 - u_mean[:, None] * s0
        groups = {'count': count, 'u_mean': u_mean, 's_uu': s_uu, 'sloped': sloped,
                  's0': s0, 's1c': s1c, 'su': su, 'suu': suu, 's1': s1}
        if not normal:
            return groups
        with np.errstate(invalid='ignore', divide='ignore'):
            proj0 = np.where(count[:, None] > 0, s0 / np.sqrt(count)[:, None], 0.0)
            proj1 = np.where(sloped[:, None], s1c / np.sqrt(np.where(sloped, s_uu, 1.0))[:, None],
                             0.0)
        n_par = z.shape[0]
        shape = (n_win, 2 * self.torque_bins, n_par)
        proj0, proj1 = proj0.reshape(shape), proj1.reshape(shape)
        correction = (np.matmul(proj0.transpose(0, 2, 1), proj0)
                      + np.matmul(proj1.transpose(0, 2, 1), proj1))
        # Second moments per window, less those of the samples outside the bins.
        out_idx = np.flatnonzero(outside)
        z_out = z[:, out_idx]
        out_bounds = np.searchsorted(out_idx, np.concatenate([starts, ends[-1:]]))
        moments = np.empty((n_win, n_par, n_par))
        for k in range(n_win):
            zk = z[:, starts[k]:ends[k]]
            moments[k] = zk @ zk.T
            if out_bounds[k + 1] > out_bounds[k]:
                zo = z_out[:, out_bounds[k]:out_bounds[k + 1]]
                moments[k] -= zo @ zo.T
        group_params = (count > 0).astype(float) + sloped
        inside = (ends - starts) - np.diff(out_bounds)
        return {
            **groups,
            'moments': moments,
            'reduced': moments - correction,
            'energy': np.einsum('wii->wi', moments)[:, :-1],
            'dof': inside - group_params.reshape(n_win, -1).sum(axis=1),
        }

    def _fit_harmonics(self, stats, n_win, te_mean, exposure, friction_taken):
        """
        Pooled least squares of the harmonics and time offset.

        The normal equations are those of the pool (:meth:`_level_correction`:
        flank lines shared by its windows), referred to one TE level through
        the windows' means ``te_mean`` [rad]; ``exposure`` [s] of operation per
        window shortens the pool where the lost motion moves (time-compressed
        recordings). The residual variance is each window's own, under its
        own flank lines. ``friction_taken`` (per window ``(Coulomb, viscous,
        RMS speed)`` of what :meth:`_friction` took out of the effort, or
        None) restarts the pool where it changed.

        Returns
        -------
        tuple
            Coefficients per window (0 where not identifiable), the
            identifiable mask, the residual TE variance per window [rad²], and
            the pool's flank groups after each window (``count``, ``su``,
            ``suu``, ``s0``, ``s1``, and the TE ``shift`` to each window's
            level) for :meth:`_borrow_flanks`.

        """
        reduced, dof = stats['reduced'], stats['dof']
        normal, rhs = reduced[:, :-1, :-1], reduced[:, :-1, -1]
        shape = (n_win, 2 * self.torque_bins)
        raw = {'moments': stats['moments'], 'count': stats['count'].reshape(shape),
               'su': stats['su'].reshape(shape), 'suu': stats['suu'].reshape(shape),
               's0': stats['s0'].reshape(shape + (-1,)), 's1': stats['s1'].reshape(shape + (-1,))}
        pool = self._pool
        # The pool after each window; its flank lines are projected out of all at once.
        after = {key: np.empty((n_win,) + value.shape) for key, value in pool.items()}
        groups = {key: after[key] for key in ('count', 'su', 'suu', 's0', 's1')}
        groups['shift'] = np.empty(n_win)
        for k in range(n_win):
            # The windows' TE is centred on each one's mean: refer it to one level for the
            # pool (a jump of the TE's constant, where a turn count was lost, starts afresh).
            # The torque that placed the samples in their flank groups is the effort less the
            # friction taken out: where that changed by more than the flanks can absorb (the
            # friction identified, a window after the first ones that carried all of it), the
            # pooled groups mix two torques and start afresh too.
            friction = friction_taken[k] if friction_taken is not None else np.zeros(3)
            moved = (abs(friction[0] - self._pool_friction[0])
                     + abs(friction[1] - self._pool_friction[1]) * friction[2])
            if self._te_ref is None or abs(te_mean[k] - self._te_ref) > _POOL_JUMP or \
                    moved > _POOL_FRICTION_JUMP * self.rated_torque:
                self._te_ref = te_mean[k]
                self._pool_friction = friction[:2].copy()
                for value in pool.values():
                    value[...] = 0.0
            d = te_mean[k] - self._te_ref
            add = {key: value[k].copy() for key, value in raw.items()}
            total = add['s0'].sum(axis=0)
            add['moments'][-1, :] += d * total
            add['moments'][:, -1] += d * total
            add['moments'][-1, -1] += d * d * add['count'].sum()
            add['s0'][:, -1] += d * add['count']
            add['s1'][:, -1] += d * add['su']
            # The flank levels are shared while the lost motion holds still: over
            # memory_windows windows, or _POOL_EXPOSURE_S of operation if that is shorter
            # (a time-compressed recording wears visibly from one window to the next).
            memory = min(self._memory, math.exp(-exposure[k] / _POOL_EXPOSURE_S))
            for key, value in pool.items():
                value *= memory
            # The pooled windows' index tau counts back from this one (0): one step older.
            pool['stt'] += pool['count'] - 2.0 * pool['st']
            pool['st'] -= pool['count']
            pool['sut'] -= pool['su']
            pool['stz'] -= pool['s0']
            for key, value in add.items():
                pool[key] += value
            for key, value in after.items():
                value[k] = pool[key]
            groups['shift'][k] = d
        red = after['moments'] - self._level_correction(after)
        pool_n, pool_r = red[:, :-1, :-1], red[:, :-1, -1]
        pool_raw = np.diagonal(after['moments'], axis1=1, axis2=2)[:, :-1]
        beta, ident = _solve_identifiable_many(pool_n, pool_r, pool_raw)
        noise = np.full(n_win, np.nan)
        free = dof - np.count_nonzero(ident, axis=1)
        for k in np.flatnonzero(free > 0).tolist():
            b = beta[k]
            rss = reduced[k, -1, -1] - 2.0 * b @ rhs[k] + b @ normal[k] @ b
            noise[k] = max(rss, 0.0) / free[k]
        return beta, ident, noise, groups

    def _level_correction(self, pool):
        """
        Projection of the pooled flank lines out of the pooled moments, ``(..., P+1, P+1)``.

        The pool's groups are ``(|T| bin, torque sign)`` over all its windows:
        each a level with a slope in ``u`` and a drift over the windows (the
        lost motion grows, quickly in a time-compressed recording), shared by
        the windows, so that the harmonics are told from the hysteresis by the
        positions at which the joint meets the same load in different moves,
        not only within one window. ``pool`` holds one pool or a stack of them (a
        leading axis of windows).
        """
        n = pool['count']
        has = n > 0
        with np.errstate(invalid='ignore', divide='ignore'):
            inv_n = np.where(has, 1.0 / np.where(has, n, 1.0), 0.0)
            u_m, t_m = pool['su'] * inv_n, pool['st'] * inv_n
            c_uu = pool['suu'] - n * u_m ** 2
            c_tt = pool['stt'] - n * t_m ** 2
            c_ut = pool['sut'] - n * u_m * t_m
            b_u = pool['s1'] - u_m[..., None] * pool['s0']
            b_t = pool['stz'] - t_m[..., None] * pool['s0']
        use_u = has & (n >= 3) & (c_uu > 1e-12 * n * self.centres.max() ** 2)
        use_t = has & (n >= 3) & (c_tt > 1e-6 * n)
        c_uu, c_tt, c_ut = (np.where(use_u, c_uu, 1.0), np.where(use_t, c_tt, 1.0),
                            np.where(use_u & use_t, c_ut, 0.0))
        b_u = np.where(use_u[..., None], b_u, 0.0)
        b_t = np.where(use_t[..., None], b_t, 0.0)
        det = c_uu * c_tt - c_ut ** 2
        ok = det > 1e-9 * c_uu * c_tt
        # Inverse of the centred (u, tau) Gram matrix; a nearly collinear pair keeps u only.
        i_uu = np.where(ok, c_tt / np.where(ok, det, 1.0), 1.0 / c_uu)
        i_tt = np.where(ok, c_uu / np.where(ok, det, 1.0), 0.0)
        i_ut = np.where(ok, -c_ut / np.where(ok, det, 1.0), 0.0)
        i_uu, i_tt, i_ut = (np.where(use_u, i_uu, 0.0), np.where(use_t, i_tt, 0.0),
                            np.where(use_u & use_t, i_ut, 0.0))
        i_tt = np.where(use_t & ~use_u, 1.0 / c_tt, i_tt)
        s0 = pool['s0']

        def gram(a, weight, b):
            return np.swapaxes(a * weight[..., None], -1, -2) @ b
        return (gram(s0, inv_n, s0) + gram(b_u, i_uu, b_u) + gram(b_t, i_tt, b_t)
                + gram(b_u, i_ut, b_t) + gram(b_t, i_ut, b_u))

    def _hysteresis(self, stats, beta, noise, pooled):
        """Observed hysteresis ``(|T|, H, std, usable)`` per window and bin, shape (W, bins)."""
        n_win, n_par = beta.shape
        b_group = np.repeat(beta, 2 * self.torque_bins, axis=0)
        s0, s1c = stats['s0'], stats['s1c']
        count, u_mean, s_uu, sloped = (stats[k] for k in ('count', 'u_mean', 's_uu', 'sloped'))
        with np.errstate(invalid='ignore', divide='ignore'):
            level = (s0[:, -1] - np.einsum('gi,gi->g', s0[:, :-1], b_group)) / count
            slope = np.where(sloped, (s1c[:, -1] - np.einsum('gi,gi->g', s1c[:, :-1], b_group))
                             / np.where(sloped, s_uu, 1.0), 0.0)
            first = self._first_order_means(s0, count)
        shape = (n_win, self.torque_bins, 2)
        count, u_mean, s_uu, sloped, level, slope, sin1, cos1 = (
            a.reshape(shape) for a in (count, u_mean, s_uu, sloped, level, slope, *first))
        needed = self.flank_samples()
        own = count >= needed
        count, u_mean, s_uu, sloped, level, slope, sin1, cos1 = self._borrow_flanks(
            own, beta, (count, u_mean, s_uu, sloped, level, slope, sin1, cos1), pooled)
        usable = (count >= needed).all(axis=2) & own.any(axis=2)
        with np.errstate(invalid='ignore', divide='ignore'):
            u_eval = (count * u_mean).sum(axis=2) / count.sum(axis=2)
            lever = u_eval[..., None] - u_mean
            at_eval = level + slope * lever
            spread = np.where(sloped, lever ** 2 / np.where(sloped, s_uu, 1.0), 0.0)
            var = noise[:, None] * (1.0 / count + spread).sum(axis=2)
        width = at_eval[..., 1] - at_eval[..., 0]
        std = np.sqrt(var + _MODEL_SIGMA ** 2)
        usable &= np.isfinite(width) & np.isfinite(std)
        odd = np.stack([sin1[..., 1] - sin1[..., 0], cos1[..., 1] - cos1[..., 0]], axis=-1)
        return u_eval + self.centres, width, std, usable, np.nan_to_num(odd)

    def _first_order_means(self, s0, count):
        """Per flank group, the mean ``sin(theta)`` and ``cos(theta)`` (zeros without order 1)."""
        if 1 not in self.orders:
            return np.zeros_like(count, dtype=float), np.zeros_like(count, dtype=float)
        j = 2 * self.orders.index(1)
        return s0[..., j] / count, s0[..., j + 1] / count

    def _first_order(self, ident):
        """Whether the window fit identified the ``sin`` and ``cos`` of order 1, ``(W, 2)``."""
        if 1 not in self.orders:
            return np.zeros((ident.shape[0], 2), dtype=bool)
        j = 2 * self.orders.index(1)
        return ident[:, j:j + 2]

    def flank_samples(self):
        """
        Return the samples a flank (a ``|T|`` bin under one torque sign) needs to count.

        ``min_bin_samples`` at :data:`FLANK_RATE_HZ` and above. Below it the bins near
        the lost-motion test torque are those the load passes through quickly at each
        reversal (a joint under gravity crosses zero torque at full speed): at 100 Hz
        they kept 5-20 samples each and were dropped, so the lost motion was read by
        extrapolating the bins from 15 % of rated torque on, along the model's curve
        (a window holds at least ``min_window_samples``, 10 s at 100 Hz). There a
        flank needs the samples of the same stream time as at :data:`FLANK_RATE_HZ`
        (``min_bin_samples/FLANK_RATE_HZ``), at least
        :data:`LOW_RATE_MIN_FLANK_SAMPLES`; its standard error counts its samples.

        Returns
        -------
        int
            The number of samples (``min_bin_samples`` before the rate is known).

        """
        rate = self.rate_hz
        if not (math.isfinite(rate) and rate < FLANK_RATE_HZ):
            return self.min_bin_samples
        same_time = math.ceil(self.min_bin_samples * rate / FLANK_RATE_HZ - 1e-9)
        return min(self.min_bin_samples, max(same_time, LOW_RATE_MIN_FLANK_SAMPLES))

    def _borrow_flanks(self, own, beta, flanks, groups):
        """
        Flank lines from the pool for a window without a hysteresis of its own.

        A window that met its loads under one sign only (the reversal fell into the
        window before or after, as a 2 s window of a slow cycle often does) has too
        few bins for a lost motion. The pool holds every ``(|T| bin, torque sign)``
        flank of the recent windows (this one included) beyond the lost-motion test
        torque, referred to one TE level: in such a window, a bin that the window met
        under one sign and the pool under both takes both flank lines from the pool,
        with this window's harmonics removed and moved to this window's TE level.
        Both flanks then come from the same samples, so harmonics left in them
        cancel as in a window's own bins; the pooled samples are older (the pool's
        memory), over which the lost motion holds still as the pooled harmonic fit
        already assumes. A window with enough bins of its own keeps them.

        Parameters
        ----------
        own : ndarray of bool, shape (W, bins, 2)
            Flanks with enough samples in the window itself.
        beta : ndarray, shape (W, P)
            Harmonic and time-offset coefficients per window.
        flanks : tuple of ndarray, shape (W, bins, 2)
            ``count, u_mean, s_uu, sloped, level, slope`` of the window's flanks and the
            means of ``sin(theta)`` and ``cos(theta)`` over their samples.
        groups : dict of ndarray
            The pool's flank groups after each window (:meth:`_fit_harmonics`).

        Returns
        -------
        tuple of ndarray
            ``flanks`` with the pooled ones where they are taken.

        """
        shape = own.shape
        n = groups['count'].reshape(shape)
        with np.errstate(invalid='ignore', divide='ignore'):
            s0 = groups['s0'].reshape(shape + (-1,))
            s1 = groups['s1'].reshape(shape + (-1,))
            u_mean = groups['su'].reshape(shape) / n
            s_uu = groups['suu'].reshape(shape) - n * u_mean ** 2
            s1c = s1 - u_mean[..., None] * s0
            b = beta[:, None, None, :]
            level = ((s0[..., -1] - (s0[..., :-1] * b).sum(axis=-1)) / n
                     - groups['shift'][:, None, None])
            sloped = (n >= 3) & (s_uu > 1e-12 * n * self.centres.max() ** 2)
            slope = np.where(sloped, (s1c[..., -1] - (s1c[..., :-1] * b).sum(axis=-1))
                             / np.where(sloped, s_uu, 1.0), 0.0)
            first = self._first_order_means(s0, n)
        pooled = ((n >= self.flank_samples()) & np.isfinite(level)).all(axis=2)
        blind = own.all(axis=2).sum(axis=1) < self.min_bins
        take = (pooled & own.any(axis=2) & blind[:, None])[..., None]
        if not take.any():
            return flanks
        return tuple(np.where(take, p, f)
                     for p, f in zip((n, u_mean, s_uu, sloped, level, slope, *first), flanks))

    def _duty(self, torque, speed, dt, starts):
        """Duty summaries per window."""
        size, rate = np.abs(torque), np.abs(speed)
        exponent = self.params.rating.life_exponent
        archard = wear_rate(size, rate, 0.0, self.params)
        rows = (dt, size * dt, rate * dt, rate * size ** exponent * dt, archard * dt)
        sums = np.stack([np.add.reduceat(row, starts) for row in rows], axis=1)
        peak = np.maximum.reduceat(size, starts)
        out = []
        for (dur, s_t, s_w, s_cube, s_wear), top in zip(sums.tolist(), peak.tolist()):
            out.append(DutySummary(
                duration_s=dur, exposure_s=dur * self.aging_factor,
                archard_increment=s_wear * self.aging_factor,
                mean_abs_torque=s_t / dur if dur > 0 else math.nan,
                mean_abs_speed=s_w / dur if dur > 0 else math.nan,
                cubic_mean_torque=(s_cube / s_w) ** (1.0 / exponent) if s_w > 0 else math.nan,
                max_abs_torque=top))
        return out

    def _hysteresis_table(self, torque_b):
        """Model hysteresis at ``|T|_b`` on every wear node of the table, shape (m, nodes)."""
        tab = self.tables
        t = np.clip(torque_b, tab.torque[0], tab.torque[-1])
        i = np.clip(np.searchsorted(tab.torque, t, side='right') - 1, 0, tab.torque.size - 2)
        f = ((t - tab.torque[i]) / (tab.torque[i + 1] - tab.torque[i]))[:, None]
        beta = (1.0 - f) * tab.beta[i] + f * tab.beta[i + 1]
        return 2.0 * (beta + (torque_b / tab.series_stiffness)[:, None])

    def _fit_wear(self, torque_b, h_b, sig_b, usable, chunk=128):
        """
        Weighted least-squares wear that explains the observed hysteresis, per window.

        Model: ``H_b = H(|T|_b, w) + 2·|T|_b·c`` with the table hysteresis
        :meth:`.transmission_error.ModelTables.hysteresis` and a compliance
        correction ``c`` [rad/(N·m)] with a Gaussian prior of
        ``compliance_prior/k_s``. ``c`` absorbs a stiffness that differs from
        the catalogue and the part of an unidentified 1x harmonic that is odd
        in torque (under gravity ``cos(theta)`` follows ``T``); wear is
        measured by the level of ``H``, not its slope. Each bin's standard
        error includes a shape error that grows with its distance from the
        test torque (:data:`_SHAPE_ERROR`): the level is read where the curve
        is observed nearest the test torque. The table is bilinear,
        so the model is linear in ``(w, c)`` between wear nodes: the weighted
        sum of squares is minimised exactly on every interval at once. The
        standard error is scaled by the reduced chi-square when above 1. The
        reading is then weighed against a straight curve's
        (:meth:`_or_straight`).

        Parameters
        ----------
        torque_b, h_b, sig_b : ndarray, shape (W, B)
            Bin torques [N·m], observed widths [rad] and their standard
            errors [rad].
        usable : ndarray of bool, shape (W, B)
            Bins that take part.
        chunk : int
            Windows per vectorised pass (bounds the memory).

        Returns
        -------
        tuple of ndarray, shape (W,)
            Wear [m], its std [m], lost motion [rad], its std [rad] and the
            compliance correction [rad/(N·m)]; NaN for windows with fewer
            than ``min_bins`` usable bins.

        """
        n_win = torque_b.shape[0]
        out = np.full((5, n_win), np.nan)
        todo = np.flatnonzero(usable.sum(axis=1) >= self.min_bins)
        for lo in range(0, todo.size, chunk):
            rows = todo[lo:lo + chunk]
            out[:, rows] = self._fit_wear_rows(torque_b[rows], h_b[rows], sig_b[rows],
                                               usable[rows])
        return tuple(out)

    def _fit_wear_rows(self, torque_b, h_b, sig_b, usable):
        """Vectorised body of :meth:`_fit_wear` for windows that all have enough bins."""
        grid = self.tables.wear
        step = np.diff(grid)
        torque_b = np.where(usable, torque_b, self.centres)
        # A bin far from the test torque says less about the lost motion there: its share of
        # the curve's shape between the two is the model's, and a reducer may differ.
        reach = 2.0 * np.abs(torque_b - self.takeup_torque) / self.tables.series_stiffness
        measured = np.where(usable, 1.0 / np.where(usable, sig_b, 1.0) ** 2, 0.0)
        sig_b = np.hypot(sig_b, _SHAPE_ERROR * reach)
        weight = np.where(usable, 1.0 / np.where(usable, sig_b, 1.0) ** 2, 0.0)[..., None]
        h_b = np.where(usable, h_b, 0.0)[..., None]
        model = self._hysteresis_table(torque_b.ravel()).reshape(torque_b.shape + grid.shape)
        slope = np.diff(model, axis=2) / step
        lever = 2.0 * torque_b[..., None]
        miss = h_b - model[..., :-1]
        prior = (self.compliance_prior / self.tables.series_stiffness) ** -2
        a11 = (weight * slope ** 2).sum(axis=1)
        a12 = (weight * slope * lever).sum(axis=1)
        a22 = (weight * lever ** 2).sum(axis=1) + prior
        b1 = (weight * slope * miss).sum(axis=1)
        b2 = (weight * lever * miss).sum(axis=1)
        det = a11 * a22 - a12 ** 2
        with np.errstate(invalid='ignore', divide='ignore'):
            move = np.where(det > 0.0, (a22 * b1 - a12 * b2) / det, 0.0)
        move = np.clip(move, 0.0, step)
        comp = (b2 - a12 * move) / a22
        chi2 = ((weight * (miss - slope * move[:, None] - lever * comp[:, None]) ** 2).sum(axis=1)
                + prior * comp ** 2)
        best = np.argmin(chi2, axis=1)
        pick = np.arange(best.size)
        wear = grid[best] + move[pick, best]
        m = usable.sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            scale = np.where(m > 1, np.maximum(1.0, chi2[pick, best] / (m - 1)), 1.0)
            wear_var = np.where(det[pick, best] > 0.0,
                                scale * a22[pick, 0] / det[pick, best], np.inf)
        wear_std = np.sqrt(wear_var)
        half = 0.5e-6
        lo, hi = np.maximum(wear - half, grid[0]), np.minimum(wear + half, grid[-1])
        dlm = (self.tables.lost_motion(hi) - self.tables.lost_motion(lo)) / (hi - lo)
        lm, lm_std = self.tables.lost_motion(wear), np.abs(dlm) * wear_std
        resid = (miss[pick, :, best] - slope[pick, :, best] * move[pick, best][:, None]
                 - lever[..., 0] * comp[pick, best][:, None])
        lm, lm_std = self._or_straight(torque_b, h_b[..., 0], weight[..., 0], measured, prior,
                                       (wear > grid[0]) & (m > 1), lm, lm_std,
                                       (measured * resid ** 2).sum(axis=1))
        return wear, wear_std, lm, lm_std, comp[pick, best]

    def _or_straight(self, torque_b, h_b, weight, measured, prior, open_, lm, lm_std, chi2):
        """
        Weigh the model's reading against a straight hysteresis curve's.

        Above its take-up a reducer's spring may be straighter than the model's, whose
        contacts stiffen with the load: read along the model's curve, a straight one is
        extrapolated to the test torque along a bend it does not have (5-6 % on units
        of 0.6-0.8 arcmin, whose model curve bends most; the sign depends on the bins'
        reach). The alternative is ``H_b = L + 2·|T|_b·(1/k_s + c)``, ``c`` with the
        compliance prior, whose lost motion is its level ``L`` (the width left when
        the windup of the fitted stiffness is taken off). The two readings are averaged
        with the weights of their likelihoods (equal prior odds; chi-square of the bins'
        measurement errors only, without the shape error, which is the model's), the
        variance including their spread. A fit on the table's lower bound (censored) or
        with a single bin keeps the model's reading.

        Parameters
        ----------
        torque_b, h_b : ndarray, shape (W, B)
            Bin torques [N·m] and widths [rad].
        weight, measured : ndarray, shape (W, B)
            Weights of the bins with and without the shape error [rad^-2], 0 where unused.
        prior : float
            Precision of the compliance prior [(N·m/rad)^2].
        open_ : ndarray of bool, shape (W,)
            Windows whose model reading may be weighed.
        lm, lm_std : ndarray, shape (W,)
            The model's lost motion and its standard error [rad].
        chi2 : ndarray, shape (W,)
            The model fit's chi-square under ``measured``.

        Returns
        -------
        tuple of ndarray
            Lost motion and its standard error [rad].

        """
        arm = 2.0 * torque_b
        rest = h_b - arm / self.tables.series_stiffness
        n11, n12 = weight.sum(axis=1), (weight * arm).sum(axis=1)
        n22 = (weight * arm ** 2).sum(axis=1) + prior
        r1, r2 = (weight * rest).sum(axis=1), (weight * arm * rest).sum(axis=1)
        det = n11 * n22 - n12 ** 2
        m = (weight > 0.0).sum(axis=1)
        with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
            level = (n22 * r1 - n12 * r2) / det
            comp = (n11 * r2 - n12 * r1) / det
            resid = rest - level[:, None] - arm * comp[:, None]
            fit_chi2 = (weight * resid ** 2).sum(axis=1) + prior * comp ** 2
            var = np.maximum(1.0, fit_chi2 / np.maximum(m - 1, 1)) * n22 / det
            odds = np.exp(np.clip(0.5 * ((measured * resid ** 2).sum(axis=1) - chi2), -50.0, 50.0))
            share = 1.0 / (1.0 + odds)
        share = np.where(open_ & (det > 0.0) & np.isfinite(level) & np.isfinite(var), share, 0.0)
        level, var = np.where(share > 0.0, level, lm), np.where(share > 0.0, var, 0.0)
        mixed = (1.0 - share) * lm + share * level
        spread = share * (1.0 - share) * (lm - level) ** 2
        return mixed, np.sqrt((1.0 - share) * lm_std ** 2 + share * var + spread)


_SHAPE_ERROR = 0.02
"""
Shape error of the hysteresis model: a fraction of the windup between a bin and the test torque.

The wear fit extrapolates the observed widths to the catalogue's test torque along the
model's curve ``H(|T|, w) + 2·|T|·c``. A reducer whose curve has another shape (a spring
straighter or stiffer than the model's, a play taken up at another torque) is read wrong
in proportion to how far the bins lie from the test torque: each bin's standard error gets
``_SHAPE_ERROR · 2·| |T|_b - T_test |/k_s`` added in quadrature, so bins near the test
torque decide the level where the window has them, and the reported standard error grows
with the reach of the extrapolation where it has not. 0.02 from bench/bench_lost_motion.py
(0.01-0.03 read alike; from 0.05 on, the noisier low bins near the takeup decide too much).
"""

_BUFFER = ('t', 'te', 'theta', 'torque', 'speed', 'dt', 'gap')

_POOL_EXPOSURE_S = 100.0 * 3600.0
"""Operation [s] over which the pooled flank levels fade (the lost motion moves little)."""

_POOL_FRICTION_JUMP = 0.01
"""
Change of the friction taken out of the effort [fraction of rated torque, at the window's
RMS speed] for which the pooled fit restarts: its flank groups were formed with another torque.
"""

_SMOOTHING_NOISE = 0.1
"""Noise of the smoothed torque, as a fraction of the lost-motion test torque, sought."""

_SMOOTHING_MAX_S = 0.15
"""Longest torque average [s] (five times the default ``torque_smoothing_s``)."""

_POOL_JUMP = 0.01
"""Change of a window's mean TE [rad] taken for a new TE constant: the pooled fit restarts."""

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

_EMPTY = np.zeros(0)

_SINCE = ('seen', 'without_effort', 'implausible', 'windows')
"""What :meth:`WindowAnalyzer.stale_reason` counts since the last lost motion."""

PLAUSIBLE_TE_SPAN_RAD = math.radians(10.0)
"""
Largest transmission-error span [rad] within one window that encoders on one reducer give.

A reducer's TE moves by arcminutes (windup, hysteresis, harmonics; an encoder time offset
adds its speed times the delay, about 2 degrees at 3 rad/s and 10 ms). Beyond 10 degrees the
two encoders do not measure the same motion: a motor encoder that counts against the link,
a frozen encoder, or a wrong ratio. Such a window gives no lost motion.
"""

PLAUSIBLE_LOST_MOTION_RAD = math.radians(1.0)
"""
Largest lost motion [rad] read as one: 60 arcmin, 20 times the usual wear limit (3 arcmin).

A reading beyond it is an encoder or configuration fault, not a reducer.
"""

EFFORT_CHECK_WINDOWS = 5
"""Windows with two or more hysteresis bins beyond twice the test torque that decide the check."""

EFFORT_CHECK_MEMORY = 50
"""The latest windows of the effort check (its medians)."""

EFFORT_SLOPE_RANGE = (0.25, 4.0)
"""
Plausible ratio of the hysteresis' growth with the effort to the model's (1 for the torque).

Beyond the play, the width between the loaded flanks grows as ``2·|T|/k_s``: an effort in
the output torque's units gives the model's series stiffness within its tolerance. Measured
(median over a joint's windows, bins beyond twice the test torque): 0.95-1.13 on the
independent generator, 0.68-1.18 on the third (catalogue stiffness +-20 %, a soft knee),
1.07-1.08 on the model's simulator; an effort ten times the torque gives 0.11, a tenth of
it 10.4. A ratio outside this range is an effort in other units, not a reducer.
"""

FIRST_ORDER_ALLOWANCE_RAD = math.radians(1.0 / 60.0)
"""
Largest 1x error of the output angle the effort check allows for where the fit cannot see it.

The eccentricity of a link encoder and the reducer's own once-per-turn error: real RV-80E
prototypes measure about +-30 arcsec (physics notes, section 4); the third generator draws
10-40 arcsec. Under gravity the torque follows ``cos(theta)``, so such an error is odd in
the torque, the window fit cannot identify it, and it changes the width's slope: a
third-generator forearm (35 arcsec, 178 N*m of gravity) read a slope ratio of 0.24 and was
refused as an effort 4.2 times the torque; with this allowance its median reaches 1.29
(windows 0.21-1.70). An effort in other units keeps its verdict: the allowance shrinks with
the effort's scale (0.04 on the model's simulator at ten times the torque, whose ratio is
then 0.11; at five times 0.22 + 0.09, below :data:`EFFORT_SLOPE_REACH`;
``bench/bench_effort_check.py``).
"""

EFFORT_SLOPE_REACH = 0.5
"""
Slope ratio a window's 1x allowance must lift a ratio below the range to, to spare it.

Half the model's torsional stiffness: at the torque's own scale the three generators read
0.68-1.18 (catalogue stiffness +-20 %, soft knees), so 0.5 leaves room; an effort five
times the torque reads 0.22 and reaches 0.31 with its allowance.
"""

EFFORT_SLOPE_PRECISION = 0.3
"""
Largest standard error of a window's slope ratio, as a share of the ratio, that the check uses.

A window whose bins beyond twice the test torque lie close together (a base joint loaded by
its accelerations alone) gives a slope the noise decides: a third-generator base read 0.025
(a median over 5 windows) and was refused as an effort 40 times the torque. The error
scales with the ratio when the effort is scaled, so an effort in other units keeps its
windows; their sign and width still count from every window.
"""

EFFORT_OFFSET_NEAR = (2.0, 4.0)
"""Bins, in lost-motion test torques, where the offset check reads the play near zero effort."""

EFFORT_OFFSET_FAR = 6.0
"""Bins from this many test torques on give the offset check the play far from zero effort."""

EFFORT_OFFSET_SHARE = 0.35
"""
Share of the far play below which the play near zero effort says the effort is offset.

The play near zero effort over that far from it (medians over a joint's windows, the far
bins' compliance error taken off both): 0.68-1.13 on 78 joints of the independent and third
generators (seeds 4-11, 150 and 400 h recordings at 10-90 % of life, soft knees and
stiffness within +-20 % included; one base with 2 such windows 0.41, its near play 1.3
arcmin) and 0.90-0.99 on the model's simulator; an effort offset by 80 N*m (10 % of an
RV-80E's rated torque) 0.20-0.23 where its near bins lie below the offset, by 150 N*m
-0.03-0.03. Offsets within the near bins (40 N*m and less) give 0.89-0.93: undetected, the
wear then reads within 10 % (one remaining-life interval of four missed the truth).
"""

EFFORT_OFFSET_NEAR_MAX_RAD = math.radians(0.2 / 60.0)
"""
Largest play near zero effort [rad] the offset check takes for none (0.2 arcmin).

A reducer's play at its test torque is at least its new lost motion (0.3 arcmin and more);
an offset effort gave -0.01-0.16 arcmin there.
"""

EFFORT_OFFSET_MIN_RAD = math.radians(0.3 / 60.0)
"""Smallest far play [rad] the offset check judges by (a new reducer's least, 0.3 arcmin)."""

EFFORT_PLAUSIBLE_RATED = 5.0
"""
Largest effort, in rated torques, a joint's reducer is taken to carry.

An RV reducer's momentary maximum torque is about 5 times its rated torque (RV-80E:
3920 N·m against 784); an effort beyond it explains a joint without lost motion as an
effort in other units.
"""

LOW_RATE_HZ = 200.0
"""
Below this sample rate [Hz] a joint without lost motion is reported as sampled too slowly.
"""

FLANK_RATE_HZ = 500.0
"""
Below this sample rate [Hz] a flank of the hysteresis needs the samples of the same stream
time as here (:meth:`WindowAnalyzer.flank_samples`).

Was :data:`LOW_RATE_HZ`: a 250 Hz recording of the model's simulator (its own, or 1 kHz
thinned) kept only the bins from 200 N*m on and read the wear 14-20 % low, with P10-P90
missing the truth on both joints; with this rule 1-2 % (README figures).
"""

LOW_RATE_MIN_FLANK_SAMPLES = 10
"""
Fewest samples a flank needs below :data:`FLANK_RATE_HZ` (a flank line takes 3).

Measured on bench_lost_motion.py recordings forced to 100 and 125 Hz (24 truths, seeds
4000-4011 and 5000-5011, 1 % effort noise): the forearms' median-of-windows lost motion
erred by 2.7 % on average (p90 6.2 %) with 20 samples a flank, 1.5 % (p90 2.8 %) with
these; the shoulders' 1.7 % -> 1.0 %. With 6 the flanks of a few samples at full speed
were noisier than the bins they added: over the bench's 72 truths (seeds 1000-1023,
2000-2023, 3000-3023) 3 more recordings had a joint beyond 5 % than with 10.
"""

_BATCH_SAMPLES = 1 << 16


def _whole(name, value, lo, hi):
    """Return ``value`` as an int in ``[lo, hi]``, else raise."""
    whole = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not whole or not lo <= value <= hi:
        raise InvalidParameter(out_of_range(name, value, '', f'a whole number in [{lo}, {hi}]'))
    return int(value)


def _harmonic(order, done):
    """
    Return ``(sin, cos)`` of ``order`` times the angle, kept in ``done`` with what it needs.

    From order ``k - 1`` and order 1 (angle addition) when ``k - 1`` is known or ``k`` is
    odd, else from order ``k/2`` (double angle); ``done`` holds order 1.
    """
    if order not in done:
        if order - 1 in done or order % 2:
            (s_a, c_a), (s_1, c_1) = _harmonic(order - 1, done), done[1]
            done[order] = (s_a * c_1 + c_a * s_1, c_a * c_1 - s_a * s_1)
        else:
            s_h, c_h = _harmonic(order // 2, done)
            done[order] = (2.0 * s_h * c_h, (c_h - s_h) * (c_h + s_h))
    return done[order]


def _window_mean(values, half, win, starts, ends):
    """
    Centred mean of ``values[i - half .. i + half]`` cut at the ends of each window.

    Returns
    -------
    tuple of ndarray
        The means and the number of samples each one averages (``2·half + 1`` inside a
        window, fewer within ``half`` of its ends); ``values`` itself when ``half`` is 0.

    """
    n = values.size
    width = 2 * half + 1
    count = np.full(n, width, dtype=np.int64)
    if half <= 0:
        return values, count
    # Whole inside, computed again (with its length) near the ends of each window.
    edge = _window_edges(starts, ends, half)
    lo = np.maximum(edge - half, starts[win[edge]])
    hi = np.minimum(edge + half + 1, ends[win[edge]])
    acc = np.concatenate([[0.0], np.cumsum(values)])
    mean = np.empty(n)
    if n > 2 * half:
        mean[half:n - half] = (acc[width:] - acc[:n + 1 - width]) / width
    mean[edge] = (acc[hi] - acc[lo]) / (hi - lo)
    count[edge] = hi - lo
    return mean, count


def _shifted(values, shift):
    """Return ``values[clip(i + shift, 0, n - 1)]`` for every index ``i`` (slices, no gather)."""
    n = values.size
    out = np.empty_like(values)
    if n == 0:
        return out
    k = min(abs(shift), n)
    if shift >= 0:
        out[:n - k] = values[k:]
        out[n - k:] = values[-1]
    else:
        out[k:] = values[:n - k]
        out[:k] = values[0]
    return out


def _window_edges(starts, ends, half):
    """Return the indices within ``half`` samples of either end of their window."""
    if half <= 0:
        return np.zeros(0, dtype=np.int64)
    offsets = np.arange(half)
    head = np.minimum(starts[:, None] + offsets, ends[:, None] - 1)
    tail = np.maximum(ends[:, None] - half + offsets, starts[:, None])
    return np.unique(np.concatenate([head.ravel(), tail.ravel()]))


def _window_medians(values, starts, ends):
    """
    Median of ``values[starts[k]:ends[k]]`` per window, 0 for a window with none.

    Windows of equal length take one call of :func:`numpy.median` along rows (the
    same partition and mean as one window at a time).
    """
    out = np.zeros(starts.size)
    lengths = ends - starts
    for m in np.unique(lengths[lengths > 0]).tolist():
        rows = np.flatnonzero(lengths == m)
        out[rows] = np.median(values[starts[rows, None] + np.arange(m)], axis=1)
    return out


def _solve_identifiable_many(normal, rhs, energy):
    """
    Solve a stack of normal equations, leaving out parameters the data cannot identify.

    Shapes (W, P, P), (W, P), (W, P). A parameter is identifiable when the share of
    its regressor's energy that no other regressor explains, ``1/(A^-1)_jj`` of the
    energy-scaled matrix ``A``, is at least :data:`_MIN_IDENTIFIABILITY`; the least
    identifiable parameter of a system is removed until all that remain pass. Each
    round inverts the systems that keep the same parameters as one stack (the same
    LAPACK call per matrix as one at a time).

    Returns
    -------
    tuple of ndarray
        Coefficients (0 where not identifiable) and the identifiable masks.

    """
    n_sys, n_par = rhs.shape
    ident = energy > 0.0
    scale = np.where(ident, 1.0 / np.sqrt(np.where(ident, energy, 1.0)), 0.0)
    a = normal * (scale[:, :, None] * scale[:, None, :])
    b = rhs * scale
    beta = np.zeros((n_sys, n_par))
    bits = 1 << np.arange(n_par)
    active = ident.any(axis=1)
    while active.any():
        rows = np.flatnonzero(active)
        keys = ident[rows] @ bits
        for key in np.unique(keys).tolist():
            group = rows[keys == key]
            idx = np.flatnonzero(ident[group[0]])
            inv, share = _identifiability(a[group[:, None, None], idx[:, None], idx])
            worst = np.argmin(share, axis=1)
            for j, k in enumerate(group.tolist()):
                if share[j, worst[j]] >= _MIN_IDENTIFIABILITY:
                    beta[k, idx] = inv[j] @ b[k, idx] * scale[k, idx]
                    active[k] = False
                else:
                    ident[k, idx[worst[j]]] = False
                    active[k] = ident[k].any()
    return beta, ident


def _identifiability(sub):
    """
    Inverses of a stack of scaled normal matrices and each parameter's unexplained share.

    A singular matrix gets a share of 0 for every parameter.
    """
    try:
        inv = np.linalg.inv(sub)
    except np.linalg.LinAlgError:
        inv = np.zeros_like(sub)
        share = np.zeros(sub.shape[:2])
        for j in range(sub.shape[0]):
            try:
                inv[j] = np.linalg.inv(sub[j])
            except np.linalg.LinAlgError:
                continue
            with np.errstate(divide='ignore'):
                share[j] = 1.0 / np.diag(inv[j])
        return inv, np.where(np.isfinite(share), share, 0.0)
    with np.errstate(divide='ignore'):
        share = 1.0 / np.diagonal(inv, axis1=1, axis2=2)
    return inv, np.where(np.isfinite(share), share, 0.0)
