"""How a node program runs: the background worker, GC tuning, the executor, signals, main()."""

from concurrent.futures import Future as TaskFuture
import contextlib
import os
from pathlib import Path
import queue
import signal
import sys
import threading
import time

import rclpy
from rclpy.exceptions import InvalidHandle, ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from reducer_twin.core.errors import InvalidParameter, ReducerTwinError

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals that stop a node program cleanly (Ctrl-C; what ``ros2 launch`` escalates to)."""


def quiet_gc():
    """
    Keep the garbage collector and background work from pausing a 1 kHz stream.

    Everything alive after start-up (modules, tables, nodes) is moved out of
    the collector's view (``gc.freeze``) and full collections are made rare.
    The nodes make no reference cycles in steady operation (the soak
    benchmark counts the objects the collector reclaims); the young
    collections that still come every 10 000 net allocations reclaim any
    cycle a library makes within minutes, not never.
    The interpreter switches threads every 0.5 ms instead of 5 ms, so the
    executor thread regains the interpreter quickly from :data:`WORKER`.
    """
    import gc
    gc.collect()
    gc.freeze()
    gc.set_threshold(10_000, 50, 1000)
    sys.setswitchinterval(0.0005)


class BackgroundWorker:
    """
    One thread that runs background work in submission order, in short turns.

    Window analysis, estimator and remaining-life updates and simulator
    blocks are each a few milliseconds of Python. Run on the executor thread
    they stall the 1 kHz streams; run back to back on another thread they
    hold the interpreter lock for tens of milliseconds at a time (the windows
    of all joints complete together), and the executor, which takes the lock
    again for every message, falls behind. This worker rests after every
    task for ``rest_ratio`` times as long as the task ran (at most
    ``max_rest_s``), so the executor always gets the interpreter back within
    one task and catches up before the next.

    Parameters
    ----------
    rest_ratio : float
        Rest after a task, relative to its duration.
    max_rest_s : float
        Longest rest [s].

    """

    def __init__(self, rest_ratio=1.0, max_rest_s=0.005):
        self.rest_ratio = float(rest_ratio)
        self.max_rest_s = float(max_rest_s)
        self._queue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name='reducer-twin-worker',
                                        daemon=True)
        self._thread.start()

    def submit(self, fn, *args, **kwargs):
        """
        Queue ``fn(*args, **kwargs)``; return a future of its result.

        Returns
        -------
        concurrent.futures.Future
            Holds the result, or the exception the call raised.

        """
        future = TaskFuture()
        self._queue.put((future, fn, args, kwargs))
        return future

    def post(self, node, fn, *args):
        """
        Queue ``fn(*args)`` that nobody waits for; a failure is logged on ``node``'s log.

        An exception of a task from :meth:`submit` waits in its future; one no caller
        reads would vanish. A node that was destroyed meanwhile is skipped quietly.

        Returns
        -------
        concurrent.futures.Future
            Holds the result (None if the task failed).

        """
        return self.submit(run_logged, node, fn, *args)

    def wait_idle(self, timeout=None):
        """Wait until everything submitted so far has run (end of a demo, tests)."""
        self.submit(lambda: None).result(timeout)

    def _run(self):
        while True:
            future, fn, args, kwargs = self._queue.get()
            if not future.set_running_or_notify_cancel():
                continue
            start = time.perf_counter()
            try:
                result = fn(*args, **kwargs)
            except BaseException as err:  # noqa: B902 - handed to whoever waits on it
                future.set_exception(err)
            else:
                future.set_result(result)
            rest = min((time.perf_counter() - start) * self.rest_ratio, self.max_rest_s)
            if rest > 0.0:
                time.sleep(rest)


def run_logged(node, fn, *args):
    """
    Return ``fn(*args)``; log an exception on ``node``'s log instead of raising it.

    For work nobody waits for (:meth:`BackgroundWorker.post`, the background timers): a
    failure must be seen. Nothing is said for a node destroyed meanwhile
    (``InvalidHandle``) or once its context is shut down.
    """
    try:
        return fn(*args)
    except InvalidHandle:
        return None
    except Exception as err:  # noqa: B902 - logged: a failing task must be seen
        if node.context.ok():
            node.get_logger().error(f'{getattr(fn, "__name__", "background task")} '
                                    f'failed: {err!r}')
        return None


WORKER = BackgroundWorker()
"""
The process's background worker (see :class:`BackgroundWorker`).

Window analysis, estimator and remaining-life updates and simulator block
generation run here in order; the executor thread keeps only the light,
latency-critical callbacks.
"""


_STORE_WORKER = []

CLOSE_FLUSH_TIMEOUT_S = 30.0
"""Longest wait for a live estimator's last segment on the store thread when it stops [s]."""


def store_worker():
    """
    Return the process's fleet-store thread (made on first use).

    Every live estimator of the process writes its segments there, one after the other:
    SQLite and ``fsync`` never run on the executor thread nor hold the background
    worker that steps the windows, and the joints of a bringup never compete for the
    store's writer lock among themselves.
    """
    if not _STORE_WORKER:
        _STORE_WORKER.append(BackgroundWorker())
    return _STORE_WORKER[0]


def default_state_dir():
    """Return ``$XDG_STATE_HOME/reducer_twin`` (``~/.local/state/reducer_twin``)."""
    base = os.environ.get('XDG_STATE_HOME') or Path.home() / '.local' / 'state'
    return Path(base) / 'reducer_twin'


def state_path(joint, state_file='', state_dir='', suffix='.json'):
    """
    Return a node's state file of a joint, or None to keep no state.

    Parameters
    ----------
    joint : str
        The joint.
    state_file : str
        A file; ``''`` = ``<state_dir>/<joint><suffix>``; ``'none'`` = no state.
    state_dir : str
        Directory of state files; ``''`` = :func:`default_state_dir`.
    suffix : str
        The node's own ending: ``.json`` for the ``wear_estimator``'s,
        ``.te_monitor.json`` for the ``te_monitor``'s.

    """
    if state_file == 'none':
        return None
    if state_file:
        return Path(state_file)
    return (Path(state_dir) if state_dir else default_state_dir()) / f'{joint}{suffix}'


def make_executor():
    """
    Return the executor the nodes spin in: EventsExecutor, or single-threaded.

    Returns
    -------
    rclpy.executors.Executor
        ``rclpy.experimental.EventsExecutor`` where available (about 4x less
        CPU per message), else ``SingleThreadedExecutor``.

    """
    try:
        from rclpy.experimental import EventsExecutor
        return EventsExecutor()
    except (ImportError, AttributeError, RuntimeError):
        return SingleThreadedExecutor()


class StopRequest:
    """
    A signal handler that asks the spin loop to stop; a second signal kills at once.

    Installed for SIGINT and SIGTERM (:func:`stop_on_signals`) by :func:`run_nodes`
    and ``reducer-twin demo`` in place of rclpy's
    handlers, which shut the context down from another thread while a
    callback may be publishing (it then fails with "publisher's context is
    invalid"). Here the loop stops first, then the nodes are destroyed and
    the context shut down, in order.
    """

    def __init__(self):
        self.signum = None

    def __call__(self, signum, frame):
        """Record the request; on a repeated one, die by the signal's default action."""
        if self.signum is not None:
            signal.signal(signum, signal.SIG_DFL)
            os.kill(os.getpid(), signum)
        self.signum = signum


@contextlib.contextmanager
def stop_on_signals():
    """
    Install a :class:`StopRequest` for SIGINT and SIGTERM; restore the handlers after.

    Install it before ``rclpy.init(..., signal_handler_options=SignalHandlerOptions.NO)``
    and let the loop watch its ``signum``.

    Yields
    ------
    StopRequest
        The handler, whose ``signum`` tells a stop.

    """
    stop = StopRequest()
    previous = {signum: signal.signal(signum, stop) for signum in STOP_SIGNALS}
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def close_nodes(nodes):
    """Close (finish the work of) and destroy the nodes, in order, before rclpy shuts down."""
    for node in nodes:
        close = getattr(node, 'close', None)
        if close is not None:
            close()
        node.destroy_node()


def spin_until_shutdown(executor, context=None, stop=None):
    """
    Spin until a stop is requested or the context shuts down.

    ``EventsExecutor.spin()`` stays in C++ and never returns for a signal:
    spinning in slices of 0.2 s lets the loop notice one.

    Parameters
    ----------
    executor : rclpy.executors.Executor
        Executor with the nodes added.
    context : rclpy.context.Context, optional
        Context to watch (default: the global one).
    stop : StopRequest, optional
        Checked between slices.

    """
    context = context or rclpy.get_default_context()
    never = Future()
    while context.ok() and (stop is None or stop.signum is None):
        executor.spin_until_future_complete(never, timeout_sec=0.2)


def check_params_files(argv):
    """
    Check every ``--params-file`` of ``--ros-args`` before rcl reads it.

    rcl reports a missing or broken file as a traceback of ``rclpy.init``; here it is
    one line with the file, and for a YAML error its line and column.

    Parameters
    ----------
    argv : list of str
        Command line.

    Raises
    ------
    InvalidParameter
        If a parameter file is missing, unreadable, not YAML or not a mapping.

    """
    from reducer_twin.config import read_yaml
    inside = False
    for i, arg in enumerate(argv):
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside and arg == '--params-file' and i + 1 < len(argv):
            path = argv[i + 1]
            try:
                data = read_yaml(path, 'a ROS 2 parameter file')
            except InvalidParameter as err:
                raise InvalidParameter(f'--params-file {err}') from None
            if not isinstance(data, dict):
                raise InvalidParameter(f'--params-file {path}: expected a mapping of node names '
                                       f'to ros__parameters, got {type(data).__name__}')


def run_nodes(factory, args=None):
    """
    Run nodes built by ``factory`` until shutdown; the body of every ``main()``.

    Ctrl-C (SIGINT) and SIGTERM stop the spin loop; then the nodes are
    destroyed and the context shut down.

    Parameters
    ----------
    factory : callable
        Called after ``rclpy.init``; returns a node or a list of nodes.
    args : list of str, optional
        Command-line arguments (``--ros-args ...``).

    Returns
    -------
    int
        Exit code: 0 on a clean shutdown, 1 on an invalid parameter.

    """
    try:
        check_params_files(sys.argv if args is None else args)
    except ReducerTwinError as err:
        sys.stderr.write(f'ERROR: {err}\n')
        return 1
    with stop_on_signals() as stop:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except Exception as err:  # noqa: B902 - rcl refuses its arguments: one line
            sys.stderr.write(f'ERROR: cannot start: {str(err).splitlines()[0]}\n')
            return 1
        nodes = []
        try:
            made = factory()
            nodes = made if isinstance(made, (list, tuple)) else [made]
            executor = make_executor()
            for node in nodes:
                executor.add_node(node)
            quiet_gc()
            spin_until_shutdown(executor, stop=stop)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except (ReducerTwinError, ParameterException) as err:
            # ParameterException: rclpy refused a start value of a plain (non-spec) parameter.
            sys.stderr.write(f'ERROR: {err}\n')
            return 1
        finally:
            close_nodes(nodes)
            rclpy.try_shutdown()
    return 0
