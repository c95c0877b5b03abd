"""
Fixtures of the node tests: real rclpy over real DDS, never mocked.

Every test module gets its own initialised rclpy context (``ros_context``);
every test gets a :class:`RosHarness` (``ros``) with its own executor, which
destroys the nodes the test added when it ends, so that modules share a
context and tests share nothing. Nodes in one process talk through the same
DDS participant over the shared-memory transport the top-level conftest
selects (``FASTDDS_BUILTIN_TRANSPORTS=SHM``, localhost discovery, a domain id
of this test session).

Nothing here waits without a deadline: :meth:`RosHarness.spin_until` spins
with ``spin_once(timeout_sec=...)`` until a predicate holds or its timeout
passes, and the test modules carry ``pytest.mark.timeout(..., method='thread')``
as the last resort.
"""

import itertools
import os
import signal
import subprocess
import time

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

_names = itertools.count()


def new_executor(context):
    """Return an EventsExecutor on ``context`` (single-threaded where unavailable)."""
    try:
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    except (ImportError, AttributeError, RuntimeError):
        return SingleThreadedExecutor(context=context)


class ProbeNode(Node):
    """
    A test's own node: publishes what a test sends, keeps what it hears.

    Parameters
    ----------
    context : rclpy.context.Context
        The context of the nodes under test.

    """

    def __init__(self, context):
        super().__init__(f'probe_{next(_names)}', context=context)
        self.received = {}

    def publisher(self, topic, msg_type, qos):
        """Create a publisher on ``topic``."""
        return self.create_publisher(msg_type, topic, qos)

    def listen(self, topic, msg_type, qos):
        """
        Subscribe to ``topic`` and return the list its messages are appended to.

        Parameters
        ----------
        topic : str
            Topic name.
        msg_type : type
            Message class.
        qos : rclpy.qos.QoSProfile
            QoS, compatible with the publisher's.

        Returns
        -------
        list
            Received messages, oldest first (filled while the executor spins).

        """
        messages = []
        self.create_subscription(msg_type, topic, messages.append, qos)
        self.received[topic] = messages
        return messages


class RosHarness:
    """
    Spin nodes under test with one executor, within deadlines.

    Parameters
    ----------
    context : rclpy.context.Context
        Initialised context the nodes are created in.

    """

    def __init__(self, context):
        self.context = context
        self.executor = new_executor(context)
        self.nodes = []

    def add(self, node):
        """Spin ``node`` from now on and destroy it at the end of the test; return it."""
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def remove(self, node):
        """Stop spinning ``node`` and destroy it (a node process that stops)."""
        self.executor.remove_node(node)
        self.nodes.remove(node)
        # The EventsExecutor may still hold an event of the node (a timer that fired just
        # before): let it run while the node's publishers are alive, then destroy the node.
        for _ in range(3):
            self.executor.spin_once(timeout_sec=0.0)
        node.destroy_node()

    def probe(self):
        """Return a new :class:`ProbeNode`, spun by this harness."""
        return self.add(ProbeNode(self.context))

    def spin_for(self, seconds):
        """Spin for ``seconds`` of wall time."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.01, max(end - time.monotonic(), 0.0)))

    def spin_until(self, predicate, timeout=10.0, what=None):
        """
        Spin until ``predicate()`` is true.

        Parameters
        ----------
        predicate : callable
            Checked after every ``spin_once``.
        timeout : float
            Wall-time limit [s].
        what : str, optional
            What is awaited: when given, a timeout fails the test with it.

        Returns
        -------
        bool
            Whether the predicate held before the timeout.

        """
        end = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > end:
                if what is not None:
                    pytest.fail(f'timed out after {timeout:g} s waiting for {what}')
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def wait_matched(self, *endpoints, timeout=10.0):
        """Spin until every publisher or subscription has matched a peer."""
        def matched(e):
            count = (e.get_subscription_count() if hasattr(e, 'get_subscription_count')
                     else e.get_publisher_count())
            return count > 0
        self.spin_until(lambda: all(matched(e) for e in endpoints), timeout,
                        what=f'{[e.topic_name for e in endpoints]} to match')

    def call(self, client, request, timeout=10.0):
        """Call a service through ``client`` and return its response."""
        self.spin_until(client.service_is_ready, timeout, what=f'service {client.srv_name}')
        return self.ask(lambda: client.call_async(request), f'a response of {client.srv_name}')

    def ask(self, send, what, timeout=30.0, resend_s=5.0):
        """
        Send a service request until it is answered; return the response.

        A server is "ready" once its request reader matched the client, which can be
        before its response writer matched the client's reader: DDS then drops that
        first response. Each request asked here is idempotent, so it is sent again
        every ``resend_s`` until one answer arrives.

        Parameters
        ----------
        send : callable
            Sends the request and returns its future.
        what : str
            What is awaited, named when ``timeout`` passes without an answer.
        timeout : float
            Wall-time limit over all attempts [s].
        resend_s : float
            Wait for one answer before the request is sent again [s].

        """
        end = time.monotonic() + timeout
        while True:
            future = send()
            if self.spin_until(future.done, min(resend_s, max(end - time.monotonic(), 0.0))):
                return future.result()
            if time.monotonic() > end:
                pytest.fail(f'timed out after {timeout:g} s waiting for {what}')

    @staticmethod
    def statuses(messages, name):
        """Return the statuses called ``name`` in received DiagnosticArrays, oldest first."""
        return [s for m in messages for s in m.status if s.name == name]

    def wait_status(self, messages, name, predicate=lambda s: True):
        """Spin until a received status called ``name`` satisfies ``predicate``; return it."""
        found = []

        def latest():
            found[:] = [s for s in self.statuses(messages, name) if predicate(s)]
            return bool(found)

        self.spin_until(latest, what=f'a diagnostics status {name!r}')
        return found[-1]

    @staticmethod
    def key_values(status):
        """Return the key/values of a DiagnosticStatus as a dict of strings."""
        return {kv.key: kv.value for kv in status.values}

    def close(self):
        """Shut the executor down, then destroy the nodes: no callback runs after that."""
        self.executor.shutdown(timeout_sec=1.0)
        for node in self.nodes:
            node.destroy_node()
        self.nodes = []


def init_context(context=None):
    """Initialise ``context`` (default: the global one) without signal handlers."""
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    return context or rclpy.get_default_context()


@pytest.fixture(scope='module')
def ros_context():
    """Return an rclpy context initialised for one test module."""
    context = init_context(Context())
    yield context
    rclpy.try_shutdown(context=context)


@pytest.fixture
def ros(ros_context):
    """Return a :class:`RosHarness` on the module's context; its nodes end with the test."""
    harness = RosHarness(ros_context)
    yield harness
    harness.close()


@pytest.fixture(scope='module')
def default_ros_context():
    """
    Initialise rclpy's global context for one test module.

    For code that creates its nodes without a ``context`` argument, such as
    ``twin_bringup.build_nodes``; the context is shut down (and the global
    one reset) at the end of the module.
    """
    context = init_context()
    yield context
    rclpy.try_shutdown()


@pytest.fixture(scope='module')
def default_ros(default_ros_context):
    """Return a :class:`RosHarness` on rclpy's global context, for the whole module."""
    harness = RosHarness(default_ros_context)
    yield harness
    harness.close()


def _run_for(argv, seconds, cwd=None):
    """
    Run a node program for ``seconds``, then stop it with SIGINT as Ctrl-C would.

    Parameters
    ----------
    argv : list of str
        Command line.
    seconds : float
        How long it must stay up [s].
    cwd : path, optional
        Working directory.

    Returns
    -------
    tuple
        ``(still_running_after_seconds, returncode, stdout, stderr)``.

    """
    proc = subprocess.Popen([str(a) for a in argv], cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        try:
            proc.wait(timeout=seconds)
        except subprocess.TimeoutExpired:
            pass
        alive = proc.poll() is None
        if alive:
            proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return alive, proc.returncode, out, err


@pytest.fixture(scope='session')
def run_for():
    """Return :func:`_run_for`: run a node program for a while, then SIGINT it."""
    return _run_for


@pytest.fixture(scope='session')
def node_program(venv_bin):
    """Return a function giving the installed executable of a node (``venv/bin/<name>``)."""
    def find(name):
        path = venv_bin / name
        if not os.access(path, os.X_OK):
            pytest.fail(f'{name} is not installed in {venv_bin} (pip install -e .)')
        return path
    return find
