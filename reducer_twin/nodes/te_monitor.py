"""
te_monitor: transmission error and per-window health features of one joint.

Subscribes to ``/reducer_twin/<joint>/encoder_pairs`` (clean, aligned motor/link samples
from ``encoder_ingest``). TE is computed on arrival, ``theta_link - theta_motor/i`` (ingest
has already unwrapped and aligned the streams), and published in batches on
``/reducer_twin/<joint>/te``. Every ``analysis_period_s`` the accumulated samples go through
the joint's :class:`~reducer_twin.core.joint_twin.TwinFront` (TE extraction, the learnt
link-encoder time offset, the window analysis); each completed window is published on
``/reducer_twin/<joint>/te_features`` (paper Table 5 figures, lost motion, order amplitudes,
duty), what the window analysis found at the test torque on ``.../test_torque_check``
(:mod:`~reducer_twin.nodes.torque_check`). Window length, gap bridging, aging, analysis
period: the fields of :class:`~reducer_twin.core.joint_twin.TwinConfig`. What the front
learnt of the reducer (the encoders' time offset, the soft-zone checks) is kept in a state
file after every batch of windows and continued from on start; a replaced reducer (the
``maintenance`` event) starts the window analysis afresh (:mod:`~reducer_twin.nodes.front_state`).

In ``twin_bringup`` the ingest node of the same process hands the pairs over directly
(:meth:`TEMonitor.take_pairs`, ``subscribe=False``) and the TE batches are published only
while something subscribes to them. The node measures how long samples take from their
stamp to their TE (``latency_stats()``, ``latency_p99_ms`` over each report's period).
"""

import time

from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput
from reducer_twin.core.joint_twin import joint_topic, TwinConfig, TwinFront
from reducer_twin.core.params import ReducerParams
from reducer_twin.msg_adapters.layouts import PAIRED_SAMPLES, record_values, TE_BATCH, TE_FEATURES
from reducer_twin.msg_adapters.ros import batch_array, BatchPublisherMessage, to_multiarray
from reducer_twin.nodes.buffers import ArrivalBatches
from reducer_twin.nodes.diagnostics import publish_diagnostics, say_faults, te_monitor_statuses
from reducer_twin.nodes.front_state import FrontKeeper, PARAMETERS
from reducer_twin.nodes.parameters import check_choice, declare_plain
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import encoder_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes, WORKER
from reducer_twin.nodes.settings import TEMonitorSettings
from reducer_twin.nodes.timers import create_spread_timer, LISTENERS_PERIOD_S
from reducer_twin.nodes.torque_check import CheckPublisher
from std_msgs.msg import Float64MultiArray

_TE_COLUMNS = [0, 2, 5, 3]
"""Columns of an arrived row that make a TE batch row: stamp, link angle, TE, effort."""

LATENCY_KEEP = 1 << 17
"""Latency samples kept for the statistics (a ring of 2 MB per joint)."""

STALE_WINDOWS = 10
"""Windows of stream without a lost motion after which the diagnostics say since when."""


class TEMonitor(Node):
    """
    Compute TE and window features of one joint.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        The joint's reducer.
    subscribe : bool, optional
        Subscribe to the joint's ``encoder_pairs`` topic (default). False
        when an ``encoder_ingest`` of the same process feeds
        :meth:`take_pairs` directly; the TE batches are then published only
        while they have subscribers.
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='te_monitor', params=None, subscribe=True, **kwargs):
        super().__init__(node_name, **kwargs)
        p = declare_plain(self, {
            'joint': ('joint_1', 'joint whose encoder pairs are monitored'),
            'window': ('auto', "'auto', 'revolution' or 'duration' (see WindowAnalyzer)"),
            **PARAMETERS})
        check_choice('window', p['window'], ('auto', 'revolution', 'duration'))
        s = SpecParameters(self, '', TEMonitorSettings()).value
        self.config = SpecParameters(self, '', TwinConfig()).value
        self.params = params or ReducerParams()
        self.joint = p['joint']
        self.twin = TwinFront(self.params, self.config, window=p['window'])
        self.state = FrontKeeper(self, self.joint, self.twin, p['state_file'], p['state_dir'])
        self.rejects = RejectCounter(self)
        self.check = CheckPublisher(self, self.joint)
        self.te_pub = self.create_publisher(Float64MultiArray, joint_topic(self.joint, 'te'),
                                            stream_qos())
        self.feat_pub = self.create_publisher(
            Float64MultiArray, joint_topic(self.joint, 'te_features'), stream_qos(WINDOW_DEPTH))
        self._te_listened = True    # fed in process, checked: see _check_listeners
        if not subscribe:
            create_spread_timer(self, LISTENERS_PERIOD_S, self._check_listeners)
        else:
            self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'encoder_pairs'),
                                     self._on_pairs, encoder_qos())
        create_spread_timer(self, self.config.analysis_period_s, self._analyze)
        publish_diagnostics(self, self._statuses)
        self.batches = ArrivalBatches(self.twin.ratio, s.te_publish_period_s, LATENCY_KEEP)
        self.latency = self.batches.latency
        self._te_msg = BatchPublisherMessage(TE_BATCH)
        self.samples = 0
        self.last_features = None
        self.silent_after_s, self._said = s.silent_after_s, set()
        self.last_pairs_at = None      # monotonic time of the latest encoder pairs

    @property
    def windows(self):
        """Windows analysed so far."""
        return self.twin.windows

    def _on_pairs(self, msg):
        try:
            rows = batch_array(msg, PAIRED_SAMPLES)
        except InvalidInput as err:
            self.rejects.reject('bad_layout', str(err))
            return
        self.take_pairs(rows)

    def take_pairs(self, rows):
        """
        Compute the TE of a batch of clean encoder pairs.

        Parameters
        ----------
        rows : ndarray, shape (n, 5)
            Rows in the ``encoder_pairs`` layout (stamp [s], motor and link
            angle [rad], effort [N*m], link velocity [rad/s]).

        """
        if rows.shape[0]:
            self.samples += rows.shape[0]
            self.last_pairs_at = time.monotonic()
            if self.batches.add(rows, time.time()):
                self._publish_te()

    def _publish_te(self):
        rows = self.batches.take()
        if rows is not None and self._te_listened:
            self.te_pub.publish(self._te_msg.fill(rows[:, _TE_COLUMNS]))

    def _check_listeners(self):
        self._te_listened = self.te_pub.get_subscription_count() > 0

    def _analyze(self):
        """Hand the accumulated samples to the worker thread (the executor must not wait)."""
        self._publish_te()
        if self.batches.pending.n:
            WORKER.post(self, self._analyze_rows, self.batches.pending.take())

    def analyze_now(self):
        """Analyse what has accumulated and wait for it (end of a demo, tests)."""
        self._analyze()
        WORKER.wait_idle()

    def _analyze_rows(self, rows):
        """Run the joint's TE extraction and window analysis; publish the windows (worker)."""
        learnt = self.twin.calibration.corrections
        ok, windows = self.rejects.guard('analysis', 'bad_samples', self.twin.update,
                                         *rows.T)
        if not ok:
            return
        if self.twin.calibration.corrections > learnt:
            self.get_logger().info(f'{self.joint}: link encoder time offset '
                                   f'{self.twin.calibration.applied * 1e6:.1f} us, compensated')
        say_faults(self.get_logger(), self.joint, self.twin, self._said)
        self.check.update(self.twin.analyzer)
        if windows:
            self.state.save()
        for f in windows:
            self.last_features = f
            rec = self.twin.record(f)
            self.feat_pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))

    def close(self):
        """Let the analysis queued finish and its state reach the file before the node goes."""
        WORKER.wait_idle()
        self.state.close()

    flush_latency = _publish_te
    """Publish the pending TE batch now so its latencies are counted."""

    def latency_stats(self, last=None):
        """Return stamp-to-TE latency statistics [s] (see :meth:`LatencyRing.stats`)."""
        return self.latency.stats(last)

    def _statuses(self):
        return te_monitor_statuses(self, STALE_WINDOWS * self.twin.config.window_s)


def main(args=None):
    """Run the te_monitor node."""
    return run_nodes(TEMonitor, args)


if __name__ == '__main__':
    raise SystemExit(main())
