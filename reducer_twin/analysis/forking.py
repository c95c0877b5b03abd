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

The process pools of several bags (:func:`stopping_pool`) stop with the command: a stop
interrupts the bag each worker analyses, which removes what it was writing, and no
queued bag is started (:func:`stop_pool`).
"""

import contextlib
import os
import signal
import sys
import threading
import time

from reducer_twin.core.errors import BagError

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


def end_process(proc, wait_s=5.0):
    """
    End a forked worker: SIGTERM, then SIGKILL if it still runs after ``wait_s``.

    Stopped mid-work, a worker may not answer SIGTERM at once (one stop of ``analyze``
    in about 300 under load took the full 5 s of this wait); one left to the
    interpreter's exit, which joins its children without a time limit, would hold the
    command for ever.
    """
    if proc.is_alive():
        proc.terminate()
        proc.join(wait_s)
    if proc.is_alive():
        proc.kill()
        proc.join(1.0)


# --------------------------------------------------------------------------- process pools

_worker_state = 'idle'
"""What this pool worker does: 'idle', 'task' or 'stopping' (see :func:`pool_worker`)."""

STOP_WAIT_S = 30.0
"""How long [s] stopped workers (a pool's, Ray's tasks) get to remove what they were writing."""


def pool_worker(parent):
    """
    Initialise a worker of a process pool: it ends with its parent and stops cleanly.

    A stop (SIGINT, SIGTERM) raises ``KeyboardInterrupt`` in the task it runs (see
    :func:`run_task`), so that the bag it analyses removes what it was writing, as a
    stopped command does; a further stop is ignored until that is done (Ctrl-C reaches
    the worker, then the pool's own stop), and the tasks already queued for it are not
    started. Between tasks it ends the worker at once, without a traceback.

    Parameters
    ----------
    parent : tuple of (int, bool)
        :func:`parent_of_fork` of the parent, taken before the fork.

    """
    end_with_parent(parent)
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, _stop_worker)


def _stop_worker(signum, frame):
    global _worker_state
    if _worker_state == 'task':
        _worker_state = 'stopping'
        raise KeyboardInterrupt()
    if _worker_state == 'idle':
        os._exit(128 + signum)


def run_task(fn, *args):
    """Run ``fn(*args)`` as a pool worker's task (a stop then raises in it)."""
    global _worker_state
    if _worker_state == 'stopping':     # work queued before the stop: never started
        raise KeyboardInterrupt()
    _worker_state = 'task'
    try:
        return fn(*args)
    finally:
        if _worker_state == 'task':
            _worker_state = 'idle'


@contextlib.contextmanager
def stopping_pool(jobs):
    """
    Run a process pool of ``jobs`` forked workers (see :func:`pool_worker`).

    Submit its work through :func:`run_task`. Left by an error, a stop or a generator
    closed early, the pool is stopped at once (:func:`stop_pool`); left normally, it is
    shut down once its work is done.

    Yields
    ------
    concurrent.futures.ProcessPoolExecutor
        The pool.

    """
    import concurrent.futures
    import multiprocessing
    pool = concurrent.futures.ProcessPoolExecutor(
        jobs, mp_context=multiprocessing.get_context('fork'), initializer=pool_worker,
        initargs=(parent_of_fork(),))
    try:
        yield pool
    except BaseException:
        stop_pool(pool)
        raise
    pool.shutdown()


def pool_broken(bag):
    """
    Return the error of a bag whose pool broke (a worker ended while the bags ran).

    Python's pool then fails every bag not yet returned; the kernel's out-of-memory
    killer is the usual cause.
    """
    return BagError(f'{bag}: not analysed: a process of the pool ended while the bags were '
                    'analysed (killed: out of memory?); run it again, with fewer --jobs if '
                    'memory ran short')


def stop_pool(pool):
    """
    Stop a pool at once, after a stop or an error of this process.

    Work not started is dropped; each worker gets SIGTERM, so that the task it runs
    removes what it was writing, and is waited for (:data:`STOP_WAIT_S`, then killed).
    Left alone, the pool ran every bag submitted to it before the stop took effect
    (``analyze`` of many bags went on for as long after Ctrl-C, writing them all).
    """
    from multiprocessing.connection import wait
    workers = list((pool._processes or {}).values())  # gone once shut down
    pool.shutdown(wait=False, cancel_futures=True)
    for worker in workers:
        worker.terminate()
    # The pool's own thread reaps its workers too: their ends are watched, not waited for.
    running = {worker.sentinel: worker for worker in workers}
    deadline = time.monotonic() + STOP_WAIT_S
    while running and time.monotonic() < deadline:
        for ended in wait(list(running), max(0.0, deadline - time.monotonic())):
            del running[ended]
    for worker in running.values():
        worker.kill()
