"""
The live twin in the fleet store: a ``wear_estimator``'s windows as live segments.

A ``wear_estimator`` with a ``store`` (and its ``robot``) is one more source of the
reducer's history, beside recorded bags:

* at start it continues from the reducer's stored state when that is newer than its own
  state file (or it has none), and starts a new reducer when the store says the one its
  state file knew was replaced since (:func:`read_start`);
* every window it steps is kept (its ``te_features``, ``wear`` and ``remaining_life``
  records, the health level) and every ``store_period_s`` the windows kept so far are
  written as one *live segment*, one transaction (:class:`LiveHistory`), so ``fleet``
  lists the reducer, a later ``analyze --store`` continues from its state and refuses a
  bag that overlaps it;
* the node's ``reset`` service (reducer replaced) becomes a replacement in the store.

Writes never wait long: a flush that finds another process writing the store (the
writer lock) waits at most :data:`LOCK_WAIT_S` and otherwise leaves the windows for the
next flush; a flush that fails (a full disk) leaves the store as it was (the
transaction rolls back), keeps the windows and says ERROR until a later flush succeeds.
Windows wait in memory up to :data:`MAX_PENDING_WINDOWS`; beyond that the oldest are
dropped from the store (counted; their operating time still counts).
"""

from dataclasses import dataclass, field
import datetime
import os
from pathlib import Path
import socket
import sqlite3
import threading
from types import SimpleNamespace
import uuid

import numpy as np
from reducer_twin.core.errors import InvalidParameter, out_of_range, ReducerTwinError
from reducer_twin.core.joint_twin import estimate_numbers
from reducer_twin.core.life_basis import life_basis, torque_check_lines
from reducer_twin.core.pipeline import features_from_record, LifeStage
from reducer_twin.core.pipeline import reducer_state
from reducer_twin.core.soft_zone import carried_line
from reducer_twin.core.units import HOUR
from reducer_twin.fleet.cli import MAX_ROBOT_NAME, valid_robot_name
from reducer_twin.fleet.store import FleetStore, iso_from_ns, Segment, StoreBusy
from reducer_twin.fleet.store import StoreConflict, StoreError
from reducer_twin.msg_adapters.layouts import (
    record_values, REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE)

LOCK_WAIT_S = 0.5
"""Longest wait for another writer's lock before a flush is left for the next one [s]."""

MAX_PENDING_WINDOWS = 50_000
"""Windows kept in memory while the store cannot be written (a day of 2-s windows)."""

_END = TE_FEATURES.fields.index('window_end_s')
_START = TE_FEATURES.fields.index('window_start_s')
_EXPOSURE = TE_FEATURES.fields.index('exposure_s')
_DURATION = TE_FEATURES.fields.index('duration_s')
_SAMPLES = TE_FEATURES.fields.index('samples')
_LOST_MOTION = TE_FEATURES.fields.index('lost_motion_rad')
_CENSORED = REMAINING_LIFE.fields.index('p10_censored')


def check_robot(robot):
    """
    Check the robot name a live node writes under.

    Raises
    ------
    InvalidParameter
        If it is empty, too long or holds spaces or unprintable characters.

    """
    if not valid_robot_name(robot):
        raise InvalidParameter(out_of_range(
            'robot', robot, '', f'a name of 1 .. {MAX_ROBOT_NAME} printable characters '
            'without spaces when store is set (the robot of the reducer in the fleet store; '
            'twin.robot in the bringup config)'))
    return robot


def _ns(seconds):
    return int(round(float(seconds) * 1e9))


@dataclass(frozen=True)
class LiveStart:
    """
    Where a live node starts, as the fleet store sees it.

    Attributes
    ----------
    state : dict or None
        The stored state to continue from (``estimator``, ``duty``,
        ``lost_motion_obs_rad``); None: keep the node's own state.
    new_reducer : bool
        The reducer the node's state file knew was replaced in the store since: start
        a new one.
    revision : int or None
        The store's reducer row revision (None: no reducer yet), what the first live
        segment expects.
    note : str
        One line for the log.

    """

    state: dict
    new_reducer: bool
    revision: int
    note: str


def read_start(path, robot, joint, file_t_end):
    """
    Decide whether a live node continues from the fleet store or from its state file.

    Parameters
    ----------
    path : str or os.PathLike
        The fleet store; a missing file is an empty history (created with the first
        segment).
    robot, joint : str
        The reducer.
    file_t_end : float or None
        Stream time of the last window in the node's state file [s]; None when it has
        no state file (or one without a window).

    Returns
    -------
    LiveStart
        The store's state when it is newer than the file (or there is no file); a new
        reducer when the store's reducer was installed after the file's last window and
        has no data yet; else the file.

    Raises
    ------
    StoreError
        If the file exists but is not a usable fleet store.

    """
    where = f'{robot}/{joint}'
    if not Path(path).exists():
        return LiveStart(None, False, None, f'fleet store {path} does not exist yet: it is '
                                            'created with the first live segment')
    with FleetStore(path) as store:
        reducer = store.in_service(robot, joint)
    if reducer is None:
        return LiveStart(None, False, None, f'no reducer {where} in the fleet store {path} '
                                            'yet: the live windows start its history')
    stored = reducer.state
    stored_t = (stored or {}).get('estimator', {}).get('t_end')
    replaced = (reducer.installed_ns is not None and file_t_end is not None
                and _ns(file_t_end) < reducer.installed_ns)
    installed = iso_from_ns(reducer.installed_ns)
    if stored is not None and (file_t_end is None or replaced or (
            stored_t is not None and stored_t > file_t_end)):
        why = 'no state file' if file_t_end is None else (
            f'the state file ends at {iso_from_ns(_ns(file_t_end))}, before the reducer was '
            f'installed at {installed}' if replaced else
            f'newer than the state file, which ends at {iso_from_ns(_ns(file_t_end))}')
        return LiveStart(stored, False, reducer.revision,
                         f'continuing {where} from the fleet store {path} (ends at '
                         f'{iso_from_ns(reducer.last_ns)}, {reducer.exposure_s / HOUR:.1f} h '
                         f'in {reducer.bags} bag(s) and {reducer.live_segments} live '
                         f'segment(s)): {why}')
    if replaced:
        return LiveStart(None, True, reducer.revision,
                         f'{where} was replaced at {installed} (fleet store {path}), after '
                         f'the state file ends ({iso_from_ns(_ns(file_t_end))}): starting '
                         'a new reducer')
    if stored is None:
        return LiveStart(None, False, reducer.revision,
                         f'the fleet store {path} has no data of {where} yet: continuing '
                         'from the state file')
    return LiveStart(None, False, reducer.revision,
                     f'the state file is as new as the fleet store {path} or newer '
                     f'(store ends at {iso_from_ns(reducer.last_ns)}): continuing from the '
                     'state file')


@dataclass
class _Chunk:
    """Windows waiting for the store; a replacement before them if ``replace_note``."""

    replace_note: str = None
    replaced: bool = False
    features: list = field(default_factory=list)
    wear: list = field(default_factory=list)
    life: list = field(default_factory=list)
    levels: list = field(default_factory=list)
    state: dict = None
    summary: dict = None
    dropped: int = 0
    dropped_exposure_s: float = 0.0
    rejected: int = 0


class LiveHistory:
    """
    A live node's windows on their way into the fleet store.

    :meth:`add` runs where the estimator steps (the node's background worker) and only
    keeps records in memory; :meth:`flush` runs on a thread of its own and does all
    file work; :meth:`status` is read by the diagnostics.

    Parameters
    ----------
    path : str or os.PathLike
        The fleet store (created when missing).
    robot, joint : str
        The reducer.
    params : ReducerParams
        Reducer parameters (for the remaining life).
    life_config : LifeConfig
        Limit and thresholds, stored with the reducer.
    start : LiveStart
        Where the node started (the revision the first segment expects, the stored
        duty).
    name : str
        The node's name, recorded with each segment (``live <name>``).
    log : callable, optional
        Called with one line of text for notable events.

    """

    def __init__(self, path, robot, joint, params, life_config, start, name, log=None):
        self.path = Path(path)
        self.robot = robot
        self.joint = joint
        self.life_config = life_config
        self.life = LifeStage(params, life_config)
        duty = (start.state or {}).get('duty')
        self.life.duty = None if duty is None else SimpleNamespace(**duty)
        self.expected = start.revision
        self.name = name
        self.source = f'live {name}'
        self.log = log or (lambda text: None)
        # What the joint's window analysis found at the test torque (``te_monitor``'s
        # :class:`.life_basis.TorqueCheckFinding`, :mod:`reducer_twin.nodes.torque_check`),
        # set by the node; None: not heard.
        self.test_torque_check = None
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime('%Y%m%dT%H%M%SZ')
        self.session = f'{stamp}-{uuid.uuid4().hex[:8]}'
        self.worker = {'engine': 'live', 'node': socket.gethostname(), 'pid': os.getpid(),
                       'ros_node': name}
        self.max_pending = MAX_PENDING_WINDOWS
        self._lock = threading.Lock()
        self._chunks = [_Chunk()]
        self._pending = 0
        self._seq = 0
        self.segments_written = 0
        self.windows_written = 0
        self.windows_not_stored = 0
        self.flushes_failed = 0
        self.busy_skips = 0
        self.last_write_utc = None
        self.error = None
        self.busy = None
        self.conflict = None

    # ------------------------------------------------------------- on the worker

    def add(self, record, wear, estimator_state, lost_motion_obs, rejected=0):
        """
        Keep one stepped window for the store.

        Parameters
        ----------
        record : mapping
            Its ``te_features`` record.
        wear : mapping
            The ``wear`` record after it (:meth:`EstimatorStage.record`).
        estimator_state : dict
            ``WearEstimator.state_dict()`` after it.
        lost_motion_obs : float
            The estimator stage's last observation [rad].
        rejected : int
            Messages the node rejected since the previous window.

        Returns
        -------
        str
            The health level of the window's remaining life.

        """
        try:
            self.life.observe_duty(features_from_record(record).duty)
            life, level, _ = self.life.process(wear)
        except ReducerTwinError as err:
            # An estimate the remaining life cannot use; the life_publisher rejects it too.
            with self._lock:
                self.windows_not_stored += 1
            self.error = (f'window ending {iso_from_ns(_ns(wear["stamp_s"]))} not stored: '
                          f'{err}')
            return 'ERROR'
        state = reducer_state(estimator_state, self.life.duty, lost_motion_obs,
                              wear.get('soft_zone_shortfall_rad', 0.0))
        features = record_values(TE_FEATURES, record)
        with self._lock:
            if self.conflict is not None:
                self.windows_not_stored += 1
                return level
            chunk = self._chunks[-1]
            chunk.features.append(features)
            chunk.wear.append(record_values(WEAR_ESTIMATE, wear))
            chunk.life.append(record_values(REMAINING_LIFE, life))
            chunk.levels.append(level)
            chunk.state = state
            chunk.rejected += int(rejected)
            self._pending += 1
            if self._pending > self.max_pending:
                self._drop_oldest()
        return level

    def _drop_oldest(self):
        """Forget the oldest waiting window (its operating time stays counted)."""
        for chunk in self._chunks:
            if chunk.features:
                chunk.dropped_exposure_s += float(chunk.features[0][_EXPOSURE])
                for rows in (chunk.features, chunk.wear, chunk.life, chunk.levels):
                    del rows[0]
                chunk.dropped += 1
                self._pending -= 1
                self.windows_not_stored += 1
                return

    def configure_life(self, config):
        """Use new life parameters from the next window on (the duty seen so far stays)."""
        duty = self.life.duty
        self.life = LifeStage(self.life.params, config)
        self.life.duty = duty
        self.life_config = config

    def mark_replacement(self, note):
        """Record that the reducer was replaced after the windows kept so far."""
        with self._lock:
            if self.conflict is None:
                self._chunks.append(_Chunk(replace_note=note))

    # ------------------------------------------------------------- on the store thread

    def flush(self):
        """
        Write the windows kept so far as live segments (one transaction each).

        Never raises for the store: a busy store (another writer) is left for the next
        flush, a failure (full disk) is kept as :attr:`error` and the windows wait.

        Returns
        -------
        int
            Segments written by this call.

        """
        with self._lock:
            if self.conflict is not None:
                return 0
            chunks = self._chunks
            self._chunks = [_Chunk()]
        written, done = 0, 0
        store = None
        try:
            if not any(c.features or (c.replace_note and not c.replaced) for c in chunks):
                done = len(chunks)
                return 0
            store = FleetStore(self.path, create=True)
            store.lock_for_writing(timeout_s=LOCK_WAIT_S)
            for chunk in chunks:
                if chunk.replace_note is not None and not chunk.replaced:
                    self._replace(store, chunk.replace_note)
                    chunk.replaced = True
                if chunk.features:
                    self._write(store, chunk)
                    written += 1
                done += 1
            if self.error is not None:
                self.log(f'fleet store {self.path} written again: {written} segment(s)')
            self.error = None
            self.busy = None
        except StoreBusy as err:
            self.busy_skips += 1
            self.busy = f'{err}; the windows wait for the next flush'
        except StoreConflict as err:
            self._conflict(err, chunks[done:])
            done = len(chunks)
        except (StoreError, sqlite3.Error, OSError) as err:
            self.flushes_failed += 1
            what = str(err) if isinstance(err, StoreError) else \
                f'cannot write the fleet store {self.path}: {err}'
            error = f'{what}; the store keeps its previous state and the windows wait for ' \
                    'the next flush'
            if error != self.error:
                self.log(error)        # once, not every flush while the disk stays full
            self.error = error
        finally:
            if store is not None:
                store.close()
            self._requeue(chunks[done:])
        return written

    def _replace(self, store, note):
        reducer = store.in_service(self.robot, self.joint)
        if reducer is None:
            # Nothing of the old reducer reached the store: the next segment starts anew.
            self.expected = None
            return
        if reducer.revision != self.expected:
            raise StoreConflict(
                f'reducer {self.robot}/{self.joint} changed in the fleet store {self.path} '
                f'since {self.source} continued from it; the replacement was not recorded: '
                'record it with reducer-twin replace and restart the node')
        _, new = store.replace(self.robot, self.joint, None, note)
        self.expected = new.revision
        self.log(f'fleet store {self.path}: {self.robot}/{self.joint} replaced at '
                 f'{iso_from_ns(new.installed_ns)} ({note})')

    def _write(self, store, chunk):
        segment, aging = self.segment(chunk)
        self.expected = store.write_live_segment(self.robot, self.session, self._seq, segment,
                                                 aging, self.source)
        self._seq += 1
        self.segments_written += 1
        self.windows_written += segment.windows
        self.last_write_utc = datetime.datetime.now(datetime.timezone.utc).isoformat(
            timespec='seconds')
        with self._lock:
            self._pending -= len(chunk.features)
        chunk.features, chunk.wear, chunk.life, chunk.levels = [], [], [], []
        chunk.dropped, chunk.dropped_exposure_s = 0, 0.0

    def segment(self, chunk):
        """
        Build the store segment of waiting windows.

        Returns
        -------
        tuple
            ``(Segment, aging_factor)``.

        """
        features = np.asarray(chunk.features, dtype=float).reshape(-1, len(TE_FEATURES.fields))
        wear = np.asarray(chunk.wear, dtype=float).reshape(-1, len(WEAR_ESTIMATE.fields))
        life = np.asarray(chunk.life, dtype=float).reshape(-1, len(REMAINING_LIFE.fields))
        exposure = float(np.nansum(features[:, _EXPOSURE])) + chunk.dropped_exposure_s
        duration = float(np.nansum(features[:, _DURATION]))
        aging = float(np.nansum(features[:, _EXPOSURE])) / duration if duration > 0 else 1.0
        start = features[0, _START] if np.isfinite(features[0, _START]) else features[0, _END]
        first_ns, last_ns = _ns(start), _ns(features[-1, _END])
        samples = features[:, _SAMPLES]
        summary = self._summary(features, wear, life, chunk.levels)
        return Segment(
            joint=self.joint, expected_revision=self.expected, state=chunk.state,
            first_ns=first_ns, last_ns=last_ns, windows=len(features), exposure_s=exposure,
            messages=int(np.nansum(samples[np.isfinite(samples)])), rejected=chunk.rejected,
            summary=summary, levels=list(chunk.levels), features=features, wear=wear,
            life=life, limit_rad=self.life_config.lost_motion_limit,
            warn_s=self.life_config.warn_s, error_s=self.life_config.error_s,
            worker=dict(self.worker, session=self.session)), aging

    def _summary(self, features, wear, life, levels):
        """Return the ``--json`` summary of the joint at the segment's end (as a bag's)."""
        w = dict(zip(WEAR_ESTIMATE.fields, wear[-1])) if len(wear) else {}
        lf = dict(zip(REMAINING_LIFE.fields, life[-1])) if len(life) else {}
        # Observed: the estimate rests on at least one lost motion, in this segment or
        # before it (the live estimate carries on; a quiet minute is no new reducer).
        observed = int(w.get('updates', 0)) > 0
        out = estimate_numbers(w, lf, observed)
        out['observed'] = observed
        out['windows'] = int(np.sum(np.isfinite(features[:, _LOST_MOTION])))
        out['reason'] = None if observed else 'the joint never reversed under load while ' \
            'watched live'

        out['rul_censored'] = bool(len(life) and life[-1][_CENSORED] > 0)
        out.update(life_basis(w, lf, observed))
        # What was found at the test torque, as a bag's "inputs" say it.
        found = self.test_torque_check if observed else None
        out['test_torque_check'] = None if found is None else found.check
        out['inputs'] = torque_check_lines(levels[-1] if levels else None, found, w)
        return out

    def _requeue(self, chunks):
        """Put windows not written back in front of the ones that came meanwhile."""
        chunks = [c for c in chunks if c.features or
                  (c.replace_note is not None and not c.replaced)]
        if not chunks:
            return
        with self._lock:
            merged = []
            for chunk in chunks + self._chunks:
                # Windows without a replacement before them belong to the reducer before.
                if merged and chunk.replace_note is None:
                    _append(merged[-1], chunk)
                else:
                    merged.append(chunk)
            self._chunks = merged

    def _conflict(self, err, chunks):
        n = sum(len(c.features) + c.dropped for c in chunks)
        with self._lock:
            n += sum(len(c.features) for c in self._chunks)
            self._chunks = [_Chunk()]
            self._pending = 0
            self.windows_not_stored += n
            self.conflict = str(err)
        self.error = str(err)
        self.log(f'{err} ({n} window(s) not stored)')

    # ------------------------------------------------------------- diagnostics

    @property
    def pending(self):
        """Windows waiting for the store."""
        return self._pending

    def status(self):
        """
        Return the store's part of the node's ``/diagnostics``.

        Returns
        -------
        tuple
            ``(level, values)``: ``'ERROR'`` while writes fail or after a conflict,
            ``'WARN'`` while another writer holds the store, else ``'OK'``; key/values.

        """
        values = {'store': str(self.path), 'robot': self.robot, 'store_session': self.session,
                  'store_segments_written': self.segments_written,
                  'store_windows_written': self.windows_written,
                  'store_windows_waiting': self._pending,
                  'store_windows_not_stored': self.windows_not_stored,
                  'store_flushes_failed': self.flushes_failed,
                  'store_busy_skips': self.busy_skips,
                  'store_last_write': self.last_write_utc or 'never'}
        level = 'OK'
        if self.busy:
            level = 'WARN'
            values['store_busy'] = self.busy
        if self.error:
            level = 'ERROR'
            values['store_error'] = self.error
        return level, values


def _append(into, chunk):
    """Append a chunk's windows (no replacement before them) to the chunk before it."""
    into.features += chunk.features
    into.wear += chunk.wear
    into.life += chunk.life
    into.levels += chunk.levels
    into.state = chunk.state if chunk.state is not None else into.state
    into.dropped += chunk.dropped
    into.dropped_exposure_s += chunk.dropped_exposure_s
    into.rejected += chunk.rejected


def join_store(stage, store, robot, joint, params, estimator_config, life_config, name,
               log=None, warn=None):
    """
    Continue a live estimator from the fleet store when it is newer, and keep its history.

    Parameters
    ----------
    stage : EstimatorStage
        The node's estimator stage, restored from its state file if it had one; its
        estimator is replaced by the stored state, or by a new reducer when the store
        says the reducer was replaced since.
    store : str or os.PathLike
        The fleet store.
    robot, joint : str
        The reducer.
    params : ReducerParams
        The reducer's parameters.
    estimator_config : EstimatorConfig
        Filter tuning.
    life_config : LifeConfig
        Limit and thresholds of the stored remaining life.
    name : str
        The node's name.
    log, warn : callable, optional
        Called with one line of text for notes and for store trouble.

    Returns
    -------
    LiveHistory
        Where the node's windows go.

    Raises
    ------
    InvalidParameter
        If ``robot`` is not a valid name.
    StoreError, StateFileError
        If the store cannot be read or its state cannot be used.

    """
    from reducer_twin.core.errors import StateFileError
    from reducer_twin.core.estimator import EstimatorConfig, WearEstimator
    log = log or (lambda text: None)
    check_robot(robot)
    file_t_end = stage.estimator.t_end if stage.restored_from else None
    try:
        start = read_start(store, robot, joint, file_t_end)
    except StoreError as err:
        raise StoreError(f'parameter store: {err}') from None
    if start.state is not None:
        try:
            stage.continue_from(start.state, estimator_config)
        except StateFileError as err:
            raise StateFileError(f'parameter store: the state of {robot}/{joint} in the '
                                 f'fleet store {store} cannot be used: {err}') from None
        stage.restored_from = f'fleet store {store} ({robot}/{joint})'
        if stage.soft_zone_shortfall != 0.0:
            log(f'{robot}/{joint}: {carried_line(stage.soft_zone_shortfall)}')
    elif start.new_reducer:
        # Fitted new: not the unit the configuration's service time was of.
        stage.estimator = WearEstimator(params,
                                        (estimator_config or EstimatorConfig()).fitted_new())
        stage.restored_from = None
    log(start.note)
    if start.state is not None or start.new_reducer:
        stage.save()          # the state file follows the store from now on
    return LiveHistory(store, robot, joint, params, life_config, start, name, log=warn)
