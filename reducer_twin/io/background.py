"""
Work handed to background threads that a stopped run never waits for.

Chunk compression (:mod:`reducer_twin.io.mcap_array_writer`) and decompression
(:mod:`reducer_twin.io.mcap_reader`) run on threads beside the analysing one; zstd,
zlib and lz4 release the GIL. ``concurrent.futures.ThreadPoolExecutor`` did this before
and let Ctrl-C hang ``reducer-twin analyze`` (about one stop in 300 under load): the
interrupt can land in the main thread just after one of the pool's Python-level locks
(its idle semaphore's) was taken and before the ``with`` block that releases it was
entered; the pool's thread then waited for that lock for ever, and the clean-up's
``shutdown()`` (or the interpreter's exit, which joins a pool's threads) waited for the
thread. Here the two sides share nothing but ``queue.SimpleQueue`` objects, whose
``put`` and ``get`` are single C calls, and the threads are daemons: a run stopped with
work in flight leaves it to finish (or not) on its own.
"""

import queue
import threading


class Pending:
    """The result of one job of :class:`Background`, awaited by :meth:`result`."""

    __slots__ = ('_slot', '_outcome')

    def __init__(self, slot):
        self._slot = slot
        self._outcome = None

    def result(self):
        """
        Return the job's value once it is done, or raise what the job raised.

        Returns
        -------
        object
            What the job returned.

        """
        if self._outcome is None:
            self._outcome = self._slot.get()
        ok, value = self._outcome
        if not ok:
            raise value
        return value


def _serve(jobs):
    """Run jobs until the ``None`` that ends this thread."""
    while True:
        job = jobs.get()
        if job is None:
            return
        fn, args, slot = job
        try:
            outcome = (True, fn(*args))
        except BaseException as err:  # noqa: B902 - handed to whoever awaits the result
            outcome = (False, err)
        slot.put(outcome)
        del job, fn, args, slot, outcome


class Background:
    """
    Daemon threads running jobs in the order they are submitted.

    Parameters
    ----------
    threads : int
        Number of threads (at least 1).
    name : str
        Prefix of the threads' names.

    """

    def __init__(self, threads, name):
        if threads < 1:
            raise ValueError(f'threads must be at least 1, got {threads}')
        self._jobs = queue.SimpleQueue()
        self._threads = [threading.Thread(target=_serve, args=(self._jobs,),
                                          name=f'{name}-{k}', daemon=True)
                         for k in range(threads)]
        for thread in self._threads:
            thread.start()

    def submit(self, fn, *args):
        """
        Run ``fn(*args)`` on a thread.

        Returns
        -------
        Pending
            Its result.

        """
        slot = queue.SimpleQueue()
        self._jobs.put((fn, args, slot))
        return Pending(slot)

    def close(self):
        """
        Let the threads end once the jobs already submitted are done; return at once.

        Results already awaited are all a finished run needs; after an error or a
        stop, work still in flight ends on its own.
        """
        for _ in self._threads:
            self._jobs.put(None)

    def __enter__(self):
        """Return the threads."""
        return self

    def __exit__(self, *exc):
        """Close (see :meth:`close`)."""
        self.close()
