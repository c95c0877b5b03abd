"""
Outputs that never destroy data: protected inputs, whole-or-nothing directories, clear limits.

Every directory the commands write (a derived or simulated bag, a report) goes through
:class:`OutputDir`:

* it is refused when it is, contains or lies inside an input (:func:`refuse_inside_inputs`);
* it is written into a temporary sibling, ``.<name>.reducer-twin-incomplete-<pid>``, and
  renamed into place only when complete, so an interrupted or failed run leaves nothing at
  the target that looks like a result; the next run into the same target removes such
  leftovers;
* a target that holds something is replaced only when every entry in it was written by
  reducer-twin (a recogniser says which entries are not) and, for bags, only with
  ``--overwrite``; foreign files are never deleted;
* one run at a time per target: an exclusive lock (``.<name>.reducer-twin.lock`` beside it,
  released by the kernel if the process dies) decides, and the loser stops at once with a
  message; the rename decides nothing by itself;
* a full disk (``ENOSPC``, ``EDQUOT``) becomes one :class:`DiskFull` error naming the path,
  the bytes needed and the bytes free;
* directories made on the way to a target (``--out`` of several bags, a parent that did
  not exist) do not outlive a run that wrote nothing into them
  (:func:`no_empty_dirs_left`).
"""

from contextlib import contextmanager
import ctypes
import errno
import fcntl
import functools
import os
from pathlib import Path
import re
import shutil
import stat

from reducer_twin.core.errors import BagError, InvalidParameter

TEMP_TAG = 'reducer-twin'
"""Marker in the names of temporaries and locks beside a target."""

OUTPUT_KEY_PREFIX = 'reducer_twin.'
"""``custom_data`` keys of every bag reducer-twin writes start so (how a bag is recognised)."""

_FULL = (errno.ENOSPC, errno.EDQUOT)


class OutputBusy(BagError):
    """Another reducer-twin run is writing the same output."""


class DiskFull(BagError):
    """The device of an output has no space (or quota) left."""


def human_bytes(size):
    """
    Format a byte count for a message (decimal units, as ``df -H`` prints them).

    Parameters
    ----------
    size : int or float
        Bytes.

    Returns
    -------
    str
        E.g. ``'61.4 GB'``.

    """
    size = float(size)
    for unit in ('bytes', 'kB', 'MB', 'GB', 'TB'):
        if abs(size) < 1000.0 or unit == 'TB':
            return f'{size:.0f} bytes' if unit == 'bytes' else f'{size:.1f} {unit}'
        size /= 1000.0
    return f'{size:.1f} TB'  # pragma: no cover - the loop returns


def free_bytes(path):
    """
    Return the bytes available to this user on the device of ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        A path; the nearest existing ancestor is asked.

    Returns
    -------
    int or None
        Free bytes, or None when the device cannot be asked.

    """
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    try:
        info = os.statvfs(path)
    except OSError:
        return None
    return info.f_bavail * info.f_frsize


def is_disk_full(err):
    """Tell whether an exception is a full device or an exhausted quota."""
    return isinstance(err, OSError) and err.errno in _FULL


def disk_full_error(err, what, path, needed=None):
    """
    Build the one-line error of a write that ran out of space.

    Parameters
    ----------
    err : OSError
        ``ENOSPC`` or ``EDQUOT``.
    what : str
        What was being written and where, e.g. ``'the derived bag --out /data/x'``.
    path : str or os.PathLike
        Where it was being written (its device is asked for the free bytes).
    needed : int, optional
        Bytes the whole output needs (an estimate where it cannot be known in advance).

    Returns
    -------
    DiskFull
        The error to raise.

    """
    reason = 'disk quota exceeded' if err.errno == errno.EDQUOT else 'no space left on device'
    free = free_bytes(path)
    need = f'it needs about {human_bytes(needed)} ({int(needed):,} bytes)' \
        if needed else 'it needs more than was free'
    have = f', {human_bytes(free)} ({free:,} bytes) free' if free is not None else ''
    return DiskFull(f'{reason} writing {what}: {need}{have}; nothing was left there: free '
                    'some space or choose another place')


# --------------------------------------------------------------------------- files


def png_text(path):
    """
    Return the text chunks (``tEXt``) of a PNG file, ``{}`` for any other file.

    Reads the chunks before the image data only (where writers put their text).

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    dict
        Keyword to text (Latin-1).

    """
    out = {}
    try:
        with open(path, 'rb') as handle:
            if handle.read(8) != b'\x89PNG\r\n\x1a\n':
                return out
            while True:
                head = handle.read(8)
                if len(head) < 8:
                    return out
                size, kind = int.from_bytes(head[:4], 'big'), head[4:]
                if kind in (b'IDAT', b'IEND') or size > 1 << 20:
                    return out
                data = handle.read(size)
                handle.read(4)   # the chunk's CRC
                if kind == b'tEXt' and b'\0' in data:
                    key, _, text = data.partition(b'\0')
                    out[key.decode('latin-1')] = text.decode('latin-1')
    except OSError:
        return out


def _alive(pid):
    """Tell whether a process ``pid`` exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def check_file_target(target, recognise, flag):
    """
    Refuse a file output that cannot be written, or whose path holds another's file.

    Parameters
    ----------
    target : str or os.PathLike
        The file to write (a link: the file it points to).
    recognise : callable
        ``recognise(path) -> bool``: the file there was written by reducer-twin (it may
        be replaced).
    flag : str
        Option name, for messages.

    Returns
    -------
    pathlib.Path
        The file's real path.

    Raises
    ------
    InvalidParameter
        If the target is a directory, its directory does not exist, or a file there
        was not written by reducer-twin.

    """
    path = _real(target)
    if path.is_dir():
        raise InvalidParameter(f'{flag} {target} is a directory; expected the path of a file')
    if not path.parent.is_dir():
        raise InvalidParameter(f'{flag} {target}: its directory {path.parent} does not exist; '
                               'expected a file in an existing directory')
    if path.exists() and not recognise(path):
        raise InvalidParameter(f'{flag} {target} exists and was not written by reducer-twin; '
                               f'it is never replaced: choose another {flag}, or move the '
                               'file away')
    return path


def write_file(target, data, recognise, what, flag):
    """
    Write a file whole or not at all: a temporary beside it, renamed into place.

    The target is checked again first (:func:`check_file_target`: another's file may have
    appeared while the command ran).

    Parameters
    ----------
    target : str or os.PathLike
        The file.
    data : bytes
        Its content.
    recognise, flag
        As :func:`check_file_target`.
    what : str
        What is written, for messages (``'the demo's plot'``).

    Raises
    ------
    InvalidParameter
        As :func:`check_file_target`.
    BagError
        If it cannot be written (:class:`DiskFull` when the device is full); nothing is
        left at or beside the target.

    """
    path = check_file_target(target, recognise, flag)
    stem = f'.{path.name}.{TEMP_TAG}-incomplete-'
    for entry in _entries(path.parent):   # left by a run that was killed while writing
        pid = entry[len(stem):]
        if entry.startswith(stem) and pid.isdigit() and not _alive(int(pid)):
            _remove(path.parent / entry)
    tmp = path.with_name(f'{stem}{os.getpid()}')
    try:
        with open(tmp, 'wb') as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except OSError as err:
        _remove(tmp)
        if is_disk_full(err):
            raise disk_full_error(err, f'{what} {flag} {target}', path.parent,
                                  len(data)) from None
        raise BagError(f'cannot write {what} {flag} {target}: {err.strerror or err}; nothing '
                       'was left there') from None
    except BaseException:
        _remove(tmp)
        raise


# --------------------------------------------------------------------------- inputs


def _real(path):
    return Path(os.path.realpath(os.path.abspath(path)))


def refuse_inside_inputs(outputs, inputs):
    """
    Refuse any output that is, contains or lies inside an input (``--overwrite`` or not).

    Parameters
    ----------
    outputs : iterable of (str, path)
        ``(flag, path)`` of each output, e.g. ``('--out', 'derived')``.
    inputs : iterable of (str, path)
        ``(what, path)`` of each input, e.g. ``('input bag', 'rec')``.

    Raises
    ------
    InvalidParameter
        Naming the output flag, both paths and the relation.

    """
    inputs = [(what, path, _real(path)) for what, path in inputs]
    for flag, out in outputs:
        target = _real(out)
        for what, given, source in inputs:
            if target == source:
                relation = 'is'
            elif source in target.parents:
                relation = 'lies inside'
            elif target in source.parents:
                relation = 'contains'
            else:
                continue
            raise InvalidParameter(
                f'{flag} {out} {relation} the {what} {given}; inputs are never written, '
                f'deleted or written into (--overwrite or not): choose an {flag} outside it')


def check_input_kind(path, what='BAG'):
    """
    Refuse an input that is neither a regular file nor a directory (FIFO, socket, device).

    Parameters
    ----------
    path : str or os.PathLike
        The input as given (it exists).
    what : str
        Name of the argument, for the message.

    Raises
    ------
    InvalidParameter
        On a named pipe, socket, or character or block device.

    """
    try:
        mode = os.stat(path).st_mode
    except OSError as err:
        raise InvalidParameter(f'{what} {path} cannot be read: {err.strerror}') from err
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return
    kind = ('a named pipe (FIFO)' if stat.S_ISFIFO(mode) else 'a socket' if stat.S_ISSOCK(mode)
            else 'a device')
    raise InvalidParameter(f'{what} {path} is {kind}; expected a rosbag2 bag directory, a .mcap '
                           'or a .db3 file')


# --------------------------------------------------------------------------- targets


def _entries(path):
    try:
        return sorted(p.name for p in Path(path).iterdir())
    except OSError:
        return []


def check_target(target, recognise, flag='--out', overwrite=False, replace_note='',
                 ignore=()):
    """
    Check that an output directory may be written: new, empty, or replaceable.

    Parameters
    ----------
    target : str or os.PathLike
        The output directory.
    recognise : callable
        ``recognise(path) -> list of str``: the entries of a non-empty ``path`` that
        reducer-twin did not write (empty: all of them are its own).
    flag : str
        Option name, for messages.
    overwrite : bool
        A previous output of reducer-twin may be replaced.
    replace_note : str
        What ``--overwrite`` replaces, for the message (e.g. ``'a bag written by
        reducer-twin'``).
    ignore : iterable of str
        Entry names that belong to the running writer (its lock and temporary).

    Returns
    -------
    bool
        True when the target holds a previous output that will be replaced.

    Raises
    ------
    InvalidParameter
        If the target is a file, holds foreign entries, or holds a previous output and
        ``overwrite`` is false.

    """
    target = Path(target)
    if target.is_symlink() and not target.exists():
        raise InvalidParameter(f'{flag} {target} is a broken symbolic link; expected a new or '
                               'empty directory')
    if target.exists() and not target.is_dir():
        raise InvalidParameter(f'{flag} {target} exists and is not a directory; expected a new '
                               'or empty directory')
    ignore = set(ignore)
    entries = [name for name in _entries(target) if name not in ignore]
    if not entries:
        return False
    foreign = [name for name in recognise(target) if name not in ignore]
    if foreign:
        shown = ', '.join(foreign[:8]) + (f' and {len(foreign) - 8} more'
                                          if len(foreign) > 8 else '')
        raise InvalidParameter(f'{flag} {target} is not empty: it holds {len(foreign)} entr'
                               f'{"y" if len(foreign) == 1 else "ies"} that reducer-twin did '
                               f'not write ({shown}), which are left alone (--overwrite or '
                               f'not); choose a new or empty {flag}')
    if not overwrite:
        raise InvalidParameter(f'{flag} {target} exists and is not empty ({len(entries)} '
                               f'entries); expected a new or empty directory, or --overwrite '
                               f'to replace {replace_note or "what reducer-twin wrote there"}')
    return True


def _missing_parents(target):
    """Return the directories above ``target`` that do not exist yet, deepest first."""
    out = []
    here = Path(os.path.abspath(target)).parent
    while not here.exists() and here != here.parent:
        out.append(here)
        here = here.parent
    return out


@contextmanager
def no_empty_dirs_left(targets):
    """
    Remove, on the way out, the directories a run made above its outputs and left empty.

    A target's missing parents are created by :meth:`OutputDir.start`; when the run
    writes nothing there (every bag failed, or a stop came first), they would stay
    behind, empty. Each one still empty when the block ends, however it ends, is
    removed (``rmdir``: a directory holding anything, an output of this run or of
    another, stays).

    Parameters
    ----------
    targets : iterable of str or os.PathLike
        The output directories of the run.

    """
    made = sorted({d for t in targets for d in _missing_parents(t)},
                  key=lambda d: len(d.parts), reverse=True)
    try:
        yield
    finally:
        for path in made:
            try:
                path.rmdir()
            except OSError:
                pass


def _renameat2():
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        func = libc.renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                     ctypes.c_uint]
    return func


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def exchange(a, b):
    """
    Swap two directory entries atomically (Linux ``renameat2(RENAME_EXCHANGE)``).

    Parameters
    ----------
    a, b : str or os.PathLike
        Existing paths on one file system.

    Returns
    -------
    bool
        False when the system cannot exchange (the caller falls back to two renames).

    Raises
    ------
    OSError
        On any other failure.

    """
    func = _renameat2()
    if func is None:
        return False
    if func(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), str(a))


@functools.lru_cache(maxsize=None)
def _sync_file_range():
    """Return libc's ``sync_file_range`` (looked up once), or None where there is none."""
    try:
        func = ctypes.CDLL(None, use_errno=True).sync_file_range
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_int64, ctypes.c_int64, ctypes.c_uint]
    return func


_SYNC_FILE_RANGE_WRITE = 2


def start_writeback(fd):
    """
    Ask the kernel to start writing a file's dirty pages to the device, without waiting.

    The ``fsync`` that :meth:`OutputDir.commit` makes before the rename then waits only
    for what was written since (on a 6-joint bag's 60 MB derived bag it waited 25-30 ms
    at the end of ``analyze``). Linux ``sync_file_range(SYNC_FILE_RANGE_WRITE)``, else
    ``posix_fadvise(POSIX_FADV_DONTNEED)`` (which starts write-back too), else nothing:
    it is a hint, durability still rests on the ``fsync``.

    Parameters
    ----------
    fd : int
        An open file descriptor.

    """
    func = _sync_file_range()
    if func is not None:
        func(fd, 0, 0, _SYNC_FILE_RANGE_WRITE)
    elif hasattr(os, 'posix_fadvise'):
        try:
            os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
        except OSError:
            pass


def _fsync_dir(path):
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _remove(path):
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        try:
            path.unlink()
        except OSError:
            pass


def foreign_bag_entries(path):
    """
    Return the entries of a directory that are not part of a bag written by reducer-twin.

    Parameters
    ----------
    path : str or os.PathLike
        A non-empty directory.

    Returns
    -------
    list of str
        Entry names; empty when the directory holds exactly a reducer-twin bag
        (``metadata.yaml`` with ``reducer_twin.*`` custom_data, and the storage files it
        lists).

    """
    import yaml
    path = Path(path)
    entries = sorted(p.name for p in path.iterdir())
    ours = set()
    try:
        info = yaml.safe_load((path / 'metadata.yaml').read_text(encoding='utf-8'))
        info = info['rosbag2_bagfile_information']
        custom = info.get('custom_data') or {}
        if any(str(key).startswith(OUTPUT_KEY_PREFIX) for key in custom):
            ours = {'metadata.yaml'} | {Path(str(f)).name
                                        for f in info.get('relative_file_paths') or []}
    except (OSError, UnicodeDecodeError, yaml.YAMLError, TypeError, KeyError,
            AttributeError):
        ours = set()
    return [name for name in entries if name not in ours or not (path / name).is_file()
            or (path / name).is_symlink()]


class OutputDir:
    """
    A directory output written whole or not at all, by one run at a time.

    Use as a context manager, or call :meth:`start`, then :meth:`commit` or
    :meth:`abort`. Files are written into :attr:`tmp`; :meth:`commit` renames it to
    the target (replacing a previous output of reducer-twin atomically where the system
    can exchange two directories).

    Parameters
    ----------
    target : str or os.PathLike
        The output directory.
    recognise : callable
        ``recognise(path) -> list of str``: entries reducer-twin did not write.
    what : str
        What is written, for messages (``'derived bag'``, ``'report'``).
    flag : str
        Option name, for messages.
    overwrite : bool
        A previous output of reducer-twin may be replaced.
    needed : int, optional
        Bytes the output needs (an estimate is fine), named when the disk is full.
    replace_note : str
        What ``--overwrite`` replaces, for messages.

    """

    def __init__(self, target, recognise, what, flag='--out', overwrite=False, needed=None,
                 replace_note=''):
        self.target = Path(os.path.realpath(os.path.abspath(target)))   # a link: its place
        self.recognise = recognise
        self.what = what
        self.flag = flag
        self.overwrite = overwrite
        self.needed = needed
        self.replace_note = replace_note
        # A mount point cannot be renamed over: the temporary goes inside it.
        self.inside = self.target.is_dir() and os.path.ismount(self.target)
        self.home = self.target if self.inside else self.target.parent
        stem = '' if self.inside else f'.{self.target.name}'
        self.lock_path = self.home / f'{stem}.{TEMP_TAG}.lock'
        self.tmp = self.home / f'{stem}.{TEMP_TAG}-incomplete-{os.getpid()}'
        self._stale = re.compile(re.escape(stem) + r'\.' + re.escape(TEMP_TAG)
                                 + r'-(incomplete|old)-\d+')
        self._own = (self.lock_path.name, self.tmp.name) if self.inside else ()
        self._lock_fd = None
        self.committed = False

    # ----------------------------------------------------------------- public API

    def start(self):
        """
        Lock the target, remove stale temporaries, check it and create the temporary.

        Returns
        -------
        pathlib.Path
            The temporary directory to write into.

        Raises
        ------
        OutputBusy
            If another run holds the target.
        InvalidParameter
            If the target may not be written (see :func:`check_target`).
        BagError
            If the directory cannot be created (:class:`DiskFull` when full).

        """
        try:
            self.home.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise self.error(err) from err
        self._lock()
        try:
            self._clean_stale()
            check_target(self.target, self.recognise, self.flag, self.overwrite,
                         self.replace_note, self._own)
            self.tmp.mkdir()
        except OSError as err:
            self._unlock()
            raise self.error(err) from err
        except BaseException:
            self._unlock()
            raise
        return self.tmp

    def commit(self):
        """
        Put the finished output in place and release the target.

        Raises
        ------
        BagError
            If the rename fails (:class:`DiskFull` when the device is full); the
            temporary is removed and the target left as it was.

        """
        try:
            for entry in self.tmp.iterdir():
                if entry.is_file():
                    fd = os.open(entry, os.O_RDONLY)
                    try:
                        os.fsync(fd)
                    finally:
                        os.close(fd)
            if self.inside:
                self._commit_inside()
            else:
                self._commit_sibling()
            _fsync_dir(self.home)
            self.committed = True
        except OSError as err:
            self.abort()
            raise self.error(err) from err
        except BaseException:
            self.abort()
            raise
        finally:
            self._unlock()

    def abort(self):
        """Remove the temporary and release the target (nothing is left at the target)."""
        _remove(self.tmp)
        self._unlock()

    def error(self, err):
        """
        Return the project's error for an ``OSError`` met while writing into :attr:`tmp`.

        Parameters
        ----------
        err : OSError
            What the write raised.

        Returns
        -------
        BagError
            :class:`DiskFull` for a full device or quota, else a BagError naming the
            target.

        """
        if is_disk_full(err):
            return disk_full_error(err, f'the {self.what} {self.flag} {self.target}',
                                   self.target, self.needed)
        where = f' ({err.filename})' if getattr(err, 'filename', None) else ''
        return BagError(f'cannot write the {self.what} {self.flag} {self.target}: '
                        f'{err.strerror or err}{where}')

    def __enter__(self):
        """Open the output; return the temporary directory."""
        return self.start()

    def __exit__(self, exc_type, exc, tb):
        """Commit after success; after an error, remove the temporary and translate OSError."""
        if exc_type is None:
            self.commit()
            return False
        self.abort()
        if isinstance(exc, OSError):
            raise self.error(exc) from exc
        return False

    # ----------------------------------------------------------------- internals

    def _lock(self):
        while True:
            try:
                fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as err:
                raise self.error(err) from err
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.read(fd, 32).decode('ascii', 'replace').strip()
                os.close(fd)
                who = f' (pid {holder})' if holder.isdigit() else ''
                raise OutputBusy(
                    f'{self.flag} {self.target} is being written by another reducer-twin run'
                    f'{who}; nothing was written: wait for it to finish and run again with '
                    '--overwrite, or choose another ' + self.flag) from None
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(self.lock_path))
            except OSError:
                same = False
            if same:  # else the holder removed it between our open and lock: again
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f'{os.getpid()}\n'.encode('ascii'))
        self._lock_fd = fd

    def _unlock(self):
        if self._lock_fd is None:
            return
        try:
            os.unlink(self.lock_path)
        except OSError:
            pass
        os.close(self._lock_fd)
        self._lock_fd = None

    def _clean_stale(self):
        for name in _entries(self.home):
            if self._stale.fullmatch(name):
                _remove(self.home / name)

    def _commit_sibling(self):
        if not self.target.exists():
            os.rename(self.tmp, self.target)
            return
        if not _entries(self.target):
            os.rename(self.tmp, self.target)  # over an empty directory
            return
        # Checked again: nothing foreign may have appeared while the output was written.
        check_target(self.target, self.recognise, self.flag, self.overwrite,
                     self.replace_note)
        if exchange(self.tmp, self.target):
            _remove(self.tmp)   # now the previous output
            return
        old = self.home / f'.{self.target.name}.{TEMP_TAG}-old-{os.getpid()}'
        os.rename(self.target, old)
        try:
            os.rename(self.tmp, self.target)
        except OSError:
            os.rename(old, self.target)   # the previous output stays where it was
            raise
        _remove(old)

    def _commit_inside(self):
        if check_target(self.target, self.recognise, self.flag, self.overwrite,
                        self.replace_note, self._own):
            for name in _entries(self.target):
                if name not in self._own:
                    _remove(self.target / name)
        names = sorted(_entries(self.tmp), key=lambda n: n == 'metadata.yaml' or
                       n == 'index.html')
        for name in names:   # the file that makes it look complete comes last
            os.rename(self.tmp / name, self.target / name)
        _remove(self.tmp)


__all__ = ['OutputDir', 'OutputBusy', 'DiskFull', 'check_target', 'check_input_kind',
           'foreign_bag_entries',
           'refuse_inside_inputs', 'disk_full_error', 'free_bytes', 'human_bytes',
           'is_disk_full', 'exchange']
