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

Until the encoder time offset is learnt (or for ``joint_twin.CALIBRATION_WINDOWS``
windows) the window analysis takes the stream in 0.1 s pieces
(``joint_twin.CALIBRATION_PIECE_S``), as live. Differences from a live run, on purpose: TE
messages are longer; after the calibration the stream goes in large chunks, so a calibration
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

What the analysis says of each joint (why it is not observed or observed in part, how its
inputs were read, what carried over from its last bag) is worded by :mod:`.joint_words`.
"""

from dataclasses import replace
from datetime import datetime, timezone
import math
from pathlib import Path
import time

import numpy as np
from reducer_twin.analysis import joint_words
from reducer_twin.analysis.joints import check_configured_topics, late_joints, plan_joints
from reducer_twin.analysis.joints import robot_plans, say_unpaired
from reducer_twin.analysis.reading import BagChunks, ForkedBagChunks, joint_columns
from reducer_twin.analysis.reading import stamp_scatter, warn
from reducer_twin.analysis.results import BagResult, is_damage, JointResult
from reducer_twin.analysis.settings import AnalysisSettings
from reducer_twin.analysis.simulate import AGING_KEY, LATEST_QOS
from reducer_twin.analysis.stages import FRONT_OUTPUT, JointFront, LocalBacks, stamp_ns
from reducer_twin.analysis.stages import te_values, WorkerBacks
from reducer_twin.core.effort_source import motor_effort_scale, motor_torque_seen
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.ingest import stream_cleaners
from reducer_twin.core.joint_twin import check_topic_tokens, joint_topic, topic_token
from reducer_twin.core.joint_twin import TOPIC_NAMESPACE
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.observability import EFFORT_PLAUSIBLE_RATED
from reducer_twin.core.pairing import pair_columns
from reducer_twin.core.tick_pairing import PAIRING_FACTS, SHARED_STAMPS
from reducer_twin.core.travel_ratio import MIN_DETECT_TRAVEL_RAD, motor_angle_form
from reducer_twin.core.travel_ratio import motor_direction, motor_travel_ratio
from reducer_twin.io.bag import BagDirWriter, open_bag
from reducer_twin.io.outputs import refuse_inside_inputs
from reducer_twin.io.rosbag2_metadata import DEFAULT_QOS
from reducer_twin.msg_adapters.diagnostic_cdr import encode_diagnostic_array
from reducer_twin.msg_adapters.diagnostic_cdr import MSGTYPE as DIAGNOSTICS
from reducer_twin.msg_adapters.diagnostic_cdr import Status
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
            warn(bag, f'the recording carries the simulated truth {truth[0]} but '
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


def stamps_before_epoch(bag, topic, earliest_ns):
    """
    Return the error of header stamps before 1970-01-01 (the derived bag is logged at them).

    Parameters
    ----------
    bag : Bag
        The recording (its path is named).
    topic : str
        The JointState topic whose stamps the derived messages carry.
    earliest_ns : int
        The earliest stamp seen [ns since 1970-01-01 UTC], < 0.

    Returns
    -------
    InvalidInput
        One line naming the bag, the topic, the stamp and the allowed range.

    """
    when = datetime.fromtimestamp(earliest_ns // 1_000_000_000, timezone.utc)
    return InvalidInput(
        f'{bag.path}: the header stamps on {topic} go back to {earliest_ns * 1e-9:.3f} s '
        f'({when:%Y-%m-%d %H:%M:%S} UTC), before 1970; expected stamps >= 0 s (1970-01-01 '
        '00:00:00 UTC or later): the derived bag is logged at the stamps, and a log time '
        'cannot be negative')


class _Output:
    """Channels and writes of the derived bag (logged at the stamps of ``stamps_of``)."""

    def __init__(self, writer, joints, truth_topics, diagnostics=None, stamps_of=None):
        self.writer = writer
        self.stamps_of = stamps_of      # (bag, topic) whose header stamps the log times are
        self.channels = {}
        check_topic_tokens(joints)
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
            self.writer.write_batch(self.channels[joint, suffix], self._stamped(log_ns),
                                    *encode_multiarrays(layout, values))

    def raw(self, channel, log_ns, payloads, stamped=True):
        """Write serialised messages, logged at header stamps unless not ``stamped``."""
        if not payloads:
            return
        bounds = np.zeros(len(payloads) + 1, np.int64)
        np.cumsum([len(p) for p in payloads], out=bounds[1:])
        log_ns = self._stamped(log_ns) if stamped else np.asarray(log_ns, np.int64)
        self.writer.write_batch(channel, log_ns, b''.join(payloads), bounds)

    def _stamped(self, log_ns):
        """Log times taken from header stamps; stamps before 1970 are refused by name."""
        log_ns = np.asarray(log_ns, np.int64)
        if log_ns.size and self.stamps_of is not None and log_ns.min() < 0:
            raise stamps_before_epoch(*self.stamps_of, int(log_ns.min()))
        return log_ns


class _EntryCounts:
    """
    Per topic of a plan, the messages that named each entry, and every name met.

    An entry a message does not name (a joint whose broadcaster starts late or stops,
    a second publisher's joints) is NaN in its row, as a bad value is: the counts tell
    the two apart (``JointStateBatch.named``), for ``messages`` and ``rejected``.
    """

    def __init__(self, plan):
        if plan.motor_topic is None:
            self.entries = {plan.link_topic: [x for j, m in zip(plan.joints, plan.motor_names)
                                              for x in (j, m)]}
        else:
            self.entries = {plan.link_topic: list(plan.joints),
                            plan.motor_topic: list(plan.motor_names)}
        self.rows = dict.fromkeys(self.entries, 0)
        self.named = {t: np.zeros(len(e), np.int64) for t, e in self.entries.items()}
        self.finite = {t: np.zeros(len(e), np.int64) for t, e in self.entries.items()}
        self.seen = {t: {} for t in self.entries}     # every name met, in order
        self.effort_faults = {}     # topic -> (messages, first problem)
        self._columns = {}          # topic -> (names of the last batch, their columns)

    def add(self, topic, batch):
        """Count one chunk's messages of a topic."""
        if batch is None or not len(batch):
            return
        n = len(batch)
        self.rows[topic] += n
        last = self._columns.get(topic)
        if last is None or last[0] is not batch.names:
            index = {name: k for k, name in enumerate(batch.names)}
            cols = np.array([index.get(e, -1) for e in self.entries[topic]], np.int64)
            last = self._columns[topic] = (batch.names, cols, (cols >= 0).all())
            self.seen[topic].update(dict.fromkeys(batch.names))
        _, cols, whole = last
        if batch.named is None:
            # Merged messages of several publishers carry no count: there an entry is
            # taken as named where it has a value (as the reader merged them).
            finite = np.count_nonzero(np.isfinite(batch.position), axis=0)
            self.finite[topic] += np.where(cols >= 0, finite[cols], 0)
            if whole:
                self.named[topic] += n
            else:
                self.named[topic] += np.where(cols >= 0, n, 0)
        else:
            named = np.where(cols >= 0, batch.named[cols], 0)
            self.named[topic] += named
            self.finite[topic] += named
        count, first = batch.effort_faults
        if count:
            before = self.effort_faults.get(topic, (0, first))
            self.effort_faults[topic] = (before[0] + count, before[1])

    def of(self, topic, columns, chunks):
        """
        Return the messages that named, and the rows that lacked, each of some entries.

        Where several publishers' messages were merged (:func:`.reading.
        merge_partial_messages`: the reader notes the topic), an entry of a merged
        message is taken as named where it has a value.
        """
        counts = self.finite if topic in chunks.merged_topics else self.named
        named = [int(counts[topic][c]) for c in columns]
        return named, [self.rows[topic] - k for k in named]


class _Run:
    """The analysis of one opened bag."""

    def __init__(self, bag, plan, settings, writer, backs, aging, chunks, diagnostics=None,
                 initial_states=None):
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
        self.out = _Output(writer, plan.joints, truth, diagnostics, (bag, plan.link_topic))
        for joint in plan.joints:
            if topic_token(joint) != joint:
                self._say(joint, joint_words.derived_topics_line(joint_topic(joint, '...')))
        count = bag.topics[plan.link_topic].count
        keep = max(1, count // REPORT_TE_POINTS)
        # What each reducer's last bag left its front, if anything (checked here: a
        # front in the worker must not fail on it).
        carried = {j: self._carried(j, (initial_states or {}).get(j)) for j in plan.joints}
        self.fronts = {j: JointFront(j, settings, aging, _motor_scale(settings, j), keep,
                                     carried[j]) for j in plan.joints}
        # With a worker, some joints' fronts run there (their paired samples go through
        # the pipe): the two processes share the window analysis.
        remote = plan.joints[1::WORKER_FRONT_EVERY] if isinstance(backs, WorkerBacks) else ()
        self.remote = set(remote)
        for joint in remote:
            backs.add_front(joint, settings, aging, _motor_scale(settings, joint), keep,
                            carried[joint])
        # (column index, joint), the worker's first: it starts on a chunk while this
        # process analyses its own joints.
        self.order = sorted(enumerate(plan.joints), key=lambda kj: kj[1] not in self.remote)
        self.results = {j: JointResult(j) for j in plan.joints}
        self.features = {j: [] for j in plan.joints}
        self.back_out = {j: [] for j in plan.joints}
        self.started = False
        self.messages_read = 0
        self.angles = {}     # joint -> 'raw' / 'output', as the data show them
        self.swapped = {}    # joint -> the link entry's travel over the motor entry's, >> 1
        self.mixed = {}      # joint -> (motor travel over link travel, core mixed_units)
        self.span = {}       # joint -> [first, last] stamp of its paired samples [ns]
        self.entries = _EntryCounts(plan)
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
                pos, _, eff = joint_columns(link, link_names[2 * k:2 * k + 2])
                x_link, x_motor, t_motor = pos[:, 0], pos[:, 1], link.stamps_ns
                efforts = eff[:, 0], eff[:, 1]
            else:
                if link is None or motor is None or not len(link) or not len(motor):
                    continue
                x_link, _, e_link = (c[:, 0] for c in joint_columns(link, [joint]))
                x_motor, _, e_motor = (c[:, 0] for c in joint_columns(
                    motor, [plan.motor_names[k]]))
                t_motor = motor.stamps_ns
                efforts = e_link, e_motor
            r = motor_travel_ratio(x_link, x_motor)
            sense = motor_direction(link.stamps_ns, x_link, t_motor, x_motor)
            if not (math.isfinite(r) and math.isfinite(sense)):
                continue
            self._against_config('motor_direction', int(sense), joint,
                                 f'step {"with" if sense > 0 else "against"} the link')
            if sense < 0 and settings.motor_direction == 'auto':   # never silent: said
                warn(self.bag, joint_words.reversed_motor_line(joint))
            found, units = motor_angle_form(r, ratio)
            if units is not None:
                # Neither raw nor output in one unit: the joint's reason, never read.
                self.mixed[joint] = (r, units)
                self._set_angles(joint, found, sense)
                continue
            if found == 'swapped':
                # The link entry moves about the ratio times the motor's: a swap, said as
                # the joint's reason (never read as encoders that jump, a ratio off, or
                # motor angles other than configured).
                self.swapped[joint] = 1.0 / r
                self._set_angles(joint, 'raw', sense)
                continue
            self._against_config('motor_angles', found, joint,
                                 f'move {r:.3g} times the link (raw angles move about '
                                 f'{ratio:g} times, output angles about 1)')
            self._set_angles(joint, found, sense, efforts)

    def _motor_torque(self, joint, front, efforts):
        """``'motor'`` where the motor entry's effort beside output angles is a motor torque."""
        link_effort, motor_effort = efforts
        if self.settings.effort_source == 'motor':     # the motor entry's, whatever the link's
            link_effort = np.full_like(link_effort, np.nan)
        lowest = front.analyzer.edges[0]
        peak = motor_torque_seen(link_effort, motor_effort, front.ratio, lowest,
                                 EFFORT_PLAUSIBLE_RATED * front.analyzer.rated_torque)
        if peak is None:
            return 'auto'
        self._say(joint, joint_words.motor_torque_line(
            self.plan.motor_topic or self.plan.link_topic, peak, lowest, front.ratio))
        return 'motor'

    def _against_config(self, key, found, joint, seen):
        """Refuse a ``twin.<key>`` of ``--config`` that the data of ``joint`` contradict."""
        configured = getattr(self.settings, key)
        if configured in ('auto', found):
            return
        raise InvalidInput(joint_words.config_contradicted(
            self.bag.path, key, configured, joint, self.plan.motor_topic or self.plan.link_topic,
            seen, found))

    def _set_angles(self, joint, angles, direction=1.0, efforts=None):
        front = self.fronts[joint]
        self.angles[joint] = angles
        front.motor_scale = _motor_scale(self.settings, joint, angles, direction)
        front.pairer.motor_scale = front.motor_scale
        units = self.settings.motor_effort_units
        if units == 'auto' and angles == 'output' and efforts is not None and \
                self.settings.effort_source != 'link':
            units = self._motor_torque(joint, front, efforts)
        # A motor that counts against the link reports its torque in its own sense too.
        front.effort_scale = direction * motor_effort_scale(units, angles, front.ratio)
        front.pairer.motor_effort_scale = front.effort_scale

    def run(self):
        plan = self.plan
        chunks = self.chunks
        link_clean, motor_clean = stream_cleaners(self.settings.ingest, bool(plan.motor_topic))
        link_names = [x for j, m in zip(plan.joints, plan.motor_names) for x in (j, m)] \
            if not plan.motor_topic else list(plan.joints)
        for chunk in chunks:
            link = chunk[plan.link_topic]
            self.entries.add(plan.link_topic, link)
            if plan.motor_topic:
                self.entries.add(plan.motor_topic, chunk[plan.motor_topic])
            if len(self.angles) < len(plan.joints):
                self._resolve_angles(link, chunk[plan.motor_topic] if plan.motor_topic else None,
                                     link_names)
            if not self.started and link is not None and len(link):
                if link.stamps_ns[0] < 0:   # refused before any work: see stamps_before_epoch
                    raise stamps_before_epoch(self.bag, plan.link_topic,
                                              int(link.stamps_ns.min()))
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
        pos, vel, eff = joint_columns(link, names)
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
            clean_link = link_clean.process(link.stamps_ns, *joint_columns(link, self.plan.joints))
        if motor is not None and len(motor):
            clean_motor = motor_clean.process(motor.stamps_ns,
                                              *joint_columns(motor, self.plan.motor_names))
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
            self.out.raw(self.out.channels[joint, 'ground_truth'], raw.log_time_ns, payloads,
                         stamped=False)
            for p in payloads:
                try:
                    rows[joint].append(decode_multiarray(p).values(GROUND_TRUTH))
                except InvalidInput:
                    continue
        for joint, values in rows.items():
            self.results[joint].truth = np.array(values) if values else None

    def _say(self, joint, *lines):
        """Say each line about ``joint`` (None: nothing to say); return the lines said."""
        said = [line for line in lines if line is not None]
        for line in said:
            warn(self.bag, f'{joint}: {line}')
        return said

    def _carried(self, joint, state):
        """Return what the reducer's last bag left its front, saying one not usable."""
        carried, unusable = joint_words.carried_front(state, self.settings.params_of(joint))
        self._say(joint, unusable)
        return carried

    def _reason(self, joint, front, counts, sides):
        """Why a joint gave no lost motion it trusts (:mod:`.joint_words`); None when it did."""
        plan = self.plan
        k = plan.joints.index(joint)
        if joint in self.swapped:
            return joint_words.swap_reason(joint, plan.motor_names[k], plan.motor_topic,
                                           self.swapped[joint], front.ratio)
        if joint in self.mixed:
            travel, units = self.mixed[joint]
            return joint_words.units_reason(joint, plan.motor_names[k], plan.motor_topic,
                                            travel, units, front.ratio)
        a = front.analyzer
        reason = None
        if not (a.windows_read and a.effort_fault is None):
            reason = joint_words.stream_reason(
                [side for side, _, _ in sides], counts, front.samples, self.span.get(joint),
                self.settings.max_gap_s, plan.link_topic, plan.motor_topic)
            if reason is None:
                reason = a.not_observed_reason(front.effort_topic)
        return joint_words.effort_faults_reason(front.twin.refusal(reason),
                                                self.entries.effort_faults, self.entries.rows)

    def _partial(self, joint, front):
        """Say when an observed joint's lost motion stopped well before its stream did."""
        a, span = front.analyzer, self.span.get(joint)
        if not a.windows_observed or span is None:
            return None
        stale = a.stale_reason(joint_words.stale_after_s(span, self.settings.window_s),
                               front.effort_topic)
        return joint_words.partial_reason(
            joint, span, self.span.values(), self.settings.window_s, stale,
            a.last_observed_t, a.samples_without_effort, a.samples_seen, front.effort_topic)

    def _finish(self, chunks, link_clean, motor_clean):
        """Say the streams' faults, fill each joint's result, write the ingest statuses."""
        plan = self.plan
        self.messages_read = sum(chunks.messages.values())
        self._say_streams(chunks, link_clean, motor_clean)
        statuses = []
        last_ns = 0
        for k, (joint, front) in enumerate(self.fronts.items()):
            res = self.results[joint]
            counts, sides, res.messages, res.rejected = _ingest_counts(
                k, front, plan, self.entries, chunks, link_clean, motor_clean)
            res.counts = counts
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
            res.reason = self._reason(joint, front, counts, sides)
            res.partial = self._partial(joint, front)
            res.velocity = _velocity_source(front.analyzer)
            res.inputs = self._say(joint, *front.twin.input_warnings().values())
            res.soft_zone = front.twin.soft_zone
            res.within_zone = front.analyzer.within_zone_said
            res.test_torque_check = front.analyzer.test_torque_check
            res.inputs += self._say(joint, joint_words.not_compared_line(
                res.observed, res.levels, res.wear, front.analyzer.test_torque_not_compared))
            res.inputs += self._say(joint, joint_words.soft_zone_carried_line(
                res.soft_zone, res.wear, front.analyzer.within_zone))
            res.time_offset_s = front.twin.calibration.to_carry
            res.front_state = front.twin.state()
            self._say(joint, joint_words.rate_line(res.observed, res.wear))
            service, refused = joint_words.service_taken(outputs)
            if service is not None:
                res.service = service
            self._say(joint, *refused)
            self._say(joint, joint_words.gaps_line(front.analyzer.gap_time_s,
                                                   front.analyzer.gaps, self.span.get(joint),
                                                   self.settings.max_gap_s))
            bad = sum(v for k, v in counts.items()
                      if k not in ('published', 'step', *PAIRING_FACTS)
                      and not k.endswith('_wrap'))
            level, message = joint_words.ingest_status(bad)
            statuses.append(Status(level, f'reducer_twin: {joint} encoder ingest', message,
                                   joint, counts))
        if statuses and last_ns:
            self.out.raw(self.out.diagnostics, [last_ns],
                         [encode_diagnostic_array(last_ns, statuses)])

    def _say_streams(self, chunks, link_clean, motor_clean):
        """Say the bag's stream faults: angles assumed raw, scatter, late, malformed."""
        plan = self.plan
        if self.settings.motor_angles == 'auto':
            unknown = [j for j in plan.joints if j not in self.angles]
            if unknown:     # never a silent guess: say what was assumed and how to say it
                warn(self.bag, joint_words.angles_assumed_raw_line(unknown,
                                                                   MIN_DETECT_TRAVEL_RAD))
        for topic, cleaner in ((plan.link_topic, link_clean), (plan.motor_topic, motor_clean)):
            if cleaner is not None:
                stamp_scatter(self.bag, topic, chunks.step_scatter.get(topic), cleaner.clock)
            late = cleaner.counts['out_of_order'] if cleaner is not None else 0
            if late:    # a loss of 1 % or more is said
                line = joint_words.out_of_order_line(late, chunks.messages[topic], topic)
                if line is not None:
                    warn(self.bag, line)
        for topic, count in chunks.malformed.items():
            if count:   # as Bag.read_joint_states reports them
                warn(self.bag, joint_words.malformed_line(count, topic,
                                                          chunks.first_problem.get(topic)))
        for topic, (count, first) in self.entries.effort_faults.items():
            warn(self.bag, joint_words.effort_faults_line(count, topic, first))


def _ingest_counts(k, front, plan, entries, chunks, link_clean, motor_clean):
    """
    Count the ingest of a plan's ``k``-th joint as encoder_ingest counts it.

    Row rules of the whole stream, value rules of this joint's columns; an entry a
    message did not name is absent, not a non-finite value.

    Returns
    -------
    counts : dict
        :attr:`.results.JointResult.counts`.
    sides : tuple of (str, StreamCleaner, list of int)
        Where they were taken: the stream or link and motor sides, their columns.
    messages, rejected : int
        :attr:`.results.JointResult.messages` and ``rejected``.

    """
    counts = {}
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
    malformed = sum(chunks.malformed.values()) + sum(
        count for count, _ in entries.effort_faults.values())
    counts['malformed_messages'] = int(malformed)
    messages = 0
    for side, _, columns in sides:
        topic = plan.motor_topic if side == 'motor' else plan.link_topic
        named, absent = entries.of(topic, columns, chunks)
        messages += named[0]     # the joint's own entry: <joint> or its motor
        counts[f'{side}_non_finite'] = max(
            0, counts.get(f'{side}_non_finite', 0) - int(sum(absent)))
    rejected = malformed + counts['unpaired'] + counts['spike'] + sum(
        counts.get(f'{side}_{r}', 0) for side, _, _ in sides for r in _REPAIRED
        if r != 'clock_jump')
    return counts, sides, messages, rejected


def _velocity_source(analyzer):
    """Return where a joint's speed came from: 'field', 'link_angle', None without samples."""
    if not analyzer.samples_seen:
        return None
    return 'link_angle' if analyzer.velocity_fault is not None or \
        analyzer.derived_velocity >= 0.5 * analyzer.samples_seen else 'field'


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
            check_configured_topics(bag, settings)
            first = plan_joints(bag, settings)
            plans = robot_plans(bag, first, settings)
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
                            initial_states, {j: settings.estimator_of(j) for j in every})
            custom = {'reducer_twin.source': str(Path(path).resolve()),
                      AGING_KEY: repr(float(aging)),
                      'reducer_twin.joints': ','.join(every)}
            needed = DERIVED_BYTES_PER_SAMPLE * sum(
                len(p.joints) * bag.topics[p.link_topic].count for p in plans)
            joints, messages, diagnostics, late = {}, 0, None, []
            with BagDirWriter(out_dir, compression=settings.compression, custom_data=custom,
                              overwrite=overwrite, needed=needed,
                              what='derived bag') as writer:
                for robot in plans:
                    run = _analyse_robot(bag, robot, settings, writer, backs, aging,
                                         diagnostics, reader_process, initial_states)
                    chunks = run.chunks
                    diagnostics = run.out.diagnostics
                    joints.update(run.run())
                    messages += run.messages_read
                    found = late_joints(robot, run.entries.seen, settings)
                    if found is not None:
                        late.append(found)
                states = dict(backs.states)
                if late:
                    # Pairs the first messages lacked (a broadcaster that started late):
                    # the recording is read again for them, as if planned from the start.
                    every += [j for p in late for j in p.joints]
                    writer.custom_data['reducer_twin.joints'] = ','.join(every)
                    backs.configure({j: settings.params_of(j) for j in every}, settings.life,
                                    initial_states, {j: settings.estimator_of(j) for j in every})
                    said = list(bag.warnings)
                    for robot in late:
                        # Read here: a reader forked now would inherit the writer's threads.
                        run = _analyse_robot(bag, robot, settings, writer, backs, aging,
                                             diagnostics, False, initial_states)
                        chunks = run.chunks
                        joints.update(run.run())
                        states.update(backs.states)
                    # What the second read says of the topics again is said once.
                    bag.warnings[len(said):] = [w for w in bag.warnings[len(said):]
                                                if w not in said]
                analysed = {n[len(p.prefix):] for p in (*plans, *late)
                            if p.link_topic == first.link_topic
                            for n in (*p.joints, *p.motor_names)}
                say_unpaired(bag, first, analysed, settings)
            warnings = list(bag.warnings)
    except BaseException:
        if isinstance(backs, WorkerBacks):
            backs.terminate()   # it may hold work of this bag: never reused
        if isinstance(chunks, ForkedBagChunks):
            chunks.terminate()
        raise
    if backs is not stage_worker:
        backs.close()
    for joint, res in joints.items():   # what the fronts learnt goes on too
        if states.get(joint) is not None:
            states[joint] = {**states[joint], 'time_offset_s': res.time_offset_s,
                             'front': res.front_state}
    return BagResult(Path(path), Path(out_dir), plan, joints, messages,
                     time.perf_counter() - start, aging, warnings,
                     any(is_damage(w) for w in warnings), states)


def _analyse_robot(bag, plan, settings, writer, backs, aging, diagnostics, reader_process,
                   initial_states=None):
    """Return the analysis of one plan's joints (a :class:`_Run`, not yet run)."""
    topics = [plan.link_topic] + ([plan.motor_topic] if plan.motor_topic else [])
    chunks = BagChunks(bag, topics, CHUNK_MESSAGES, plan.prefix)
    if reader_process:   # forked before the writer opens its file and threads
        chunks = ForkedBagChunks(chunks)
    return _Run(bag, plan, settings, writer, backs, aging, chunks, diagnostics, initial_states)
