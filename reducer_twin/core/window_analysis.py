"""
The window analysis: health indicators of a TE stream, window by window.

:class:`WindowAnalyzer` cuts the TE stream of :mod:`.te_extraction` into
windows and reports, per window, the paper's Table 5 figures, the
manufacturing-error orders, the encoder time offset, the duty the reducer saw,
and the lost motion observed at torque reversals (physics notes section 4),
which is the observation of the wear estimator.

The features of each batch of windows are read by :class:`.window_fit.WindowFit` (the
lost-motion model, the flanks and harmonics, the friction and the checks of the effort);
this module buffers the stream, bridges and cuts it across gaps and clock resets, and
keeps the counts a joint's observability is told from (said in words by
:mod:`.observability`). The output speed of the samples it buffers is
:class:`.output_speed.OutputSpeed`'s (the velocity field, or the link angle's rate), the
torque of a drive's filtered effort :class:`.effort_lag.EffortLag`'s.
"""

import math

import numpy as np

from . import observability
from .effort_lag import EffortLag
from .errors import InvalidInput, InvalidParameter, out_of_range
from .held_effort import HeldEffort
from .kinematics import total_ratio
from .output_speed import OutputSpeed
from .stamp_clock import median_step
from .te_extraction import checked_float, cut_pieces, reset_indices, stream_slice
from .te_extraction import TIME_OFFSET_LINEAR_S
from .window_cut import cut_windows, WINDOW_MODES
from .window_fit import WindowFit


class WindowAnalyzer:
    """
    Streaming analysis of a TE stream in windows.

    Windows end as :func:`.window_cut.cut_windows` says: never across a gap
    of the stream; ``window='duration'`` every ``window_s`` of stream;
    ``'revolution'`` after each output revolution of net travel (or
    ``max_window_s``); ``'auto'`` (default) after one revolution while the
    joint turns continuously in one direction, otherwise after ``window_s``.

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
        (at least :data:`LOW_RATE_MIN_FLANK_SAMPLES`; see :func:`flank_samples`).
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
        (:meth:`.torque_smoothing.TorqueSmoothing.quiet_half`), up to
        :data:`.torque_smoothing.SMOOTHING_MAX_S`.
    sign_sigmas : float
        Samples whose smoothed torque lies within this many standard
        deviations of its noise from zero take no part in the hysteresis:
        there the noise, not the load, would pick the flank (standstill of
        an unloaded joint, torque reversals).
    friction : bool
        Identify the friction the effort carries and the reducer's output does
        not see, and take it out of the torque (see :meth:`.friction_fit.FrictionFit.fit`).
    friction_memory_windows : float
        Memory of the pooled friction identification in windows.
    effort_lag_s : float
        How late the effort is published against the encoders [s]: a drive that
        low-pass filters its torque estimate publishes the load of about one time
        constant before (a first-order filter delays slow signals by its time
        constant). The filter is undone (:class:`.effort_lag.EffortLag`); 0 (default):
        the effort is read as published.

    Raises
    ------
    InvalidParameter
        If a setting is out of range.

    """

    def __init__(self, params, window='auto', window_s=2.0, max_window_s=20.0, aging_factor=1.0,
                 orders=None, torque_bins=16, bin_range=(0.02, 1.5), min_bin_samples=20,
                 min_bins=2, memory_windows=10.0, min_speed=0.01, compliance_prior=0.3,
                 min_window_samples=1000, torque_smoothing_s=0.03, sign_sigmas=3.0,
                 friction=True, friction_memory_windows=30.0, effort_lag_s=0.0):
        if window not in WINDOW_MODES:
            raise InvalidParameter(out_of_range(
                'window', window, '', 'one of ' + ', '.join(repr(m) for m in WINDOW_MODES)))
        self.window = window
        self.window_s = _positive('window_s', window_s, 's')
        self.max_window_s = checked_float('max_window_s', max_window_s, 's',
                                          f'>= window_s = {window_s}',
                                          lambda v: v >= self.window_s)
        self.aging_factor = _non_negative('aging_factor', aging_factor, '')
        self.memory_windows = _non_negative('memory_windows', memory_windows, 'windows')
        self.min_speed = _non_negative('min_speed', min_speed, 'rad/s')
        self.compliance_prior = _positive('compliance_prior', compliance_prior, '')
        self.torque_bins = _whole('torque_bins', torque_bins, 1, 200)
        self.min_bin_samples = _whole('min_bin_samples', min_bin_samples, 3, 10 ** 9)
        self.min_bins = _whole('min_bins', min_bins, 1, 200)
        self.min_window_samples = _whole('min_window_samples', min_window_samples, 1, 10 ** 9)
        self.torque_smoothing_s = _non_negative('torque_smoothing_s', torque_smoothing_s, 's')
        self.sign_sigmas = _non_negative('sign_sigmas', sign_sigmas, '')
        self.friction = bool(friction)
        self.effort_lag_s = checked_float('effort_lag_s', effort_lag_s, 's', '0-1',
                                          lambda v: 0.0 <= v <= 1.0)
        friction_memory_windows = _positive('friction_memory_windows', friction_memory_windows,
                                            'windows')
        edges = _bin_edges(bin_range, self.torque_bins)
        g = params.geometry
        self.orders = tuple(int(k) for k in (orders or (1, 2, g.z_cycloid, g.z_pins)))
        if not self.orders or min(self.orders) < 1:
            raise InvalidParameter(out_of_range('orders', orders, '', 'whole numbers >= 1'))
        self.params = params
        self.rated_torque = params.rating.rated_torque
        self.edges = edges * self.rated_torque
        memory = math.exp(-1.0 / self.memory_windows) if self.memory_windows > 0 else 0.0
        self._speed = OutputSpeed(self.min_speed, total_ratio(g))
        self.fit = WindowFit(params, self.orders, self.edges, self.min_bins, memory,
                             self.compliance_prior, self.torque_smoothing_s, self.sign_sigmas,
                             self.friction, friction_memory_windows, self.aging_factor,
                             HeldEffort())
        self._lag = EffortLag(self.effort_lag_s, self.fit.smoothing)
        self._buf = {name: np.empty(0) for name in _BUFFER}
        self._last_t = None
        self._last_theta = None
        self._aliased = False
        self.ignored_samples = 0
        self.clock_resets = 0
        self.samples_without_effort = 0
        self.largest_effort = 0.0
        self.samples_seen = 0
        self.windows_emitted = 0
        self.windows_observed = 0
        self.windows_censored = 0       # of those, fits on the table's lower bound
        self.offset_removed = False     # set by the calibration once what is left is linear
        self.gaps = 0                   # holes longer than max_gap_s between samples
        self.gap_time_s = 0.0           # the stream time they span [s]
        self.last_observed_t = None     # end of the last window with a lost motion [s]
        self.latest_t = None            # latest stamp fed [s]
        self._segment = None            # (first stamp since the last clock reset [s], stream
        self._segment_origin_s = 0.0    # time before it [s]): stream time across resets
        self._since = observability.SinceLostMotion()
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
        resets = reset_indices(np.where(stream.valid, stream.t, np.nan), self._last_t)
        if resets:
            found = []
            for k, sl in enumerate(cut_pieces(stream.t.size, resets)):
                if k:
                    found += self._emit(final=True)
                    if self._segment is not None and self._last_t is not None:
                        self._segment_origin_s += self._last_t - self._segment
                    self._segment = None
                    self._last_t = None
                    self.clock_resets += 1
                found += self._update(stream_slice(stream, sl), effort[sl], velocity[sl])
            return found
        return self._update(stream, effort, velocity)

    def _update(self, stream, effort, velocity):
        """Feed a chunk without a clock reset."""
        fresh = stream.valid if self._last_t is None else stream.valid & (stream.t > self._last_t)
        n_fresh = int(np.count_nonzero(fresh))
        self.samples_seen += n_fresh
        if n_fresh:
            if self._segment is None:
                self._segment = float(np.min(stream.t[fresh]))
            latest = float(np.max(stream.t[fresh]))
            self.latest_t = latest if self.latest_t is None else max(self.latest_t, latest)
        if self._period_s is None and n_fresh > 16:
            self._period_s = median_step(stream.t[fresh][:4096])
        use = fresh & np.isfinite(effort)
        if self.fit.held_effort.watching:
            self.fit.held_effort.observe(stream.t[use], effort[use])
        effortless = fresh & ~use
        self.samples_without_effort += int(np.count_nonzero(effortless))
        self._since.samples(stream.t[fresh], stream.t[effortless])
        velocity, buffered = self._speed.speeds(stream, use, velocity, self._last_t,
                                                self._last_theta)
        if buffered is not None:    # the field was found not to be the link angle's rate
            self._buf['speed'] = buffered
        self.ignored_samples += int(np.count_nonzero(stream.valid & ~use))
        kept = slice(None) if use.all() else use    # all: no copy (see _aliased)
        t = stream.t[kept]
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
            self._last_theta = float(stream.output_angle[kept][-1])
            new = {'t': t, 'te': stream.te[kept], 'theta': stream.output_angle[kept],
                   'torque': effort[kept], 'speed': velocity[kept], 'dt': dt,
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

    @property
    def effort_fault(self):
        """Return why the effort is not the output torque, once found (:mod:`.effort_check`)."""
        return self.fit.effort.effort_fault

    @property
    def derived_velocity(self):
        """Return the samples given the link angle's rate as speed (:mod:`.output_speed`)."""
        return self._speed.derived

    @property
    def velocity_fault(self):
        """Return why the velocity field is not the link angle's rate, once found, else None."""
        return self._speed.check.fault

    @property
    def velocity_leads(self):
        """Say when the velocity field leads the link angle (``VelocityCheck.leads``)."""
        return self._speed.check.leads

    @property
    def soft_zone(self):
        """Say when the play is still being taken up at the test torque (:mod:`.soft_zone`)."""
        return self.fit.soft_zone.reason

    @property
    def test_torque_caveat(self):
        """Say when one window showed a soft zone, too few to say (``SoftZoneCheck.caveat``)."""
        return self.fit.soft_zone.caveat if self.windows_observed else None

    @property
    def test_torque_not_compared(self):
        """Say why no window compared the width at the test torque (``SoftZoneCheck``)."""
        # Its claim, the play given where the width there may be less, is wrong where the
        # lost motion reads below that width (:attr:`within_zone`).
        if not self.windows_observed or self.within_zone is not None:
            return None
        return self.fit.soft_zone.not_compared

    @property
    def within_zone(self):
        """Say when the lost motion read is below its bins' width at the test torque."""
        return self.fit.within_zone.reason if self.windows_observed else None

    @property
    def load_reach(self):
        """Say when the lost motion read depends on the windows' reach (:mod:`.load_reach`)."""
        # Loads within a soft zone (:attr:`within_zone`) are the more telling line.
        if not self.windows_observed or self.within_zone is not None:
            return None
        return self.fit.load_reach.reason

    @property
    def within_zone_said(self):
        """Return the within-zone check's figures where said, else None (``.said``)."""
        return self.fit.within_zone.said if self.windows_observed else None

    @property
    def test_torque_check(self):
        """Return what the width at the test torque showed (``SoftZoneCheck.outcome``), or None."""
        return self.fit.soft_zone.outcome if self.windows_observed else None

    @property
    def soft_zone_said(self):
        """Return the soft zone's pooled figures once said, else None (``SoftZoneCheck.said``)."""
        return self.fit.soft_zone.said

    @property
    def effort_held(self):
        """Say if the effort updates slower than the stream, else None (:mod:`.observability`)."""
        return observability.effort_held(self)

    @property
    def effort_correlated(self):
        """Say when the effort's noise is correlated, else None (:mod:`.observability`)."""
        return observability.effort_correlated(self)

    @property
    def te_stepped(self):
        """Say where the TE's constant stepped, else None (:mod:`.observability`)."""
        return observability.te_stepped(self)

    def _stream_s(self, t):
        """Return the stream time [s] at stamp ``t`` of the current clock (counted over resets)."""
        return self._segment_origin_s + t - self._segment

    @property
    def velocity_scale(self):
        """Return the velocity field's median ratio to the link angle's rate (NaN: no motion)."""
        return self._speed.check.scale

    @property
    def coulomb_friction(self):
        """Return the Coulomb friction last taken out of the effort [N·m]."""
        return self.fit.friction_fit.coulomb_friction

    @property
    def viscous_friction(self):
        """Return the viscous friction last taken out of the effort [N·m·s/rad]."""
        return self.fit.friction_fit.viscous_friction

    @property
    def efficiency(self):
        """Return the drive's efficiency last fitted (1: a constant Coulomb friction)."""
        return self.fit.friction_fit.efficiency

    def not_observed_reason(self, effort_source='the joint states'):
        """Say why no window has given a lost motion; None once one has (:mod:`.observability`)."""
        return observability.not_observed_reason(self, effort_source)

    @property
    def since_lost_motion(self):
        """Return the counts since the last lost motion (``observability.SinceLostMotion``)."""
        return dict(self._since.counts)

    def stale_reason(self, after_s, effort_source='the joint states'):
        """Say why an observed reducer's lost motion stopped (:mod:`.observability`)."""
        return observability.stale_reason(self, after_s, effort_source)

    def discard_buffer(self):
        """
        Drop the samples of the partial window and start the flank pool afresh.

        For a TE found wrong after it was fed: an encoder's reading held between slower
        updates is judged from the first few hundred moving samples
        (:mod:`.held_encoders`), before which the stale samples went in.
        """
        self._buf = {name: np.empty(0) for name in _BUFFER}
        self._speed.restart()
        self._lag.restart()
        self.fit.flanks.restart()

    def retime(self, delta_s):
        """
        Take ``delta_s`` added to the link encoder's stamps (the learnt time offset).

        The TE of the buffered samples and of the pooled windows was extracted
        before: both are referred to the new stamps (:meth:`.flanks.FlankPool.retime`),
        so the next windows' fits see one offset. An offset beyond
        :data:`.te_extraction.TIME_OFFSET_LINEAR_S` is not a linear term of that TE: the partial
        window is dropped, the pool starts afresh (:meth:`discard_buffer`) and the effort
        is judged afresh (a verdict on windows that carried such an offset included).

        Parameters
        ----------
        delta_s : float
            Time added to the link encoder's stamps [s].

        """
        self.fit.flanks.retime(delta_s)
        if abs(delta_s) > TIME_OFFSET_LINEAR_S:
            self.discard_buffer()
            self.fit.effort.restart()
        elif self._buf['te'].size:
            self._buf['te'] = self._buf['te'] - delta_s * self._buf['speed']

    def flush(self):
        """
        Close the current partial window.

        Returns
        -------
        list of WindowFeatures
            The partial window, if it holds samples.

        """
        return self._emit(final=True)

    def _emit(self, final):
        cuts = self._cut(final)
        if not cuts:
            if final:
                self._lag.restart()     # the stream starts over (a reset, a flush)
            if self._aliased:
                # The buffer must not alias arrays the caller may reuse.
                self._buf = {k: v.copy() for k, v in self._buf.items()}
                self._aliased = False
            return []
        out, first = [], 0
        b = self._buf
        buf = {**b, 'torque': self._lag.torque(b['t'], b['torque'], b['gap'], self._period_s)}
        # Batches of windows of about _BATCH_SAMPLES samples keep the temporaries small.
        while first < len(cuts):
            base = cuts[first][0]
            last = first + 1
            while last < len(cuts) and cuts[last][1] - base <= _BATCH_SAMPLES:
                last += 1
            end = cuts[last - 1][1]
            part = {k: v[base:end] for k, v in buf.items()}
            found = self.fit.analyze(part, [(a - base, b - base, r) for a, b, r in
                                            cuts[first:last]], self.flank_samples(),
                                     self.offset_removed, self._stream_s)
            self.windows_emitted += len(found)
            self.windows_observed += sum(math.isfinite(f.lost_motion) for f in found)
            self.windows_censored += sum(math.isfinite(f.lost_motion) and f.wear_fit <= 0.0
                                         for f in found)
            for f in found:
                if math.isfinite(f.lost_motion):
                    self.last_observed_t = f.t_end
            self._since.windows(found)
            out += found
            first = last
        end = cuts[-1][1]
        if final:
            self._lag.restart()
        else:
            self._lag.keep(b['t'], b['torque'], end, self._period_s)
        self._buf = {k: v[end:].copy() for k, v in b.items()}
        self._speed.drop(end)
        self._aliased = False
        return out

    def _cut(self, final):
        """Return ``[(start, end, reason)]`` of the windows complete in the buffer."""
        b = self._buf
        # A sample's torque may need the effort after it (:meth:`.effort_lag.EffortLag.complete`).
        known = b['t'].size if final else self._lag.complete(b['t'], self._period_s)
        return cut_windows(*(b[k][:known] for k in ('t', 'theta', 'speed', 'gap')), final,
                           self.window, self.window_s, self.max_window_s,
                           self.min_window_samples, self.min_speed)

    def flank_samples(self):
        """Return the samples a flank needs at the stream's rate (:func:`flank_samples`)."""
        return flank_samples(self.min_bin_samples, self.rate_hz)


_BUFFER = ('t', 'te', 'theta', 'torque', 'speed', 'dt', 'gap')


FLANK_RATE_HZ = 500.0
"""
Below this sample rate [Hz] a flank of the hysteresis needs the samples of the same stream
time as here (:func:`flank_samples`).

Was :data:`.observability.LOW_RATE_HZ`: a 250 Hz recording of the model's simulator (its
own, or 1 kHz thinned) kept only the bins from 200 N*m on and read the wear 14-20 % low,
with P10-P90 missing the truth on both joints; with this rule 1-2 % (README figures).
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


def flank_samples(min_bin_samples, rate_hz):
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

    Parameters
    ----------
    min_bin_samples : int
        Samples a flank needs at :data:`FLANK_RATE_HZ` and above.
    rate_hz : float
        Sample rate of the stream [Hz]; NaN while unknown.

    Returns
    -------
    int
        The number of samples (``min_bin_samples`` before the rate is known).

    """
    if not (math.isfinite(rate_hz) and rate_hz < FLANK_RATE_HZ):
        return min_bin_samples
    same_time = math.ceil(min_bin_samples * rate_hz / FLANK_RATE_HZ - 1e-9)
    return min(min_bin_samples, max(same_time, LOW_RATE_MIN_FLANK_SAMPLES))


def _whole(name, value, lo, hi):
    """Return ``value`` as an int in ``[lo, hi]``, else raise."""
    whole = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    if not whole or not lo <= value <= hi:
        raise InvalidParameter(out_of_range(name, value, '', f'a whole number in [{lo}, {hi}]'))
    return int(value)


def _positive(name, value, unit):
    """Return ``value`` as a float if finite and > 0, else raise."""
    return checked_float(name, value, unit, '> 0', lambda v: v > 0.0)


def _non_negative(name, value, unit):
    """Return ``value`` as a float if finite and >= 0, else raise."""
    return checked_float(name, value, unit, '>= 0', lambda v: v >= 0.0)


def _bin_edges(bin_range, bins):
    """
    Return the edges of ``bins`` log-spaced ``|T|`` bins, as fractions of rated torque.

    ``bin_range`` holds the lowest and highest edge; raise InvalidParameter unless
    ``0 < low < high``, both finite.
    """
    try:
        lo, hi = (float(v) for v in bin_range)
    except (TypeError, ValueError):
        raise InvalidParameter(out_of_range('bin_range', bin_range, '',
                                            '(low, high) fractions of rated torque')) from None
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise InvalidParameter(out_of_range('bin_range', bin_range, '', '0 < low < high'))
    return np.geomspace(lo, hi, bins + 1)
