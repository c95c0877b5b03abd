"""
Offline analysis of a rosbag2 recording with the twin's own stages.

The same core objects the live nodes run, in the same order, on whole arrays:

* ``encoder_ingest``: :class:`~reducer_twin.core.ingest.StreamCleaner` over all joint
  columns of a chunk of JointState messages at once, :func:`~reducer_twin.core.ingest.
  pair_columns` (one message with ``<joint>`` and ``<joint><motor_suffix>``) or
  :class:`~reducer_twin.core.ingest.Pairer` (link and motor on two topics), then
  :class:`~reducer_twin.core.ingest.SpikeFilter`;
* ``te_monitor``: :class:`~reducer_twin.core.te_extraction.TEExtractor`,
  :class:`~reducer_twin.core.pipeline.TimeOffsetCalibration` and
  :class:`~reducer_twin.core.window_analysis.WindowAnalyzer`, records by
  :func:`~reducer_twin.core.pipeline.features_record`;
* ``wear_estimator`` and ``life_publisher``: :class:`~reducer_twin.core.pipeline.
  EstimatorStage` and :class:`~reducer_twin.core.pipeline.LifeStage` per window.

JointState messages are taken in log-time order, as ``encoder_ingest`` takes them in
arrival order (rosbag2 writes in receive order; MCAP chunks of different topics that
overlap in time are merged by the reader); the ingestion rules drop and count what comes
out of stamp order, and several publishers' partial messages of one tick are merged
(:func:`merge_partial_messages`). The derived bag carries what the nodes publish, in their layouts:
``/reducer_twin/<joint>/te`` (TE batches, ``TE_BATCH_S`` = 0.5 s of stream per message
instead of the node's 20 ms), ``te_features``, ``wear`` and ``remaining_life`` per window,
``/diagnostics`` (the life publisher's status per window and joint, and the ingest
counts at the end), and the input's ``ground_truth`` topics when it has them.
Log times are the stamps of the data a message was computed from.

Differences from a live run, on purpose: TE messages are longer; until the encoder time
offset is learnt (or for ``CALIBRATION_WINDOWS`` windows) the stream is fed in
0.1 s pieces (``CALIBRATION_PIECE_S``), then in large chunks, so a calibration
that is learnt late applies from the next chunk; the last, partial window is analysed
(a node that stops drops it); the estimator starts from a new reducer and keeps no state
file. Once the time offset applies, the motor angle of each piece's last link sample is
extrapolated over the offset (the link encoder samples 50 µs after its stamp), so no
sample is lost at piece boundaries, live or offline.

Speed: the estimator and life stages (the Kalman step and 2000-sample life predictions per
window) can run in a forked worker process while this process cleans and analyses the
next chunk (``stage_worker=True``); the worker then also runs the TE extraction and window
analysis of every sixth joint (:data:`WORKER_FRONT_EVERY`; their paired samples go to it,
their TE batches and window records come back to be written here). The bag can be read
and decoded a few chunks ahead by a second forked process (``reader_process=True``);
results are identical.
"""

from dataclasses import dataclass, field, replace
import math
from pathlib import Path
import time

import numpy as np
from reducer_twin.analysis.simulate import AGING_KEY, LATEST_QOS
from reducer_twin.analysis.stages import FRONT_OUTPUT, JointFront, LocalBacks, stamp_ns
from reducer_twin.analysis.stages import te_values, WorkerBacks
from reducer_twin.config import joint_reducers, load_config_sources, twin_config
from reducer_twin.core.errors import BagError, InvalidInput, InvalidParameter
from reducer_twin.core.ingest import CLOCK_SCATTER, EFFORT_SOURCES, IngestConfig
from reducer_twin.core.ingest import motor_effort_scale
from reducer_twin.core.ingest import MOTOR_EFFORT_UNITS, pair_columns, PAIRING_FACTS
from reducer_twin.core.ingest import retimed_message, SHARED_STAMPS, step_scatter
from reducer_twin.core.ingest import stream_cleaners
from reducer_twin.core.joint_twin import estimate_numbers, joint_topic, TOPIC_NAMESPACE
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import LifeConfig
from reducer_twin.core.robot_ingest import check_effort_scale
from reducer_twin.io.bag import BagDirWriter, JOINT_STATE_TYPES, open_bag
from reducer_twin.io.mcap_reader import ReadWarning
from reducer_twin.io.outputs import refuse_inside_inputs
from reducer_twin.io.rosbag2_metadata import DEFAULT_QOS
from reducer_twin.msg_adapters.diagnostic_cdr import (
    encode_diagnostic_array, MSGTYPE as DIAGNOSTICS)
from reducer_twin.msg_adapters.diagnostic_cdr import Status
from reducer_twin.msg_adapters.dynamic_joint_state import InterfaceMap
from reducer_twin.msg_adapters.jointstate_cdr import concat_batches, JointStateBatch
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
from reducer_twin.msg_adapters.layouts import GROUND_TRUTH, REMAINING_LIFE, TE_BATCH
from reducer_twin.msg_adapters.layouts import TE_FEATURES, WEAR_ESTIMATE
from reducer_twin.msg_adapters.multiarray_cdr import decode_multiarray, encode_multiarrays
from reducer_twin.msg_adapters.multiarray_cdr import MSGTYPE as MULTIARRAY

CHUNK_MESSAGES = 1 << 15
"""
JointState messages cleaned, paired and analysed per step.

With a stage worker the steps are the pipeline's grain: the worker starts on the first
chunk's windows, and ends after the last chunk's, one chunk after this process (on a
6-joint bag at 1 kHz, 33 s of stream a chunk). Measured on it against 1 << 17: this
process's CPU, which sets the wall time, 3 % lower (its arrays stay in the caches), the
worker's the same, 5 % less wall time on two cores and 40 % less peak memory; 1 << 14
costs more per chunk than it saves.
"""

REPORT_TE_POINTS = 20_000
"""TE samples per joint kept for the report plots (evenly thinned)."""

WORKER_FRONT_EVERY = 6
"""
With a stage worker, the front of every sixth joint (the 2nd, the 8th, ...) runs in it.

The worker also runs every joint's estimator and life stages (about as much CPU per
joint as a front), and it starts only once the first chunk is read and paired: on a
6-joint robot at 1 kHz one front there lets both processes end together (measured:
with two, this process waited 0.3-0.4 s for the worker at the end).
"""

DERIVED_BYTES_PER_SAMPLE = 36
"""Bytes of derived bag per joint and JointState message, uncompressed (measured: 33.9)."""

_REPAIRED = ('non_finite', 'duplicate', 'out_of_order', 'clock_jump')

_END, _ERROR = '!end', '!error'


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class AnalysisSettings:
    """
    How to analyse a bag (the bringup configuration's meaning, offline).

    Attributes
    ----------
    joints : tuple of str or None
        Joints to analyse; None: every ``<joint>``/``<joint><motor_suffix>`` pair found.
    link_topic, motor_topic : str
        JointState topics (``motor_topic`` empty: motor entries are in the link topic).
    motor_suffix : str
        Suffix of motor entries in a combined message.
    motor_angles : str
        ``'raw'``, ``'output'`` (already divided by the ratio) or ``'auto'``: found
        from the data (motor travel against link travel); a configured value the
        data contradict is an error naming both.
    motor_direction : int or str
        1 (the motor encoder counts with the link), -1 (against it) or ``'auto'``:
        found per joint from the data (its steps against the link's); a configured
        value the data contradict is an error naming both.
    effort_source : str
        Where the torque is read: ``'link'``, ``'motor'`` or ``'auto'`` (the link
        entry where it has an effort, else the motor entry).
    motor_effort_units : str
        The motor entry's effort: ``'motor'`` (motor torque, times the ratio),
        ``'joint'`` (already output torque) or ``'auto'`` (motor torque when the
        motor angles are raw).
    effort_scale : float
        Output torque [N·m] per unit of the effort so read (-1: an effort of the other
        sign; a torque constant times the ratio for a motor current in A).
    interfaces : InterfaceMap
        DynamicJointState interfaces of the joint (``position``, ...) and the motor
        (``motor_position``, ...) entries.
    aging_factor : float or None
        Seconds of wear exposure per stream second; None: the bag's own
        (``custom_data`` :data:`~reducer_twin.analysis.simulate.AGING_KEY`), else 1.
    window_s : float
        Analysis window [s of stream].
    max_gap_s : float
        Largest stamp gap TE extraction bridges inside a window [s].
    friction_in_effort : int
        1: the effort is the drive's torque, whose friction and efficiency are fitted
        and taken out; 0: a torque sensor at the reducer's output (``twin.friction_in_effort``).
    params : ReducerParams
        Reducer parameters of every joint without its own.
    joint_params : tuple of (str, ReducerParams)
        Reducer parameters of the joints that carry another reducer (an RV-160E at the
        base, an RV-40E at the wrist); see :meth:`params_of`.
    life : LifeConfig
        Limit and thresholds of the remaining-life stage.
    ingest : IngestConfig
        Ingestion thresholds.
    compression : str
        MCAP chunk compression of the derived bag (``'none'``: as ``ros2 bag record``
        writes by default, and the cheapest to write).
    configured_topics : tuple of (str, str)
        ``(key, topic)`` of the topics the configuration names explicitly; each must be
        in the bag.

    """

    joints: tuple = None
    link_topic: str = '/joint_states'
    motor_topic: str = ''
    motor_suffix: str = '_motor'
    motor_angles: str = 'auto'
    motor_direction: object = 'auto'
    effort_source: str = 'auto'
    motor_effort_units: str = 'auto'
    effort_scale: float = 1.0
    interfaces: InterfaceMap = field(default_factory=InterfaceMap)
    aging_factor: float = None
    window_s: float = TwinConfig().window_s
    max_gap_s: float = TwinConfig().max_gap_s
    friction_in_effort: int = TwinConfig().friction_in_effort
    params: ReducerParams = field(default_factory=ReducerParams)
    joint_params: tuple = ()
    life: LifeConfig = field(default_factory=LifeConfig)
    ingest: IngestConfig = field(default_factory=IngestConfig)
    compression: str = 'none'
    configured_topics: tuple = ()

    def params_of(self, joint):
        """Return the reducer parameters of ``joint`` (its own, else :attr:`params`)."""
        for name, params in self.joint_params:
            if name == joint:
                return params
        return self.params

    @classmethod
    def from_config(cls, path):
        """
        Read a bringup YAML (``config/twin.yaml``) as analysis settings.

        Joints and the aging factor count only when the file sets them; otherwise the
        joints are found in the bag and the bag's aging factor applies.

        Parameters
        ----------
        path : str or Path or None
            The file; None gives the defaults.

        Returns
        -------
        AnalysisSettings
            The settings.

        Raises
        ------
        InvalidParameter
            If the file is unreadable or holds invalid values.

        """
        config, given = load_config_sources(path)
        twin = config['twin']
        for key, allowed in (('motor_angles', MOTOR_ANGLES), ('effort_source', EFFORT_SOURCES),
                             ('motor_effort_units', MOTOR_EFFORT_UNITS)):
            if twin[key] not in allowed:
                raise InvalidParameter(f'{path}: twin.{key} must be one of '
                                       f'{", ".join(repr(a) for a in allowed)}, got {twin[key]!r}')
        aging = None
        if 'twin.aging_factor' in given:
            aging = _number(path, 'twin.aging_factor', twin['aging_factor'], 0.0, 1e9)
            if aging == 0.0:    # every window would count no operating time
                raise InvalidParameter(f'{path}: twin.aging_factor must be a number in (0, '
                                       '1e9] (operating seconds per stream second), got 0')
        try:
            spec = twin_config(config)
        except InvalidParameter as err:
            raise InvalidParameter(f'{path}: {err}') from None
        try:
            params, joint_params = joint_reducers(config, path)
            life = LifeConfig(**{k: (int(v) if k == 'n_samples' else float(v))
                                 for k, v in config['life'].items()})
        except TypeError as err:
            raise InvalidParameter(f'{path}: life section: {err}; allowed keys: '
                                   f'{sorted(LifeConfig.__dataclass_fields__)}') from None
        except ValueError as err:
            raise InvalidParameter(f'{path}: {err}') from None
        try:
            interfaces = InterfaceMap.from_mapping(twin['interfaces'], 'twin.interfaces')
        except InvalidParameter as err:
            raise InvalidParameter(f'{path}: {err}') from None
        named = tuple((f'twin.{key}', twin[key]) for key in ('link_topic', 'motor_topic')
                      if f'twin.{key}' in given and twin[key])
        return cls(joints=tuple(twin['joints']) if 'twin.joints' in given else None,
                   configured_topics=named,
                   link_topic=str(twin['link_topic']), motor_topic=str(twin['motor_topic']),
                   motor_suffix=str(twin['motor_suffix']),
                   motor_angles=twin['motor_angles'] if 'twin.motor_angles' in given else 'auto',
                   motor_direction=(twin['motor_direction'] if 'twin.motor_direction' in given
                                    else 'auto'),
                   effort_source=twin['effort_source'],
                   motor_effort_units=twin['motor_effort_units'],
                   effort_scale=check_effort_scale(twin['effort_scale'], f'{path}: twin.'),
                   interfaces=interfaces, aging_factor=aging, window_s=spec.window_s,
                   max_gap_s=spec.max_gap_s, friction_in_effort=spec.friction_in_effort,
                   params=params,
                   joint_params=tuple(joint_params.items()), life=life)


MOTOR_ANGLES = ('auto', 'raw', 'output')


def _number(path, name, value, lo, hi):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and \
        math.isfinite(value) and lo <= value <= hi
    if not ok:
        raise InvalidParameter(f'{path}: {name} must be a number in [{lo:g}, {hi:g}], got '
                               f'{value!r}')
    return float(value)


# --------------------------------------------------------------------------- joints


@dataclass(frozen=True)
class JointPlan:
    """
    Where the joints of a bag are.

    Attributes
    ----------
    link_topic : str
        JointState topic of the link side (and of the motor side when combined).
    motor_topic : str or None
        JointState topic of the motor side when split.
    joints : tuple of str
        Joint names.
    motor_names : tuple of str
        Name of each joint's motor entry (``<joint><suffix>`` combined, ``<joint>``
        split).
    others : tuple of tuple
        ``(link topic, joints, motor topic or None, motor entry names)`` of the other
        topics with motor/link pairs, which this plan leaves out (:meth:`not_analysed`;
        :func:`robot_plans` makes a plan of each).
    prefix : str
        Put before the topic's entry names (``<namespace>/``) when a recording holds
        several robots; ``joints`` and ``motor_names`` carry it.

    """

    link_topic: str
    motor_topic: str
    joints: tuple
    motor_names: tuple
    others: tuple = ()
    prefix: str = ''

    def not_analysed(self):
        """
        Joints of the bag's other paired topics, which this analysis leaves out.

        Returns
        -------
        dict of str to str
            ``<namespace>/<joint>`` (the topic's namespace, else the topic) to the reason.

        """
        out = {}
        for topic, joints, *_ in self.others:
            space = _namespace(topic) or topic
            for joint in joints:
                out[f'{space}/{joint}'] = (
                    f'not analysed: {topic} also holds motor/link pairs, and twin.joints '
                    f'in --config chose joints of {self.link_topic}; analyse it with '
                    f'twin.link_topic: {topic} in --config')
        return out


def _topic_list(bag):
    if not bag.topics:
        return 'no topics'
    return ', '.join(f'{name} ({t.msgtype})' for name, t in bag.topics.items())


def _check_configured_topics(bag, settings):
    """Refuse a topic that ``--config`` names and the bag does not have."""
    for key, topic in settings.configured_topics:
        if topic not in bag.topics:
            raise BagError(f'{bag.path}: {key} {topic} set in --config is not in the bag; '
                           f'found: {_topic_list(bag)}')


def _first_names(bag, topic, malformed=None):
    """Joint names of the first readable messages of a topic (count malformed ones before)."""
    batches = bag.iter_joint_states([topic])
    try:
        for _, decoded in batches:
            if decoded.rejected and malformed is not None:
                count, first = malformed.get(topic, (0, decoded.rejected[0][1]))
                malformed[topic] = (count + len(decoded.rejected), first)
            if len(decoded):
                return decoded.names
    finally:
        batches.close()
    return ()


def plan_joints(bag, settings):
    """
    Find the JointState topics and motor/link pairs by the ingestion node's rules.

    Combined form: one topic whose messages name ``<joint>`` and
    ``<joint><motor_suffix>``. Split form: ``motor_topic`` (configured, or a
    JointState topic whose name contains ``motor``, or a DynamicJointState topic)
    names the same joints as the link topic (or ``<joint><motor_suffix>``). The
    configured ``link_topic`` is used when the bag has it, else the topic that holds
    pairs. A DynamicJointState topic counts as a JointState topic with ``<joint>`` and
    ``<joint><motor_suffix>`` entries
    (:mod:`reducer_twin.msg_adapters.dynamic_joint_state`): alone, or beside
    ``/joint_states`` that has no motor entries, it gives the combined form.

    Parameters
    ----------
    bag : Bag
        Opened bag.
    settings : AnalysisSettings
        Topics, suffix and joints.

    Returns
    -------
    JointPlan
        Topics and joints.

    Raises
    ------
    BagError
        If the bag has no JointState topic (naming the topics it has), no pairs, or
        lacks a configured joint or topic.

    """
    states = [n for n, t in bag.topics.items() if t.msgtype in JOINT_STATE_TYPES]
    if not states:
        raise BagError(f'{bag.path}: no {JOINT_STATE} topic; found: {_topic_list(bag)} '
                       f'(and no {JOINT_STATE_TYPES[1]})')
    names, malformed = {}, {}

    def names_of(topic):
        if topic not in names:
            names[topic] = _first_names(bag, topic, malformed)
        return names[topic]

    suffix = settings.motor_suffix
    if settings.motor_topic:
        for topic in (settings.link_topic, settings.motor_topic):
            if topic not in states:
                raise BagError(f'{bag.path}: configured JointState topic {topic} is not in the '
                               f'bag; its JointState topics: {states}')
        link, motor = settings.link_topic, settings.motor_topic
        return _pick(bag, settings, link, motor,
                     *_motor_entries(names_of(link), names_of(motor), suffix))
    candidates = [settings.link_topic] if settings.link_topic in states else []
    candidates += [t for t in states if t not in candidates]
    found = _paired_topics(candidates, states, bag, names_of, suffix)
    if found:
        (link, motor), (pairs, motor_names) = found[0]
        plan = _pick(bag, settings, link, motor, pairs, motor_names)
        if settings.configured_topics:     # the configuration chose the topic
            return plan
        # Never silent: another robot (or arm) in the same recording is named.
        used = {link, motor} - {None}
        others = tuple((topic, tuple(joints), other, tuple(motor_names))
                       for (topic, other), (joints, motor_names) in found[1:]
                       if topic not in used and other not in used)
        return replace(plan, others=others)
    if not any(names_of(t) for t in states):
        problems = ''.join(f'; {t}: {n:,} malformed messages, the first: {first}'
                           for t, (n, first) in malformed.items())
        problems += ''.join(f'; {w}' for w in bag.warnings)
        raise BagError(f'{bag.path}: no readable message on its JointState topics {states}'
                       f'{problems}')
    found = '; '.join(f'{t}: {list(names_of(t))[:12]}' for t in states)
    dynamic = any(bag.topics[t].msgtype != JOINT_STATE for t in states)
    hint = (f'; a DynamicJointState joint gives <joint>{suffix} from its interface '
            f'{settings.interfaces.motor_position!r} (twin.interfaces.motor_position)'
            if dynamic else '')
    raise BagError(f'{bag.path}: no motor/link encoder pairs: expected <joint> and '
                   f'<joint>{suffix} in one JointState message, or a motor JointState topic '
                   f'(twin.motor_topic in --config){hint}; JointState topics and names: '
                   f'{found}')


def _motor_entries(link_names, motor_names, suffix):
    """Joints of a link topic found on a motor topic, as ``<joint>`` or ``<joint><suffix>``."""
    have = set(motor_names)
    joints, entries = [], []
    for name in link_names:
        for entry in (name + suffix, name):
            if entry in have:
                joints.append(name)
                entries.append(entry)
                break
    return joints, entries


def _namespace(topic):
    """Return a topic's namespace without slashes (``'/robot_b/joint_states'``: ``robot_b``)."""
    return topic.rsplit('/', 1)[0].strip('/')


def robot_plans(bag, plan, settings):
    """
    Every robot's plan when a recording holds several (one per paired link topic).

    Each robot's joints are named ``<namespace>/<joint>`` (the topic's namespace; none
    for a topic at the root): two arms with the same joint names stay apart. With
    ``twin.joints`` configured only the plan given is analysed (the others are said).

    Returns
    -------
    list of JointPlan
        The plans, the given one first; just it when there is no other robot.

    """
    if not plan.others or settings.joints is not None:
        return [plan]
    plans = []
    for topic, joints, motor, motor_names in ((plan.link_topic, plan.joints, plan.motor_topic,
                                               plan.motor_names), *plan.others):
        space = _namespace(topic)
        prefix = f'{space}/' if space else ''
        plans.append(JointPlan(topic, motor, tuple(prefix + j for j in joints),
                               tuple(prefix + m for m in motor_names), prefix=prefix))
    return plans


def _paired_topics(candidates, states, bag, names_of, suffix):
    """
    Every link topic with motor/link pairs, in order of preference.

    Returns
    -------
    list of tuple
        ``((link topic, motor topic or None), (joints, motor entry names))``: the
        combined form first (one topic with ``<joint>`` and ``<joint><suffix>``), then
        the split form (a motor JointState topic, or a DynamicJointState one, naming
        the link topic's joints).

    """
    found = []
    for link in candidates:
        have = names_of(link)
        pairs = [n for n in have if n + suffix in have]
        if pairs:
            found.append(((link, None), (pairs, [n + suffix for n in pairs])))
    dynamic = [t for t in states if bag.topics[t].msgtype != JOINT_STATE]
    combined = {link for (link, _), _ in found}
    for link in candidates:
        if link in combined or 'motor' in link.lower():
            continue
        for motor in [t for t in states if t != link and ('motor' in t.lower() or t in dynamic)]:
            common, motor_names = _motor_entries(names_of(link), names_of(motor), suffix)
            if common:
                found.append(((link, motor), (common, motor_names)))
                break
    return found


def _pick(bag, settings, link, motor, available, motor_names):
    lookup = dict(zip(available, motor_names))
    if settings.joints is None:
        joints = tuple(available)
    else:
        missing = [j for j in settings.joints if j not in lookup]
        if missing:
            raise BagError(f'{bag.path}: configured joints {missing} have no motor/link pair '
                           f'on {link}{" and " + motor if motor else ""}; pairs found: '
                           f'{list(available)}')
        joints = tuple(settings.joints)
    if not joints:
        raise BagError(f'{bag.path}: {link} and {motor} name no common joints')
    return JointPlan(link, motor, joints, tuple(lookup[j] for j in joints))


# --------------------------------------------------------------------------- reading


def _say(bag, text):
    """Add a warning about the bag (printed as ``WARNING: <bag>: <text>``)."""
    bag.warnings.append(ReadWarning(str(bag.path), None, text))


class _Chunks:
    """JointState messages of the plan's topics, decoded in chunks of about N messages."""

    def __init__(self, bag, topics, size, prefix=''):
        self.bag = bag
        self.topics = list(topics)
        self.size = size
        self.prefix = prefix    # put before every entry name (a robot's namespace)
        self.messages = dict.fromkeys(self.topics, 0)
        self.malformed = dict.fromkeys(self.topics, 0)
        self.first_problem = {}
        self.repeated_names = dict.fromkeys(self.topics, 0)
        self.stamp_repeats = dict.fromkeys(self.topics, 0)
        self.stamp_clashes = dict.fromkeys(self.topics, 0)
        self.step_scatter = {}      # topic -> [(period, scatter)] of each chunk [ns]
        self.zero_stamps = dict.fromkeys(self.topics, 0)
        self.name_messages = {}     # topic -> name -> messages, once a message was partial
        self._last_stamp = {}

    def __iter__(self):
        parts = {t: [] for t in self.topics}
        pending = 0
        for topic, decoded in self.bag.iter_joint_states(self.topics):
            if decoded.rejected:
                self.malformed[topic] += len(decoded.rejected)
                self.first_problem.setdefault(topic, decoded.rejected[0][1])
            self.repeated_names[topic] += decoded.repeated_names
            self.messages[topic] += len(decoded)
            parts[topic].append(decoded)
            pending += len(decoded)
            if pending >= self.size:
                yield {t: self._ready(t, p) for t, p in parts.items()}
                parts = {t: [] for t in self.topics}
                pending = 0
        if pending:
            yield {t: self._ready(t, p) for t, p in parts.items()}
        self._warn()

    def _ready(self, topic, parts):
        """Return a topic's messages of one chunk, several publishers' partial ones merged."""
        if not parts:
            return None
        batch = concat_batches(parts)
        if self.prefix:
            batch = replace(batch, names=tuple(self.prefix + n for n in batch.names))
        absent = np.isnan(batch.position)
        merged = merge_partial_messages(batch) if absent.any() else batch
        counts = self.name_messages.get(topic)
        if merged is not batch:     # several publishers: a joint is in the messages naming it
            counts = self.name_messages.setdefault(topic, {})
            for name, n in zip(batch.names, len(batch) - np.count_nonzero(absent, axis=0)):
                counts[name] = counts.get(name, 0) + int(n)
        elif counts is not None:    # (a NaN value alone is a bad sample of a message naming it)
            for name in batch.names:
                counts[name] = counts.get(name, 0) + len(batch)
        batch = merged
        self._note_stamps(topic, batch.stamps_ns, batch.position)
        return batch

    def joint_messages(self, topic, name):
        """Messages of ``topic`` that carried ``name`` (all of them, unless partial)."""
        counts = self.name_messages.get(topic)
        return self.messages[topic] if counts is None else counts.get(name, 0)

    def _note_stamps(self, topic, stamps, position):
        """
        Count messages whose header stamp repeats the one before (a clock that stands).

        Those that repeat a stamp once, not in a run, with other positions than the
        message before are counted apart: two streams under one clock (a clock set back
        while recording), neither a message logged twice nor a clock that stands.
        """
        if not stamps.size:
            return
        last = self._last_stamp.get(topic)
        same = stamps[1:] == stamps[:-1]
        self.stamp_repeats[topic] += int(np.count_nonzero(same)) + int(
            last is not None and stamps[0] == last)
        if same.any():
            pair = same.copy()
            pair[1:] &= ~same[:-1]
            pair[:-1] &= ~same[1:]
            a, b = position[1:][pair], position[:-1][pair]
            self.stamp_clashes[topic] += int(np.count_nonzero(
                ((a != b) & ~(np.isnan(a) & np.isnan(b))).any(axis=1)))
        self.zero_stamps[topic] += int(np.count_nonzero(stamps == 0))
        self._last_stamp[topic] = stamps[-1]
        steps = np.diff(stamps)
        steps = steps[steps > 0]
        if steps.size >= 64:     # the period and the scatter of the steps about it
            self.step_scatter.setdefault(topic, []).append(step_scatter(steps))

    def _warn(self):
        """Say what the messages did wrong that the ingestion counts do not name."""
        for topic in self.topics:
            n, repeats = self.messages[topic], self.stamp_repeats[topic]
            if repeats >= 2 and repeats * 100 >= n:   # 1 % or more: a clock that stands
                zeros, clashes = self.zero_stamps[topic], self.stamp_clashes[topic]
                if not zeros and clashes * 2 >= repeats:
                    _say(self.bag, f'{repeats:,} of {n:,} JointState messages on {topic} repeat '
                         f'the header stamp of the message before, {clashes:,} with '
                         'other positions: two streams under one clock, as when the '
                         'clock is set back while recording; the first message of each '
                         'stamp is read, and the operating time the others cover is not '
                         'counted')
                else:
                    kind = 'all zero' if zeros == n else (
                        f'{zeros:,} of them zero' if zeros else
                        'a frozen clock, or each message logged twice')
                    _say(self.bag, f'{repeats:,} of {n:,} JointState messages on {topic} '
                         'carry the header stamp of the message before (stamps that do not '
                         f'advance: {kind}); their samples are dropped as duplicates')
            if self.repeated_names[topic]:
                _say(self.bag, f'{self.repeated_names[topic]:,} JointState entries on {topic} '
                     'named a joint their message had named before; those entries were dropped '
                     '(the first entry of a name counts)')


def _stamp_scatter(bag, topic, scatter, clock):
    """Say that a topic's stamps scatter about their period, and whether they were re-timed."""
    if clock.active:
        _say(bag, retimed_message(topic, clock))
        return
    if not scatter:
        return
    period, spread = np.median(np.array(scatter), axis=0).tolist()
    if period > 0 and spread >= CLOCK_SCATTER * period:
        _say(bag, f'the header stamps on {topic} scatter by {spread * 1e-6:.3g} ms about '
             f'their {period * 1e-6:.3g} ms period ({100 * spread / period:.0f} %): stamped '
             'when a message arrived rather than when the encoders were read? Speeds, the '
             "torque smoothing and the encoders' time offset rest on the stamps: each "
             "window's lost motion is noisier, and the wear can read low")


def merge_partial_messages(batch):
    """
    Merge the messages of a tick that several publishers sent, each with some entries.

    Two ``joint_state_broadcaster`` (or a link and a motor publisher) on one topic each
    send their own entries of a controller tick, with the same stamp or stamps a fraction
    of a period apart, in either order. Taken one by one, the second message of a tick
    repeated or preceded the first's stamp and was dropped with all its entries (a joint
    reported as "stamps do not advance"). Within the chunk the messages are put in stamp
    order where they are at most a period out of it, and neighbours that name disjoint
    entries less than half a period apart become one message (at the first's stamp; the
    entries of one message keep theirs together). Full messages are left alone: a stamp
    that repeats on them is a clock that stands, and said so.

    Parameters
    ----------
    batch : JointStateBatch
        One topic's messages of a chunk, NaN where a message did not name an entry.

    Returns
    -------
    JointStateBatch
        The merged messages.

    """
    t = batch.stamps_ns
    if len(batch) < 2:
        return batch
    steps = np.diff(t)
    # The tick period, from the entry named most often (the stamps of all messages
    # alternate between the publishers' offsets).
    present = np.isfinite(batch.position)
    ticks = np.diff(np.sort(t[present[:, np.argmax(present.sum(axis=0))]]))
    ticks = ticks[ticks > 0]
    if not ticks.size:
        return batch
    period = float(np.median(ticks))
    if (steps < 0).any() and -steps.min() <= period:
        order = np.argsort(t, kind='stable')
        batch, present = batch.take(order), present[order]
        t = batch.stamps_ns
    # Only messages within half a tick of the one before can merge: a stream whose
    # partial messages are bad values of full ones (NaN) has none, and costs no loop.
    close = np.flatnonzero(np.diff(t) < 0.5 * period) + 1
    if not close.size:
        return batch
    pos, vel, eff = (a.copy() for a in (batch.position, batch.velocity, batch.effort))
    keep = np.ones(len(batch), dtype=bool)
    for k in close.tolist():
        j = k - 1
        while not keep[j]:
            j -= 1
        if t[k] - t[j] < 0.5 * period and not (present[k] & present[j]).any():
            take = present[k]
            pos[j, take], vel[j, take], eff[j, take] = pos[k, take], vel[k, take], eff[k, take]
            present[j] |= take
            keep[k] = False
    if keep.all():
        return batch
    log = None if batch.log_time_ns is None else batch.log_time_ns[keep]
    return JointStateBatch(t[keep], batch.names, pos[keep], vel[keep], eff[keep],
                           batch.frame_id, log, ())


def _read_worker(chunks, queue):
    """Read and decode the chunks in a forked process; end with the counts and warnings."""
    try:
        for chunk in chunks:
            queue.put(chunk)
        queue.put((_END, {'messages': chunks.messages, 'malformed': chunks.malformed,
                          'name_messages': chunks.name_messages,
                          'first_problem': chunks.first_problem,
                          'step_scatter': chunks.step_scatter,
                          'warnings': list(chunks.bag.warnings)}))
    except BaseException as err:  # noqa: B902 - reported to the parent, which raises
        import traceback
        queue.put((_ERROR, f'{type(err).__name__}: {err}\n{traceback.format_exc()}'))


class _ForkedChunks:
    """
    The chunks of :class:`_Chunks`, read and decoded by a forked process.

    The reading process runs a few chunks ahead (a bounded queue); the chunks, their
    order and the counts are the same as when read here. Its read warnings are added to
    this process's bag at the end.
    """

    def __init__(self, chunks):
        import multiprocessing
        ctx = multiprocessing.get_context('fork')
        self.bag = chunks.bag
        self.messages = chunks.messages
        self.malformed = chunks.malformed
        self.name_messages = chunks.name_messages
        self.first_problem = chunks.first_problem
        self.step_scatter = chunks.step_scatter
        self._queue = ctx.Queue(maxsize=3)
        self._proc = ctx.Process(target=_read_worker, name='reducer-twin-reader',
                                 args=(chunks, self._queue), daemon=True)
        self._proc.start()

    def __iter__(self):
        while True:
            item = self._queue.get()
            if isinstance(item, dict):
                yield item
                continue
            kind, payload = item
            if kind == _ERROR:
                raise RuntimeError(f'the bag reading process failed: {payload}')
            self.messages = payload['messages']
            self.malformed = payload['malformed']
            self.name_messages = payload['name_messages']
            self.first_problem = payload['first_problem']
            self.step_scatter = payload['step_scatter']
            for warning in payload['warnings']:
                if warning not in self.bag.warnings:
                    self.bag.warnings.append(warning)
            break
        self._proc.join(timeout=10)

    joint_messages = _Chunks.joint_messages

    def terminate(self):
        """Stop the reading process (after an error)."""
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5)


def _columns(batch, names, fields=3):
    """
    Position, velocity and effort columns of the given names (NaN where absent).

    Each in Fortran order: a column is contiguous, and every later pass (cleaning,
    pairing, each joint's front) reads one joint's columns, not every entry of every
    message (as a message's entries are decoded side by side).
    """
    names = list(names)
    fields = (batch.position, batch.velocity, batch.effort)[:fields]
    if names == list(batch.names):
        return [np.asfortranarray(values) for values in fields]
    index = {n: k for k, n in enumerate(batch.names)}
    have = [j for j, name in enumerate(names) if name in index]
    take = [index[names[j]] for j in have]
    out = []
    for values in fields:
        if len(have) == len(names):
            out.append(values.T[take].T)
            continue
        cols = np.full((len(names), len(batch)), np.nan)
        cols[have] = values.T[take]
        out.append(cols.T)
    return out


# --------------------------------------------------------------------------- results


@dataclass
class JointResult:
    """
    What the analysis found for one joint.

    Attributes
    ----------
    name : str
        Joint name.
    messages : int
        JointState messages read that carry the joint.
    rejected : int
        Samples the ingestion rules dropped (non-finite, duplicate, out of order,
        unpaired, spikes) plus malformed messages skipped.
    counts : dict
        Count of every ingestion rule (as ``encoder_ingest`` reports them).
    features : numpy.ndarray
        ``te_features`` records, (windows, fields).
    wear, life : numpy.ndarray
        ``wear`` and ``remaining_life`` records, (windows + 1, fields) (first: start).
    levels : list of str
        Health level of each ``life`` record.
    te : numpy.ndarray
        Thinned TE samples (stamp_s, output_angle_rad, te_rad, torque_nm).
    truth : numpy.ndarray or None
        ``ground_truth`` records from the bag, if it has them.

    """

    name: str
    messages: int = 0
    rejected: int = 0
    counts: dict = field(default_factory=dict)
    features: np.ndarray = None
    wear: np.ndarray = None
    life: np.ndarray = None
    levels: list = field(default_factory=list)
    te: np.ndarray = None
    truth: np.ndarray = None
    windows: int = 0
    reason: str = None
    partial: str = None

    @property
    def observed(self):
        """Whether windows gave a lost motion the twin trusts (the estimate rests on data)."""
        return self.windows > 0 and self.reason is None

    def summary(self):
        """
        Return the ``--json`` fields of this joint (edge units; NaN as None).

        Returns
        -------
        dict
            ``wear_um``, ``wear_std_um``, ``rul_p10_h``, ``rul_p50_h``, ``rul_p90_h``,
            ``lost_motion_arcmin`` (None when not observed), ``messages``, ``rejected``,
            ``observed``, ``windows`` (windows with a lost motion), ``reason`` (why
            not observed, else None), ``partial`` (why an observed estimate stands as of
            a window well before the recording's end, else None) and ``pairing`` (how
            link and motor samples were paired, and why).

        """
        wear = dict(zip(WEAR_ESTIMATE.fields, self.wear[-1])) if self.wear is not None and \
            len(self.wear) else {}
        life = dict(zip(REMAINING_LIFE.fields, self.life[-1])) if self.life is not None and \
            len(self.life) else {}
        observed = self.observed
        out = estimate_numbers(wear, life, observed)
        out['messages'] = int(self.messages)
        out['rejected'] = int(self.rejected)
        out['observed'] = observed
        out['windows'] = int(self.windows)
        out['reason'] = None if observed else (self.reason or 'no usable window')
        out['partial'] = self.partial if observed else None
        out['pairing'] = self.counts.get('pairing')
        return out


@dataclass
class BagResult:
    """
    The analysis of one bag.

    Attributes
    ----------
    bag : pathlib.Path
        The input.
    out : pathlib.Path
        The derived bag directory.
    plan : JointPlan
        Topics and joints used.
    joints : dict of str to JointResult
        Per joint.
    messages : int
        JointState messages read.
    seconds : float
        Wall time of the analysis [s].
    aging_factor : float
        Aging factor applied.
    warnings : list of ReadWarning
        Problems met while reading.
    damaged : bool
        Whether reading stopped early or skipped data (truncated or corrupt files).
    states : dict of str to dict
        Per joint, where its estimator and life stages ended (``JointBack.state``): the
        ``initial_states`` of the reducer's next bag.

    """

    bag: Path
    out: Path
    plan: JointPlan
    joints: dict
    messages: int
    seconds: float
    aging_factor: float
    warnings: list
    damaged: bool
    states: dict = field(default_factory=dict)

    @property
    def messages_per_s(self):
        """Return the JointState messages analysed per second of wall time."""
        return self.messages / self.seconds if self.seconds > 0 else float('nan')

    def as_json(self):
        """Return ``{"joints": {name: {...}}, "messages_per_s": x}``."""
        rate = self.messages_per_s
        joints = {name: j.summary() for name, j in self.joints.items()}
        for name, reason in self.plan.not_analysed().items():
            joints[name] = {**estimate_numbers({}, {}, False), 'messages': 0, 'rejected': 0,
                            'observed': False, 'windows': 0, 'reason': reason,
                            'partial': None, 'pairing': None}
        return {'joints': joints,
                'messages_per_s': float(rate) if math.isfinite(rate) else None}


def is_damage(warning):
    """
    Tell whether a read warning means data were lost (truncation, corruption).

    Parameters
    ----------
    warning : ReadWarning
        A warning of the bag reader.

    Returns
    -------
    bool
        True when reading stopped early or skipped a damaged part.

    """
    text = warning.message
    # A file cut short (no footer), storage files missing, or fewer messages than the
    # metadata counts: messages were lost even where everything left is readable.
    return warning.offset is not None or any(
        key in text for key in ('reading stopped', 'corrupt', 'skipping that file',
                                'without a data end', 'no footer', 'do not exist',
                                'but the storage files hold', 'but no storage file holds'))


# --------------------------------------------------------------------------- the run


def _bag_aging_factor(bag, settings):
    if settings.aging_factor is not None:
        return settings.aging_factor
    text = bag.metadata.get(AGING_KEY)
    if text is None:
        truth = sorted(t for t in bag.topics
                       if t.startswith(f'/{TOPIC_NAMESPACE}/') and t.endswith('/ground_truth'))
        if truth:
            # A simulator's recording ages its reducers faster than its clock; the factor
            # lives in metadata.yaml's custom_data, which a bare storage file has lost.
            _say(bag, f'the recording carries the simulated truth {truth[0]} but '
                 f'no {AGING_KEY} in its metadata: aging factor 1 assumed (operating seconds '
                 'per stream second); if it was simulated faster, remaining life and wear '
                 'rates are off by that factor: set twin.aging_factor with --config')
        return 1.0
    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not (math.isfinite(value) and 0.0 < value <= 1e9):
        raise InvalidInput(f'{bag.path}: custom_data {AGING_KEY} = {text!r} is not an aging '
                           'factor in (0, 1e9] (operating seconds per stream second); set '
                           'twin.aging_factor with --config')
    return value


def _motor_scale(settings, joint, angles=None, direction=1.0):
    if (angles or settings.motor_angles) == 'output':
        return direction * total_ratio(settings.params_of(joint).geometry)
    return direction


GAP_SHARE = 0.05
"""Share of a joint's stream in holes without samples from which the time lost is said."""

PARTIAL_SHARE = 0.2
"""Share of a joint's stream after its last lost motion from which the estimate is partial."""

PARTIAL_WINDOWS = 3
"""Windows of stream after the last lost motion below which the estimate is taken as current."""

COARSE_STEP_RAD = math.radians(0.5 / 60.0)
"""
Encoder step [rad at the output] beyond which a joint's lost motion is said to be uncertain.

Half an arcminute: a reducer's lost motion is 0.4-3 arcmin. A 16-bit link encoder steps by
0.33 arcmin, a 12-bit one by 5.3; motor encoders' steps are divided by the ratio.
"""

MIN_DETECT_TRAVEL_RAD = 0.05
"""Link travel [rad] a chunk must show before its motor angles are classified."""


def motor_travel_ratio(link, motor):
    """
    Motor travel over link travel (total variation) of one joint in one chunk.

    About the reduction ratio for raw motor angles and about 1 for angles
    already divided by it; NaN when the link moved less than
    :data:`MIN_DETECT_TRAVEL_RAD` (nothing to tell them apart by).

    Parameters
    ----------
    link, motor : ndarray
        Positions of the link and motor entries [rad] (NaN where absent).

    Returns
    -------
    float
        The ratio of travels.

    """
    def travel(x):
        x = x[np.isfinite(x)]
        return float(np.abs(np.diff(x)).sum()) if x.size > 1 else 0.0
    t_link, t_motor = travel(link), travel(motor)
    return t_motor / t_link if t_link >= MIN_DETECT_TRAVEL_RAD else math.nan


def motor_direction(t_link, link, t_motor, motor):
    """
    Whether the motor encoder counts with the link (+1) or against it (-1), in one chunk.

    A gear stage or the encoder's mounting may reverse the motor's sense (ros2_control
    then carries a negative reduction): the motor's steps, taken at the link's stamps,
    then correlate negatively with the link's. NaN when the link moved less than
    :data:`MIN_DETECT_TRAVEL_RAD` or the two do not overlap in time.

    Parameters
    ----------
    t_link, link, t_motor, motor : ndarray
        Stamps [ns] and positions [rad] of the link and motor entries (NaN where absent).

    Returns
    -------
    float
        +1, -1 or NaN.

    """
    lk, mk = np.isfinite(link), np.isfinite(motor)
    t_l, x_l, t_m, x_m = t_link[lk], link[lk], t_motor[mk], motor[mk]
    if x_l.size < 2 or x_m.size < 2 or np.abs(np.diff(x_l)).sum() < MIN_DETECT_TRAVEL_RAD:
        return math.nan
    inside = (t_l >= t_m[0]) & (t_l <= t_m[-1])
    if np.count_nonzero(inside) < 2:
        return math.nan
    order = np.argsort(t_m, kind='stable')
    # Single-turn encoders wrap at +-pi: each side unwrapped before its steps are taken.
    steps_l = np.diff(np.unwrap(x_l)[inside])
    steps_m = np.diff(np.interp(t_l[inside], t_m[order], np.unwrap(x_m[order])))
    product = float(steps_l @ steps_m)
    return math.copysign(1.0, product) if product else math.nan


class _Output:
    """Channels and writes of the derived bag."""

    def __init__(self, writer, joints, truth_topics, diagnostics=None):
        self.writer = writer
        self.channels = {}
        for joint in joints:
            for suffix, qos in (('te', DEFAULT_QOS), ('te_features', DEFAULT_QOS),
                                ('wear', LATEST_QOS), ('remaining_life', LATEST_QOS)):
                self.channels[joint, suffix] = writer.add_topic(joint_topic(joint, suffix),
                                                                MULTIARRAY, qos)
            if joint in truth_topics:
                self.channels[joint, 'ground_truth'] = writer.add_topic(
                    truth_topics[joint], MULTIARRAY, LATEST_QOS)
        self.diagnostics = diagnostics if diagnostics is not None else writer.add_topic(
            '/diagnostics', DIAGNOSTICS, DEFAULT_QOS)

    def arrays(self, joint, suffix, layout, log_ns, values):
        values = np.asarray(values, dtype=np.float64)
        if values.shape[0]:
            self.writer.write_batch(self.channels[joint, suffix], np.asarray(log_ns, np.int64),
                                    *encode_multiarrays(layout, values))

    def raw(self, channel, log_ns, payloads):
        if not payloads:
            return
        bounds = np.zeros(len(payloads) + 1, np.int64)
        np.cumsum([len(p) for p in payloads], out=bounds[1:])
        self.writer.write_batch(channel, np.asarray(log_ns, np.int64), b''.join(payloads),
                                bounds)


class _Run:
    """The analysis of one opened bag."""

    def __init__(self, bag, plan, settings, writer, backs, aging, chunks, diagnostics=None):
        self.bag = bag
        self.chunks = chunks
        self.plan = plan
        self.settings = settings
        self.backs = backs
        self.aging = aging
        truth = {}
        for joint in plan.joints:
            topic = joint_topic(joint, 'ground_truth')
            if bag.topics.get(topic, (None,))[0] == MULTIARRAY:
                truth[joint] = topic
        self.truth_topics = truth
        self.out = _Output(writer, plan.joints, truth, diagnostics)
        count = bag.topics[plan.link_topic].count
        keep = max(1, count // REPORT_TE_POINTS)
        self.fronts = {j: JointFront(j, settings, aging, _motor_scale(settings, j), keep)
                       for j in plan.joints}
        # With a worker, some joints' fronts run there (their paired samples go through
        # the pipe): the two processes share the window analysis.
        remote = plan.joints[1::WORKER_FRONT_EVERY] if isinstance(backs, WorkerBacks) else ()
        self.remote = set(remote)
        for joint in remote:
            backs.add_front(joint, settings, aging, _motor_scale(settings, joint), keep)
        # (column index, joint), the worker's first: it starts on a chunk while this
        # process analyses its own joints.
        self.order = sorted(enumerate(plan.joints), key=lambda kj: kj[1] not in self.remote)
        self.results = {j: JointResult(j) for j in plan.joints}
        self.features = {j: [] for j in plan.joints}
        self.back_out = {j: [] for j in plan.joints}
        self.started = False
        self.messages_read = 0
        self.angles = {}     # joint -> 'raw' / 'output', as the data show them
        self.span = {}       # joint -> [first, last] stamp of its paired samples [ns]
        for joint, front in self.fronts.items():
            front.effort_topic = plan.link_topic if settings.effort_source != 'motor' or \
                not plan.motor_topic else plan.motor_topic
            if settings.effort_source == 'auto' and plan.motor_topic:
                front.effort_topic = f'{plan.link_topic} or {plan.motor_topic}'

    def _resolve_angles(self, link, motor, link_names):
        """
        Tell raw from output motor angles by their travel against the link, per joint.

        Sets each front's motor scale and motor effort scale once its joint moved.

        Raises
        ------
        InvalidInput
            If ``twin.motor_angles`` in the configuration contradicts the data.

        """
        settings, plan = self.settings, self.plan
        for k, joint in enumerate(plan.joints):
            if joint in self.angles:
                continue
            ratio = self.fronts[joint].ratio
            if plan.motor_topic is None:
                if link is None or not len(link):
                    continue
                pos = _columns(link, link_names[2 * k:2 * k + 2], fields=1)[0]
                x_link, x_motor, t_motor = pos[:, 0], pos[:, 1], link.stamps_ns
            else:
                if link is None or motor is None or not len(link) or not len(motor):
                    continue
                x_link = _columns(link, [joint], fields=1)[0][:, 0]
                x_motor = _columns(motor, [plan.motor_names[k]], fields=1)[0][:, 0]
                t_motor = motor.stamps_ns
            r = motor_travel_ratio(x_link, x_motor)
            sense = motor_direction(link.stamps_ns, x_link, t_motor, x_motor)
            if not (math.isfinite(r) and math.isfinite(sense)):
                continue
            self._against_config('motor_direction', int(sense), joint,
                                 f'step {"with" if sense > 0 else "against"} the link')
            if sense < 0 and settings.motor_direction == 'auto':   # never silent: said
                _say(self.bag, f'the motor encoder of {joint} counts against '
                     'the link (a negative reduction): its angles are taken reversed')
            found = 'raw' if r > math.sqrt(ratio) else 'output'
            self._note_resolution(joint, x_link, x_motor / (ratio if found == 'raw' else 1.0))
            self._against_config('motor_angles', found, joint,
                                 f'move {r:.3g} times the link (raw angles move about '
                                 f'{ratio:g} times, output angles about 1)')
            self._set_angles(joint, found, sense)

    def _note_resolution(self, joint, link, motor):
        """Say when an encoder's steps [rad at the output] are too coarse for the lost motion."""
        for side, x in (('link', link), ('motor', motor)):
            steps = np.abs(np.diff(x[np.isfinite(x)]))
            steps = steps[steps > 0]
            if steps.size < 100:
                continue
            step = float(np.percentile(steps, 0.1))     # the smallest move it reports
            if step > COARSE_STEP_RAD:
                _say(self.bag, f'the {side} encoder of {joint} moves in steps '
                     f'of {math.degrees(step) * 60:.2g} arcmin at the output, coarser than the '
                     f'{math.degrees(COARSE_STEP_RAD) * 60:g} arcmin the lost motion is read '
                     'to: its lost motion and wear are uncertain by about that much')

    def _against_config(self, key, found, joint, seen):
        """Refuse a ``twin.<key>`` of ``--config`` that the data of ``joint`` contradict."""
        configured = getattr(self.settings, key)
        if configured in ('auto', found):
            return
        where = self.plan.motor_topic or self.plan.link_topic
        raise InvalidInput(f'{self.bag.path}: twin.{key} is {configured!r} in --config, but '
                           f'the motor angles of {joint} on {where} {seen}: {key} {found!r}')

    def _set_angles(self, joint, angles, direction=1.0):
        front = self.fronts[joint]
        self.angles[joint] = angles
        front.motor_scale = _motor_scale(self.settings, joint, angles, direction)
        front.pairer.motor_scale = front.motor_scale
        # A motor that counts against the link reports its torque in its own sense too.
        front.effort_scale = direction * motor_effort_scale(self.settings.motor_effort_units,
                                                            angles, front.ratio)
        front.pairer.motor_effort_scale = front.effort_scale

    def run(self):
        plan = self.plan
        chunks = self.chunks
        link_clean, motor_clean = stream_cleaners(self.settings.ingest, bool(plan.motor_topic))
        link_names = [x for j, m in zip(plan.joints, plan.motor_names) for x in (j, m)] \
            if not plan.motor_topic else list(plan.joints)
        for chunk in chunks:
            link = chunk[plan.link_topic]
            if len(self.angles) < len(plan.joints):
                self._resolve_angles(link, chunk[plan.motor_topic] if plan.motor_topic else None,
                                     link_names)
            if not self.started and link is not None and len(link):
                self._start(int(link.stamps_ns[0]))
            if plan.motor_topic is None:
                self._combined(link_clean, link, link_names)
            else:
                self._split(link_clean, motor_clean, link, chunk[plan.motor_topic])
            self._drain(self.backs.poll())
            self.out.writer.start_writeback()   # the final fsync then has little to wait for
        for _, joint in self.order:
            front = self.fronts[joint]
            if plan.motor_topic is not None:
                pairs = front.pairer.pop(final=True)
                self._feed(joint, pairs.t_ns, pairs.motor_angle, pairs.link_angle, pairs.effort,
                           pairs.link_velocity)
            if joint in self.remote:
                self.backs.submit(joint, 'flush', None)
            else:
                self._front_output(joint, front.outputs(front.flush(), None, final=True))
        self._copy_truth()     # while the estimator worker finishes
        self._drain(self.backs.finish())
        self._finish(chunks, link_clean, motor_clean)
        return self.results

    def _start(self, stamp_ns):
        self.started = True
        for joint in self.plan.joints:
            self.backs.submit(joint, 'start', stamp_ns * 1e-9)

    def _combined(self, cleaner, link, names):
        if link is None or not len(link):
            return
        pos, vel, eff = _columns(link, names)
        clean = cleaner.process(link.stamps_ns, pos, vel, eff)
        for k, joint in self.order:
            front = self.fronts[joint]
            cols, unpaired = pair_columns(clean, 2 * k, 2 * k + 1, front.motor_scale,
                                          self.settings.effort_source, front.effort_scale,
                                          self.settings.effort_scale)
            front.unpaired += unpaired
            self._feed(joint, *cols)

    def _split(self, link_clean, motor_clean, link, motor):
        clean_link = clean_motor = None
        if link is not None and len(link):
            clean_link = link_clean.process(link.stamps_ns, *_columns(link, self.plan.joints))
        if motor is not None and len(motor):
            clean_motor = motor_clean.process(motor.stamps_ns,
                                              *_columns(motor, self.plan.motor_names))
        for k, joint in self.order:
            front = self.fronts[joint]
            if clean_link is not None:
                front.pairer.add_link(clean_link.column(k))
            if clean_motor is not None:
                front.pairer.add_motor(clean_motor.column(k))
            pairs = front.pairer.pop()
            self._feed(joint, pairs.t_ns, pairs.motor_angle, pairs.link_angle, pairs.effort,
                       pairs.link_velocity)

    def _feed(self, joint, t_ns, motor, link, effort, velocity):
        if t_ns.size == 0:
            return
        samples = (np.asarray(t_ns, np.int64), motor, link, effort, velocity)
        span = self.span.setdefault(joint, [int(t_ns[0]), int(t_ns[-1])])
        span[1] = max(span[1], int(t_ns[-1]))
        if joint in self.remote:
            self.backs.submit(joint, 'feed', samples)
            return
        front = self.fronts[joint]
        self._front_output(joint, front.outputs(*front.feed(*samples)))

    def _front_output(self, joint, out):
        """Write a front's TE batches and window records; its windows go to the back."""
        for log_ns, values in out.te:
            self.out.arrays(joint, 'te', TE_BATCH, log_ns, values)
        if not out.records:
            return
        self.features[joint].append(out.values)
        self.out.arrays(joint, 'te_features', TE_FEATURES, out.stamps_ns, out.values)
        if joint not in self.remote:   # a front in the worker hands them over there
            self.backs.submit(joint, 'windows', out.records)

    def _drain(self, done):
        for item in done:
            if item[0] == FRONT_OUTPUT:
                _, joint, out, state = item
                self._front_output(joint, out)
                if state is not None:   # its last feed: the counts and windows come home
                    self.fronts[joint].take_feed_side(state)
                continue
            joint, outputs = item
            self.back_out[joint] += outputs
            log_ns = [o['log_ns'] for o in outputs]
            self.out.arrays(joint, 'wear', WEAR_ESTIMATE, log_ns, [o['wear'] for o in outputs])
            self.out.arrays(joint, 'remaining_life', REMAINING_LIFE, log_ns,
                            [o['life'] for o in outputs])
            self.out.raw(self.out.diagnostics, log_ns, [o['diagnostics'] for o in outputs])

    def _copy_truth(self):
        topics = {topic: joint for joint, topic in self.truth_topics.items()}
        if not topics:
            return
        rows = {joint: [] for joint in self.truth_topics}
        for topic, raw in self.bag.iter_raw(list(topics)):
            joint = topics[topic]
            payloads = [raw.payload(i) for i in range(len(raw))]
            self.out.raw(self.out.channels[joint, 'ground_truth'], raw.log_time_ns, payloads)
            for p in payloads:
                try:
                    rows[joint].append(decode_multiarray(p).values(GROUND_TRUTH))
                except InvalidInput:
                    continue
        for joint, values in rows.items():
            self.results[joint].truth = np.array(values) if values else None

    def _not_observed(self, front, counts, sides):
        """Why a joint gave no lost motion it trusts, naming the topic; None when it did."""
        if front.analyzer.windows_read and front.analyzer.effort_fault is None:
            return None
        plan = self.plan
        for side, _, _ in sides:
            topic = plan.motor_topic if side == 'motor' else plan.link_topic
            dup = counts.get(f'{side}_duplicate', 0)
            if dup and dup >= 0.5 * max(front.samples + dup, 1):
                return (f'stamps do not advance on {topic}: {dup} samples repeat an earlier '
                        'stamp (frozen clock or all-zero header stamps)')
        spikes = counts.get('spike', 0)
        if spikes and spikes >= front.samples:
            return (f'{spikes} of {spikes + front.samples} motor/link sample pairs were '
                    'dropped as spikes of the transmission error: the encoders jump against '
                    'each other (positions in degrees or counts, a wrong reduction ratio or '
                    'motor_angles, or faulty encoders)')
        if front.samples == 0:
            return (f'no motor/link sample pairs on {plan.link_topic}'
                    + (f' and {plan.motor_topic}' if plan.motor_topic else '')
                    + f' ({counts.get("unpaired", 0)} unpaired)')
        return front.analyzer.not_observed_reason(front.effort_topic)

    def _note_gaps(self, joint, front):
        """Say how much of a joint's stream fell in holes, not counted as operation."""
        a = front.analyzer
        if joint not in self.span or not a.gaps:
            return
        first, last = (t * 1e-9 for t in self.span[joint])
        if a.gap_time_s < GAP_SHARE * max(last - first, 1e-9):
            return
        _say(self.bag, f'{joint}: {a.gap_time_s:,.1f} s of its '
             f'{last - first:,.1f} s stream ({100 * a.gap_time_s / (last - first):.0f} %) fall '
             f'in {a.gaps:,} hole{"s" if a.gaps > 1 else ""} longer than '
             f'{self.settings.max_gap_s:g} s without samples '
             '(lost messages, or a pause in publishing): that time is not counted as '
             'operation; if the robot ran meanwhile, its wear rate per operating hour reads '
             'high and its remaining life short by up to that share')

    def _partial(self, joint, front):
        """
        Say when an observed joint's lost motion stopped well before its stream did.

        The estimate then stands as of its last observed window (without effort the
        operating time after it is not even counted): never presented as the end's
        without a word.
        """
        a = front.analyzer
        if not a.windows_observed or joint not in self.span:
            return None
        first, last = (t * 1e-9 for t in self.span[joint])
        start = min(s[0] for s in self.span.values()) * 1e-9
        end = max(s[1] for s in self.span.values()) * 1e-9
        if end - last >= max(PARTIAL_SHARE * (end - start),
                             PARTIAL_WINDOWS * self.settings.window_s):
            # Its entries went missing while the others' went on: renamed, or no longer
            # published (nothing about its reducer after that is in the recording).
            return (f'its samples stop {end - last:.1f} s before the recording ends (after '
                    f'{last - start:.1f} s of {end - start:.1f} s): the later messages do not '
                    f'carry {joint} with its motor entry (renamed, or no longer published); '
                    'the wear and remaining life stand as of its last observed window')
        stale = a.stale_reason(max(PARTIAL_SHARE * (last - first),
                                   PARTIAL_WINDOWS * self.settings.window_s),
                               front.effort_topic)
        if stale is not None:
            gap, why, _ = stale
            return (f'no lost motion in the last {100 * gap / (last - first):.0f} % of the '
                    f'stream (after {a.last_observed_t - first:.1f} s of {last - first:.1f} '
                    f's): {why}; the wear and remaining life stand as of the last observed '
                    'window')
        if a.samples_without_effort >= PARTIAL_SHARE * max(a.samples_seen, 1):
            return (f'no effort on {front.effort_topic} in {a.samples_without_effort} of '
                    f'{a.samples_seen} samples: their operating time is not counted in the '
                    'wear')
        return None

    def _finish(self, chunks, link_clean, motor_clean):
        plan = self.plan
        self.messages_read = sum(chunks.messages.values())
        if self.settings.motor_angles == 'auto':
            unknown = [j for j in plan.joints if j not in self.angles]
            if unknown:     # never a silent guess: say what was assumed and how to say it
                _say(self.bag, f'motor angles of {", ".join(unknown)} could not '
                     f'be told raw from output (the link moved less than '
                     f'{MIN_DETECT_TRAVEL_RAD:g} rad in a chunk): taken as raw; set '
                     'twin.motor_angles in --config')
        for topic, cleaner in ((plan.link_topic, link_clean), (plan.motor_topic, motor_clean)):
            if cleaner is not None:
                _stamp_scatter(self.bag, topic, chunks.step_scatter.get(topic), cleaner.clock)
            late = cleaner.counts['out_of_order'] if cleaner is not None else 0
            if late and late * 100 >= chunks.messages[topic]:   # a loss that size is said
                _say(self.bag, f'{late:,} of {chunks.messages[topic]:,} '
                     f'JointState messages on {topic} were logged after a later stamp (out of '
                     'stamp order) and were dropped, as encoder_ingest drops them live')
        for topic, count in chunks.malformed.items():
            if count:   # as Bag.read_joint_states reports them
                _say(self.bag, f'{count} malformed JointState message(s) on '
                     f'{topic} skipped; the first: {chunks.first_problem.get(topic)}')
        statuses = []
        last_ns = 0
        for k, (joint, front) in enumerate(self.fronts.items()):
            res = self.results[joint]
            counts = {}
            # As encoder_ingest counts them: row rules of the whole stream, value rules of
            # this joint's columns.
            sides = (('stream', link_clean, [2 * k, 2 * k + 1]),) if motor_clean is None else (
                ('link', link_clean, [k]), ('motor', motor_clean, [k]))
            for side, cleaner, columns in sides:
                for reason, count in cleaner.counts_for(columns).items():
                    counts[f'{side}_{reason}'] = int(count)
                counts[f'{side}_missing'] = int(cleaner.missing)
                counts[f'{side}_retimed'] = int(cleaner.clock.retimed)
            counts['unpaired'] = int(front.unpaired + front.pairer.unpaired)
            counts.update(front.pairer.ticks.facts() if motor_clean is not None else
                          {'pairing': SHARED_STAMPS, 'tick_paired': 0})
            counts.update({k: int(v) for k, v in front.spikes.counts.items()})
            counts['published'] = int(front.samples)
            malformed = sum(chunks.malformed.values())
            counts['malformed_messages'] = int(malformed)
            res.counts = counts
            res.messages = chunks.joint_messages(plan.link_topic, joint) + (
                chunks.joint_messages(plan.motor_topic, plan.motor_names[k])
                if plan.motor_topic else 0)
            res.rejected = malformed + counts['unpaired'] + counts['spike'] + sum(
                counts.get(f'{side}_{r}', 0) for side, _, _ in sides for r in _REPAIRED
                if r != 'clock_jump')
            outputs = self.back_out[joint]
            res.wear = np.array([o['wear'] for o in outputs])
            res.life = np.array([o['life'] for o in outputs])
            res.levels = [o['level'] for o in outputs]
            feats = self.features[joint]
            res.features = np.concatenate(feats) if feats else np.zeros(
                (0, len(TE_FEATURES.fields)))
            res.te = te_values(np.concatenate(front.report_te)[None])[0] \
                if front.report_te else np.zeros((0, 4))
            if len(res.wear):
                last_ns = max(last_ns, stamp_ns(res.wear[-1][0]))
            res.windows = int(front.analyzer.windows_observed)
            res.reason = self._not_observed(front, counts, sides)
            res.partial = self._partial(joint, front)
            self._note_gaps(joint, front)
            bad = sum(v for k, v in counts.items()
                      if k not in ('published', 'step', *PAIRING_FACTS)
                      and not k.endswith('_wrap'))
            statuses.append(Status('OK' if bad == 0 else 'WARN',
                                   f'reducer_twin: {joint} encoder ingest', 'streams clean'
                                   if bad == 0 else f'{bad} samples dropped or repaired',
                                   joint, counts))
        if statuses and last_ns:
            self.out.raw(self.out.diagnostics, [last_ns],
                         [encode_diagnostic_array(last_ns, statuses)])


def analyze_bag(path, out_dir, settings=None, overwrite=False, stage_worker=False,
                reader_process=False, initial_states=None):
    """
    Analyse one rosbag2 recording and write the derived bag.

    Parameters
    ----------
    path : str or os.PathLike
        Bag directory, ``.mcap`` or ``.db3`` file.
    out_dir : str or os.PathLike
        Derived bag directory to create (empty or missing unless ``overwrite``).
    settings : AnalysisSettings, optional
        Topics, joints, aging factor, windows, thresholds.
    overwrite : bool
        Replace a bag already in ``out_dir``.
    stage_worker : bool or WorkerBacks
        Run the estimator and life stages in a forked worker process: a new one (True)
        or the one given (forked early by the caller, reusable for the next bag).
    reader_process : bool
        Read and decode the bag in a forked process, a few chunks ahead.
    initial_states : dict of str to dict, optional
        Per joint, the state an earlier bag of the same reducer ended in
        (``BagResult.states``): the estimator continues from it instead of a new reducer.

    Returns
    -------
    BagResult
        Per-joint results, counts, warnings and timing.

    Raises
    ------
    BagError
        If the bag cannot be read, has no JointState topic or no encoder pairs, or the
        output cannot be written.
    InvalidInput
        If the bag's aging factor is unusable.

    """
    settings = settings or AnalysisSettings()
    refuse_inside_inputs([('--out', out_dir)], [('input bag', path)])
    start = time.perf_counter()
    backs = chunks = None
    try:
        with open_bag(path, interfaces=settings.interfaces,
                      motor_suffix=settings.motor_suffix) as bag:
            _check_configured_topics(bag, settings)
            plans = robot_plans(bag, plan_joints(bag, settings), settings)
            if len(plans) > 1:      # every robot of the recording is analysed, one by one
                plans[0] = replace(plans[0], others=())
            plan = plans[0]
            every = [j for p in plans for j in p.joints]
            aging = _bag_aging_factor(bag, settings)
            if isinstance(stage_worker, WorkerBacks):
                backs = stage_worker
            else:  # forked only now: a bag that cannot be analysed costs no process
                backs = WorkerBacks() if stage_worker else LocalBacks()
            backs.configure({j: settings.params_of(j) for j in every}, settings.life,
                            initial_states)
            custom = {'reducer_twin.source': str(Path(path).resolve()),
                      AGING_KEY: repr(float(aging)),
                      'reducer_twin.joints': ','.join(every)}
            needed = DERIVED_BYTES_PER_SAMPLE * sum(
                len(p.joints) * bag.topics[p.link_topic].count for p in plans)
            joints, messages, diagnostics = {}, 0, None
            with BagDirWriter(out_dir, compression=settings.compression, custom_data=custom,
                              overwrite=overwrite, needed=needed,
                              what='derived bag') as writer:
                for robot in plans:
                    topics = [robot.link_topic] + ([robot.motor_topic] if robot.motor_topic
                                                   else [])
                    chunks = _Chunks(bag, topics, CHUNK_MESSAGES, robot.prefix)
                    if reader_process:   # forked before the writer opens its file and threads
                        chunks = _ForkedChunks(chunks)
                    run = _Run(bag, robot, settings, writer, backs, aging, chunks, diagnostics)
                    diagnostics = run.out.diagnostics
                    joints.update(run.run())
                    messages += run.messages_read
            warnings = list(bag.warnings)
    except BaseException:
        if isinstance(backs, WorkerBacks):
            backs.terminate()   # it may hold work of this bag: never reused
        if isinstance(chunks, _ForkedChunks):
            chunks.terminate()
        raise
    if backs is not stage_worker:
        backs.close()
    return BagResult(Path(path), Path(out_dir), plan, joints, messages,
                     time.perf_counter() - start, aging, warnings,
                     any(is_damage(w) for w in warnings), dict(backs.states))
