"""
Forked worker processes that end with the process that forked them.

A worker blocked on its queue never learns that its parent is gone: it holds both ends
of the queue's pipe (inherited at the fork), so a receive waits for ever once the parent
is killed with SIGKILL (the stage worker of ``reducer-twin analyze`` was found asleep,
reparented to pid 1, minutes later). Each worker calls :func:`end_with_parent` first:
on Linux the kernel sends it SIGKILL when its parent dies (``PR_SET_PDEATHSIG``);
elsewhere, or when forked from a thread other than the main one (the signal would come
when that thread ends), a thread of the worker looks at its parent twice a second.
A worker holds no output of its own beyond what a killed run leaves anyway (a named
temporary, which the next run removes); the lock of an output, inherited or taken, goes
with it.
"""

import os
import signal
import sys
import threading
import time

PARENT_CHECK_S = 0.5
"""How often [s] a worker without ``PR_SET_PDEATHSIG`` looks whether its parent lives."""

_PR_SET_PDEATHSIG = 1
"""``prctl`` option: the signal the calling process gets when its parent dies (Linux)."""


def parent_of_fork():
    """
    Return what :func:`end_with_parent` needs to know of the process about to fork.

    Call it in the parent, just before the fork: the worker cannot tell afterwards
    whether its parent already died.

    Returns
    -------
    tuple of (int, bool)
        The parent's pid, and whether it forks from its main thread.

    """
    return os.getpid(), threading.current_thread() is threading.main_thread()


def end_with_parent(parent):
    """
    End this forked worker when its parent process ends, whatever ended it.

    Parameters
    ----------
    parent : tuple of (int, bool)
        :func:`parent_of_fork` of the parent, taken before the fork.

    """
    pid, main_thread = parent
    if not (main_thread and _kill_me_when_parent_dies()):
        threading.Thread(target=_watch_parent, args=(pid,), name='reducer-twin-parent-watch',
                         daemon=True).start()
    if os.getppid() != pid:     # it died before the request above: nobody to work for
        os._exit(1)


def _kill_me_when_parent_dies():
    """Ask Linux for SIGKILL when the parent dies; return whether it was granted."""
    if not sys.platform.startswith('linux'):
        return False
    import ctypes
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(pid):
    """End this process once its parent is no longer ``pid`` (it died: reparented)."""
    while os.getppid() == pid:
        time.sleep(PARENT_CHECK_S)
    os._exit(1)
