"""
te_monitor: transmission error and per-window health features of one joint.

Subscribes to ``/reducer_twin/<joint>/encoder_pairs`` (clean, aligned
motor/link samples from ``encoder_ingest``). TE is computed on arrival,
``theta_link - theta_motor/i`` (ingest has already unwrapped and aligned the
streams), and published in batches on ``/reducer_twin/<joint>/te``. Every
``analysis_period_s`` the accumulated samples go through the core's
:func:`~reducer_twin.core.te_extraction.compute_te` and
:class:`~reducer_twin.core.te_extraction.WindowAnalyzer`; each completed
window is published on ``/reducer_twin/<joint>/te_features`` (paper Table 5
figures, lost motion, order amplitudes, duty).

In ``twin_bringup`` the ingest node of the same process hands the pairs
over directly (:meth:`TEMonitor.take_pairs`, ``subscribe=False``) and the TE
batches are published only while something subscribes to them.

The link encoder's time offset is learnt from the first windows and then
compensated (:class:`~reducer_twin.core.pipeline.TimeOffsetCalibration`).
The node also measures how long samples take from their stamp to their TE
(``latency_stats()``, and the ``latency_p99_ms`` diagnostic over each report's period).
"""

import time

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.layouts import PAIRED_SAMPLES, record_values, TE_BATCH, TE_FEATURES
from msg_adapters.ros import batch_array, BatchPublisherMessage, diagnostic_array
from msg_adapters.ros import diagnostic_status, to_multiarray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams
# features_record lives in the ROS-free core (the bag analysis uses it too); importable from here.
from reducer_twin.core.pipeline import features_record, TimeOffsetCalibration
from reducer_twin.core.te_extraction import TEExtractor, WindowAnalyzer
from reducer_twin.core.units import rad_to_arcmin
from reducer_twin.nodes.buffers import RowBuffer
from reducer_twin.nodes.qos import diagnostics_qos, encoder_qos, stream_qos, WINDOW_DEPTH
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes, WORKER
from reducer_twin.nodes.timers import create_background_timer, create_spread_timer
from reducer_twin.nodes.timers import LISTENERS_PERIOD_S
from std_msgs.msg import Float64MultiArray

_TE_COLUMNS = [0, 2, 5, 3]
"""Columns of an arrived row that make a TE batch row: stamp, link angle, TE, effort."""

LATENCY_KEEP = 1 << 17
"""Latency samples kept for the statistics (a ring of 2 MB per joint)."""


class TEMonitor(Node):
    """
    Compute TE and window features of one joint.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        Reducer parameters.
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
        p = self._declare_plain()
        self.params = params or ReducerParams()
        self.joint = p['joint']
        self.ratio = total_ratio(self.params.geometry)
        self.analyzer = WindowAnalyzer(self.params, window=p['window'], window_s=p['window_s'],
                                       aging_factor=p['aging_factor'])
        self.extractor = TEExtractor(self.ratio, max_gap_s=p['max_gap_s'])
        self.calibration = TimeOffsetCalibration(self.extractor)
        self.rejects = RejectCounter(self)
        self.te_pub = self.create_publisher(Float64MultiArray, joint_topic(self.joint, 'te'),
                                            stream_qos())
        self.feat_pub = self.create_publisher(
            Float64MultiArray, joint_topic(self.joint, 'te_features'), stream_qos(WINDOW_DEPTH))
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        self._te_listened = True    # fed in process, checked: see _check_listeners
        if not subscribe:
            create_spread_timer(self, LISTENERS_PERIOD_S, self._check_listeners)
        else:
            self.create_subscription(Float64MultiArray, joint_topic(self.joint, 'encoder_pairs'),
                                     self._on_pairs, encoder_qos())
        create_spread_timer(self, p['analysis_period_s'], self._analyze)
        create_background_timer(self, p['diagnostics_period_s'], self._publish_diagnostics)
        self._pending = RowBuffer(5, 4096)   # encoder pairs waiting for the window analysis
        self._arrived = RowBuffer(7, 256)    # encoder pair, its TE, when the TE was computed
        self._minus_inv_ratio = -1.0 / self.ratio
        # TE batches go out as rows arrive, once the oldest waiting row is this old (no 50 Hz
        # timer per joint to wake the executor), and with every window analysis.
        self._te_period_s = p['te_publish_period_s']
        self._first_arrival = None
        self._te_msg = BatchPublisherMessage(TE_BATCH)
        # Rings filled now: np.zeros would commit pages as they fill, a slow RSS growth.
        self._stamps = np.empty(LATENCY_KEEP)     # sample stamps [s]
        self._arrival = np.empty(LATENCY_KEEP)    # when their TE was computed [s]
        self._stamps.fill(0.0)
        self._arrival.fill(0.0)
        self._latency_n = 0
        self._diag_mark = 0     # latency samples already reported in /diagnostics
        self.samples = 0
        self.windows = 0
        self.last_features = None

    def _declare_plain(self):
        specs = {
            'joint': ('joint_1', 'joint whose encoder pairs are monitored'),
            'aging_factor': (1.0, 'seconds of wear exposure per second of stream (1: real '
                                  'robot)'),
            'window': ('auto', "'auto', 'revolution' or 'duration' (see WindowAnalyzer)"),
            'window_s': (2.0, 'window length in stream time [s]'),
            'max_gap_s': (0.05, 'largest stamp gap bridged inside a window [s]'),
            'analysis_period_s': (0.5, 'period of the window analysis [s] (features of a '
                                       'window come at most this late)'),
            'te_publish_period_s': (0.02, 'longest wait of a TE row for its batch while the '
                                          'stream flows [s] (the last rows of a stopped '
                                          'stream go with the next analysis)'),
            'diagnostics_period_s': (1.0, 'period of /diagnostics [s]'),
        }
        out = {}
        for name, (default, doc) in specs.items():
            out[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=doc, read_only=True)).value
        for name in ('window_s', 'max_gap_s', 'analysis_period_s', 'te_publish_period_s',
                     'diagnostics_period_s'):
            if not 0.0 < out[name] <= 3600.0:
                raise InvalidParameter(f'{name} must be in (0, 3600] s, got {out[name]!r}')
        if not 0.0 <= out['aging_factor'] <= 1e9:
            raise InvalidParameter(
                f"aging_factor must be in [0, 1e9], got {out['aging_factor']!r}")
        return out

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
        n = rows.shape[0]
        if n == 0:
            return
        # TE on arrival, kept with its pair; the TE batch, the latencies and the rows for the
        # window analysis are made in bulk at the TE period, which keeps this 1 kHz call to
        # a handful of array operations.
        now = time.time()
        if n == 1:      # the live case, one controller message: cheaper in plain floats
            row = rows[0].tolist()
            row += (row[2] + row[1] * self._minus_inv_ratio, now)
            self._arrived.append(row)
        else:
            out = self._arrived.extend(n)
            out[:, :5] = rows
            te = out[:, 5]
            np.multiply(rows[:, 1], self._minus_inv_ratio, out=te)
            te += rows[:, 2]
            out[:, 6] = now
        self.samples += n
        if self._first_arrival is None:
            self._first_arrival = now
        elif now - self._first_arrival >= self._te_period_s:
            self._publish_te()

    def _publish_te(self):
        if not self._arrived.n:
            return
        rows = self._arrived.take()
        self._first_arrival = None
        self._record_latency(rows[:, 0], rows[:, 6])
        self._pending.extend(rows.shape[0])[:] = rows[:, :5]
        if self._te_listened:
            self.te_pub.publish(self._te_msg.fill(rows[:, _TE_COLUMNS]))

    def _check_listeners(self):
        self._te_listened = self.te_pub.get_subscription_count() > 0

    def _record_latency(self, stamps, arrival):
        k = self._latency_n % LATENCY_KEEP
        m = min(stamps.size, LATENCY_KEEP - k)
        self._stamps[k:k + m] = stamps[:m]
        self._arrival[k:k + m] = arrival[:m]
        self._latency_n += stamps.size

    def _analyze(self):
        """Hand the accumulated samples to the worker thread (the executor must not wait)."""
        self._publish_te()
        if not self._pending.n:
            return
        WORKER.submit(self._analyze_rows, self._pending.take())

    def analyze_now(self):
        """Analyse what has accumulated and wait for it (end of a demo, tests)."""
        self._analyze()
        WORKER.wait_idle()

    def _analyze_rows(self, rows):
        """Run TE extraction and the window analysis; publish completed windows (worker)."""
        ok, windows = self.rejects.guard('analysis', 'bad_samples', self._windows_of, rows)
        if not ok:
            return
        for f in windows:
            if self.calibration.observe(f):
                self.get_logger().info(f'{self.joint}: link encoder time offset '
                                       f'{self.calibration.applied * 1e6:.1f} us, compensated')
            self.windows += 1
            self.last_features = f
            rec = features_record(f, self.params)
            self.feat_pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))

    def _windows_of(self, rows):
        stream = self.extractor.update(rows[:, 0], rows[:, 1], rows[:, 0], rows[:, 2])
        return self.analyzer.update(stream, rows[:, 3], rows[:, 4])

    def reset_latency(self):
        """Forget the latency samples so far (a benchmark's warm-up)."""
        self._latency_n = 0
        self._diag_mark = 0

    def latency_records(self):
        """Return ``(stamps [s], TE times [s])`` of the kept samples."""
        n = min(self._latency_n, LATENCY_KEEP)
        return self._stamps[:n].copy(), self._arrival[:n].copy()

    def flush_latency(self):
        """Publish the pending TE batch now so its latencies are counted."""
        self._publish_te()

    def latency_stats(self, last=None):
        """
        Return stamp-to-TE latency statistics [s].

        Parameters
        ----------
        last : int, optional
            Only the newest ``last`` samples; default every kept sample.

        Returns
        -------
        dict
            ``count``, ``p50``, ``p99``, ``max``.

        """
        kept = min(self._latency_n, LATENCY_KEEP)
        n = kept if last is None else max(min(last, kept), 0)
        if n == 0:
            return {'count': 0, 'p50': float('nan'), 'p99': float('nan'), 'max': float('nan')}
        rows = (slice(0, n) if last is None
                else np.arange(self._latency_n - n, self._latency_n) % LATENCY_KEEP)
        lat = self._arrival[rows] - self._stamps[rows]
        return {'count': self._latency_n if last is None else n,
                'p50': float(np.percentile(lat, 50)), 'p99': float(np.percentile(lat, 99)),
                'max': float(lat.max())}

    def _publish_diagnostics(self):
        # The p99 of the samples since the last report (the ring holds the last 131 k).
        lat = self.latency_stats(last=self._latency_n - self._diag_mark)
        self._diag_mark = self._latency_n
        f = self.last_features
        values = {'samples': self.samples, 'windows': self.windows,
                  'rejected_messages': self.rejects.total,
                  'latency_p99_ms': lat['p99'] * 1e3}
        if f is not None:
            values.update({'te_pp_arcmin': rad_to_arcmin(f.te_pp),
                           'lost_motion_arcmin': rad_to_arcmin(f.lost_motion)})
        level = 'OK' if self.rejects.total == 0 else 'WARN'
        message = f'{self.windows} windows analysed'
        reason = self.analyzer.not_observed_reason(joint_topic(self.joint, 'encoder_pairs'))
        values['observed_windows'] = self.analyzer.windows_observed
        if reason is not None:
            # Never OK without a lost motion: say why the reducer cannot be seen.
            level, message = 'STALE', f'not observed: {reason}'
        self.diag_pub.publish(diagnostic_array(
            self.get_clock().now().nanoseconds,
            [diagnostic_status(f'reducer_twin: {self.joint} transmission error', self.joint,
                               level, message, values)]))


def main(args=None):
    """Run the te_monitor node."""
    return run_nodes(TEMonitor, args)


if __name__ == '__main__':
    raise SystemExit(main())
