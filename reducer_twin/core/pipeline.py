"""
The twin's processing stages, shared by the live nodes and the bag analysis.

* :class:`EstimatorStage` steps the Kalman filter with each window's
  features and persists its state (the ``wear_estimator`` node);
* :class:`LifeStage` turns an estimate into remaining life and a health
  level (the ``life_publisher`` node).

Stages exchange plain records keyed like the topic layouts of
:mod:`reducer_twin.msg_adapters.layouts` (unit-suffixed names, SI), so a live recording
and an offline analysis carry the same values.
"""

from dataclasses import dataclass, replace
import math
from types import SimpleNamespace

import numpy as np

from .errors import InvalidInput, InvalidParameter, out_of_range
from .estimator import lognormal_sd
from .life import catalogue_life, DEFAULT_HORIZON_S, GrowthTrendState, LifeDraws
from .life import LifeQuery, LOST_MOTION_LIMIT, remaining_lives
from .life_basis import curve_note, growth_note, life_trend_probability, play_limit
from .life_basis import rate_note, rate_resolved
from .params import _Validated, spec
from .service_time import service_note
from .soft_zone import carried_line
from .te_extraction import TIME_OFFSET_LINEAR_S
from .units import HOUR

DUTY_FIELDS = ('duration_s', 'exposure_s', 'archard_increment', 'mean_abs_torque',
               'mean_abs_speed', 'cubic_mean_torque', 'mean_speed', 'max_abs_torque')
"""Attributes of a window's duty summary."""

_DUTY_KEYS = {
    'duration_s': 'duration_s', 'exposure_s': 'exposure_s',
    'archard_increment': 'archard_increment_m', 'mean_abs_torque': 'mean_abs_torque_nm',
    'mean_abs_speed': 'mean_abs_speed_rad_s', 'cubic_mean_torque': 'cubic_mean_torque_nm',
    'mean_speed': 'mean_speed_rad_s', 'max_abs_torque': 'max_abs_torque_nm'}

CLOCK_RESET_S = 60.0
"""A window ending this far before the last one means the clock was reset, not a replay."""

SOFT_ZONE_KEY = 'soft_zone_shortfall_rad'
"""
The key of the soft zone's shortfall [rad] in a reducer's state and in the estimator's state
file (written only while the lost motion is given less one, so a file without a soft zone is
the estimator's state alone).
"""


def features_from_record(record):
    """
    Rebuild a window-features object from a ``te_features`` record.

    Parameters
    ----------
    record : mapping
        Field name to value, as in the ``te_features`` layout.

    Returns
    -------
    types.SimpleNamespace
        With ``t_start``, ``t_end``, ``lost_motion``, ``lost_motion_std``,
        ``wear_fit``, ``wear_fit_std``, ``duty`` (a namespace with the
        duty fields), ``soft_zone_shortfall`` and ``soft_zone_width``, what the estimator
        stage reads.

    """
    duty = SimpleNamespace(**{k: float(record[v]) for k, v in _DUTY_KEYS.items()})
    return SimpleNamespace(
        t_start=float(record['window_start_s']), t_end=float(record['window_end_s']),
        lost_motion=float(record['lost_motion_rad']),
        lost_motion_std=float(record['lost_motion_std_rad']),
        wear_fit=float(record['wear_fit_m']), wear_fit_std=float(record['wear_fit_std_m']),
        duty=duty, soft_zone_shortfall=float(record.get('soft_zone_shortfall_rad', 0.0)),
        soft_zone_width=float(record.get('soft_zone_width_rad', 0.0)))


def duty_to_record(duty):
    """
    Return the duty fields of a ``te_features`` record.

    Parameters
    ----------
    duty : object
        Duty summary with the attributes of :data:`DUTY_FIELDS`.

    Returns
    -------
    dict
        Layout field name to value.

    """
    # The mean output speed Nm of the catalogue formula is the mean of |speed|.
    return {v: float(getattr(duty, k, None) if hasattr(duty, k) else duty.mean_abs_speed)
            for k, v in _DUTY_KEYS.items()}


TIME_OFFSET_TRACK_S = 0.5e-3
"""
Median of the next windows' time offsets [s] from which a learnt offset is corrected again.

Half the linear term (:data:`.te_extraction.TIME_OFFSET_LINEAR_S`): a clock drifting by
50 ppm moves 0.5 ms in the ten seconds of five 2-s windows, so its corrections stay within
the linear map. Measured on the independent generator: 20 ppm every joint within 2.5 %,
100 ppm within 3.7 %, 50 ppm one base +30 % (README, two clocks that drift apart).
"""


TIME_OFFSET_SAID_S = 3e-3
"""
Time offset between the encoders [s] from which it is said (:attr:`TimeOffsetCalibration.reason`).

The calibration removes an offset once learnt; windows whose fit finds one beyond
:data:`.te_extraction.TIME_OFFSET_LINEAR_S` before that give no lost motion, and those the fit
cannot tell it in still read one with it. Measured with the motor's stamps shifted (link
and motor on two topics, 1 kHz): on the independent generator (two truths, three joints
each) every joint reads within 0.7 % at -20 to 50 ms, one base -2.3 % at 2 ms; on the
model's simulator an unloaded and a gravity-loaded joint within 0.6 % at 5-20 ms (before the
window-withholding and the refinement: a base refused at 50 ms, an unloaded joint +41 % at
10 ms and refused at 20 ms). An offset of 0.05 ms (an encoder's latency) reads within
0.3 %. At 1 ms, a base of the third generator at 100 Hz was said to be stamped apart where
its truth has no offset (a tenth of its sample period, read by a window fit of another
physics): 3 ms is above that.
"""


class TimeOffsetCalibration:
    """
    Learn the link encoder's time offset from the first windows, apply it and follow it.

    A time offset ``delta`` between the encoders adds ``omega·delta`` to the
    TE (16 arcsec at 90 deg/s for 50 µs). The window analysis fits it; for an
    encoder's latency it is a hardware constant, so the median of the first
    ``windows`` finite estimates is added to the extractor's ``link_time_offset_s``.
    Feeding back every window would over-correct: the window fit pools recent
    windows, part of them still uncompensated; the next ``windows`` estimates are
    taken after each change.

    An offset beyond :data:`.te_extraction.TIME_OFFSET_LINEAR_S` (milliseconds: two clocks,
    a topic stamped a control cycle late) is read less exactly by windows whose TE
    carries it, the term being linear only in the encoders' common motion: the first
    median can miss by more than that (a shoulder of the independent generator at
    20 ms: 18.8 ms learnt, its later windows then withheld for the 1.2 ms left). Two
    clocks that are not synchronised drift apart besides (a crystal's 20-100 ppm:
    3-15 ms over 150 s; the independent generator's base read +30 % at 50 ppm and was
    refused at 100 ppm with the offset learnt once). So the median of every next
    ``windows`` estimates is added in turn where it exceeds :data:`TIME_OFFSET_TRACK_S`
    and they agree (their spread within the median's size: a third-generator shoulder's
    windows found -0.1, 0, 2.2, 1.6, 1.6 ms through a change of its load, where its
    offset is -0.6 ms); the calibration is :attr:`settled` while what is left lies
    within the linear term.

    Parameters
    ----------
    extractor : TEExtractor
        The TE extractor whose ``link_time_offset_s`` is set.
    windows : int
        Estimates to collect before applying.

    Attributes
    ----------
    applied : float or None
        The offset added to the extractor so far [s] (None until learnt).
    delta : float or None
        What the latest application added [s] (the window analysis refers its TE by it).
    drift : float or None
        How fast the offset drifts [s per s] (:meth:`_drift`), None while it does not.
    settled : bool
        What is left of the offset lies within the linear term (until a later median
        says otherwise, or :meth:`restart`).

    """

    def __init__(self, extractor, windows=5):
        self.extractor = extractor
        self.windows = windows
        self.estimates = []
        self.applied = None
        self.delta = None
        self.settled = False
        self.drift = None
        self._times = []        # the estimates' window ends [s]
        self._changes = []      # (mid-stamp of its windows [s], offset after it [s])
        self.carried = False    # the offset came from the reducer's last stream

    def carry(self, offset_s):
        """
        Start from the offset the reducer's last stream ended with [s].

        Applied at once, not yet :attr:`settled`: windows whose fit still finds more than
        the linear term give no lost motion until the next windows' median confirms it
        (within :data:`TIME_OFFSET_TRACK_S`) or corrects it, as after a first median.
        Recordings of short bags (a fleet's snippets of 10-30 s) then keep their windows
        where each would otherwise spend its first five learning the offset again.
        """
        self.extractor.link_time_offset_s += offset_s
        self.applied = float(offset_s)
        self.carried = True

    def observe(self, features):
        """
        Take one window's ``time_offset_s`` into account.

        Parameters
        ----------
        features : WindowFeatures
            A completed window.

        Returns
        -------
        bool
            True when this call changed the extractor's offset (by :attr:`delta`).

        """
        if not np.isfinite(features.time_offset_s):
            return False
        self.estimates.append(float(features.time_offset_s))
        self._times.append(float(features.t_end))
        if len(self.estimates) < self.windows:
            return False
        median = float(np.median(self.estimates))
        spread = float(np.ptp(self.estimates))
        middle = float(np.mean(self._times))
        self.estimates, self._times = [], []
        if self.applied is not None and abs(median) <= TIME_OFFSET_TRACK_S:
            self.settled = True
            return False
        if self.applied is not None and spread > abs(median):
            return False    # windows that disagree (a transient of the load): no evidence
        self.applied = median if self.applied is None else self.applied + median
        self.settled = abs(median) <= TIME_OFFSET_LINEAR_S
        self.delta = median
        self._changes.append((middle, self.applied))
        self.drift = self._drift()
        self.extractor.link_time_offset_s += median
        return True

    @property
    def corrections(self):
        """Return how many times the windows changed the offset (following a drift is not one)."""
        return len(self._changes)

    def follow(self, t_s):
        """
        Move the offset along its :attr:`drift` to stream stamp ``t_s`` [s]; return the change.

        Between the windows' corrections the offset follows the drift last measured, so
        that what the windows find stays within the linear term.
        """
        if self.drift is None or not np.isfinite(t_s):
            return 0.0
        t0, a0 = self._changes[-1]
        delta = a0 + self.drift * max(t_s - t0, 0.0) - self.applied
        self.applied += delta
        self.extractor.link_time_offset_s += delta
        return delta

    def _drift(self):
        """
        Return how fast the offset drifts [s per s], or None while it does not.

        Measured from the corrections after the first: at least two, all the same way,
        each at the middle of its windows. A large offset's convergence (18.8 ms, then
        1.2 ms more) is two corrections: a third the same way would be taken for a drift,
        and followed until the windows find the other sign.
        """
        if len(self._changes) < 3:
            return None
        (t0, a0), (t1, a1) = self._changes[0], self._changes[-1]
        steps = np.diff([a for _, a in self._changes])
        if t1 <= t0 or not (np.all(steps > 0.0) or np.all(steps < 0.0)):
            return None
        return (a1 - a0) / (t1 - t0)

    @property
    def reason(self):
        """
        Say when the encoders' stamps lie :data:`TIME_OFFSET_SAID_S` or more apart, else None.

        The offset applied, or before that the largest of the windows' estimates; and
        how fast it drifts where later windows kept finding more (:attr:`drift`).
        """
        offsets = [self.applied] if self.applied is not None else self.estimates
        offset = max(offsets, key=abs, default=0.0)
        drift = self.drift
        if abs(offset) < TIME_OFFSET_SAID_S and drift is None:
            return None
        if drift is not None:
            return (f'the link and motor encoders are stamped {1e3 * abs(offset):.1f} ms '
                    f'apart and drift by {6e4 * abs(drift):.2g} ms a minute '
                    f'({1e6 * abs(drift):.0f} ppm: two clocks that are not synchronised): '
                    'followed from the windows and removed as it goes; windows whose '
                    'transmission error still carries more than '
                    f'{1e3 * TIME_OFFSET_LINEAR_S:g} ms of it give no lost motion: '
                    'synchronise the clocks or stamp both encoders on one')
        how = ('read by the first windows, not yet removed' if self.applied is None else
               "carried over from the reducer's last recording, checked by its windows"
               if self.carried and not self._changes else
               'learnt from the first windows and removed from then on')
        return (f'the link and motor encoders are stamped {1e3 * abs(offset):.1f} ms apart '
                '(two clocks, or one topic stamped on arrival or a control cycle late): '
                f'{how}; windows whose transmission error still carries it give no lost '
                'motion where their fit finds it: stamp both encoders on one clock')

    def restart(self):
        """Learn again from the next windows, undoing an offset learnt from a TE found wrong."""
        if self.applied is not None:
            self.extractor.link_time_offset_s -= self.applied
        self.applied = self.delta = None
        self.settled = False
        self.carried = False
        self.drift = None
        self._changes = []
        self.estimates, self._times = [], []

    @property
    def to_carry(self):
        """
        Return the offset a reducer's next stream may start from [s], or None.

        The offset applied, where it does not drift (two clocks that drift apart are
        somewhere else by the next recording). Confirmed or not: the next stream's windows
        check it before they give a lost motion (:meth:`carry`).
        """
        if self.applied is None or self.drift is not None:
            return None
        return float(self.applied)


def features_record(f, params):
    """
    Flatten window features into a ``te_features`` record.

    Shared by the ``te_monitor`` node and the bag analysis, so a live recording and an
    offline analysis carry the same values.

    Parameters
    ----------
    f : WindowFeatures
        Output of the window analysis.
    params : ReducerParams
        Reducer parameters (for the order numbers).

    Returns
    -------
    dict
        Layout field name to value (SI).

    """
    g = params.geometry
    orders = f.orders
    rec = {
        'window_start_s': f.t_start, 'window_end_s': f.t_end, 'samples': f.samples,
        'te_max_rad': f.te_max, 'te_min_rad': f.te_min, 'te_pp_rad': f.te_pp,
        'te_mean_rad': f.te_mean, 'loaded_mean_te_rad': f.loaded_mean_te,
        'lost_motion_rad': f.lost_motion, 'lost_motion_std_rad': f.lost_motion_std,
        'wear_fit_m': f.wear_fit, 'wear_fit_std_m': f.wear_fit_std,
        'order1_rad': orders.get(1, np.nan), 'order2_rad': orders.get(2, np.nan),
        'order_zc_rad': orders.get(g.z_cycloid, np.nan),
        'order_zp_rad': orders.get(g.z_pins, np.nan), 'time_offset_s': f.time_offset_s,
        'soft_zone_shortfall_rad': f.soft_zone_shortfall,
        'soft_zone_width_rad': f.soft_zone_width}
    rec.update(duty_to_record(f.duty))
    return rec


class EstimatorStage:
    """
    Kalman wear estimation with persistence, one reducer.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    config : EstimatorConfig, optional
        Filter tuning.
    store : object, optional
        Where the state persists (e.g. :class:`reducer_twin.io.state_file.StateFile`):
        ``restore(params, config)`` returns a loaded state (``estimator``,
        ``path``, ``used_backup``, ``primary_error``, ``soft_zone_shortfall``) or None
        for a new reducer, ``save(state_dict)`` persists a state, ``flush()`` waits for
        queued saves and ``path`` names it. None keeps the state in memory.
    log : callable, optional
        Called with one line of text for notable events (restore, reset).

    Raises
    ------
    StateFileError
        If the store holds a state but neither it nor its backup can be used.

    """

    def __init__(self, params, config=None, store=None, log=None):
        from .estimator import WearEstimator
        self.params = params
        self.store = store
        self.log = log or (lambda text: None)
        self.last_observation = float('nan')
        self.soft_zone_shortfall = 0.0
        self._soft_zone_said = False     # a window of this stream carried one
        self.skipped_replays = 0
        self.restored_from = None
        self.service_said = None
        loaded = store.restore(params, config) if store is not None else None
        if loaded is not None:
            self.estimator = loaded.estimator
            self.restored_from = str(loaded.path)
            note = f' (primary unusable: {loaded.primary_error})' if loaded.used_backup else ''
            self.log(f'restored estimator state from {loaded.path}{note}: wear '
                     f'{self.estimator.wear * 1e6:.3f} um after '
                     f'{self.estimator.exposure_s / HOUR:.1f} h')
            # Carried as from an earlier bag: it stays until this stream's check says one.
            self.soft_zone_shortfall = float(getattr(loaded, 'soft_zone_shortfall', 0.0))
            if self.soft_zone_shortfall != 0.0:
                self.log(carried_line(self.soft_zone_shortfall))
        else:
            self.estimator = WearEstimator(params, config)
            if store is not None:
                self.log(f'no estimator state at {store.path}: starting from a new reducer')

    @property
    def state_path(self):
        """Return the path of the state (None without a store)."""
        return None if self.store is None else self.store.path

    def process(self, features):
        """
        Step the filter with one window and persist the state.

        A window that ends at or before the last one stepped is a replay
        (e.g. a restarted node received it again) and is skipped, unless it
        lies more than :data:`CLOCK_RESET_S` back (the clock was reset).

        Parameters
        ----------
        features : object
            Window features (see :func:`features_from_record`).

        Returns
        -------
        str
            Update status: ``accepted``, ``rejected``, ``recovered``,
            ``skipped`` or ``replay``.

        """
        last = self.estimator.t_end
        if last is not None and last - CLOCK_RESET_S < features.t_end <= last:
            self.skipped_replays += 1
            return 'replay'
        result = self.step(features)
        self.save()
        return result.status

    def step(self, features):
        """
        Step the filter with one window: :meth:`process` without its replay check or save.

        Returns the estimator's update result (``status``, ``nis``, ...); the stage's last
        observation and soft-zone shortfall follow the window, as in :meth:`process`:
        the shortfall the window carries, but no more than takes the play the estimator
        follows down to the window's ``soft_zone_width`` (:func:`taken_off`); a negative one
        (loads within a soft zone, :mod:`.within_zone`) adds no more than takes it up to
        that width.
        """
        said = self.estimator.service_verdict
        result = self.estimator.step(features)
        self.last_observation = float(features.lost_motion)
        shortfall = float(getattr(features, 'soft_zone_shortfall', 0.0))
        taken = 0.0 if not (math.isfinite(shortfall) and shortfall != 0.0) else taken_off(
            shortfall, float(getattr(features, 'soft_zone_width', 0.0)),
            lambda: self.estimator.lost_motion(self.estimator.growth_trend())[0])
        added_before = shortfall < 0.0 and self.soft_zone_shortfall < 0.0
        if shortfall > 0.0 or taken < 0.0 or added_before:
            # A soft zone, or loads within one that give the lost motion more than the play
            # followed (the play already that wide: nothing added, a soft zone carried over
            # from the reducer's last stream stays).
            self.soft_zone_shortfall = taken
            self._soft_zone_said = True
        elif self._soft_zone_said:
            # This stream's check said it and no longer does: its evidence is followed.
            self.soft_zone_shortfall = 0.0
        # Otherwise a soft zone carried over from the reducer's last stream stays until
        # this stream's own check says one (the next bag of a fleet, BagResult.states).
        if said is None and self.estimator.service_verdict is not None:
            self.service_said = service_note(self.estimator.service_verdict,
                                             self.estimator.config.service_time_s)
            self.log(self.service_said)
        return result

    def continue_from(self, state, config=None):
        """
        Continue from a reducer's state (:func:`reducer_state`: an earlier bag, the store).

        The estimator, its last observation and the soft zone carried over; the duty is the
        life stage's. Raises :class:`~.errors.StateFileError` for an unusable estimator.
        """
        from .estimator import WearEstimator
        self.estimator = WearEstimator.from_state(self.params, state['estimator'], config)
        obs = state.get('lost_motion_obs_rad')
        self.last_observation = float('nan') if obs is None else float(obs)
        self.soft_zone_shortfall = float(state.get(SOFT_ZONE_KEY, 0.0))

    def save(self):
        """
        Hand the state to the store (at once, or queued by a background store).

        The estimator's state, with the soft zone's shortfall (:data:`SOFT_ZONE_KEY`)
        while the lost motion is given less one: a restarted stage continues with it.
        """
        if self.store is not None:
            state = self.estimator.state_dict()
            if self.soft_zone_shortfall != 0.0:
                state[SOFT_ZONE_KEY] = float(self.soft_zone_shortfall)
            self.store.save(state)

    def flush(self):
        """Wait until the store has written the queued states (a no-op without a store)."""
        if self.store is not None:
            self.store.flush()

    def reset(self, reason):
        """
        Record a maintenance event (reducer replaced) and restart the filter.

        Parameters
        ----------
        reason : str
            Why, for the event log in the state.

        """
        self.estimator.reset(reason)
        self.soft_zone_shortfall = 0.0
        self._soft_zone_said = False
        self.save()
        self.flush()
        self.log(f'estimator reset: {reason}')

    def record(self, stamp_s):
        """
        Return the current estimate as a ``wear`` record.

        The variance of ``ln s`` the remaining life extrapolates with is the estimator's
        times its forecast scale (:attr:`.estimator.WearEstimator.forecast_scale`: how
        far both models' predictions eight windows ahead fell short of what they
        claimed), its correlations kept; the wear, the lost motion and the growth law
        are the estimator's (the law's samples are not widened: how far its exponent
        should be is not measured). The lost motion is given at the test torque: the play
        the estimator follows less the ``soft_zone_shortfall`` of the latest window (0
        unless a soft zone reaching beyond the test torque is said, :mod:`.soft_zone`; one
        carried over from the reducer's last stream stays until this stream's windows say
        one, cleared by :meth:`reset`), which the record carries; the remaining life meets
        the limit where the play reaches the limit plus it (:func:`.life_basis.play_limit`).

        Parameters
        ----------
        stamp_s : float
            Stamp of the record [s].

        Returns
        -------
        dict
            Layout field name to value (SI).

        """
        est = self.estimator
        x, P = est.x, est.P
        trend = est.growth_trend()
        lm, lm_std = est.lost_motion(trend)
        widen = math.sqrt(est.forecast_scale)     # P is a copy: the filter's stays
        P[1, :] *= widen
        P[:, 1] *= widen
        rec = {
            'stamp_s': stamp_s, 'wear_m': est.wear, 'wear_std_m': est.wear_std,
            'rate_scale': est.rate_scale, 'rate_scale_std': lognormal_sd(x[1], P[1, 1]),
            'duty_rate_m_per_s': est.duty_rate, 'lost_motion_rad': lm - self.soft_zone_shortfall,
            'lost_motion_obs_rad': self.last_observation,
            'exposure_s': est.exposure_s, 'updates': est.updates, 'rejected': est.rejected,
            'baseline_m': float(x[2]), 'log_rate_scale': float(x[1]),
            'lost_motion_std_rad': lm_std, 'lost_motion_new_rad': est.lost_motion_new,
            'duty_rate_rel_std': est.duty_rate_rel_std,
            'log_rate_drift_per_s': est.config.log_rate_scale_noise_density,
            'soft_zone_shortfall_rad': self.soft_zone_shortfall}
        for (i, j), key in _COVARIANCE_KEYS.items():
            rec[key] = float(P[i, j])
        probability, mean, cov, exposure = trend
        rec['archard_exposure_m'] = exposure
        rec['trend_probability'] = probability
        for i, key in enumerate(_TREND_KEYS):
            rec[key] = float(mean[i])
        for (i, j), key in _TREND_COVARIANCE_KEYS.items():
            rec[key] = float(cov[i, j])
        return rec


def taken_off(shortfall, width, play):
    """
    Return the share of a soft zone's shortfall taken off the play the estimator follows.

    The shortfall is how much narrower the hysteresis is at the test torque than the
    flanks of loads far beyond it give; the estimator follows the play its windows read,
    which is that of those flanks where the windows' loads reach beyond the soft zone's
    knee, but lies nearer the width at the test torque where they seldom do (a base:
    third-generator bases were given 0.02 arcmin for a true 1.19, the whole shortfall
    taken off a play read 6 % high). So it is taken off only down to the ``width`` the
    same comparison gives at the test torque: ``min(shortfall, max(play - width, 0))``.

    A negative shortfall is the other way round (:mod:`.within_zone`): loads that never
    leave a soft zone, the flanks' reading below the width its bins give at the test
    torque. It is added only up to that width: ``max(shortfall, min(play - width, 0))``.

    Parameters
    ----------
    shortfall : float or ndarray
        The soft zone's shortfall [rad] (per window for the report's readings; negative:
        a lost motion read below the width at the test torque, added).
    width : float or ndarray
        The width at the test torque [rad]; 0 or less: not known (a record from before
        it was carried), the whole shortfall is taken off.
    play : callable
        Returns the play the estimator follows [rad], like ``width`` (called only where a
        width is known; not a number: the whole shortfall is taken off).

    Returns
    -------
    float or ndarray
        The shortfall taken off [rad], from 0 to ``shortfall``.

    """
    width = np.asarray(width, dtype=float)
    known = np.isfinite(width) & (width > 0.0)
    if not known.any():
        return shortfall
    with np.errstate(invalid='ignore'):
        above = np.asarray(play(), dtype=float) - width
    bounded = np.where(np.asarray(shortfall) >= 0.0,
                       np.minimum(shortfall, np.maximum(above, 0.0)),
                       np.maximum(shortfall, np.minimum(above, 0.0)))
    taken = np.where(known & np.isfinite(above), bounded, shortfall)
    return float(taken) if taken.ndim == 0 else taken


def reducer_state(estimator_state, duty, lost_motion_obs, soft_zone_shortfall):
    """
    Return where a reducer's stages are, to continue with its next bag or live segment.

    Parameters
    ----------
    estimator_state : dict
        ``WearEstimator.state_dict()``.
    duty : object or None
        The life stage's last duty summary.
    lost_motion_obs : float
        The estimator stage's last observation [rad] (NaN: none).
    soft_zone_shortfall : float
        The soft zone the lost motion is given with [rad] (:class:`EstimatorStage`).

    Returns
    -------
    dict
        JSON-able: ``estimator``, ``duty`` (or None), ``lost_motion_obs_rad`` (or None) and
        ``soft_zone_shortfall_rad``; :meth:`EstimatorStage.continue_from` reads it.

    """
    return {'estimator': estimator_state,
            'duty': None if duty is None else {k: float(v) for k, v in vars(duty).items()},
            'lost_motion_obs_rad': float(lost_motion_obs) if np.isfinite(lost_motion_obs)
            else None,
            SOFT_ZONE_KEY: float(soft_zone_shortfall)}


_COVARIANCE_KEYS = {
    (0, 0): 'var_wear_m2', (0, 1): 'cov_wear_log_rate_m', (1, 1): 'var_log_rate',
    (2, 2): 'var_baseline_m2', (0, 2): 'cov_wear_baseline_m2',
    (1, 2): 'cov_log_rate_baseline_m'}
"""Entry of the state covariance ``[w, ln s, b]`` -> ``wear`` record field."""

_TREND_KEYS = ('trend_new_rad', 'trend_growth_rad', 'trend_exponent')
"""``wear`` record fields of the observed growth law's mean ``[β, k, g]``."""

_TREND_COVARIANCE_KEYS = {
    (0, 0): 'var_trend_new_rad2', (1, 1): 'var_trend_growth_rad2', (2, 2): 'var_trend_exponent',
    (0, 1): 'cov_trend_new_growth_rad2', (0, 2): 'cov_trend_new_exponent_rad',
    (1, 2): 'cov_trend_growth_exponent_rad'}
"""Entry of the growth law's covariance -> ``wear`` record field."""


def state_from_record(record):
    """
    Rebuild ``(x, P)`` from a ``wear`` record.

    Parameters
    ----------
    record : mapping
        Wear record; one without the per-unit states (``baseline_m``...)
        gives ``[w, ln s]`` and its 2x2 covariance (a nominal unit).

    Returns
    -------
    tuple of ndarray
        ``x = [w, ln s, b]`` and its 3x3 covariance (or the two-state form).

    Raises
    ------
    InvalidInput
        If any value is not finite.

    """
    n = 3 if 'baseline_m' in record else 2
    names = ('wear_m', 'log_rate_scale', 'baseline_m')[:n]
    x = np.array([record[k] for k in names], dtype=float)
    P = np.zeros((n, n))
    for (i, j), key in _COVARIANCE_KEYS.items():
        if i < n and j < n:
            P[i, j] = P[j, i] = float(record[key])
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
        raise InvalidInput(f'wear record holds non-finite state: x={x.tolist()}, '
                           f'P={P.tolist()}')
    return x, P


@dataclass(frozen=True)
class LifeConfig(_Validated):
    """Accuracy limit, health thresholds and sampling of the remaining-life prediction."""

    _prefix = 'life'
    lost_motion_limit: float = spec(LOST_MOTION_LIMIT, 'rad', 0.0, 0.1,
                                    'accuracy limit on lost motion (3 arcmin)', lo_open=True)
    warn_s: float = spec(1000.0 * HOUR, 's', 0.0, 1e10,
                         'WARN when the P10 remaining life falls to this (1000 h)')
    error_s: float = spec(200.0 * HOUR, 's', 0.0, 1e10,
                          'ERROR when the P10 remaining life falls to this (200 h)')
    horizon_s: float = spec(DEFAULT_HORIZON_S, 's', 0.0, 1e12,
                            'prediction horizon; beyond it a percentile is censored',
                            lo_open=True)
    n_samples: int = spec(2000, '', 100, 1_000_000, 'samples of the state distribution',
                          integer=True)
    duty_rate_rel_std: float = spec(0.0, '', 0.0, 5.0,
                                    'allowance for a change of the future duty wear rate, '
                                    'beyond the standard error the estimator reports')

    def _check(self):
        if self.error_s > self.warn_s:
            raise InvalidParameter(f'life.error_s ({self.error_s:g} s) must not exceed '
                                   f'life.warn_s ({self.warn_s:g} s)')


class LifeStage:
    """
    Remaining life, catalogue life and health level of one reducer.

    Health is WARN when the P10 remaining life falls to ``warn_s`` operating
    seconds, ERROR at ``error_s`` or when the limit is reached.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    config : LifeConfig, optional
        Limit, thresholds and sampling.

    """

    def __init__(self, params, config=None):
        config = config or LifeConfig()
        self.params = params
        self.config = config
        self.limit = config.lost_motion_limit
        self.warn_s = config.warn_s
        self.error_s = config.error_s
        self.horizon_s = config.horizon_s
        self.n_samples = config.n_samples
        self.duty_rate_rel_std = config.duty_rate_rel_std
        self.duty = None
        self._draws = None   # the same draws every prediction: drawn at the first

    def observe_duty(self, duty):
        """
        Keep the latest duty summary for the catalogue life.

        A window without operation (no duration: a single sample closed by a gap
        or a clock reset) has no mean speed or torque and says nothing about the
        duty: the previous summary stays.
        """
        if duty is not None and not (
                getattr(duty, 'duration_s', 1.0) > 0.0
                and np.isfinite(getattr(duty, 'mean_speed', np.nan))
                and np.isfinite(getattr(duty, 'cubic_mean_torque', np.nan))):
            return
        self.duty = duty

    def prediction(self, wear_record, keep_samples=False, law_weight=None):
        """
        Sample the remaining life of a ``wear`` record.

        The future duty's uncertainty is the estimator's standard error of the
        recent duty rate (``duty_rate_rel_std`` of the record) and this stage's
        allowance, added in quadrature; ``ln s`` drifts as the estimator's
        process model says (``log_rate_drift_per_s``).

        Parameters
        ----------
        wear_record : mapping
            Output of :meth:`EstimatorStage.record`.
        keep_samples : bool
            Keep the sampled times in the result.
        law_weight : float, optional
            A what-if: the observed growth law's weight in the remaining life instead of
            :func:`.life_basis.life_trend_probability` (0: the wear model's curve alone, 1: the law
            alone, where the record has one), in [0, 1].

        Returns
        -------
        LifePrediction
            The prediction (common random numbers: the same record gives the same answer).

        """
        return self.predictions([wear_record], keep_samples, law_weight)[0]

    def predictions(self, wear_records, keep_samples=False, law_weight=None):
        """
        Sample the remaining life of several ``wear`` records at once.

        Each is the :meth:`prediction` of its record alone; the samples of all are
        evaluated together (:func:`~reducer_twin.core.life.remaining_lives`).

        Parameters
        ----------
        wear_records : sequence of mapping
            Outputs of :meth:`EstimatorStage.record`.
        keep_samples : bool
            Keep the sampled times in the results.
        law_weight : float, optional
            As for :meth:`prediction`.

        Returns
        -------
        list of LifePrediction
            One per record, in order.

        Raises
        ------
        InvalidParameter
            If ``law_weight`` lies outside [0, 1].

        """
        if law_weight is not None and not 0.0 <= law_weight <= 1.0:
            raise InvalidParameter(out_of_range('law_weight', law_weight, '', 'in [0, 1]'))
        queries = [self._query(r, law_weight) for r in wear_records]
        if self._draws is None:
            self._draws = LifeDraws.draw(self.n_samples, np.random.default_rng(0))
        # The play the estimator follows meets the limit at the test torque where it
        # reaches the limit plus the record's soft-zone shortfall (0 for almost all).
        limits = [play_limit(r, self.limit) for r in wear_records]
        out = [None] * len(queries)
        for limit in dict.fromkeys(limits):
            rows = [i for i, x in enumerate(limits) if x == limit]
            found = remaining_lives([queries[i] for i in rows], self.params, limit=limit,
                                    horizon_s=self.horizon_s, n_samples=self.n_samples,
                                    draws=self._draws, keep_samples=keep_samples)
            for i, pred in zip(rows, found):
                out[i] = pred
        return out

    def _query(self, wear_record, law_weight=None):
        """Return the :class:`~reducer_twin.core.life.LifeQuery` of a ``wear`` record."""
        x, P = state_from_record(wear_record)
        rate = float(wear_record['duty_rate_m_per_s'])
        measured = float(wear_record.get('duty_rate_rel_std', 0.0))
        drift = float(wear_record.get('log_rate_drift_per_s', 0.0))
        if not (np.isfinite(measured) and measured >= 0.0 and np.isfinite(drift)
                and drift >= 0.0):
            raise InvalidInput(f'wear record holds a bad duty_rate_rel_std ({measured!r}) or '
                               f'log_rate_drift_per_s ({drift!r}): both must be finite and >= 0')
        trend = trend_from_record(wear_record)
        if trend is not None:
            weight = life_trend_probability(wear_record, self.limit) if law_weight is None \
                else float(law_weight)
            trend = replace(trend, probability=weight)
        return LifeQuery((x, P), rate, float(np.hypot(measured, self.duty_rate_rel_std)), drift,
                         trend)

    def process(self, wear_record):
        """
        Predict remaining life from a ``wear`` record.

        Parameters
        ----------
        wear_record : mapping
            Output of :meth:`EstimatorStage.record`.

        Returns
        -------
        tuple
            ``(record, level, message)``: the ``remaining_life`` record, the
            level ``'OK'``/``'WARN'``/``'ERROR'`` and a one-line message; while no
            lost motion has been observed (``updates`` 0), ``'STALE'`` whatever the duty
            alone predicts, and the record's percentiles, mean and event state NaN, its
            flags 0 (the message keeps the duty's prediction as words).

        """
        return self.process_many([wear_record])[0]

    def process_many(self, wear_records, duties=None):
        """
        Predict remaining life from several ``wear`` records at once.

        Parameters
        ----------
        wear_records : sequence of mapping
            Outputs of :meth:`EstimatorStage.record`.
        duties : sequence, optional
            The duty summary in force at each record (what :meth:`observe_duty`
            kept when it was made), for the catalogue life; default the current one.

        Returns
        -------
        list of tuple
            :meth:`process` of each record, in order.

        """
        if duties is None:
            duties = [self.duty] * len(wear_records)
        return [self._assessment(r, p, d) for r, p, d in
                zip(wear_records, self.predictions(wear_records), duties)]

    def _assessment(self, wear_record, pred, duty):
        """Return ``(record, level, message)`` of a record, its prediction and duty."""
        cat = catalogue_life(duty, self.params) if duty is not None else float('nan')
        record = {
            'stamp_s': wear_record['stamp_s'], 'p10_s': pred.p10, 'p50_s': pred.p50,
            'p90_s': pred.p90, 'mean_s': pred.mean, 'p10_censored': float(pred.p10_censored),
            'p50_censored': float(pred.p50_censored), 'p90_censored': float(pred.p90_censored),
            'censored_fraction': pred.fraction_censored, 'horizon_s': pred.horizon_s,
            'event_state': pred.event_state, 'threshold_met': float(pred.threshold_met),
            'catalogue_life_s': cat, 'lost_motion_rad': wear_record['lost_motion_rad'],
            'lost_motion_limit_rad': self.limit}
        if pred.threshold_met or pred.limit_reached:
            level = 'ERROR'
        elif pred.p10 <= self.error_s:
            # A P10 that spans the rates the windows cannot tell apart is not the wear.
            level = 'ERROR' if rate_resolved(wear_record) else 'WARN'
        elif pred.p10 <= self.warn_s:
            level = 'WARN'
        else:
            level = 'OK'
        p10 = 'beyond horizon' if pred.p10_censored else f'{pred.p10 / HOUR:.0f} h'
        message = (f'remaining life P10 {p10}, P50 {pred.p50 / HOUR:.0f} h'
                   + (' (censored)' if pred.p50_censored else ''))
        if pred.limit_reached:
            message = 'lost motion beyond the accuracy limit: reducer worn out'
        else:
            message += (growth_note(wear_record, self.limit) + rate_note(wear_record)
                        + curve_note(wear_record, record))
        if int(wear_record.get('updates', 0)) == 0:
            # A prediction from the duty alone is no assessment: never 'OK' without
            # evidence, nor 'ERROR' (on a heavy duty the model's rate alone wore a joint
            # whose link angle was the motor's out in 1 500 h: "reducer worn out", from
            # no lost motion at all). No number stands for the reducer in the record (a
            # consumer of the topic that acts on threshold_met or P10 acts on evidence);
            # the message keeps the duty's prediction as words.
            record.update(dict.fromkeys(_UNOBSERVED_NAN, math.nan))
            record.update(dict.fromkeys(_UNOBSERVED_ZERO, 0.0))
            level = 'STALE'
            message = ('not observed: no lost-motion observation yet; from the duty alone '
                       f"(the model's wear rate, no evidence): {message}")
        return record, level, message


_UNOBSERVED_NAN = ('p10_s', 'p50_s', 'p90_s', 'mean_s', 'censored_fraction', 'event_state')
"""``remaining_life`` fields that are NaN while no lost motion has been observed."""

_UNOBSERVED_ZERO = ('p10_censored', 'p50_censored', 'p90_censored', 'threshold_met')
"""``remaining_life`` flags that are 0 while no lost motion has been observed."""


def trend_from_record(record):
    """
    Rebuild the observed growth law from a ``wear`` record.

    Parameters
    ----------
    record : mapping
        Wear record.

    Returns
    -------
    GrowthTrendState or None
        None when the record has no growth law (a record of an older twin).

    """
    if 'trend_probability' not in record:
        return None
    mean = np.array([record[k] for k in _TREND_KEYS], dtype=float)
    cov = np.zeros((3, 3))
    for (i, j), key in _TREND_COVARIANCE_KEYS.items():
        cov[i, j] = cov[j, i] = float(record[key])
    return GrowthTrendState(float(record['trend_probability']), mean, cov,
                            float(record['archard_exposure_m']))
