"""
The fleet store: every reducer's history across bags, in one SQLite file.

A reducer is a robot's joint between two maintenance events: ``(robot, joint)`` names
the reducer in service, and a replacement retires it and installs a new one. Per
reducer the store keeps where its estimator ended (the state the next bag continues
from), and per analysed bag a *segment*: the bag's span, counts, the summary at its end
and every window's ``te_features``, ``wear`` and ``remaining_life`` records (float64
arrays in the layouts of :mod:`reducer_twin.msg_adapters.layouts`, zlib-compressed), so trends span
bags. Bags are known by a fingerprint of their files' content, not by their path.

The live twin joins the same history: a ``wear_estimator`` with a ``store`` writes its
windows as *live segments* (:meth:`FleetStore.write_live_segment`), each recorded in the
``bags`` table as a source of kind ``live`` (one row per segment, named by the node's
session), so a reducer watched live and later analysed from bags has one history.

Durability: SQLite in WAL mode with ``synchronous=FULL``; each bag's results for all
its reducers are one transaction, so a ``kill -9`` at any point leaves the store as it
was before or after that bag. Writers take an exclusive lock on ``<store>.lock`` for
their whole run, so two ``analyze --store`` runs serialise (the second waits, then
finds the first one's bags in the store); a live writer takes it for one segment at a
time and skips a flush rather than wait long; a reducer whose row changed between planning
and writing (its ``revision``) is refused with :class:`StoreConflict`, never
overwritten. The schema is versioned (``PRAGMA user_version``) and older stores are
migrated in a transaction on opening; a newer or foreign file is refused.
"""

from dataclasses import dataclass
import datetime
import json
import os
from pathlib import Path
import sqlite3
import time
import zlib

import numpy as np
from reducer_twin.core.errors import InvalidParameter, ReducerTwinError
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, TE_FEATURES, WEAR_ESTIMATE

STORE_KIND = 'reducer_twin.fleet'
"""``store_info`` value of ``kind`` that marks a fleet store."""

LAYOUTS = {'features': TE_FEATURES, 'wear': WEAR_ESTIMATE, 'life': REMAINING_LIFE}
"""Segment columns holding window arrays, and their layouts."""

_BAG_COLUMNS = ('id, fingerprint, robot, path, first_ns, last_ns, aging_factor, messages, '
                'analysed_utc, source, session')
"""Columns of :class:`BagRow`, in order."""

BUSY_TIMEOUT_S = 60.0
"""How long a statement waits for another connection's write transaction [s]."""

_V1 = """
CREATE TABLE store_info (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE reducers (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL,
    joint TEXT NOT NULL,
    installed_ns INTEGER,
    retired_ns INTEGER,
    state TEXT,
    last_ns INTEGER,
    revision INTEGER NOT NULL DEFAULT 0,
    lost_motion_limit_rad REAL,
    warn_s REAL,
    error_s REAL
);
CREATE UNIQUE INDEX reducers_in_service ON reducers (robot, joint) WHERE retired_ns IS NULL;
CREATE TABLE bags (
    id INTEGER PRIMARY KEY,
    fingerprint TEXT NOT NULL UNIQUE,
    robot TEXT NOT NULL,
    path TEXT NOT NULL,
    first_ns INTEGER NOT NULL,
    last_ns INTEGER NOT NULL,
    aging_factor REAL NOT NULL,
    messages INTEGER NOT NULL,
    analysed_utc TEXT NOT NULL
);
CREATE INDEX bags_robot ON bags (robot, first_ns);
CREATE TABLE segments (
    reducer_id INTEGER NOT NULL REFERENCES reducers (id),
    bag_id INTEGER NOT NULL REFERENCES bags (id),
    first_ns INTEGER NOT NULL,
    last_ns INTEGER NOT NULL,
    windows INTEGER NOT NULL,
    exposure_s REAL NOT NULL,
    messages INTEGER NOT NULL,
    rejected INTEGER NOT NULL,
    summary TEXT NOT NULL,
    levels TEXT NOT NULL,
    features BLOB NOT NULL,
    wear BLOB NOT NULL,
    life BLOB NOT NULL,
    PRIMARY KEY (reducer_id, bag_id)
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL,
    joint TEXT NOT NULL,
    kind TEXT NOT NULL,
    at_ns INTEGER NOT NULL,
    note TEXT NOT NULL,
    retired_id INTEGER REFERENCES reducers (id),
    installed_id INTEGER REFERENCES reducers (id),
    recorded_utc TEXT NOT NULL
);
"""

# Version 2: which engine, node and process analysed each segment.
_V2 = 'ALTER TABLE segments ADD COLUMN worker TEXT;'

# Version 3: live segments. A row of ``bags`` is a source of windows: a recorded bag
# (``source`` 'bag') or one segment of a live session (``source`` 'live', ``session`` the
# node's session id).
_V3 = """
ALTER TABLE bags ADD COLUMN source TEXT NOT NULL DEFAULT 'bag';
ALTER TABLE bags ADD COLUMN session TEXT;
"""

MIGRATIONS = (_V1, _V2, _V3)
"""Schema steps: ``MIGRATIONS[k]`` takes a store from version k to k + 1."""

SCHEMA_VERSION = len(MIGRATIONS)


class StoreError(ReducerTwinError):
    """The fleet store cannot be opened, read or written as asked."""


class StoreConflict(StoreError):
    """Another process changed a reducer between this run's planning and its writing."""


class StoreBusy(StoreError):
    """Another process holds the store's writer lock."""


def utc_now():
    """Return the current time as ISO 8601 UTC text (seconds)."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')


def iso_from_ns(stamp_ns):
    """Return a bag-clock stamp [ns since the epoch] as ISO 8601 UTC text, None for None."""
    if stamp_ns is None:
        return None
    seconds, ns = divmod(int(stamp_ns), 1_000_000_000)
    moment = datetime.datetime.fromtimestamp(seconds, datetime.timezone.utc)
    text = moment.isoformat(timespec='seconds')
    return text[:-6] + 'Z' if text.endswith('+00:00') else text


def parse_time(text, flag='--at'):
    """
    Read a time given as ISO 8601 text or as bag-clock nanoseconds.

    Parameters
    ----------
    text : str
        ``2026-03-01T08:00:00Z`` (a time without a zone is UTC) or an integer
        number of nanoseconds since the epoch.
    flag : str
        Option name for the message.

    Returns
    -------
    int
        Nanoseconds since the epoch.

    Raises
    ------
    InvalidParameter
        If the text is neither.

    """
    text = str(text).strip()
    if text.lstrip('-').isdigit():
        value = int(text)
        if value < 0:
            raise InvalidParameter(f'{flag} must be a time >= 0 ns, got {text!r}')
        return value
    try:
        moment = datetime.datetime.fromisoformat(text.replace('Z', '+00:00'))
    except ValueError:
        raise InvalidParameter(f'{flag} must be an ISO 8601 time (e.g. 2026-03-01T08:00:00Z) '
                               f'or nanoseconds since the epoch, got {text!r}') from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=datetime.timezone.utc)
    delta = moment - datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc)
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


def pack_array(values, layout):
    """Encode window records (rows in ``layout`` order) as zlib-compressed float64."""
    values = np.asarray(values, dtype='<f8').reshape(-1, len(layout.fields))
    return zlib.compress(values.tobytes(), 6)


def unpack_array(blob, layout):
    """Decode :func:`pack_array` output to an array (rows, fields)."""
    flat = np.frombuffer(zlib.decompress(blob), dtype='<f8')
    return flat.reshape(-1, len(layout.fields)).copy()


@dataclass(frozen=True)
class Reducer:
    """
    One reducer of the store (a robot's joint between maintenance events).

    Attributes
    ----------
    row_id : int
        Row id.
    robot, joint : str
        Where it is mounted.
    installed_ns, retired_ns : int or None
        When it was installed (None: before its first data) and retired (None: in
        service) [ns, bag clock].
    state : dict or None
        Where its stages ended (``JointBack.state``); None before its first bag.
    last_ns : int or None
        End of its newest analysed data [ns].
    revision : int
        Count of writes to this row (optimistic concurrency).
    bags : int
        Bags analysed for it.
    windows : int
        Windows analysed for it.
    exposure_s : float
        Operating seconds observed [s].
    summary : dict or None
        The ``--json`` summary at the end of its newest bag.
    lost_motion_limit_rad, warn_s, error_s : float or None
        Limit and thresholds its newest bag was analysed with.
    live_segments : int
        Live segments written for it by a ``wear_estimator`` (not counted in ``bags``).
    live_exposure_s : float
        Operating seconds of those live segments (part of ``exposure_s``) [s].

    """

    row_id: int
    robot: str
    joint: str
    installed_ns: int
    retired_ns: int
    state: dict
    last_ns: int
    revision: int
    bags: int
    windows: int
    exposure_s: float
    summary: dict
    lost_motion_limit_rad: float
    warn_s: float
    error_s: float
    live_segments: int = 0
    live_exposure_s: float = 0.0

    @property
    def key(self):
        """Return ``(robot, joint)``."""
        return self.robot, self.joint

    @property
    def in_service(self):
        """Whether the reducer has not been replaced."""
        return self.retired_ns is None


@dataclass(frozen=True)
class BagRow:
    """A bag the store holds results of (see the ``bags`` table)."""

    row_id: int
    fingerprint: str
    robot: str
    path: str
    first_ns: int
    last_ns: int
    aging_factor: float
    messages: int
    analysed_utc: str
    source: str = 'bag'
    session: str = None


@dataclass
class Segment:
    """
    One bag's results for one reducer, to be written.

    Attributes
    ----------
    joint : str
        The joint (the reducer is the one in service on the bag's robot).
    expected_revision : int or None
        The reducer row's revision when the run was planned (None: no reducer yet).
    state : dict
        Where the reducer's stages ended with this bag.
    first_ns, last_ns : int
        Span of the bag's data [ns].
    windows : int
        Windows analysed.
    exposure_s : float
        Operating seconds of the windows [s].
    messages, rejected : int
        JointState messages and rejected samples.
    summary : dict
        The joint's ``--json`` summary.
    levels : list of str
        Health level of each ``remaining_life`` record.
    features, wear, life : ndarray
        Window records in the layouts of :data:`LAYOUTS`.
    limit_rad, warn_s, error_s : float
        The life configuration used.
    worker : dict or None
        ``{"engine", "node", "pid"}`` of the process that analysed it.

    """

    joint: str
    expected_revision: int
    state: dict
    first_ns: int
    last_ns: int
    windows: int
    exposure_s: float
    messages: int
    rejected: int
    summary: dict
    levels: list
    features: np.ndarray
    wear: np.ndarray
    life: np.ndarray
    limit_rad: float
    warn_s: float
    error_s: float
    worker: dict = None


@dataclass(frozen=True)
class Trend:
    """A reducer's windows over all its bags, in time order."""

    features: np.ndarray
    wear: np.ndarray
    life: np.ndarray
    levels: list
    bag_starts_h: list


class FleetStore:
    """
    An open fleet store.

    Parameters
    ----------
    path : str or os.PathLike
        The SQLite file.
    create : bool
        Create the file when missing (``analyze --store``); otherwise a missing file
        is an error (``fleet``, ``replace``).

    Raises
    ------
    StoreError
        If the file is missing (without ``create``), not a fleet store, of a newer
        schema, or cannot be opened.

    """

    def __init__(self, path, create=False):
        self.path = Path(path)
        if not self.path.exists() and not create:
            raise StoreError(f'no fleet store at {self.path}; expected a file written by '
                             'reducer-twin analyze --store')
        if self.path.exists() and not self.path.is_file():
            raise StoreError(f'fleet store {self.path} is not a file')
        self._lock_fd = None
        try:
            self.conn = sqlite3.connect(str(self.path), timeout=BUSY_TIMEOUT_S,
                                        isolation_level=None)
            self.conn.execute('PRAGMA foreign_keys = ON')
            self.conn.execute('PRAGMA synchronous = FULL')
            self._prepare()
        except sqlite3.OperationalError as err:
            # The file may be fine: its disk is full, or not writable, or it is locked.
            self.close()
            raise StoreError(f'cannot open the fleet store {self.path}: {err}') from None
        except sqlite3.DatabaseError as err:
            self.close()
            raise StoreError(f'{self.path} is not a usable fleet store: {err}') from None

    # ----------------------------------------------------------------- schema

    def _prepare(self):
        conn = self.conn
        # One read transaction: the version and the tables of one moment (another process
        # creating the store at the same time commits its schema and version together).
        conn.execute('BEGIN')
        try:
            version = conn.execute('PRAGMA user_version').fetchone()[0]
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
        finally:
            conn.execute('COMMIT')
        if version > SCHEMA_VERSION:
            raise StoreError(f'{self.path}: fleet store schema version {version} is newer than '
                             f'this reducer-twin reads (up to {SCHEMA_VERSION}); update '
                             'reducer-twin')
        if version == 0 and tables:
            raise StoreError(f'{self.path} is an SQLite file but not a fleet store (tables: '
                             f'{sorted(tables)}); expected a file written by analyze --store')
        if version > 0:
            kind = conn.execute("SELECT value FROM store_info WHERE key = 'kind'").fetchone()
            if kind is None or kind[0] != STORE_KIND:
                raise StoreError(f'{self.path} is not a fleet store (kind {kind!r})')
        if version < SCHEMA_VERSION:
            self.migrate(SCHEMA_VERSION)
        # Two processes opening a new store at once: the switch to WAL needs the file to
        # itself and can fail at once as locked (no busy wait); it is tried again.
        deadline = time.monotonic() + BUSY_TIMEOUT_S
        while True:
            try:
                if conn.execute('PRAGMA journal_mode').fetchone()[0].lower() == 'wal':
                    break
                conn.execute('PRAGMA journal_mode = WAL')
            except sqlite3.OperationalError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.01)

    def migrate(self, target):
        """
        Bring the schema to version ``target`` in one transaction.

        Parameters
        ----------
        target : int
            Schema version, at most :data:`SCHEMA_VERSION`.

        """
        conn = self.conn
        conn.execute('BEGIN IMMEDIATE')
        try:
            version = conn.execute('PRAGMA user_version').fetchone()[0]
            for step in range(version, target):
                for statement in MIGRATIONS[step].split(';'):
                    if statement.strip():
                        conn.execute(statement)
                if step == 0:
                    conn.executemany('INSERT INTO store_info (key, value) VALUES (?, ?)', [
                        ('kind', STORE_KIND), ('created_utc', utc_now())] + [
                        (f'layout.{name}', layout.label) for name, layout in LAYOUTS.items()])
                conn.execute(f'PRAGMA user_version = {step + 1}')
            conn.execute('COMMIT')
        except BaseException:
            conn.execute('ROLLBACK')
            raise

    @property
    def schema_version(self):
        """Return the schema version of the open store."""
        return self.conn.execute('PRAGMA user_version').fetchone()[0]

    # ----------------------------------------------------------------- locking

    def lock_for_writing(self, wait=True, notify=None, timeout_s=None):
        """
        Take the store's writer lock (``<store>.lock``) until :meth:`unlock` or :meth:`close`.

        Parameters
        ----------
        wait : bool
            Wait for another writer to finish (serialise) instead of failing.
        notify : callable, optional
            Called with one line of text when this has to wait.
        timeout_s : float, optional
            With ``wait``: give up after this long [s] (a live writer waits briefly,
            then skips its flush); default wait as long as it takes.

        Raises
        ------
        StoreBusy
            If another process holds the lock and ``wait`` is False, or still holds it
            after ``timeout_s``.
        StoreError
            If the lock file cannot be made.

        """
        import fcntl
        if self._lock_fd is not None:
            return
        lock_path = self.path.with_name(self.path.name + '.lock')
        try:
            fd = os.open(lock_path, os.O_CREAT | os.O_RDWR, 0o644)
        except OSError as err:
            raise StoreError(f'cannot create the writer lock {lock_path}: {err}') from None
        busy = StoreBusy(f'another process is writing the fleet store {self.path} '
                         f'(it holds {lock_path}); try again when it has finished')
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            if not wait:
                os.close(fd)
                raise busy from None
            if notify:
                notify(f'waiting for another process writing {self.path} to finish')
            if timeout_s is None:
                fcntl.flock(fd, fcntl.LOCK_EX)
            else:
                deadline = time.monotonic() + float(timeout_s)
                while True:
                    time.sleep(0.02)
                    try:
                        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                        break
                    except OSError:
                        if time.monotonic() >= deadline:
                            os.close(fd)
                            raise busy from None
        self._lock_fd = fd

    def unlock(self):
        """Release the writer lock (if held); the connection stays open."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def close(self):
        """Close the connection and release the writer lock."""
        conn = getattr(self, 'conn', None)
        if conn is not None:
            conn.close()
            self.conn = None
        self.unlock()

    def __enter__(self):
        """Use as a context manager."""
        return self

    def __exit__(self, *exc):
        """Close the store."""
        self.close()

    # ----------------------------------------------------------------- reading

    _REDUCER_SQL = """
        SELECT r.id, r.robot, r.joint, r.installed_ns, r.retired_ns, r.state, r.last_ns,
               r.revision, COALESCE(SUM(b.source = 'bag'), 0), COALESCE(SUM(s.windows), 0),
               COALESCE(SUM(s.exposure_s), 0.0),
               (SELECT summary FROM segments WHERE reducer_id = r.id
                ORDER BY last_ns DESC LIMIT 1),
               r.lost_motion_limit_rad, r.warn_s, r.error_s,
               COALESCE(SUM(b.source = 'live'), 0),
               COALESCE(SUM(CASE WHEN b.source = 'live' THEN s.exposure_s END), 0.0)
        FROM reducers r LEFT JOIN segments s ON s.reducer_id = r.id
             LEFT JOIN bags b ON b.id = s.bag_id"""

    @staticmethod
    def _reducer(row):
        state = json.loads(row[5]) if row[5] else None
        summary = json.loads(row[11]) if row[11] else None
        return Reducer(row[0], row[1], row[2], row[3], row[4], state, row[6], row[7], row[8],
                       row[9], float(row[10]), summary, row[12], row[13], row[14], row[15],
                       float(row[16]))

    def reducers(self):
        """Return every reducer, retired ones included, by robot, joint and installation."""
        rows = self.conn.execute(self._REDUCER_SQL + ' GROUP BY r.id ORDER BY r.robot, '
                                 'r.joint, COALESCE(r.installed_ns, -1)').fetchall()
        return [self._reducer(r) for r in rows]

    def in_service(self, robot, joint):
        """Return the reducer in service at ``(robot, joint)``, or None."""
        row = self.conn.execute(self._REDUCER_SQL + ' WHERE r.robot = ? AND r.joint = ? AND '
                                'r.retired_ns IS NULL GROUP BY r.id', (robot, joint)).fetchone()
        return self._reducer(row) if row else None

    def bag(self, fingerprint):
        """Return the stored source of this fingerprint (a bag or a live segment), or None."""
        row = self.conn.execute(f'SELECT {_BAG_COLUMNS} FROM bags WHERE fingerprint = ?',
                                (fingerprint,)).fetchone()
        return BagRow(*row) if row else None

    def bags_of(self, robot):
        """Return the robot's stored bags in time order (recorded bags, not live segments)."""
        rows = self.conn.execute(f'SELECT {_BAG_COLUMNS} FROM bags WHERE robot = ? AND '
                                 "source = 'bag' ORDER BY first_ns", (robot,)).fetchall()
        return [BagRow(*r) for r in rows]

    def bags_of_ids(self, ids):
        """Return the stored bags of these ids."""
        ids = sorted(int(i) for i in ids)
        marks = ','.join('?' * len(ids))
        rows = self.conn.execute(f'SELECT {_BAG_COLUMNS} FROM bags WHERE id IN ({marks})',
                                 ids).fetchall()
        return [BagRow(*r) for r in rows]

    def segment_bags(self, reducer_id):
        """Return the ids of the bags analysed for a reducer."""
        return {r[0] for r in self.conn.execute(
            'SELECT bag_id FROM segments WHERE reducer_id = ?', (reducer_id,))}

    def trend(self, reducer_id):
        """
        Return a reducer's windows across all its bags, in time order.

        Parameters
        ----------
        reducer_id : int
            The reducer.

        Returns
        -------
        Trend
            Concatenated ``te_features``, ``wear`` and ``remaining_life`` records, the
            levels, and the operating hours at which each bag (or live session) starts.

        """
        rows = self.conn.execute(
            'SELECT s.features, s.wear, s.life, s.levels, b.source, b.session FROM segments s '
            'JOIN bags b ON b.id = s.bag_id WHERE s.reducer_id = ? ORDER BY s.first_ns',
            (reducer_id,)).fetchall()
        parts = {name: [np.zeros((0, len(layout.fields)))] for name, layout in LAYOUTS.items()}
        levels, starts = [], []
        exposure = WEAR_ESTIMATE.fields.index('exposure_s')
        session = None
        for features, wear, life, lv, source, this_session in rows:
            for name, blob in (('features', features), ('wear', wear), ('life', life)):
                parts[name].append(unpack_array(blob, LAYOUTS[name]))
            # A live session's segments are one stretch of data: only its first one starts.
            new = source != 'live' or this_session != session
            session = this_session if source == 'live' else None
            if new and len(parts['wear'][-1]):
                starts.append(float(parts['wear'][-1][0, exposure]) / 3600.0)
            levels += json.loads(lv)
        return Trend(*(np.concatenate(parts[name]) for name in LAYOUTS), levels, starts)

    def events(self):
        """Return the maintenance events, oldest first, as dicts."""
        cur = self.conn.execute('SELECT robot, joint, kind, at_ns, note, retired_id, '
                                'installed_id, recorded_utc FROM events ORDER BY at_ns, id')
        names = [d[0] for d in cur.description]
        return [dict(zip(names, row)) for row in cur.fetchall()]

    def size_bytes(self):
        """Return the store's size on disk, write-ahead log included [bytes]."""
        total = 0
        for suffix in ('', '-wal'):
            try:
                total += self.path.with_name(self.path.name + suffix).stat().st_size
            except OSError:
                pass
        return total

    # ----------------------------------------------------------------- writing

    def _transaction(self, work):
        conn = self.conn
        conn.execute('BEGIN IMMEDIATE')
        try:
            out = work(conn)
            conn.execute('COMMIT')
        except BaseException:
            conn.execute('ROLLBACK')
            raise
        return out

    def write_bag(self, robot, fingerprint, path, first_ns, last_ns, aging_factor, messages,
                  segments, forget=()):
        """
        Record one analysed bag and its segments in one transaction.

        Parameters
        ----------
        robot : str
            The robot the bag belongs to.
        fingerprint, path : str
            The bag's identity and where it was read.
        first_ns, last_ns : int
            Span of its data [ns].
        aging_factor : float
            Aging factor applied.
        messages : int
            JointState messages read.
        segments : list of Segment
            Results per reducer (the one in service at ``(robot, segment.joint)``,
            created when there is none yet).
        forget : iterable of int
            Reducer ids whose stored history is dropped first (``--rebuild``): their
            segments, state and last stamp.

        Raises
        ------
        StoreConflict
            If a reducer's revision is not the one planned with, or the bag is stored
            for another robot.

        """
        def work(conn):
            for reducer_id in forget:
                conn.execute('DELETE FROM segments WHERE reducer_id = ?', (reducer_id,))
                conn.execute('UPDATE reducers SET state = NULL, last_ns = NULL, '
                             'revision = revision + 1 WHERE id = ?', (reducer_id,))
            row = conn.execute('SELECT id, robot FROM bags WHERE fingerprint = ?',
                               (fingerprint,)).fetchone()
            if row is not None and row[1] != robot:
                raise StoreConflict(f'{path}: this bag is in the store as a bag of robot '
                                    f'{row[1]!r}, not {robot!r}')
            if row is None:
                bag_id = conn.execute(
                    'INSERT INTO bags (fingerprint, robot, path, first_ns, last_ns, '
                    'aging_factor, messages, analysed_utc) VALUES (?, ?, ?, ?, ?, ?, ?, ?)',
                    (fingerprint, robot, str(path), int(first_ns), int(last_ns),
                     float(aging_factor), int(messages), utc_now())).lastrowid
            else:
                bag_id = row[0]
                conn.execute('UPDATE bags SET path = ?, analysed_utc = ? WHERE id = ?',
                             (str(path), utc_now(), bag_id))
            for seg in segments:
                self._write_segment(conn, robot, bag_id, seg, path)
            return bag_id

        return self._transaction(work)

    def write_live_segment(self, robot, session, seq, segment, aging_factor, path):
        """
        Record one segment of a live session (a ``wear_estimator``'s windows) in one transaction.

        The segment continues the reducer in service at ``(robot, segment.joint)``
        (created when there is none yet) exactly as a bag's would: its windows and the
        estimator state at their end. It is kept as a source of kind ``live`` in the
        ``bags`` table, so ``fleet`` counts it apart from the recorded bags, a later bag
        continues from its state and a bag overlapping it is refused.

        Parameters
        ----------
        robot : str
            The robot.
        session : str
            The node's session id (one per start of the node).
        seq : int
            The segment's number within the session.
        segment : Segment
            The windows; ``first_ns`` is the first window's start, ``last_ns`` the last
            window's end.
        aging_factor : float
            Exposure seconds per stream second of its windows.
        path : str
            What wrote it, for the ``bags`` table and messages (``live <node>``).

        Returns
        -------
        int
            The reducer row's revision after the write (what the next segment expects).

        Raises
        ------
        StoreConflict
            If the reducer changed since the writer last saw it (another process wrote
            or replaced it).
        StoreError
            If its first window does not end after the stored history.

        """
        stride = len(TE_FEATURES.fields)
        first_end_ns = segment.last_ns
        if len(segment.features):
            end = TE_FEATURES.fields.index('window_end_s')
            first_end_ns = int(round(float(
                np.asarray(segment.features).reshape(-1, stride)[0, end]) * 1e9))

        def work(conn):
            bag_id = conn.execute(
                'INSERT INTO bags (fingerprint, robot, path, first_ns, last_ns, aging_factor, '
                'messages, analysed_utc, source, session) '
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?, 'live', ?)",
                (f'live:{session}:{int(seq)}', robot, str(path), int(segment.first_ns),
                 int(segment.last_ns), float(aging_factor), int(segment.messages), utc_now(),
                 str(session))).lastrowid
            self._write_segment(conn, robot, bag_id, segment, path, start_ns=first_end_ns)
            return conn.execute('SELECT revision FROM reducers WHERE robot = ? AND joint = ? '
                                'AND retired_ns IS NULL', (robot, segment.joint)).fetchone()[0]

        return self._transaction(work)

    def _write_segment(self, conn, robot, bag_id, seg, path, start_ns=None):
        row = conn.execute('SELECT id, revision, last_ns FROM reducers WHERE robot = ? AND '
                           'joint = ? AND retired_ns IS NULL', (robot, seg.joint)).fetchone()
        expected = seg.expected_revision
        live = start_ns is not None
        if (row is None) != (expected is None) or (row is not None and row[1] != expected):
            if live:
                raise StoreConflict(
                    f'reducer {robot}/{seg.joint} changed in the fleet store {self.path} since '
                    f'{path} continued from it (another process analysed a bag of it or '
                    'replaced it); live windows are not stored: restart the node to continue '
                    'from the store')
            raise StoreConflict(
                f'{path}: reducer {robot}/{seg.joint} changed in the store while this bag '
                'was analysed (another process wrote it); nothing of this bag was stored: '
                'run the command again')
        start = seg.first_ns if start_ns is None else start_ns
        if row is not None and row[2] is not None and start <= row[2]:
            if live:
                raise StoreError(
                    f'{path}: its window ending {iso_from_ns(start)} does not end after the '
                    f'stored history of {robot}/{seg.joint} ({iso_from_ns(row[2])}): the '
                    'window stamps went back (a clock reset?) or overlap a stored bag')
            raise StoreError(f'{path}: starts at {iso_from_ns(seg.first_ns)}, before the end '
                             f'of the stored history of {robot}/{seg.joint} '
                             f'({iso_from_ns(row[2])}): the bags overlap in time')
        if row is None:
            reducer_id = conn.execute('INSERT INTO reducers (robot, joint) VALUES (?, ?)',
                                      (robot, seg.joint)).lastrowid
        else:
            reducer_id = row[0]
        conn.execute(
            'INSERT INTO segments (reducer_id, bag_id, first_ns, last_ns, windows, exposure_s, '
            'messages, rejected, summary, levels, features, wear, life, worker) '
            'VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)',
            (reducer_id, bag_id, int(seg.first_ns), int(seg.last_ns), int(seg.windows),
             float(seg.exposure_s), int(seg.messages), int(seg.rejected),
             json.dumps(seg.summary), json.dumps(list(seg.levels)),
             pack_array(seg.features, TE_FEATURES), pack_array(seg.wear, WEAR_ESTIMATE),
             pack_array(seg.life, REMAINING_LIFE),
             json.dumps(seg.worker) if seg.worker else None))
        conn.execute(
            'UPDATE reducers SET state = ?, last_ns = MAX(COALESCE(last_ns, ?), ?), '
            'revision = revision + 1, lost_motion_limit_rad = ?, warn_s = ?, error_s = ? '
            'WHERE id = ?',
            (json.dumps(seg.state), int(seg.last_ns), int(seg.last_ns), float(seg.limit_rad),
             float(seg.warn_s), float(seg.error_s), reducer_id))

    def replace(self, robot, joint, at_ns=None, note=''):
        """
        Record a replacement: retire the reducer in service and install a new one.

        Parameters
        ----------
        robot, joint : str
            Where.
        at_ns : int, optional
            When [ns, bag clock]; default just after the newest analysed data.
        note : str
            Free text kept with the event.

        Returns
        -------
        tuple of Reducer
            The retired and the new reducer.

        Raises
        ------
        StoreError
            If there is no such reducer, or ``at_ns`` is not after its analysed data.

        """
        def work(conn):
            old = self.in_service(robot, joint)
            if old is None:
                known = sorted({r.joint for r in self.reducers() if r.robot == robot})
                where = f'joints of {robot}: {", ".join(known)}' if known else \
                    f'robots: {", ".join(sorted({r.robot for r in self.reducers()})) or "none"}'
                raise StoreError(f'no reducer {robot}/{joint} in the fleet store {self.path} '
                                 f'({where})')
            at = at_ns
            if at is None:
                at = (old.last_ns if old.last_ns is not None else old.installed_ns or 0) + 1
            floor = max(x for x in (old.last_ns, old.installed_ns, -1) if x is not None)
            if at <= floor:
                raise StoreError(
                    f'--at {iso_from_ns(at)} ({at} ns) is not after the newest data of '
                    f'{robot}/{joint} ({iso_from_ns(floor)}, {floor} ns); a replacement '
                    'must follow the analysed history')
            conn.execute('UPDATE reducers SET retired_ns = ?, revision = revision + 1 '
                         'WHERE id = ?', (int(at), old.row_id))
            new_id = conn.execute('INSERT INTO reducers (robot, joint, installed_ns) '
                                  'VALUES (?, ?, ?)', (robot, joint, int(at))).lastrowid
            conn.execute('INSERT INTO events (robot, joint, kind, at_ns, note, retired_id, '
                         'installed_id, recorded_utc) VALUES (?, ?, ?, ?, ?, ?, ?, ?)',
                         (robot, joint, 'replaced', int(at), note, old.row_id, new_id, utc_now()))
            return old.row_id, new_id

        old_id, new_id = self._transaction(work)
        by_id = {r.row_id: r for r in self.reducers()}
        return by_id[old_id], by_id[new_id]
