"""
One joint of the twin: TE -> windows -> estimate -> life, shared by the nodes and the analysis.

A joint's processing is written here once. :class:`JointTwin` runs it whole
(:class:`TwinFront`: TE extraction, the learnt encoder time offset and the
window analysis; then :class:`TwinBack`: the Kalman wear estimate and the
remaining-life prediction), and returns frozen results:
:class:`~reducer_twin.core.window_fit.WindowFeatures` per window,
:class:`WearEstimate`, :class:`LifeEstimate` and :class:`HealthSummary`.

The live ROS nodes are shells over these pieces on separate topics
(``te_monitor`` holds a :class:`TwinFront`, ``wear_estimator`` the estimator
stage of a :class:`TwinBack`, ``life_publisher`` its life stage and the
:class:`HealthSummary`); the bag analysis runs a :class:`TwinFront` per joint
in the reading process and a :class:`TwinBack` per joint in a worker. The
defaults of how a stream is cut and aged live in :class:`TwinConfig`, from
which the nodes' parameters, ``config/twin.yaml`` and ``analyze --config``
are derived.
"""

import copy
from dataclasses import dataclass
import math
from types import MappingProxyType
from typing import Mapping, Optional

import numpy as np

from .errors import InvalidParameter, StateFileError
from .ingest import IngestConfig
from .kinematics import total_ratio
from .observability import UNLIKE_MOTIONS
from .params import _Validated, spec
from .pipeline import EstimatorStage, features_from_record, features_record, LifeConfig
from .pipeline import LifeStage, reducer_state, TimeOffsetCalibration
from .te_extraction import TEExtractor, TIME_OFFSET_LINEAR_S
from .units import HOUR, m_to_um, rad_to_arcmin
from .velocity_check import ANGLE_UNITS, angles_in
from .window_analysis import WindowAnalyzer

TOPIC_NAMESPACE = 'reducer_twin'

CALIBRATION_PIECE_S = 0.1
"""
Stream seconds per piece fed to the window analysis until the time offset is learnt.

A learnt offset applies from the next piece on (:meth:`TwinFront.update`, and the bag
analysis): windows read before it carry the offset into the flank pool and the soft-zone
check. ``te_monitor`` analyses what arrived every ``analysis_period_s`` (0.5 s), but a
backlog (a stalled executor, a burst of messages) came as one piece: 60 s of a swing whose
encoders are stamped 4 ms apart, taken as 0.5 s then 59.5 s, left its 0.6-arcmin soft
zone unsaid (0.52 +- 0.10 arcmin pooled against 0.596 +- 0.004 in 0.5-s pieces).
"""

CALIBRATION_WINDOWS = 20
"""Windows fed in :data:`CALIBRATION_PIECE_S` pieces at most while the offset is not learnt."""

FRONT_STATE_KIND = 'reducer_twin.front_state'
"""Kind of :meth:`TwinFront.state` (``te_monitor``'s state file)."""

FRONT_STATE_VERSION = 1
"""Version of :meth:`TwinFront.state`."""
"""Namespace of every derived topic."""


def topic_token(joint):
    """
    Return a joint's name as it stands in topic names: valid for ROS 2, one per name.

    A ROS 2 topic name takes ASCII letters, digits, ``_`` and ``/``, and none of its
    tokens starts with a digit; a joint's name takes anything (``joint-1``, ``Joint 2``,
    ``3rd_axis``), and ``ros2 bag play`` of a derived bag, or a node's publisher, refused
    such a topic. Every other character becomes ``_``, a token that starts with a digit
    gets a ``_`` before it, and empty tokens (``//``, a leading ``/``) are dropped; a
    valid name is returned unchanged (``robot_b/joint_1``).

    Parameters
    ----------
    joint : str
        The joint's name, as the JointState messages carry it.

    Returns
    -------
    str

    """
    tokens = [''.join(c if c.isascii() and (c.isalnum() or c == '_') else '_' for c in t)
              for t in str(joint).split('/') if t]
    return '/'.join('_' + t if t[0].isdigit() else t for t in tokens) or '_'


def node_token(joint):
    """Return a joint's name as it stands in node names (:func:`topic_token`, ``/`` as ``_``)."""
    return topic_token(joint).replace('/', '_')


def joint_topic(joint, suffix, namespace=TOPIC_NAMESPACE):
    """
    Return the topic of a derived value of one joint, ``/reducer_twin/<joint>/<suffix>``.

    The joint's name as :func:`topic_token` writes it.
    """
    return f'/{namespace}/{topic_token(joint)}/{suffix}'


def check_topic_tokens(joints):
    """
    Refuse joints whose names would share their topics (``joint-1`` and ``joint_1``).

    Parameters
    ----------
    joints : iterable of str
        The joints' names.

    Raises
    ------
    InvalidParameter
        Naming both joints and the topic token they share.

    """
    seen = {}
    for joint in joints:
        token = topic_token(joint)
        if token in seen and seen[token] != joint:
            raise InvalidParameter(f'joints {seen[token]!r} and {joint!r} would publish on the '
                                   f'same topics (/{TOPIC_NAMESPACE}/{token}/...): a topic '
                                   "name takes letters, digits and '_' only")
        seen[token] = joint


@dataclass(frozen=True)
class TwinConfig(_Validated):
    """How one joint's stream is aged, cut into windows and analysed: the one source."""

    _prefix = 'twin'
    aging_factor: float = spec(1.0, '', 0.0, 1e9,
                               'seconds of wear exposure per second of stream (1: real robot)')
    window_s: float = spec(2.0, 's', 0.0, 3600.0, 'window length in stream time',
                           lo_open=True)
    max_gap_s: float = spec(IngestConfig().max_gap_s, 's', 0.0, 3600.0,
                            'largest stamp gap bridged inside a window', lo_open=True)
    analysis_period_s: float = spec(0.5, 's', 0.0, 3600.0,
                                    'period of the live window analysis (features of a window '
                                    'come at most this late)', lo_open=True)
    friction_in_effort: int = spec(1, '', 0, 1, "1: the effort is the drive's torque (motor "
                                   'current), whose friction and efficiency are fitted and '
                                   'taken out; 0: a torque sensor at the output (nothing is)',
                                   integer=True)
    effort_lag_s: float = spec(0.0, 's', 0.0, 1.0, 'how late the effort is published: the time '
                               "constant of the drive's torque filter (0: unfiltered)")


@dataclass(frozen=True)
class WearEstimate:
    """
    The estimator's answer to one window (or its state at start).

    Attributes
    ----------
    status : str
        ``accepted``, ``rejected``, ``recovered``, ``skipped``, ``replay`` or ``start``.
    record : Mapping
        The ``wear`` record (layout field name to value, SI), read-only.

    """

    status: str
    record: Mapping


@dataclass(frozen=True)
class LifeEstimate:
    """
    Remaining life of one estimate and the health level it gives.

    Attributes
    ----------
    record : Mapping
        The ``remaining_life`` record (SI), read-only.
    level : str
        ``'OK'``, ``'WARN'``, ``'ERROR'`` or ``'STALE'`` (no lost motion observed yet).
    message : str
        One line for ``/diagnostics``.

    """

    record: Mapping
    level: str
    message: str


@dataclass(frozen=True)
class HealthSummary:
    """
    One reducer's health in edge units: what ``/diagnostics`` and the demo show.

    Attributes
    ----------
    wear_um, wear_std_um : float
        Combined wear and its standard deviation [µm].
    rate_scale : float
        Estimated wear-rate multiplier.
    lost_motion_arcmin, lost_motion_std_arcmin, lost_motion_obs_arcmin : float
        Estimated lost motion, its standard deviation and the last observed one [arcmin].
    rul_p10_h, rul_p50_h, rul_p90_h : float
        Remaining operating life percentiles [h].
    rul_p90_censored : bool
        Whether P90 lies beyond the horizon.
    catalogue_life_h : float
        Catalogue (rated) life at the observed duty [h].
    exposure_h : float
        Wear exposure so far [h].
    level, message : str
        Health level and its line (:class:`LifeEstimate`).
    updates, rejected_updates : int
        Windows the filter took and refused.
    te_pp_arcmin : float or None
        Peak-to-peak TE of the last window [arcmin]; None before one.
    lost_motion_limit_arcmin : float
        The accuracy limit [arcmin].
    soft_zone_shortfall_arcmin : float
        The soft zone the lost motion is given at the test torque with (the play less it),
        found by this stream or carried over from the reducer's last (:mod:`.soft_zone`;
        negative: the lost motion read below its bins' width there, given more,
        :mod:`.within_zone`); 0 without one [arcmin].

    """

    wear_um: float
    wear_std_um: float
    rate_scale: float
    lost_motion_arcmin: float
    lost_motion_std_arcmin: float
    lost_motion_obs_arcmin: float
    rul_p10_h: float
    rul_p50_h: float
    rul_p90_h: float
    rul_p90_censored: bool
    catalogue_life_h: float
    exposure_h: float
    level: str
    message: str
    updates: int
    rejected_updates: int
    te_pp_arcmin: Optional[float]
    lost_motion_limit_arcmin: float
    soft_zone_shortfall_arcmin: float = 0.0

    @classmethod
    def of(cls, wear, life, te_pp_rad=None):
        """
        Summarise a ``wear`` record and its :class:`LifeEstimate`.

        Parameters
        ----------
        wear : Mapping
            The ``wear`` record.
        life : LifeEstimate
            Its remaining life.
        te_pp_rad : float, optional
            Peak-to-peak TE of the last window [rad].

        Returns
        -------
        HealthSummary
            The summary.

        """
        rec = life.record
        return cls(
            wear_um=m_to_um(wear['wear_m']), wear_std_um=m_to_um(wear['wear_std_m']),
            rate_scale=wear['rate_scale'],
            lost_motion_arcmin=rad_to_arcmin(wear['lost_motion_rad']),
            lost_motion_std_arcmin=rad_to_arcmin(wear.get('lost_motion_std_rad', math.nan)),
            lost_motion_obs_arcmin=rad_to_arcmin(wear['lost_motion_obs_rad']),
            rul_p10_h=rec['p10_s'] / HOUR, rul_p50_h=rec['p50_s'] / HOUR,
            rul_p90_h=rec['p90_s'] / HOUR, rul_p90_censored=bool(rec['p90_censored']),
            catalogue_life_h=rec['catalogue_life_s'] / HOUR,
            exposure_h=wear['exposure_s'] / HOUR, level=life.level, message=life.message,
            updates=int(wear['updates']), rejected_updates=int(wear['rejected']),
            te_pp_arcmin=None if te_pp_rad is None else rad_to_arcmin(te_pp_rad),
            lost_motion_limit_arcmin=rad_to_arcmin(rec['lost_motion_limit_rad']),
            soft_zone_shortfall_arcmin=rad_to_arcmin(wear.get('soft_zone_shortfall_rad', 0.0)))

    def as_dict(self):
        """
        Return the summary as a dict.

        ``te_pp_arcmin`` only once a window was seen, ``soft_zone_shortfall_arcmin`` only
        while the lost motion is given at the test torque less a soft zone (negative: more,
        loads within one).
        """
        out = {'wear_um': self.wear_um, 'wear_std_um': self.wear_std_um,
               'rate_scale': self.rate_scale, 'lost_motion_arcmin': self.lost_motion_arcmin,
               'lost_motion_std_arcmin': self.lost_motion_std_arcmin,
               'lost_motion_obs_arcmin': self.lost_motion_obs_arcmin,
               'rul_p10_h': self.rul_p10_h, 'rul_p50_h': self.rul_p50_h,
               'rul_p90_h': self.rul_p90_h, 'rul_p90_censored': self.rul_p90_censored,
               'catalogue_life_h': self.catalogue_life_h, 'exposure_h': self.exposure_h,
               'level': self.level, 'message': self.message, 'updates': self.updates,
               'rejected_updates': self.rejected_updates}
        if self.te_pp_arcmin is not None:
            out['te_pp_arcmin'] = self.te_pp_arcmin
        if self.soft_zone_shortfall_arcmin != 0.0:
            out['soft_zone_shortfall_arcmin'] = self.soft_zone_shortfall_arcmin
        return out

    def diagnostic(self, rejected_messages=0):
        """
        Return the reducer's ``/diagnostics`` status: level, message and key/values.

        Parameters
        ----------
        rejected_messages : int
            Messages the node dropped; an OK with a finite P10 becomes WARN.

        Returns
        -------
        tuple
            ``(level, message, values)``.

        """
        values = {k: v for k, v in self.as_dict().items() if k not in ('level', 'message')}
        values['rejected_messages'] = int(rejected_messages)
        values['lost_motion_limit_arcmin'] = self.lost_motion_limit_arcmin
        level = self.level
        if level == 'OK' and rejected_messages and math.isfinite(self.rul_p10_h):
            level = 'WARN'
        return level, self.message, values


def assess(stage, wear_record):
    """
    Return the :class:`LifeEstimate` of a ``wear`` record by a life stage.

    Parameters
    ----------
    stage : LifeStage
        The reducer's life stage (limit, thresholds, the duty it observed).
    wear_record : Mapping
        The ``wear`` record.

    """
    return assess_many(stage, [wear_record])[0]


def assess_many(stage, wear_records, duties=None):
    """
    Return the :class:`LifeEstimate` of each of several ``wear`` records, sampled together.

    Parameters
    ----------
    stage : LifeStage
        The reducer's life stage.
    wear_records : sequence of Mapping
        The ``wear`` records.
    duties : sequence, optional
        The duty summary in force at each record (default the stage's current one).

    """
    return [LifeEstimate(MappingProxyType(record), level, message)
            for record, level, message in stage.process_many(wear_records, duties)]


def estimate_numbers(wear, life, observed):
    """
    Return a reducer's estimate in edge units: the numbers of ``analyze --json`` and ``fleet``.

    Parameters
    ----------
    wear, life : Mapping
        The last ``wear`` and ``remaining_life`` records (empty: none yet).
    observed : bool
        Whether the estimate rests on a lost motion; if not, no number stands for the
        reducer (a model guess is not a finding).

    Returns
    -------
    dict
        ``wear_um``, ``wear_std_um``, ``rul_p10_h``, ``rul_p50_h``, ``rul_p90_h``,
        ``lost_motion_arcmin``, ``lost_motion_std_arcmin`` (the lost motion's standard
        deviation, the window fit's bias allowed for); None where not observed or not
        finite.

    """
    nan = float('nan')
    out = {'wear_um': m_to_um(wear.get('wear_m', nan)),
           'wear_std_um': m_to_um(wear.get('wear_std_m', nan)),
           'rul_p10_h': life.get('p10_s', nan) / HOUR,
           'rul_p50_h': life.get('p50_s', nan) / HOUR,
           'rul_p90_h': life.get('p90_s', nan) / HOUR,
           'lost_motion_arcmin': rad_to_arcmin(wear.get('lost_motion_rad', nan)),
           'lost_motion_std_arcmin': rad_to_arcmin(wear.get('lost_motion_std_rad', nan))}
    return {k: (float(v) if observed and math.isfinite(v) else None) for k, v in out.items()}


def maintenance_event(events):
    """
    Return the text of a reducer's latest maintenance event, or None without one.

    What ``wear_estimator`` publishes on ``maintenance`` (transient-local) for the joint's
    ``te_monitor`` to start its window analysis afresh once per event
    (:meth:`TwinFront.new_reducer`): numbered and placed by the operation before it, so
    that two events never read alike.

    Parameters
    ----------
    events : list of dict
        :attr:`.estimator.WearEstimator.events` (``exposure_s``, ``reason``).

    """
    if not events:
        return None
    last = events[-1]
    return (f'maintenance event {len(events)} after {last["exposure_s"] / HOUR:.3f} h of '
            f'operation: {last["reason"]}')


def reducer_status_name(joint):
    """Return the ``/diagnostics`` name of a joint's reducer status."""
    return f'reducer_twin: {joint} reducer'


class TwinFront:
    """
    TE extraction, the learnt encoder time offset and the window analysis of one joint.

    Parameters
    ----------
    params : ReducerParams
        The joint's reducer.
    config : TwinConfig, optional
        Aging, window length and gap bridging.
    window : str
        ``'auto'``, ``'revolution'`` or ``'duration'`` (see ``WindowAnalyzer``).

    """

    def __init__(self, params, config=None, window='auto'):
        self.params = params
        self.config = config = config or TwinConfig()
        self.ratio = total_ratio(params.geometry)
        self.extractor = TEExtractor(self.ratio, max_gap_s=config.max_gap_s)
        self.calibration = TimeOffsetCalibration(self.extractor)
        self._restarted_for_held = False
        self._waiting = None    # (t, motor, link, effort, velocity) of samples awaiting motor
        self._window = window
        self.analyzer = self._new_analyzer()
        self.windows = 0
        self.maintenance = None     # the last maintenance event followed (new_reducer)

    def _new_analyzer(self):
        config = self.config
        return WindowAnalyzer(self.params, window=self._window, window_s=config.window_s,
                              aging_factor=config.aging_factor,
                              friction=bool(config.friction_in_effort),
                              effort_lag_s=config.effort_lag_s)

    def new_reducer(self, event):
        """
        Start the window analysis afresh: the joint's reducer was replaced.

        What the windows learnt of the old reducer (the soft-zone check, the flank pool,
        the friction fit) goes, with the samples of the window in progress; what belongs
        to the encoders (the time offset, their judgements in the TE extraction) stays.
        The analysis of a reducer's next recording after a replacement starts so too.

        Parameters
        ----------
        event : str
            The maintenance event (``wear_estimator``'s reset), kept as :attr:`maintenance`
            (and in :meth:`state`) so that it is followed once.

        """
        self.analyzer = self._new_analyzer()
        self.analyzer.offset_removed = self.calibration.settled
        self._waiting = None
        self.maintenance = str(event)

    def carry_time_offset(self, offset_s):
        """
        Start from the encoders' time offset the reducer's last stream ended with [s].

        What :attr:`.pipeline.TimeOffsetCalibration.to_carry` gave at that stream's end
        (``BagResult.states``, the fleet); None or a non-finite value: learnt afresh.
        """
        if offset_s is not None and math.isfinite(offset_s) and offset_s != 0.0:
            self.calibration.carry(float(offset_s))

    def state(self):
        """
        Return what this front learnt of the joint's reducer, to continue after a restart.

        The encoders' time offset a next stream may start from
        (:attr:`.pipeline.TimeOffsetCalibration.to_carry`: not while the clocks drift) and
        the pools of the soft-zone, within-zone and load-reach checks
        (:meth:`.soft_zone.SoftZoneCheck.state`, :meth:`.within_zone.WithinZoneCheck.state`,
        :meth:`.load_reach.LoadReachCheck.state`). The rest of
        the window analysis (the flank pool, the friction fit) is relearnt by the first
        windows of any stream.

        Returns
        -------
        dict
            ``kind`` (:data:`FRONT_STATE_KIND`), ``version``, ``windows`` (analysed so far),
            ``time_offset_s`` (or None), ``soft_zone``, ``within_zone``, ``load_reach`` and
            ``maintenance`` (the last maintenance event followed, or None).

        """
        return {'kind': FRONT_STATE_KIND, 'version': FRONT_STATE_VERSION,
                'windows': self.windows, 'time_offset_s': self.calibration.to_carry,
                'soft_zone': self.analyzer.fit.soft_zone.state(),
                'within_zone': self.analyzer.fit.within_zone.state(),
                'load_reach': self.analyzer.fit.load_reach.state(),
                'maintenance': self.maintenance}

    def continue_from(self, state):
        """
        Continue from :meth:`state` of this joint's front before a restart.

        The time offset is carried as from a reducer's last stream (:meth:`carry_time_offset`:
        checked by the next windows before they give a lost motion); the soft-zone check
        goes on with its pools, so a soft zone said before the restart is said, and
        carried by every window, from the first. A check made for another reducer (the
        joint's reducer changed in the configuration) starts afresh.

        Parameters
        ----------
        state : dict
            :meth:`state`.

        Returns
        -------
        list of str
            What was continued, one line each (for the node's log).

        Raises
        ------
        StateFileError
            If ``state`` is not a front's state of this version, or its values are unusable.

        """
        if not isinstance(state, dict) or state.get('kind') != FRONT_STATE_KIND \
                or state.get('version') != FRONT_STATE_VERSION:
            found = (state.get('kind'), state.get('version')) if isinstance(state, dict) \
                else type(state).__name__
            raise StateFileError(f'state must be {FRONT_STATE_KIND!r} version '
                                 f'{FRONT_STATE_VERSION}, got {found!r}')
        offset = state.get('time_offset_s')
        if offset is not None and (isinstance(offset, bool) or not isinstance(
                offset, (int, float)) or not abs(offset) < 1.0):
            raise StateFileError('time_offset_s must be null or a finite offset within '
                                 f'+-1 s, got {offset!r}')
        event = state.get('maintenance')
        if event is not None and not isinstance(event, str):
            raise StateFileError(f'maintenance must be null or an event text, got {event!r}')
        # Made for the same reducer as the soft-zone check's; a state from before it was
        # kept has none, and the check starts afresh. Read first: nothing is changed by a
        # state that raises.
        within = copy.copy(self.analyzer.fit.within_zone)
        reach = copy.copy(self.analyzer.fit.load_reach)
        for key, check in (('within_zone', within), ('load_reach', reach)):
            try:
                if state.get(key) is not None:
                    check.continue_from(state[key])
            except (KeyError, TypeError, ValueError) as err:
                raise StateFileError(f"{key} is not its check's state: {err}") from None
        check = self.analyzer.fit.soft_zone
        lines = []
        try:
            other = check.other_reducer(state['soft_zone'])
            if other is None:
                check.continue_from(state['soft_zone'])
                self.analyzer.fit.within_zone, self.analyzer.fit.load_reach = within, reach
        except (KeyError, TypeError, ValueError) as err:
            raise StateFileError(f"soft_zone is not a soft-zone check's state: {err}") from None
        if other is not None:
            lines.append(f'the soft-zone check starts afresh: its state was {other}')
        else:
            said = check.said
            lines.append(f'soft-zone check continued ({check.windows} windows compared'
                         + (f'; said: {rad_to_arcmin(said["shortfall"]):.2f} arcmin narrower '
                            'at the test torque)' if said is not None else '; none said)'))
        self.carry_time_offset(offset)
        self.maintenance = event
        if self.calibration.carried:
            lines.insert(0, f'link encoder time offset {offset * 1e6:.1f} us carried over '
                            '(checked by the next windows before they give a lost motion)')
        return lines

    def te(self, t_s, motor, link):
        """
        Return the TE stream of paired samples (stamps [s], motor and link angles [rad]).

        Where the encoders' clocks drift apart (:attr:`.pipeline.TimeOffsetCalibration.drift`),
        the offset is first moved along the drift to the chunk's middle, and the TE
        already pooled and buffered referred to it.
        """
        if self.calibration.drift is not None:
            t = np.asarray(t_s, dtype=float)
            delta = self.calibration.follow(float(0.5 * (t[0] + t[-1]))) \
                if t.ndim == 1 and t.size else 0.0
            if delta:
                self.analyzer.retime(delta)
        return self.extractor.update(t_s, motor, t_s, link)

    def analyze(self, stream, effort, velocity):
        """
        Take a TE stream into the window analysis; return the windows it completed.

        Each window's fitted time offset feeds the calibration (applied once learnt,
        then followed); the windows of this batch after a change were read before it.
        """
        held = self.extractor.held
        if held is not None and not self._restarted_for_held and any(held.held.values()):
            # The TE fed before the held reading was found is stale: start again.
            self._restarted_for_held = True
            self.analyzer.discard_buffer()
            self.calibration.restart()
        found = self.analyzer.update(stream, effort, velocity)
        for f in found:
            # The windows after a change in this batch were read before it: not taken.
            if self.calibration.observe(f):
                self.analyzer.retime(self.calibration.delta)
                break
        self.analyzer.offset_removed = self.calibration.settled
        self.windows += len(found)
        return found

    def input_warnings(self):
        """
        Return how the inputs are read otherwise than published, kind to line (only those found).

        ``'velocity'``: a velocity field that is not the link angle's rate;
        ``'velocity_leads'``: one that leads it (a link reading latched late); ``'held'``: an
        effort held between slower updates; ``'correlated'``: an effort whose noise is
        correlated over samples; ``'encoders'``: an encoder reading held so; ``'steps'``:
        an encoder that reports the output angle coarsely (:mod:`.encoder_steps`);
        ``'ratio'``: a motor that turns another number of times than the configured
        ratio (:mod:`.travel_ratio`); ``'time_offset'``: encoders stamped 3 ms or
        more apart (:attr:`.pipeline.TimeOffsetCalibration.reason`); ``'te_step'``: the TE's
        constant stepped (an encoder re-homed, :attr:`.window_analysis.WindowAnalyzer.te_stepped`);
        ``'soft_zone'``: a play still being taken up at the test torque (:mod:`.soft_zone`);
        ``'test_torque'``: a lost motion that is the play of the loaded flanks where the one
        window that compared the width at the test torque showed a soft zone
        (:attr:`.soft_zone.SoftZoneCheck.caveat`); ``'within_zone'``: a lost motion read
        below its bins' width at the test torque, loads that never leave a soft zone
        (:mod:`.within_zone`); ``'load_reach'``: a lost motion read that depends on how
        far the windows' loads reach (:mod:`.load_reach`).
        """
        found = (('velocity', self.analyzer.velocity_fault),
                 ('velocity_leads', self.analyzer.velocity_leads),
                 ('held', self.analyzer.effort_held),
                 ('correlated', self.analyzer.effort_correlated),
                 ('encoders', self.extractor.held_reason),
                 ('steps', self.extractor.step_reason),
                 ('ratio', self.extractor.ratio_reason),
                 ('time_offset', self.calibration.reason),
                 ('te_step', self.analyzer.te_stepped),
                 ('soft_zone', self.analyzer.soft_zone),
                 ('test_torque', self.analyzer.test_torque_caveat),
                 ('within_zone', self.analyzer.within_zone),
                 ('load_reach', self.analyzer.load_reach))
        return {kind: line for kind, line in found if line is not None}

    @property
    def soft_zone(self):
        """
        Return the figures of a play still being taken up at the test torque, else None.

        The pooled figures of :attr:`.soft_zone.SoftZoneCheck.said` once the soft zone is said
        (``shortfall``, ``shortfall_sd``, ``play``, ``width`` [rad], ``windows``,
        ``few_samples``): the line of :meth:`input_warnings` as numbers. From then on each
        window carries the shortfall (``WindowFeatures.soft_zone_shortfall``), and the back
        gives the lost motion at the test torque (:meth:`.pipeline.EstimatorStage.record`).
        """
        return self.analyzer.soft_zone_said

    def refusal(self, reason):
        """
        Return why the joint is not observed, with what else the encoders show that explains it.

        A motor that turns another number of times than the configured ratio is refused
        for what its TE then shows (an effort of the other sign, encoders that do not
        measure one motion); the line naming the ratio (:mod:`.travel_ratio`) follows, as
        does the one of encoders stamped milliseconds apart (whose TE follows the speed
        until the offset is learnt). Where the velocity field shows the angles published
        in degrees or revolutions (:data:`.velocity_check.ANGLE_UNITS`), that leads: the TE
        is then in those units, and what it shows follows from them. ``None`` (observed)
        stays ``None``. The nodes' ``/diagnostics`` and the analysis of recordings both
        give this reason.
        """
        if reason is None:
            return None
        said = (self.extractor.ratio_reason, self.calibration.reason)
        velocity = self.analyzer.velocity_fault or ''
        for unit, (_, written) in ANGLE_UNITS.items():
            if angles_in(unit) in velocity:
                reason = '; '.join([reason] + [line for line in said if line is not None])
                return (f'the angles look published in {unit}: the velocity field reads '
                        f'{self.analyzer.velocity_scale:.4g} times the rate of the link '
                        f'angle ({written}, a velocity in radians per second beside angles '
                        f'in {unit}); positions are read in radians (REP 103): publish them '
                        f'in radians. What the transmission error in {unit} shows: {reason}')
        said += (self._in_degrees(reason),)
        return '; '.join([reason] + [line for line in said if line is not None])

    @property
    def calibrating(self):
        """Whether the stream goes in :data:`CALIBRATION_PIECE_S` pieces (offset not settled)."""
        return not self.calibration.settled and self.windows < CALIBRATION_WINDOWS

    def _in_degrees(self, reason):
        """
        Say when a TE of degrees comes with the configured ratio: the angles in degrees.

        Encoders refused as not measuring one motion whose motor still turns the
        configured number of times the link (within 1 %) do measure one; a TE span of
        degrees is then arcminutes read in degrees (without a velocity field to show it).
        """
        travel = self.extractor.travel
        measured = travel.measured if travel is not None else None
        if measured is None or not reason.startswith(UNLIKE_MOTIONS) or \
                not abs(measured / self.ratio - 1.0) <= 0.01:
            return None
        span = math.degrees(self.analyzer.fit.largest_te_span)
        return (f'but the motor turns {measured:.2f} times the link, the configured ratio '
                f'({self.ratio:.4g}), so they do: read in degrees, a span of {span:.3g} is '
                f"{span * 60.0 / math.degrees(1.0):.3g} arcmin, a reducer's. The angles look "
                'published in degrees: publish them in radians (REP 103)')

    def update(self, t_s, motor, link, effort, velocity):
        """
        TE and windows of paired samples; return the completed windows.

        While :attr:`calibrating`, the window analysis takes the chunk's TE in pieces of
        :data:`CALIBRATION_PIECE_S` of stamps, and a learnt offset applies from the next
        piece (the rest of the chunk's TE computed again with it) whatever the chunk's
        length, as the bag analysis feeds its chunks.

        A link read ``delta`` after its stamp (a learnt ``link_time_offset_s`` beyond
        :data:`.te_extraction.TIME_OFFSET_LINEAR_S`) needs the motor angle ``delta``
        after it, which for the chunk's last samples comes with the next chunk: they
        wait for it (taken again then) rather than extrapolate the motor along its last
        segment. Extrapolated, a joint of the model's simulator whose link was read
        20 ms late read +8 % in 0.5 s chunks (``te_monitor``'s period) and +16 % in
        0.1 s ones against the whole recording.
        """
        rows = tuple(np.asarray(r, dtype=float) for r in (t_s, motor, link, effort, velocity))
        if self._waiting is not None:
            rows = tuple(np.concatenate([w, r]) for w, r in zip(self._waiting, rows))
            self._waiting = None
        found = []
        while True:
            cut = self._ready(rows[0])
            n = rows[0].shape[0] if cut is None else cut
            stream = self.te(*rows[:3])     # (moves the offset along a drift first)
            start = self._analyze_pieces(stream, rows, n, found)
            if start >= n:
                break
            # Learnt (or refined) within the chunk: the rest again with it, its TE
            # continuous with the last one used.
            valid = np.flatnonzero(stream.valid[:start])
            if valid.size:
                self.extractor.last_te = float(stream.te[valid[-1]])
            rows = tuple(r[start:] for r in rows)
        if cut is not None:
            self._waiting = tuple(r[cut:].copy() for r in rows)
            valid = np.flatnonzero(stream.valid[:cut])
            if valid.size:      # the next chunk's TE continues from the last one used
                self.extractor.last_te = float(stream.te[valid[-1]])
        return found

    def _analyze_pieces(self, stream, rows, n, found):
        """
        Analyse the first ``n`` samples of a chunk's TE; return where it stopped.

        Whole, or while :attr:`calibrating` in pieces of :data:`CALIBRATION_PIECE_S` until
        the windows move the extractor's offset (then the rest waits for its TE).
        """
        t, start, offset = rows[0], 0, self.extractor.link_time_offset_s
        pieces = self.calibrating and t.ndim == 1 and n > 1 and bool(np.all(np.diff(t) > 0.0))
        while pieces and start < n and self.calibrating:
            if self.extractor.link_time_offset_s != offset:
                return start
            end = int(np.searchsorted(t, t[start] + CALIBRATION_PIECE_S, side='left'))
            end = min(max(end, start + 1), n)
            found += self.analyze(stream.part(slice(start, end)), rows[3][start:end],
                                  rows[4][start:end])
            start = end
        if start < n and self.extractor.link_time_offset_s != offset:
            return start
        if start < n:
            found += self.analyze(stream.part(slice(start, n)), rows[3][start:n],
                                  rows[4][start:n])
        return n

    def _ready(self, t_s):
        """Return how many leading samples have their motor angle ``delta`` on, or None: all."""
        delta = self.extractor.link_time_offset_s
        if not delta > TIME_OFFSET_LINEAR_S:
            return None
        t = np.asarray(t_s, dtype=float)
        if t.ndim != 1 or t.size < 2 or not np.all(np.diff(t) > 0.0):
            return None     # a clock reset or disordered stamps: as before
        cut = int(np.searchsorted(t, t[-1] - delta, side='right'))
        return cut if cut < t.size else None

    def flush(self):
        """Close the last, partial window (samples still waiting for motor angles included)."""
        found = []
        if self._waiting is not None:
            rows, self._waiting = self._waiting, None
            found += self.analyze(self.te(*rows[:3]), *rows[3:])
        end = self.analyzer.flush()
        self.windows += len(end)
        return found + end

    def record(self, features):
        """Return the ``te_features`` record of a window (SI)."""
        return features_record(features, self.params)


class TwinBack:
    """
    The Kalman wear estimate and the remaining life of one reducer.

    Parameters
    ----------
    params : ReducerParams
        The reducer.
    life_config : LifeConfig, optional
        Limit, thresholds and sampling.
    estimator : EstimatorStage, optional
        The estimator stage (with its state file, or restored); default a new reducer.

    """

    def __init__(self, params, life_config=None, estimator=None):
        self.params = params
        self.estimator = estimator or EstimatorStage(params)
        self.life = LifeStage(params, life_config or LifeConfig())
        self.te_pp_rad = None

    def start(self, stamp_s):
        """Return the estimate and life before any window (what the nodes publish at start)."""
        wear = WearEstimate('start', MappingProxyType(self.estimator.record(stamp_s)))
        return wear, self.assess(wear.record)

    def estimate(self, record):
        """
        Step the estimator with one ``te_features`` record; the duty goes to the life stage.

        Returns
        -------
        WearEstimate
            The status and the ``wear`` record stamped at the window's end.

        """
        features = features_from_record(record)
        status = self.estimator.process(features)
        self.life.observe_duty(features.duty)
        self.te_pp_rad = float(record['te_pp_rad'])
        return WearEstimate(status, MappingProxyType(self.estimator.record(features.t_end)))

    def assess(self, wear_record):
        """Return the :class:`LifeEstimate` of a ``wear`` record."""
        return assess(self.life, wear_record)

    def step(self, record):
        """Estimate and assess one window; return ``(WearEstimate, LifeEstimate)``."""
        wear = self.estimate(record)
        return wear, self.assess(wear.record)

    def step_many(self, records):
        """
        Step the estimator with each window in turn, then assess all of them at once.

        The same results as :meth:`step` and :meth:`summary` window by window; the
        remaining-life samples of all windows are evaluated as one array.

        Parameters
        ----------
        records : sequence of Mapping
            ``te_features`` records, oldest first.

        Returns
        -------
        list of tuple
            ``(WearEstimate, LifeEstimate, HealthSummary)`` per window.

        """
        wears, duties, te_pp = [], [], []
        for record in records:
            wears.append(self.estimate(record))
            duties.append(self.life.duty)
            te_pp.append(self.te_pp_rad)
        lives = assess_many(self.life, [w.record for w in wears], duties)
        return [(wear, life, HealthSummary.of(wear.record, life, pp))
                for wear, life, pp in zip(wears, lives, te_pp)]

    def summary(self, wear, life):
        """Return the :class:`HealthSummary` of an estimate and its life."""
        return HealthSummary.of(wear.record, life, self.te_pp_rad)

    def state(self):
        """
        Return where this reducer's stages are, to continue with its next bag.

        Returns
        -------
        dict
            :func:`.pipeline.reducer_state`: the estimator, the life stage's last duty, the
            last observation and the soft zone the lost motion is given with.

        """
        stage = self.estimator
        return reducer_state(stage.estimator.state_dict(), self.life.duty,
                             stage.last_observation, stage.soft_zone_shortfall)

    def restore(self, state):
        """Continue from :meth:`state` of an earlier analysis of the same reducer."""
        from types import SimpleNamespace
        self.estimator.continue_from(state)
        duty = state.get('duty')
        self.life.duty = None if duty is None else SimpleNamespace(**duty)


@dataclass(frozen=True)
class JointUpdate:
    """What one window changed: its features, the estimate, the life and the summary."""

    features: object
    record: Mapping
    wear: WearEstimate
    life: LifeEstimate
    summary: HealthSummary


class JointTwin:
    """
    One joint's whole pipeline in one object: paired samples in, frozen results out.

    Parameters
    ----------
    joint : str
        Joint name.
    params : ReducerParams
        The joint's reducer.
    config : TwinConfig, optional
        Aging, window length and gap bridging.
    life_config : LifeConfig, optional
        Limit, thresholds and sampling of the remaining life.
    estimator : EstimatorStage, optional
        The estimator stage (a state file, a restored state); default a new reducer.
    window : str
        Window rule (see :class:`TwinFront`).

    """

    def __init__(self, joint, params, config=None, life_config=None, estimator=None,
                 window='auto'):
        self.joint = joint
        self.front = TwinFront(params, config, window)
        self.back = TwinBack(params, life_config, estimator)

    def update(self, t_s, motor, link, effort, velocity):
        """
        Process paired samples; return a :class:`JointUpdate` per completed window.

        Parameters
        ----------
        t_s : ndarray
            Stamps [s].
        motor, link : ndarray
            Motor (raw, input side) and link angles [rad].
        effort : ndarray
            Output torque [N*m].
        velocity : ndarray
            Link velocity [rad/s].

        """
        return [self._step(f) for f in self.front.update(t_s, motor, link, effort, velocity)]

    def flush(self):
        """Close the last window; return its updates."""
        return [self._step(f) for f in self.front.flush()]

    def _step(self, features):
        record = MappingProxyType(self.front.record(features))
        wear, life = self.back.step(record)
        return JointUpdate(features, record, wear, life, self.back.summary(wear, life))
