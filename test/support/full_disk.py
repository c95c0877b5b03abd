"""
Full disks for tests: a real, small tmpfs (root only), or ENOSPC at the file-write edge.

:func:`small_tmpfs` mounts a tmpfs of a given size and unmounts it afterwards; without
the right to mount it skips, and the tests that use :class:`FillingFile` (an ``open``
whose files raise ``OSError(ENOSPC)`` once a byte budget is spent) cover the same code
paths on any machine.
"""

import builtins
import contextlib
import errno
import os
from pathlib import Path
import subprocess

import pytest


@contextlib.contextmanager
def small_tmpfs(path, size):
    """
    Mount a tmpfs of ``size`` bytes at ``path`` (created) for the ``with`` block.

    Fails the test when the system refuses the mount: the project's tests run as root
    (CI and the README's set-up), and a full disk is checked on a real file system.
    """
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    done = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={int(size)}', 'tmpfs',
                           str(path)], capture_output=True, text=True)
    if done.returncode != 0:
        pytest.fail(f'cannot mount a tmpfs at {path}: {done.stderr.strip()} (run as root)')
    try:
        yield path
    finally:
        subprocess.run(['umount', '-l', str(path)], capture_output=True)


def fill(path, leave=0):
    """
    Fill the device of directory ``path`` up to ``leave`` bytes with ``path/filler``.

    Returns
    -------
    pathlib.Path
        The filler file (delete it to give the space back).

    """
    filler = Path(path) / 'filler'
    block = b'\0' * 65536
    with open(filler, 'wb') as stream:
        try:
            while True:
                stats = os.statvfs(path)
                room = stats.f_bavail * stats.f_frsize - leave
                if room <= 0:
                    break
                stream.write(block[:min(len(block), room)])
                stream.flush()
        except OSError as err:
            assert err.errno == errno.ENOSPC, err
    return filler


class FillingFile:
    """
    A file object that raises ``OSError(ENOSPC)`` once a shared byte budget is spent.

    Patch a module's ``open`` with :meth:`opener` (``monkeypatch.setattr(module, 'open',
    budget.opener, raising=False)``): files opened for writing there count against the
    budget; the disk is "full" after it.
    """

    def __init__(self, budget):
        self.left = int(budget)

    def opener(self, file, mode='r', *args, **kwargs):
        """Open like ``open``; writable files run out of space after the budget."""
        handle = builtins.open(file, mode, *args, **kwargs)
        if not any(flag in mode for flag in 'wxa+'):
            return handle
        return _Limited(handle, self)


class _Limited:
    def __init__(self, handle, budget):
        self._handle = handle
        self._budget = budget

    def write(self, data):
        size = len(memoryview(data).cast('B'))
        if size > self._budget.left:
            self._budget.left = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._budget.left -= size
        return self._handle.write(data)

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._handle.close()
