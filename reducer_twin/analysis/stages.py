"""
The per-joint stages of the offline analysis, and where the slow ones run.

:class:`JointFront` is what ``encoder_ingest``'s spike rule and ``te_monitor`` do for one
joint (TE extraction with the learnt encoder time offset, window analysis, TE batches);
:class:`JointBack` is ``wear_estimator`` and ``life_publisher`` (Kalman step and the
2000-sample remaining-life prediction per window, with the life publisher's diagnostic
key/values). The back stages run in this process (:class:`LocalBacks`) or in a forked
worker (:class:`WorkerBacks`) that takes window records while this process reads and
analyses the next chunk; the worker can also run the front of some joints
(:meth:`WorkerBacks.add_front`: it takes their paired samples and sends back their TE
batches and window records). Both give identical results, since each stage sees the same
samples and records in the same order.
"""

from typing import NamedTuple

import numpy as np
from reducer_twin.analysis.forking import end_process, end_with_parent, parent_of_fork
from reducer_twin.core.effort_source import motor_effort_scale
from reducer_twin.core.errors import ReducerTwinError
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.joint_twin import CALIBRATION_PIECE_S
from reducer_twin.core.joint_twin import reducer_status_name, TwinBack, TwinConfig, TwinFront
from reducer_twin.core.pairing import Pairer
from reducer_twin.core.pipeline import EstimatorStage
from reducer_twin.core.spikes import SpikeFilter
from reducer_twin.core.units import HOUR
from reducer_twin.core.wear import depth_per_mesh_pass
from reducer_twin.msg_adapters.diagnostic_cdr import encode_diagnostic_array, Status
from reducer_twin.msg_adapters.layouts import record_values, REMAINING_LIFE, TE_FEATURES
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE

TE_BATCH_S = 0.5
"""
Stream seconds of TE per ``te`` message (the node sends 20 ms batches).

Every sample is in the bag whatever the batch; ``te_monitor``'s analysis period (0.5 s)
per message makes a fifth of the messages 0.1 s did, and the derived bag's writing is
per message (of 23 k messages of a 6-joint bag at 1 kHz, 18 k were TE at 0.1 s).
"""

PAIR_HOLD_S = 60.0
"""How long [s of link stream] a link sample of a bag waits for its motor partner."""

_ERROR = '!error'
"""Marks a failure report of the worker (no ROS name starts with '!')."""

_CONFIG = '!config'
_FLUSH = '!flush'
_ADD_FRONT = '!add_front'
"""Control messages of the worker protocol."""

FRONT_OUTPUT = '!front'
"""Marks what a joint's front in the worker produced (see :meth:`LocalBacks.submit`)."""


class JointFront:
    """The ``te_monitor`` part of one joint, and the spike rule of ``encoder_ingest``."""

    def __init__(self, joint, settings, aging_factor, motor_scale, keep_every, carried=None):
        params = settings.params_of(joint)
        self.joint = joint
        self.params = params
        self.twin = TwinFront(params, TwinConfig(
            aging_factor=aging_factor, window_s=settings.window_s, max_gap_s=settings.max_gap_s,
            friction_in_effort=settings.friction_in_effort, effort_lag_s=settings.effort_lag_s))
        # What the reducer's last bag left (BagResult.states): the front's state (the time
        # offset and the soft-zone check, as a restarted te_monitor continues), or from a
        # store written before it was kept, the time offset alone.
        carried = carried or {}
        if carried.get('front') is not None:
            self.twin.continue_from(carried['front'])
        else:
            self.twin.carry_time_offset(carried.get('time_offset_s'))
        self.ratio = self.twin.ratio
        self.extractor = self.twin.extractor
        self.calibration = self.twin.calibration
        self.analyzer = self.twin.analyzer
        self.motor_scale = motor_scale
        self.effort_scale = motor_effort_scale(settings.motor_effort_units,
                                               settings.motor_angles, self.ratio)
        self.effort_topic = 'the joint states'
        self.spikes = SpikeFilter(self.ratio, settings.ingest)
        # Offline a partner can come chunks later: hold link samples for PAIR_HOLD_S.
        self.pairer = Pairer(settings.ingest, motor_scale, hold_s=PAIR_HOLD_S,
                             effort=settings.effort_source,
                             motor_effort_scale=self.effort_scale, ratio=self.ratio,
                             effort_scale=settings.effort_scale)
        self.unpaired = 0
        self.samples = 0
        self.period_ns = None
        self.keep_every = max(1, int(keep_every))
        self.report_te = []
        self._te = []        # pending TE rows (t_ns, theta, te, torque), not yet a full batch
        self._te_n = 0
        self._kept = 0

    def feed(self, t_ns, motor, link, effort, velocity):
        """Spike rule, TE and windows of paired samples; return ``(windows, te_rows)``."""
        keep = self.spikes.keep(motor, link)
        if not keep.all():
            t_ns, motor, link, effort, velocity = (a[keep] for a in
                                                   (t_ns, motor, link, effort, velocity))
        else:   # columns of a multi-joint message: every later pass is faster on copies
            t_ns, motor, link, effort, velocity = (np.ascontiguousarray(a) for a in
                                                   (t_ns, motor, link, effort, velocity))
        if t_ns.size == 0:
            return [], None
        if self.period_ns is None and t_ns.size > 16:
            self.period_ns = float(np.median(np.diff(t_ns[:4096])))
        self.samples += t_ns.size
        t_s = t_ns * 1e-9
        windows, te_parts, start, stream = [], [], 0, None
        if self._calibrating() and not _cut_free(t_ns, motor, link):
            return self._feed_pieces(t_ns, t_s, motor, link, effort, velocity)
        while self._calibrating():
            # Until the offset is learnt the TE of a piece does not depend on where the
            # pieces are cut (see _cut_free): computed once, it is fed to the window
            # analysis in pieces of CALIBRATION_PIECE_S.
            piece = self._piece()
            reference = self.extractor.last_te
            offset = self.extractor.link_time_offset_s
            stream = self.twin.te(t_s, motor, link)
            n, start = t_ns.size, 0
            while start < n and self._calibrating() and \
                    self.extractor.link_time_offset_s == offset:
                windows += self._analyze(stream.part(slice(start, start + piece)),
                                         effort[start:start + piece],
                                         velocity[start:start + piece])
                start += piece
            if start >= n or self.extractor.link_time_offset_s == offset:
                break
            # Learnt (or refined): the offset applies from the next piece on, with the TE
            # kept continuous with the last one before it.
            valid = np.flatnonzero(stream.valid[:start])
            self.extractor.last_te = float(stream.te[valid[-1]]) if valid.size else reference
            te_parts.append(_te_rows(t_ns[:start], stream.part(slice(0, start)),
                                     effort[:start]))
            t_ns, t_s, motor, link, effort, velocity = (
                a[start:] for a in (t_ns, t_s, motor, link, effort, velocity))
            start, stream = 0, None
        if stream is None:
            stream = self.twin.te(t_s, motor, link)
        if start < t_ns.size:
            windows += self._analyze(stream.part(slice(start, None)), effort[start:],
                                     velocity[start:])
        te_parts.append(_te_rows(t_ns, stream, effort))
        rows = te_parts[0] if len(te_parts) == 1 else np.concatenate(te_parts)
        self._keep_for_report(rows)
        return windows, rows

    @property
    def windows(self):
        """Windows completed so far."""
        return self.twin.windows

    _FEED_SIDE = ('twin', 'extractor', 'calibration', 'analyzer', 'spikes', 'samples',
                  'period_ns', 'report_te', '_te', '_te_n', '_kept')
    """What :meth:`feed`, :meth:`flush` and :meth:`te_messages` change (not the pairing)."""

    def feed_side(self):
        """Return the state that feeding changed (for :meth:`take_feed_side`)."""
        return {name: getattr(self, name) for name in self._FEED_SIDE}

    def take_feed_side(self, state):
        """Continue from the :meth:`feed_side` of a copy of this front fed elsewhere."""
        for name, value in state.items():
            setattr(self, name, value)

    def outputs(self, windows, te_rows, final=False):
        """
        Return what windows and TE rows give for the derived bag and the back stages.

        Parameters
        ----------
        windows : list of WindowFeatures
            Completed windows.
        te_rows : ndarray or None
            TE rows of :meth:`feed`.
        final : bool
            Send the last, partial TE batch too.

        Returns
        -------
        JointOutput
            TE batches, ``te_features`` records, their stamps and values.

        """
        records = [self.twin.record(f) for f in windows]
        values = np.array([record_values(TE_FEATURES, r) for r in records]) if records \
            else np.zeros((0, len(TE_FEATURES.fields)))
        return JointOutput(self.te_messages(te_rows, final), records,
                           [stamp_ns(f.t_end) for f in windows], values)

    def _calibrating(self):
        """Whether the stream still goes in calibration pieces (time offset not settled)."""
        return self.twin.calibrating and bool(self.period_ns)

    def _piece(self):
        return max(1, int(round(CALIBRATION_PIECE_S * 1e9 / max(self.period_ns, 1.0))))

    def _analyze(self, stream, effort, velocity):
        return self.twin.analyze(stream, effort, velocity)

    def _feed_pieces(self, t_ns, t_s, motor, link, effort, velocity):
        """Feed stamps that do not increase in calibration pieces, TE piece by piece."""
        windows, te_parts = [], []
        piece, start = self._piece(), 0
        while start < t_ns.size:
            if not self._calibrating():
                piece = t_ns.size
            sl = slice(start, start + piece)
            stream = self.twin.te(t_s[sl], motor[sl], link[sl])
            windows += self._analyze(stream, effort[sl], velocity[sl])
            te_parts.append(_te_rows(t_ns[sl], stream, effort[sl]))
            start += piece
        rows = te_parts[0] if len(te_parts) == 1 else np.concatenate(te_parts)
        self._keep_for_report(rows)
        return windows, rows

    def _keep_for_report(self, rows):
        first = (-self._kept) % self.keep_every
        self.report_te.append(rows[first::self.keep_every])
        self._kept += rows.shape[0]

    def flush(self):
        """Close the last, partial window."""
        return self.twin.flush()

    def te_messages(self, rows, final=False):
        """
        Cut TE rows into messages of :data:`TE_BATCH_S` of stream.

        Returns
        -------
        list of tuple
            ``(log_times_ns, values[M, K, 4])`` groups of equal-length messages.

        """
        if rows is not None and rows.shape[0]:
            self._te.append(rows)
            self._te_n += rows.shape[0]
        if not self._te_n:
            return []
        k = max(1, int(round(TE_BATCH_S * 1e9 / self.period_ns))) if self.period_ns else 100
        if self._te_n < k and not final:
            return []
        pending = np.concatenate(self._te) if len(self._te) > 1 else self._te[0]
        m = pending.shape[0] // k
        out = []
        if m:
            block = pending[:m * k].reshape(m, k, 4)
            out.append((block[:, -1, 0].astype(np.int64), te_values(block)))
        rest = pending[m * k:]
        if final and rest.shape[0]:
            out.append((rest[-1:, 0].astype(np.int64), te_values(rest[None])))
            rest = rest[:0]
        self._te = [rest] if rest.shape[0] else []
        self._te_n = rest.shape[0]
        return out


class JointOutput(NamedTuple):
    """
    What a joint's front gave for one feed: TE batches and window records.

    Attributes
    ----------
    te : list of tuple
        ``(log_times_ns, values[M, K, 4])`` of ``te`` messages (:meth:`JointFront.te_messages`).
    records : list of dict
        ``te_features`` records of the completed windows.
    stamps_ns : list of int
        Their log times (the windows' ends).
    values : ndarray
        The records in layout order, (windows, fields).

    """

    te: list
    records: list
    stamps_ns: list
    values: np.ndarray


def stamp_ns(t_s):
    """Return a stamp [s] as integer nanoseconds (the log time of a derived message)."""
    return int(round(float(t_s) * 1e9))


def _cut_free(t_ns, motor, link):
    """
    Whether TE extraction gives the same TE for these samples whole or cut in pieces.

    True when the stamps increase and neither angle steps by half a turn or more
    between samples: with no time offset, then nothing is unwrapped or dropped inside
    a piece, and the TE is continued across piece boundaries as across gaps.
    """
    if t_ns.size < 2:
        return True
    return bool((np.diff(t_ns) > 0).all() and np.abs(np.diff(motor)).max() < np.pi
                and np.abs(np.diff(link)).max() < np.pi)


def _te_rows(t_ns, stream, effort):
    """TE rows ``(t_ns, output angle, TE, torque)`` of a stream's valid samples."""
    valid = stream.valid
    if valid.all():
        return np.column_stack([t_ns, stream.output_angle, stream.te, effort])
    return np.column_stack([t_ns[valid], stream.output_angle[valid], stream.te[valid],
                            effort[valid]])


def te_values(block):
    """TE rows with ns stamps to the ``te`` layout (stamps in seconds)."""
    values = block.copy()
    values[..., 0] *= 1e-9
    return values


NEW_REDUCER = {'new_reducer': True}
"""The initial state of a reducer the fleet store knows was fitted new (a replacement)."""


class JointBack:
    """
    The ``wear_estimator`` and ``life_publisher`` part of one joint (a :class:`TwinBack`).

    Parameters
    ----------
    joint : str
        Joint name (also the reducer's ``hardware_id``).
    params : ReducerParams
        Reducer parameters.
    life_config : LifeConfig
        Limit and thresholds.
    state : dict, optional
        Where an earlier analysis of the same reducer ended (:meth:`state`), or
        :data:`NEW_REDUCER` (a reducer fitted by a recorded replacement); default a
        reducer met without state.
    estimator_config : EstimatorConfig, optional
        Estimator tuning of a reducer met without state (its service time); default
        the defaults.

    """

    def __init__(self, joint, params, life_config, state=None, estimator_config=None):
        self.joint = joint
        if state == NEW_REDUCER:
            # Fitted by a recorded replacement: new, whatever the configuration says of
            # the unit the twin first met (its service time).
            estimator_config, state = (estimator_config or EstimatorConfig()).fitted_new(), None
        self.twin = TwinBack(params, life_config, EstimatorStage(params, estimator_config))
        if state is not None:
            self.twin.restore(state)

    def state(self):
        """Return where this reducer's stages are (:meth:`TwinBack.state`)."""
        return self.twin.state()

    def initial(self, stamp_s):
        """
        Return the outputs the nodes publish when they start (no window yet).

        With ``service``, ``(None, None, None, hours)``, while a service time waits to be
        judged (:meth:`process_many`).
        """
        wear, life = self.twin.start(stamp_s)
        out = self._outputs(wear, life)
        estimator = self.twin.estimator.estimator
        if estimator.service_pending:
            out['service'] = (None, None, None, estimator.config.service_time_s / HOUR)
        return out

    def process(self, record):
        """
        Step the estimator and the life prediction with one ``te_features`` record.

        Parameters
        ----------
        record : dict
            The window's record.

        Returns
        -------
        dict
            ``status``, ``log_ns`` (the window's end), ``wear`` and ``life`` record values
            in layout order, ``level`` and the serialised ``/diagnostics`` message (the life
            publisher's status with its key/values).

        """
        return self._outputs(*self.twin.step(record))

    def process_many(self, records):
        """
        Step the estimator with each record in turn; the life predictions are made together.

        Returns
        -------
        list of dict
            :meth:`process` of each record, in order; the output of the batch in which
            the reducer's service time was judged also has ``service``: ``(taken,
            rate_scale, line, hours)`` (:func:`.core.service_time.service_note`).

        """
        said = self.twin.estimator.service_said
        out = [self._outputs(wear, life, summary)
               for wear, life, summary in self.twin.step_many(records)]
        verdict = self.twin.estimator.estimator.service_verdict
        if out and said is None and self.twin.estimator.service_said is not None:
            # How the service time was taken, once, with the window that took it.
            out[-1]['service'] = (*verdict, self.twin.estimator.service_said,
                                  self.twin.estimator.estimator.config.service_time_s / HOUR)
        return out

    def _outputs(self, wear, life, summary=None):
        summary = summary or self.twin.summary(wear, life)
        level, message, values = summary.diagnostic()
        # Encoded here: in a worker process this work leaves the reading process.
        log_ns = stamp_ns(wear.record['stamp_s'])
        diagnostics = encode_diagnostic_array(log_ns, [Status(
            level, reducer_status_name(self.joint), message, self.joint, values)])
        return {'status': wear.status, 'log_ns': log_ns, 'level': level,
                'wear': record_values(WEAR_ESTIMATE, wear.record),
                'life': record_values(REMAINING_LIFE, life.record), 'diagnostics': diagnostics}


class LocalBacks:
    """
    Estimator and life stages of every joint, in this process.

    Parameters
    ----------
    params : ReducerParams or dict of str to ReducerParams, optional
        Reducer parameters of every joint, or per joint (or later through
        :meth:`configure`).
    life_config : LifeConfig, optional
        Limit and thresholds.

    """

    def __init__(self, params=None, life_config=None):
        self.configure(params, life_config)

    def configure(self, params, life_config, states=None, estimators=None):
        """
        Start over for a new bag with these parameters (and reducers' earlier states).

        ``estimators`` maps a joint to the estimator tuning of its reducer met without
        state (:meth:`.settings.AnalysisSettings.estimator_of`).
        """
        self.params = params
        self.life_config = life_config
        self.initial = dict(states or {})
        self.estimators = dict(estimators or {})
        self.states = {}
        self.backs = {}
        self.fronts = {}
        self._done = []

    def add_front(self, joint, front):
        """Run the front of ``joint`` here (a :class:`JointFront`; see :meth:`submit`)."""
        self.fronts[joint] = front

    def submit(self, joint, kind, items):
        """
        Process work of one joint.

        ``'start'``: a stamp [s]; ``'windows'``: ``te_features`` records. For a joint
        whose front runs here (:meth:`add_front`): ``'feed'``, its paired samples
        ``(t_ns, motor, link, effort, velocity)``, and ``'flush'`` (None), closing
        its last window; each gives ``(FRONT_OUTPUT, joint, JointOutput, state)``
        (``state`` the front's :meth:`JointFront.feed_side` after the flush, else
        None) and the back stages' outputs of its windows.
        """
        if kind in ('feed', 'flush'):
            front = self.fronts[joint]
            if kind == 'feed':
                out = front.outputs(*front.feed(*items))
            else:
                out = front.outputs(front.flush(), None, final=True)
            self._done.append((FRONT_OUTPUT, joint, out,
                               front.feed_side() if kind == 'flush' else None))
            if out.records:
                self.submit(joint, 'windows', out.records)
            return
        back = self.backs.get(joint)
        if back is None:
            params = self.params[joint] if isinstance(self.params, dict) else self.params
            back = self.backs[joint] = JointBack(joint, params, self.life_config,
                                                 self.initial.get(joint),
                                                 self.estimators.get(joint))
        if kind == 'start':
            self._done.append((joint, [back.initial(items)]))
        else:
            self._done.append((joint, back.process_many(items)))

    def poll(self):
        """Return the outputs ready so far, ``[(joint, [outputs])]``."""
        done, self._done = self._done, []
        return done

    def finish(self):
        """Return the outputs of everything submitted; :attr:`states` holds the end states."""
        self.states = {joint: back.state() for joint, back in self.backs.items()}
        return self.poll()

    def close(self):
        """Release nothing (the stages live in this process)."""


def _warm_up(params, life_config):
    """
    Build what a reducer's stages compute once per process, before its first samples come.

    The window analysis's mesh depth table (about 50 ms), the model tables and the life
    stage's first draws are kept by the process once made; the worker makes them for
    every configured reducer while the reading process opens the bag and reads its
    first chunk, instead of when its first window needs them.
    """
    reducers = set(params.values()) if isinstance(params, dict) else {params}
    for reducer in reducers - {None}:
        depth_per_mesh_pass(reducer.rating.rated_torque, reducer)
        JointBack('', reducer, life_config).initial(0.0)


def _back_worker(inbox, outbox, parent):
    """Run the estimator and life stages on records sent by the analysing process."""
    end_with_parent(parent)
    try:
        # Warm up while the parent imports, opens the bag and reads the first chunk.
        from reducer_twin.core import estimator, life  # noqa: F401
        local = LocalBacks()
        while True:
            item = inbox.get()
            if item is None:
                break
            if item[0] == _CONFIG:
                local.configure(*item[1:])
                _warm_up(item[1], item[2])
            elif item[0] == _ADD_FRONT:
                local.add_front(item[1], JointFront(*item[1:]))
            elif item[0] == _FLUSH:
                done = local.finish()
                for joint_done in done:
                    outbox.put(joint_done)
                outbox.put((_FLUSH, local.states))
            else:
                local.submit(*item)
                for done in local.poll():
                    outbox.put(done)
    except ReducerTwinError as err:   # a joint's data refused: the parent raises it as is
        outbox.put((_ERROR, err))
    except BaseException as err:  # noqa: B902 - reported to the parent, which raises
        import traceback
        outbox.put((_ERROR, f'{type(err).__name__}: {err}\n{traceback.format_exc()}'))


class WorkerBacks:
    """
    Estimator and life stages in a forked worker process (the same results as local).

    Fork it early (before the bag is opened): the worker warms up while this
    process gets ready. It can run joints' fronts too (:meth:`add_front`). One worker
    serves bags one after the other (:meth:`configure` ... :meth:`finish` per bag,
    :meth:`close` at the end).
    """

    def __init__(self):
        import multiprocessing
        ctx = multiprocessing.get_context('fork')
        self._inbox = ctx.Queue()
        self._outbox = ctx.Queue()
        self._proc = ctx.Process(target=_back_worker, name='reducer-twin-stages',
                                 args=(self._inbox, self._outbox, parent_of_fork()),
                                 daemon=True)
        self._proc.start()
        self.states = {}

    @property
    def alive(self):
        """Whether the worker process runs."""
        return self._proc.is_alive()

    def configure(self, params, life_config, states=None, estimators=None):
        """Start over for a new bag (see :meth:`LocalBacks.configure`)."""
        self.states = {}
        self._inbox.put((_CONFIG, params, life_config, states, estimators))

    def add_front(self, joint, settings, aging_factor, motor_scale, keep_every, carried=None):
        """
        Run the front of ``joint`` in the worker (a :class:`JointFront` of these arguments).

        Its paired samples then go to :meth:`submit` as ``'feed'`` work, and its
        windows to the worker's back stages directly (see :meth:`LocalBacks.submit`).
        """
        self._inbox.put((_ADD_FRONT, joint, settings, aging_factor, motor_scale, keep_every,
                         carried))

    def submit(self, joint, kind, items):
        """Send work (see :meth:`LocalBacks.submit`)."""
        self._inbox.put((joint, kind, items))

    @staticmethod
    def _take(item):
        if item[0] == _ERROR:
            if isinstance(item[1], ReducerTwinError):
                raise item[1]
            raise RuntimeError(f'the estimator worker failed: {item[1]}')
        return item

    def poll(self):
        """Return the outputs ready so far, without waiting."""
        import queue
        out = []
        while True:
            try:
                item = self._outbox.get_nowait()
            except queue.Empty:
                return out
            out.append(self._take(item))

    def finish(self):
        """Wait for the outputs of everything submitted and return them."""
        self._inbox.put((_FLUSH,))
        out = []
        while True:
            item = self._take(self._outbox.get())
            if item[0] == _FLUSH:
                self.states = item[1]
                return out
            out.append(item)

    def close(self):
        """Stop the worker."""
        if self._proc.is_alive():
            self._inbox.put(None)
            self._proc.join(timeout=10)
        self.terminate()

    def terminate(self):
        """
        Stop the worker at once (after an error).

        Work still queued for it is dropped: the queue's feeder thread would
        otherwise wait at exit to write it into a pipe nobody reads (the
        analysing process hung on a full disk with the worker gone).
        """
        self._inbox.cancel_join_thread()
        end_process(self._proc)
