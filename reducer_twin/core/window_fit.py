"""
The features of a batch of windows of a TE stream: flanks, friction, checks, lost motion.

:class:`WindowFit` reads the windows :class:`.window_analysis.WindowAnalyzer` cuts from
the stream, a batch at a time, and returns their :class:`WindowFeatures`: the paper's
Table 5 figures, the manufacturing-error orders, the encoder time offset, the duty the
reducer saw, and the lost motion observed at torque reversals (physics notes section 4),
which is the observation of the wear estimator.

Lost motion model (physics notes sections 3-4): the loaded mesh makes
``TE = -(sign(T)·beta(|T|, w) + T/k_s)``, so at equal ``|T|`` the TE under a
negative torque minus the TE under a positive torque is the hysteresis
``H(|T|, w) = 2·(beta + |T|/k_s)``, which grows with the wear ``w``. On top
the encoders see the manufacturing harmonics (functions of the output angle),
``omega·delta`` from a time offset ``delta`` between the encoders, and an
unknown constant offset. One linear least-squares fit removes the harmonics
and the time offset jointly with a straight line in ``|T|`` per torque bin
and torque sign (:mod:`.flanks`); ``H`` at each bin follows from the two lines, and the
wear that explains all bins through
:meth:`.transmission_error.ModelTables.hysteresis` gives the lost motion
(:mod:`.wear_fit`).

Two things the data cannot do are handled explicitly. A harmonic or the time
offset that the window's motion cannot separate from the torque dependence
(at constant speed ``omega`` is a constant; under gravity ``cos(theta)``
follows ``T``) is reported as NaN and left to the bin lines. What such a 1x
harmonic leaves in ``H`` is odd in torque and grows with ``|T|``, like a
stiffness error, so the wear fit carries a compliance correction with a prior
and reads the wear from the level of ``H``, not its slope.

The effort is first cleared of the drive's friction and efficiency
(:mod:`.friction_fit`) and checked to be the output torque (:mod:`.effort_check`).
"""

from dataclasses import dataclass, field
import math

import numpy as np

from .duty_summary import duty_summaries, DutySummary
from .effort_check import EffortCheck, PLAUSIBLE_LOST_MOTION_RAD
from .flanks import FlankPool
from .friction_fit import FrictionFit
from .load_reach import LoadReachCheck
from .soft_zone import NEAR_FLANK_SAMPLES, SoftZoneCheck
from .te_extraction import TIME_OFFSET_LINEAR_S
from .torque_smoothing import nominal_step, TorqueSmoothing
from .transmission_error import model_tables
from .wear_fit import LostMotionFit
from .within_zone import WithinZoneCheck

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


STILL_SPAN_RAD = 2e-5
"""
Travel of the output angle [rad] (4 arcsec) below which a window stood still: no lost motion.

Play is taken up by motion: a load that changes sign moves the joint by its lost motion
(0.4-3 arcmin), a window that never moves shows none. A joint standing still under a
held load with a drive's noise gives one flank at one torque and a frozen TE, which the
pooled flanks completed into a lost motion: measured (the model's simulator, a used unit
at 2.27 arcmin, 40 s held at 47 N·m), its 16 windows read a lost motion creeping 2.38 ->
2.56 arcmin, and the pool they joined read the next 35 windows 5-8 % high. Its samples
enter neither the window's flanks nor the pool.
"""


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
    soft_zone_shortfall : float
        How much narrower the hysteresis is at the test torque than the flanks of higher
        loads give, pooled over the stream's recent comparisons up to this window
        (:data:`.soft_zone.SHORTFALL_MEMORY`), where the soft zone is said
        (:attr:`.soft_zone.SoftZoneCheck.said`), else 0 [rad]. ``lost_motion`` is the
        play those flanks give; the catalogue's lost motion is this much less.
    soft_zone_width : float
        The width at the test torque the same comparison gives (the play those flanks
        give less the shortfall, pooled alike), where the soft zone is said, else 0
        [rad]: a play the estimate follows below that of those flanks is taken down to
        it, not below (:meth:`.pipeline.EstimatorStage.step`).

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
    soft_zone_shortfall: float = 0.0
    soft_zone_width: float = 0.0


PLAUSIBLE_TE_SPAN_RAD = math.radians(10.0)
"""
Largest transmission-error span [rad] within one window that encoders on one reducer give.

A reducer's TE moves by arcminutes (windup, hysteresis, harmonics; an encoder time offset
adds its speed times the delay, about 2 degrees at 3 rad/s and 10 ms). Beyond 10 degrees the
two encoders do not measure the same motion: a motor encoder that counts against the link,
a frozen encoder, or a wrong ratio. Such a window gives no lost motion.
"""


class WindowFit:
    """
    Read the features of batches of windows of one joint's stream.

    Holds what carries over from one batch to the next: the flank pool and the
    harmonics' fit (:class:`.flanks.FlankPool`), the friction identified in the effort
    (:class:`.friction_fit.FrictionFit`), the effort's check
    (:class:`.effort_check.EffortCheck`), the torque smoothing
    (:class:`.torque_smoothing.TorqueSmoothing`), the soft-zone check
    (:class:`.soft_zone.SoftZoneCheck`), the lost motion read against its bins' width at
    the test torque (:class:`.within_zone.WithinZoneCheck`) and the lost-motion fit
    (:class:`.wear_fit.LostMotionFit`); and the counts of windows that read no lost
    motion, by reason, with the largest figures behind them (:mod:`.observability`
    words them).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (the model's tables are those of ``params``).
    orders : tuple of int
        Harmonic orders per output revolution.
    edges : ndarray
        Edges of the log-spaced ``|T|`` bins [N·m].
    min_bins : int
        Usable bins needed for a lost-motion value.
    memory : float
        Factor by which the flank pool fades per window (0: this window only).
    compliance_prior : float
        Prior standard deviation of the wear fit's compliance correction, as a
        fraction of the series compliance.
    torque_smoothing_s, sign_sigmas : float
        The effort's average [s] and the half-width of its noise band [standard
        deviations] (:class:`.torque_smoothing.TorqueSmoothing`).
    friction : bool
        Identify the friction the effort carries and take it out.
    friction_memory_windows : float
        Memory of the pooled friction identification in windows.
    aging_factor : float
        Seconds of wear exposure per second of stream.
    held_effort : HeldEffort
        The stream's judge of an effort held between slower updates (its samples per
        update size the effort's noise estimate).

    """

    def __init__(self, params, orders, edges, min_bins, memory, compliance_prior,
                 torque_smoothing_s, sign_sigmas, friction, friction_memory_windows,
                 aging_factor, held_effort):
        self.params = params
        self.tables = tables = model_tables(params)   # cached per parameter set
        self.orders = orders
        self.min_bins = min_bins
        self.friction = friction
        self.aging_factor = aging_factor
        self.rated_torque = params.rating.rated_torque
        self.takeup_torque = params.rating.lost_motion_torque_fraction * self.rated_torque
        self.flanks = FlankPool(orders, edges, self.rated_torque, min_bins, memory)
        self.friction_fit = FrictionFit(self.rated_torque, friction_memory_windows)
        self.effort = EffortCheck(tables, self.takeup_torque)
        self.held_effort = held_effort
        self.smoothing = TorqueSmoothing(torque_smoothing_s, sign_sigmas, self.takeup_torque,
                                         self.rated_torque)
        self.lost_motion_fit = LostMotionFit(tables, self.flanks.centres, self.takeup_torque,
                                             compliance_prior, min_bins)
        self.soft_zone = SoftZoneCheck(self.takeup_torque, tables.series_stiffness)
        self.within_zone = WithinZoneCheck(self.takeup_torque, tables.series_stiffness)
        self.load_reach = LoadReachCheck()
        self.windows_friction_unknown = 0
        self.windows_offset_unremoved = 0   # withheld: a time offset not yet removed
        self.largest_unremoved_offset_s = 0.0
        self.windows_implausible = 0
        self.windows_still = 0          # the joint stood still: no lost motion (STILL_SPAN_RAD)
        self.largest_te_span = 0.0
        self.windows_reversed = 0       # with bins enough for a lost motion
        self.largest_reversed_te_span = 0.0  # of those [rad]
        self.te_step = None             # (stream time [s], step [rad]) of the first step
        self.te_steps = 0               # steps of the TE's constant
        self.windows_effort_fault = 0

    def analyze(self, buf, cuts, flank_samples, offset_removed, stream_s):
        """
        Compute the features of the windows ``cuts`` of ``buf`` (vectorised over windows).

        Parameters
        ----------
        buf : dict of ndarray
            The buffered samples: stamps ``t`` [s], ``te`` [rad], output angle ``theta``
            [rad], ``torque`` [N·m], ``speed`` [rad/s], ``dt`` [s] and ``gap``.
        cuts : list of tuple
            ``(start, end, end_reason)`` of each window in ``buf``.
        flank_samples : int
            Samples a flank needs (:meth:`.window_analysis.WindowAnalyzer.flank_samples`).
        offset_removed : bool
            Whether the encoders' time offset is removed down to a linear term
            (:class:`.pipeline.TimeOffsetCalibration`); before, a window that fits one
            beyond :data:`.te_extraction.TIME_OFFSET_LINEAR_S` reads no lost motion.
        stream_s : callable
            Stream time [s] of a stamp [s] (across clock resets).

        Returns
        -------
        list of WindowFeatures
            One per window, in order.

        """
        starts = np.array([c[0] for c in cuts])
        ends = np.array([c[1] for c in cuts])
        n_win = starts.size
        t, y, torque, speed, dt = (buf[k] for k in ('t', 'te', 'torque', 'speed', 'dt'))
        win = np.repeat(np.arange(n_win), ends - starts)
        drag = model = taken = unknown = None
        period = nominal_step(t)
        smoothing = self.smoothing
        half = smoothing.half_width(period)
        harmonics = self.flanks.harmonics(buf['theta'])
        if self.friction:
            torque, drag, model, taken, unknown = self.friction_fit.fit(
                torque, t, harmonics, speed, win, starts, ends, half)
        torque, band = smoothing.smooth(torque, half, t, period, model, win, starts, ends,
                                        self.held_effort.hold_samples)
        if model is not None:
            torque, band = smoothing.toward_model(torque, band, model, win, starts)
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
        z = self.flanks.regressors(harmonics, speed, y - te_mean[win])
        x = z[:-1]
        bins = self.flanks.bins(z, torque)
        theta = buf['theta']
        still = (np.maximum.reduceat(theta, starts) - np.minimum.reduceat(theta, starts)
                 < STILL_SPAN_RAD)
        if still.any():
            self.windows_still += int(still.sum())
            ambiguous = ambiguous | still[win]
        stats = self.flanks.group_stats(z, torque, bins, win, starts, ends, ambiguous,
                                        normal=False)
        # The harmonics and the time offset come from samples whose load surely takes most
        # of the play up (:data:`_HARMONIC_FIT_TORQUE`).
        taken_up = (low > _HARMONIC_FIT_TORQUE * self.takeup_torque) & ~still[win]
        fit_stats = self.flanks.group_stats(z, torque, bins, win, starts, ends, ~taken_up)
        exposure = np.add.reduceat(dt, starts) * self.aging_factor
        speed_mean = np.add.reduceat(speed, starts) / (ends - starts)
        # The TE lags the load: a window's mean moves with its mean load, not a new constant.
        windup_mean = (-np.add.reduceat(torque, starts) / (ends - starts)
                       / self.tables.series_stiffness)
        beta, ident, noise, pooled = self.flanks.fit_harmonics(
            fit_stats, n_win, te_mean, exposure, taken, speed_mean, windup_mean)
        if self.flanks.steps:
            if self.te_step is None:
                k, step = self.flanks.steps[0]
                self.te_step = (stream_s(float(t[starts[k]])), step)
            self.te_steps += len(self.flanks.steps)
        torque_h, width, std, usable, odd, fewest = self.flanks.hysteresis(
            stats, beta, noise, pooled, flank_samples)
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
        # A time offset beyond a linear term of the TE, not yet removed (learnt from the
        # first windows, :class:`.pipeline.TimeOffsetCalibration`): no lost motion is read.
        # Once removed, what is left is within it: a window's fit beyond it is then its
        # noise (at 100 Hz 1 ms is a tenth of the sample period).
        offset = np.where(ident[:, -1], beta[:, -1], np.nan)
        unremoved = (np.abs(offset) > TIME_OFFSET_LINEAR_S) & (not offset_removed)
        if unremoved.any():
            self.windows_offset_unremoved += int(
                (unremoved & (usable.sum(axis=1) >= self.min_bins)).sum())
            self.largest_unremoved_offset_s = max(self.largest_unremoved_offset_s,
                                                  float(np.max(np.abs(offset[unremoved]))))
            usable &= ~unremoved[:, None]
        te_max = np.maximum.reduceat(y, starts)
        te_min = np.minimum.reduceat(y, starts)
        implausible = (te_max - te_min) > PLAUSIBLE_TE_SPAN_RAD
        usable &= ~(implausible | still)[:, None]
        # Windows with bins enough for a lost motion crossed a torque reversal under load:
        # their TE spans at least the play (:data:`.observability.DERIVED_LINK_SPAN_RAD`).
        reversed_ = usable.sum(axis=1) >= self.min_bins
        if reversed_.any():
            self.windows_reversed += int(reversed_.sum())
            self.largest_reversed_te_span = max(self.largest_reversed_te_span,
                                                float(np.max((te_max - te_min)[reversed_])))
        # From the window where the effort is found not to be the torque, none is read.
        faulty = self.effort.check(torque_h, width, std, usable,
                                   odd * ~self.flanks.first_order(ident)[:, None, :])
        usable &= ~faulty[:, None]
        self.windows_effort_fault += int(faulty.sum())
        # Bins of a few samples a flank, in windows from which a lost motion may be read.
        unread = unremoved | implausible | still | faulty
        if unknown is not None:
            unread = unread | unknown
        thin = (fewest >= NEAR_FLANK_SAMPLES) & ~unread[:, None] & np.isfinite(width) \
            & np.isfinite(std)
        self.soft_zone.observe(torque_h, width, std, usable, thin)
        fit = self.lost_motion_fit.fit(torque_h, width, std, usable)
        # A lost motion no reducer has is an encoder or configuration fault.
        beyond = fit[2] > PLAUSIBLE_LOST_MOTION_RAD
        for k in (0, 1, 2, 3, 4):
            fit[k][beyond] = np.nan
        implausible |= beyond
        if implausible.any():
            self.windows_implausible += int(implausible.sum())
            self.largest_te_span = max(self.largest_te_span,
                                       float(np.max((te_max - te_min)[implausible])))
        # Nor a time offset: fitted to a TE no reducer has, it says nothing of the clocks
        # (encoders in other units read as stamped 0.1-1 s apart, and it was learnt).
        offset[implausible] = np.nan
        self.within_zone.observe(torque_h, width, std, usable, fit[2])
        self.load_reach.observe(np.where(usable, torque_h, 0.0).max(axis=1, initial=0.0),
                                fit[2], fit[3], t[ends - 1])
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
        duty = duty_summaries(torque, speed, dt, starts, self.params, self.aging_factor)
        n_ord = len(self.orders)
        amp = np.hypot(beta[:, 0:2 * n_ord:2], beta[:, 1:2 * n_ord:2])
        amp = np.where(ident[:, 0:2 * n_ord:2] & ident[:, 1:2 * n_ord:2], amp, np.nan)
        # The lost motion at the test torque: the play less a soft zone's shortfall, or the
        # flanks' reading plus the gap to the width of loads within one (negative).
        shortfall, zone_width = 0.0, 0.0
        soft, within = self.soft_zone.said, self.within_zone.said
        if soft is not None:
            shortfall, zone_width = float(soft['shortfall']), float(soft['width'])
        elif within is not None:
            shortfall, zone_width = -float(within['gap']), float(within['width'])
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
                duty=duty[k], implausible=bool(implausible[k]),
                soft_zone_shortfall=shortfall, soft_zone_width=zone_width))
        return out
