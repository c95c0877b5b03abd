"""
What every reducer_twin node shares: parameters, QoS, rejection counting, main().

Parameters are declared from the core's validated dataclasses (one source
of names, defaults, units and ranges): each field becomes a ROS parameter
``<section>.<name>`` with a descriptor carrying its description, unit and
range, and a set-parameters callback rejects an invalid value with the
core's own message while the old value stays.
"""

from concurrent.futures import Future as TaskFuture
from dataclasses import fields, replace
import itertools
import os
import queue
import signal
import sys
import threading
import time

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType, SetParametersResult
import rclpy
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from reducer_twin.core.errors import InvalidInput, InvalidParameter, out_of_range
from reducer_twin.core.errors import ReducerTwinError
from reducer_twin.core.params import check_value, describe_range

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals that stop a node program cleanly (Ctrl-C; what ``ros2 launch`` escalates to)."""

LISTENERS_PERIOD_S = 0.5
"""How often composed nodes check whether a topic they may skip has subscribers [s]."""

ENCODER_DEPTH = 200
"""History depth of 1 kHz encoder streams (>= 100: a stalled reader loses old samples)."""


def encoder_qos(reliable=True):
    """
    Return the QoS of encoder streams (controller topics and paired samples).

    Parameters
    ----------
    reliable : bool
        RELIABLE (default, matches ros2_control's broadcaster) or BEST_EFFORT.

    Returns
    -------
    rclpy.qos.QoSProfile
        KEEP_LAST with depth :data:`ENCODER_DEPTH`, volatile.

    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=ENCODER_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE)


WINDOW_DEPTH = 20
"""History depth of per-window topics (``te_features``): 40 s of windows for a stalled reader."""


def stream_qos(depth=100):
    """
    Return the QoS of derived streams: reliable, volatile.

    Parameters
    ----------
    depth : int
        KEEP_LAST depth: 100 for TE batches (2 s at 50 Hz), :data:`WINDOW_DEPTH`
        for per-window features.

    Returns
    -------
    rclpy.qos.QoSProfile
        The profile.

    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def latest_qos():
    """Return the QoS of estimates: reliable, transient-local, the latest sample kept."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def diagnostics_qos():
    """Return the QoS of ``/diagnostics``: reliable, depth 10, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


_PHASES = itertools.count(1)
_GOLDEN = (5 ** 0.5 - 1) / 2


def create_spread_timer(node, period_s, callback):
    """
    Create a periodic timer whose phase is spread from the other such timers of the process.

    The bringup's nodes are built within milliseconds of each other, so their
    once-a-second timers (diagnostics of every node, the ground truth,
    subscriber checks) would all fire in the same millisecond and hold the
    executor for the sum of their callbacks, a stall the 1 kHz stream feels.
    Each timer made here starts only after its own fraction of the period
    (a golden-ratio sequence over the process's timers, so any number of
    them stay apart) and then keeps that phase.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the timer.
    period_s : float
        Period [s].
    callback : callable
        Called every period.

    Returns
    -------
    rclpy.timer.Timer
        The periodic timer (started after the phase offset).

    """
    phase = (next(_PHASES) * _GOLDEN) % 1.0
    timer = node.create_timer(period_s, callback, autostart=False)

    def start():
        starter.cancel()
        timer.reset()

    starter = node.create_timer(max(phase * period_s, 1e-3), start)
    return timer


def create_background_timer(node, period_s, fn):
    """
    Create a spread periodic timer whose work runs on :data:`WORKER`.

    For the nodes' ``/diagnostics``: building a DiagnosticArray of a dozen
    key/values and publishing it is a millisecond of Python, several with
    the worker busy, and the nodes of a bringup publish twenty a second. On
    the executor thread that is the stream waiting; on the worker the
    executor takes the interpreter back within one switch interval.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the timer.
    period_s : float
        Period [s].
    fn : callable
        The work; it may read what the executor thread updates (counters).

    Returns
    -------
    rclpy.timer.Timer
        The timer.

    """
    def run():
        try:
            fn()
        except _rclpy.InvalidHandle:
            pass                # the node was destroyed while the task waited
        except Exception as err:  # noqa: B902 - logged: a failing report must be seen
            if node.context.ok():
                node.get_logger().error(f'{getattr(fn, "__name__", "periodic task")} '
                                        f'failed: {err!r}')

    return create_spread_timer(node, period_s, lambda: WORKER.submit(run))


def joint_topic(joint, suffix, namespace='reducer_twin'):
    """Return the topic of a derived value of one joint, ``/reducer_twin/<joint>/<suffix>``."""
    return f'/{namespace}/{joint}/{suffix}'


class SpecParameters:
    """
    Declare a validated dataclass as ROS parameters and keep it in sync.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    prefix : str
        Parameter name prefix (e.g. ``'reducer.geometry'``, ``'sim'``).
    instance : dataclass
        Default values (a frozen, validated dataclass of the core).
    on_change : callable, optional
        Called with the new instance after an accepted change. Without it
        the node cannot apply a change while running, and the parameters are
        declared read-only (set them at start).

    """

    def __init__(self, node, prefix, instance, on_change=None):
        self.node = node
        self.prefix = prefix
        self.value = instance
        self.on_change = on_change
        self._names = {}
        values = {}
        for f in fields(instance):
            meta = f.metadata
            if 'unit' not in meta:
                continue
            name = f'{prefix}.{f.name}'
            self._names[name] = (f.name, meta)
            default = getattr(instance, f.name)
            desc = ParameterDescriptor(
                name=name,
                description=f"{meta['doc']} [{meta['unit'] or '-'}]",
                additional_constraints=f"{describe_range(meta)} {meta['unit']}".strip(),
                read_only=on_change is None)
            if meta['integer']:
                desc.type = ParameterType.PARAMETER_INTEGER
                if meta['lo'] is not None and meta['hi'] is not None:
                    desc.integer_range = [IntegerRange(from_value=int(meta['lo']),
                                                       to_value=int(meta['hi']), step=1)]
            else:
                desc.type = ParameterType.PARAMETER_DOUBLE
                if meta['lo'] is not None and meta['hi'] is not None:
                    # ROS ranges are closed: an open bound is declared closed (tools show the
                    # range), additional_constraints says it is open and the core enforces it.
                    desc.floating_point_range = [FloatingPointRange(
                        from_value=float(meta['lo']), to_value=float(meta['hi']), step=0.0)]
            try:
                param = node.declare_parameter(name, default, desc)
            except (InvalidParameterTypeException, InvalidParameterValueException) as err:
                raise InvalidParameter(
                    f'{node.get_name()}: {_refused_override(node, name, meta, err)}') from err
            values[f.name] = param.value
        try:
            self.value = replace(instance, **values)
        except InvalidParameter as err:
            raise InvalidParameter(f'{node.get_name()}: {err}') from err
        node.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, params):
        changes = {}
        for p in params:
            if p.name not in self._names:
                continue
            field_name, meta = self._names[p.name]
            try:
                changes[field_name] = check_value(p.name, p.value, meta)
            except InvalidParameter as err:
                return SetParametersResult(successful=False, reason=str(err))
        if not changes:
            return SetParametersResult(successful=True)
        try:
            candidate = replace(self.value, **changes)
        except InvalidParameter as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.value = candidate
        if self.on_change is not None:
            self.on_change(candidate)
        return SetParametersResult(successful=True)


def _refused_override(node, name, meta, err):
    """
    Say in the core's words why rclpy refused the start value of a parameter.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    name : str
        Parameter name.
    meta : mapping
        Field metadata made by :func:`reducer_twin.core.params.spec`.
    err : rclpy.exceptions.ParameterException
        What rclpy raised (wrong type, or outside the descriptor's range).

    Returns
    -------
    str
        ``'<name> must be <allowed> <unit>, got <value>'``.

    """
    # rclpy keeps the command-line and constructor overrides here, and nowhere public.
    given = getattr(node, '_parameter_overrides', {}).get(name)
    if given is None:
        return str(err)
    try:
        check_value(name, given.value, meta)
    except InvalidParameter as bad:
        return str(bad)
    kind = 'a whole number' if meta['integer'] else 'a floating-point number (e.g. 5.0, not 5)'
    return out_of_range(name, given.value, meta['unit'], f'{kind} {describe_range(meta)}')


class RejectCounter:
    """
    Count rejected messages by reason and warn, throttled.

    Parameters
    ----------
    node : rclpy.node.Node
        Node whose logger is used.
    period_s : float
        Shortest interval between two warnings [s].

    """

    def __init__(self, node, period_s=5.0):
        self.node = node
        self.period_s = period_s
        self.counts = {}
        self._last_warn = -1e18

    @property
    def total(self):
        """Return the number of rejected messages."""
        return sum(self.counts.values())

    def reject(self, reason, detail):
        """
        Count one rejected message and warn at most once per period.

        Parameters
        ----------
        reason : str
            Short reason key (e.g. ``'bad_layout'``).
        detail : str
            What was wrong, for the log.

        """
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = time.monotonic()
        if now - self._last_warn >= self.period_s:
            self._last_warn = now
            self.node.get_logger().warning(
                f'dropped a message ({reason}): {detail} [{self.total} dropped so far: '
                f'{self.counts}]')

    def guard(self, task, reason, fn, *args):
        """
        Run ``fn(*args)`` for a background task; count what fails instead of losing it.

        An :class:`~reducer_twin.core.errors.InvalidInput` is counted as
        ``reason``; any other exception is logged as an error and counted as
        ``'<task>_error'`` (a worker's failure must be seen, not vanish in a
        future).

        Parameters
        ----------
        task : str
            Short name of the task, for the log and the count (e.g. ``'estimator'``).
        reason : str
            Reason key of invalid input.
        fn : callable
            The task.
        *args
            Its arguments.

        Returns
        -------
        tuple
            ``(True, result)``, or ``(False, None)`` when it failed.

        """
        try:
            return True, fn(*args)
        except InvalidInput as err:
            self.reject(reason, str(err))
        except Exception as err:  # noqa: B902 - counted and logged, the node goes on
            self.node.get_logger().error(f'{task} failed: {err!r}')
            self.reject(f'{task}_error', repr(err))
        return False, None


class RowBuffer:
    """
    Rows accumulated in place in one preallocated array.

    For a node that receives small batches (one row per controller message)
    and processes them later: rows are copied in as they come, and taken out
    as one array, with no list of batch arrays to keep and concatenate.

    Parameters
    ----------
    width : int
        Columns per row.
    capacity : int
        Initial rows; the buffer doubles when it must.

    """

    def __init__(self, width, capacity=1024):
        self._data = np.empty((int(capacity), int(width)))
        self.n = 0

    def extend(self, rows):
        """
        Return a view of ``rows`` new rows at the end, for the caller to fill.

        Parameters
        ----------
        rows : int
            Rows to add.

        Returns
        -------
        ndarray
            Writable ``(rows, width)`` view.

        """
        end = self.n + rows
        if end > self._data.shape[0]:
            grown = np.empty((max(2 * self._data.shape[0], end), self._data.shape[1]))
            grown[:self.n] = self._data[:self.n]
            self._data = grown
        view = self._data[self.n:end]
        self.n = end
        return view

    def append(self, row):
        """
        Add one row.

        Parameters
        ----------
        row : sequence of float
            ``width`` values.

        """
        if self.n == self._data.shape[0]:
            self.extend(1)
            self.n -= 1
        self._data[self.n] = row
        self.n += 1

    def take(self):
        """Return a copy of the rows so far and empty the buffer."""
        out = self._data[:self.n].copy()
        self.n = 0
        return out


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


WORKER = BackgroundWorker()
"""
The process's background worker (see :class:`BackgroundWorker`).

Window analysis, estimator and remaining-life updates and simulator block
generation run here in order; the executor thread keeps only the light,
latency-critical callbacks.
"""


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

    Installed for SIGINT and SIGTERM by :func:`run_nodes` in place of rclpy's
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
    stop = StopRequest()
    previous = {signum: signal.signal(signum, stop) for signum in STOP_SIGNALS}
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as err:  # noqa: B902 - rcl refuses its arguments: one line, no traceback
        for signum, handler in previous.items():
            signal.signal(signum, handler)
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
        for node in nodes:
            close = getattr(node, 'close', None)
            if close is not None:
                close()
            node.destroy_node()
        rclpy.try_shutdown()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
    return 0


__all__ = ['Node', 'SpecParameters', 'RejectCounter', 'encoder_qos', 'stream_qos',
           'latest_qos', 'diagnostics_qos', 'joint_topic', 'make_executor', 'run_nodes',
           'check_params_files',
           'spin_until_shutdown', 'StopRequest']
