"""
Estimator state files: checksummed JSON written atomically, with a backup.

A state file holds ``{'format', 'sha256', 'state'}``: the state dict of
:meth:`~reducer_twin.core.estimator.WearEstimator.state_dict` as canonical
JSON and its sha256. It is written to a temporary file in the same
directory, fsynced and moved over the target with ``os.replace`` (a crash
leaves either the old or the new file), and the previous good file is kept
as ``<path>.bak``. Loading falls back to the backup when the primary is
truncated or corrupt, and never starts from zeros silently.

:class:`StateFile` is what a caller hands to
:class:`~reducer_twin.core.pipeline.EstimatorStage`: it restores the
estimator on start and saves each new state, either at once (offline) or
on one background thread (live nodes, so a 1 kHz executor never waits for
the disk).
"""

from dataclasses import dataclass
import errno
import hashlib
import json
import math
import os
from pathlib import Path
import queue
import tempfile
import threading

from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import STATE_KIND, WearEstimator
from reducer_twin.core.pipeline import SOFT_ZONE_KEY


def save_estimator(estimator, path):
    """
    Write an estimator's state atomically, keeping the previous good file as ``<path>.bak``.

    Parameters
    ----------
    estimator : WearEstimator
        The estimator.
    path : str or Path
        Destination file.

    Raises
    ------
    StateFileError
        If the file cannot be written.

    """
    write_state_file(path, encode_state(estimator.state_dict()))


def load_estimator(path, params, config=None):
    """
    Read a state file written by :func:`save_estimator` and restore the estimator.

    Parameters
    ----------
    path : str or Path
        State file.
    params : ReducerParams
        Parameters of the reducer.
    config : EstimatorConfig, optional
        Tuning; by default the one stored in the state.

    Returns
    -------
    WearEstimator
        The restored estimator.

    Raises
    ------
    StateFileError
        If the file is missing, truncated, corrupt (checksum), of another
        version or of another reducer.

    """
    return _load(path, params, config)[0]


def _load(path, params, config=None):
    """Return the estimator of a state file and the soft-zone shortfall it carries [rad]."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise StateFileError(f'cannot read estimator state {path}: {err}') from err
    state = decode_state(data, path)
    try:
        estimator = WearEstimator.from_state(params, state, config)
    except StateFileError as err:
        raise StateFileError(f'{path}: {err}') from err
    shortfall = state.get(SOFT_ZONE_KEY, 0.0)
    if isinstance(shortfall, bool) or not isinstance(shortfall, (int, float)) \
            or not math.isfinite(shortfall):
        raise StateFileError(f'{path}: {SOFT_ZONE_KEY} must be a finite number of radians, '
                             f'got {shortfall!r}')
    return estimator, float(shortfall)


@dataclass(frozen=True)
class LoadedState:
    """
    Result of :func:`load_with_fallback`.

    Attributes
    ----------
    estimator : WearEstimator
        The restored estimator.
    path : Path
        The file actually used.
    used_backup : bool
        True when the primary file failed and ``<path>.bak`` was used.
    primary_error : str or None
        Why the primary file was not used.
    soft_zone_shortfall : float
        The soft zone's shortfall the stage gave the lost motion less when it saved the
        state (:attr:`.pipeline.EstimatorStage.soft_zone_shortfall`; 0 without one,
        negative where loads within a soft zone gave it more, :mod:`.within_zone`) [rad].

    """

    estimator: WearEstimator
    path: Path
    used_backup: bool
    primary_error: str = None
    soft_zone_shortfall: float = 0.0


def backup_path(path):
    """
    Return the backup file of a state file, ``<path>.bak``.

    Parameters
    ----------
    path : str or Path
        State file.

    Returns
    -------
    Path
        Backup file.

    """
    path = Path(path)
    return path.with_name(path.name + '.bak')


def load_with_fallback(path, params, config=None):
    """
    Load a state file, falling back to ``<path>.bak`` if the primary fails.

    Never starts from zeros silently: if neither file is usable the error
    names both reasons, and the caller decides whether to start afresh.

    Parameters
    ----------
    path : str or Path
        Primary state file.
    params : ReducerParams
        Parameters of the reducer.
    config : EstimatorConfig, optional
        Tuning; by default the one stored in the state.

    Returns
    -------
    LoadedState
        The estimator and which file it came from.

    Raises
    ------
    StateFileError
        If neither the primary nor the backup file can be used.

    """
    (est, shortfall), used, primary = read_with_fallback(
        path, lambda p: _load(p, params, config), 'estimator state')
    return LoadedState(est, used, primary is not None, primary, shortfall)


def read_with_fallback(path, load, what):
    """
    Read a state file with ``load``, falling back to ``<path>.bak`` if the primary fails.

    Parameters
    ----------
    path : str or Path
        Primary state file.
    load : callable
        Reads one file (a Path); raises :class:`StateFileError` naming it when unusable.
    what : str
        What the file holds, for the message when neither can be used.

    Returns
    -------
    tuple
        ``(load's result, the file used, why the primary was not used or None)``.

    Raises
    ------
    StateFileError
        If neither file can be used: both reasons.

    """
    path = Path(path)
    try:
        return load(path), path, None
    except StateFileError as primary:
        backup = backup_path(path)
        try:
            return load(backup), backup, str(primary)
        except StateFileError as secondary:
            raise StateFileError(f'no usable {what}: {primary}; backup: {secondary}') \
                from primary


def canonical_json(state):
    """
    Serialize a state dict canonically (sorted keys, no spaces, no NaN).

    Parameters
    ----------
    state : dict
        A state dict.

    Returns
    -------
    str
        JSON text; floats are written with ``repr`` and read back exactly.

    """
    return json.dumps(state, sort_keys=True, separators=(',', ':'), allow_nan=False)


def encode_state(state, kind=STATE_KIND):
    """
    Wrap a state dict with its checksum as the bytes of a state file.

    Parameters
    ----------
    state : dict
        A state dict.
    kind : str
        What the state is of (the file's ``format`` is ``<kind>.file``): the estimator's
        by default.

    Returns
    -------
    bytes
        UTF-8 JSON ``{'format', 'sha256', 'state'}``.

    """
    body = canonical_json(state)
    digest = hashlib.sha256(body.encode('utf-8')).hexdigest()
    # One key a line, the state as its canonical text: json's indenting encoder is the pure
    # Python one, which leaves reference cycles behind on every call (an estimator writes
    # its file after every window) and costs several times the C encoder's time.
    text = (f'{{\n "format": {json.dumps(kind + ".file")},\n "sha256": "{digest}",\n'
            f' "state": {body}\n}}\n')
    return text.encode('utf-8')


def decode_state(data, path='<bytes>', kind=STATE_KIND):
    """
    Check a state file's format and checksum and return its state dict.

    Parameters
    ----------
    data : bytes
        File content.
    path : str or Path
        File name, for messages.
    kind : str
        What the state must be of (:func:`encode_state`).

    Returns
    -------
    dict
        The state dict.

    Raises
    ------
    StateFileError
        If the content is not JSON, not a state file or fails its checksum.

    """
    try:
        wrapper = json.loads(data.decode('utf-8'))
    except (UnicodeDecodeError, ValueError) as err:
        raise StateFileError(
            f'{path} is not valid JSON (truncated or corrupt?): {err}') from err
    if not isinstance(wrapper, dict) or wrapper.get('format') != kind + '.file':
        found = wrapper.get('format') if isinstance(wrapper, dict) else type(wrapper).__name__
        raise StateFileError(
            f'{path}: format must be {kind + ".file"!r}, got {found!r}')
    state = wrapper.get('state')
    try:
        digest = hashlib.sha256(canonical_json(state).encode('utf-8')).hexdigest()
    except (TypeError, ValueError) as err:
        raise StateFileError(f'{path}: state cannot be serialized: {err}') from err
    if digest != wrapper.get('sha256'):
        raise StateFileError(
            f'{path}: checksum mismatch, sha256 of the state must be '
            f'{wrapper.get("sha256")!r}, got {digest!r} (file corrupt or edited)')
    return state


def write_state_file(path, data, kind=STATE_KIND, what='estimator state'):
    """
    Write encoded state bytes atomically, keeping the previous good file as ``.bak``.

    Parameters
    ----------
    path : str or Path
        Destination file.
    data : bytes
        Output of :func:`encode_state`.
    kind : str
        What the state is of: a primary file that is not a good one of it is never
        made the backup.
    what : str
        What the file holds, for messages.

    Raises
    ------
    StateFileError
        If the file cannot be written.

    """
    path = Path(path)
    backup = backup_path(path)
    try:
        if path.exists():
            previous = path.read_bytes()
            try:
                decode_state(previous, path, kind)
            except StateFileError:
                pass  # never replace a good backup by a corrupt primary
            else:
                _atomic_write(backup, previous)
        _atomic_write(path, data)
    except OSError as err:
        if err.errno in (errno.ENOSPC, errno.EDQUOT):
            try:
                stats = os.statvfs(path.parent)
                free = f', {stats.f_bavail * stats.f_frsize:,} free'
            except OSError:
                free = ''
            raise StateFileError(
                f'{"disk quota exceeded" if err.errno == errno.EDQUOT else "no space left"} '
                f'writing the {what} {path}: {len(data):,} bytes needed{free}; the '
                'previous state file is kept') from err
        raise StateFileError(f'cannot write {what} to {path}: {err}') from err


def _atomic_write(path, data):
    """Write bytes to ``path`` through a fsynced temporary file and ``os.replace``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'wb') as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)


class StateWriter:
    """
    Write estimator state files on one background thread, in order.

    The state is snapshotted (encoded) by the caller at once; only the file
    work (backup, temporary file, fsync, rename) runs on the thread. A write
    that fails (a full disk) leaves the previous file in place, is kept as
    :attr:`error` and counted; the next one is tried as usual, and the first
    that succeeds clears :attr:`error` and counts a recovery.

    """

    def __init__(self):
        self._queue = queue.Queue()
        self.error = None
        self.failures = 0
        self.recoveries = 0
        self.written = 0
        self._thread = threading.Thread(target=self._run, name='state-writer', daemon=True)
        self._thread.start()

    def submit(self, path, data, kind=STATE_KIND, what='estimator state'):
        """Queue ``data`` (encoded state of ``kind``) for ``path``."""
        self._queue.put((path, data, kind, what))

    def flush(self):
        """Wait until every queued state is written."""
        self._queue.join()

    def _run(self):
        while True:
            path, data, kind, what = self._queue.get()
            try:
                write_state_file(path, data, kind, what)
                self.written += 1
                if self.error is not None:
                    self.error = None
                    self.recoveries += 1
            except StateFileError as err:
                self.error = err
                self.failures += 1
            finally:
                self._queue.task_done()


class KeptStateFile:
    """
    A state file written atomically with a backup: in place, or on a writer thread.

    Parameters
    ----------
    path : str or Path
        State file: written atomically (the previous good one kept as ``<path>.bak``).
    background : bool
        Write on a :class:`StateWriter` thread (live nodes) instead of in
        :meth:`save` (offline, tests).

    Attributes
    ----------
    kind : str
        What the state is of (the file's ``format`` is ``<kind>.file``).
    what : str
        What the file holds, for messages.
    writer : StateWriter or None
        The background writer (its ``error``, ``failures``, ``recoveries``
        and ``written`` tell how writing goes), None when writing in place.

    Raises
    ------
    StateFileError
        If the directory of the file cannot be created.

    """

    kind = STATE_KIND
    what = 'estimator state'

    def __init__(self, path, background=False):
        self.path = Path(path)
        # A fresh machine has no ~/.local/state/reducer_twin: make it now, so that the
        # first save does not fail in the middle of a run.
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise StateFileError(f'cannot create the directory of the {self.what} '
                                 f'{self.path}: {err}') from err
        self.writer = StateWriter() if background else None

    def save(self, state):
        """
        Persist a state dict now, or queue it for the writer thread.

        Parameters
        ----------
        state : dict
            The state (:meth:`WearEstimator.state_dict`, ...), encoded at once.

        Raises
        ------
        StateFileError
            If writing in place fails.

        """
        data = encode_state(state, self.kind)
        if self.writer is None:
            write_state_file(self.path, data, self.kind, self.what)
        else:
            self.writer.submit(self.path, data, self.kind, self.what)

    def flush(self):
        """Wait until the queued states are written (a no-op without a writer)."""
        if self.writer is not None:
            self.writer.flush()


class StateFile(KeptStateFile):
    """
    The state file of one reducer's estimator, as an EstimatorStage uses it.

    Restored on start (falling back to its ``.bak`` copy), written atomically after every
    window (see :class:`KeptStateFile` for the parameters).

    """

    def restore(self, params, config=None):
        """
        Load the estimator from the file or its backup, if either exists.

        Parameters
        ----------
        params : ReducerParams
            Parameters of the reducer.
        config : EstimatorConfig, optional
            Tuning; by default the one stored in the state.

        Returns
        -------
        LoadedState or None
            None when neither the file nor its backup exists (a new reducer).

        Raises
        ------
        StateFileError
            If a file exists but neither it nor its backup can be used.

        """
        if not (self.path.exists() or backup_path(self.path).exists()):
            return None
        return load_with_fallback(self.path, params, config)
