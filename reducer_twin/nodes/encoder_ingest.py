"""
encoder_ingest: controller joint topics in, clean paired encoder samples out.

Subscribes to what robot controllers publish, in either form:

* one ``sensor_msgs/JointState`` (ros2_control's ``/joint_states``) carrying
  ``<joint>`` (link side) and ``<joint><motor_suffix>`` (motor side), or
* link and motor sides on two JointState topics with the same joint names
  (``motor_topic`` set).

Motor angles are raw (input side) or already divided by the gear ratio
(``motor_angles: output``). Every stream goes through the core ingestion
rules (:mod:`reducer_twin.core.ingest`); clean, time-aligned samples are
published per joint on ``/reducer_twin/<joint>/encoder_pairs``
(``Float64MultiArray``, layout ``encoder_pairs``) in small batches
(``batch_period_s``), and counts go to ``/diagnostics``.
"""

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.layouts import PAIRED_SAMPLES
from msg_adapters.ros import diagnostic_array, diagnostic_status, JointStatePicker
from msg_adapters.ros import stamp_to_ns, to_multiarray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.ingest import IngestConfig, pair_same_stamps, Pairer, StreamCleaner
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import Geometry
from reducer_twin.nodes.base import diagnostics_qos, encoder_qos, joint_topic, Node
from reducer_twin.nodes.base import RejectCounter, run_nodes, SpecParameters
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


class _JointStreams:
    """Cleaners, pairer and pending output of one joint."""

    def __init__(self, name, config, motor_scale, ratio):
        self.name = name
        self.link = StreamCleaner(config.link_spike_rad, config)
        self.motor = StreamCleaner(config.motor_spike_rad, config)
        self.pairer = Pairer(config, motor_scale)
        self.motor_scale = motor_scale
        self.pending = []
        self.pending_since = None
        self.published = 0
        self.publisher = None

    def counts(self):
        out = {}
        for side, cleaner in (('link', self.link), ('motor', self.motor)):
            for reason, count in cleaner.counts.items():
                out[f'{side}_{reason}'] = count
            out[f'{side}_missing'] = cleaner.missing
        out['unpaired'] = self.pairer.unpaired
        out['published'] = self.published
        return out


class EncoderIngest(Node):
    """
    Validate and pair motor/link encoder streams of one robot's joints.

    Parameters
    ----------
    node_name : str
        ROS node name.
    **kwargs
        Passed to :class:`rclpy.node.Node` (e.g. ``parameter_overrides``).

    """

    def __init__(self, node_name='encoder_ingest', **kwargs):
        super().__init__(node_name, **kwargs)
        p = self._declare_plain()
        self.ingest_params = SpecParameters(self, 'ingest', IngestConfig())
        self.rejects = RejectCounter(self)
        self.joints = p['joints']
        ratio = total_ratio(Geometry()) if p['gear_ratio'] <= 0 else p['gear_ratio']
        scale = ratio if p['motor_angles'] == 'output' else 1.0
        self.batch_ns = int(p['batch_period_s'] * 1e9)
        self.split = bool(p['motor_topic'])
        self.streams = {}
        for joint in self.joints:
            s = _JointStreams(joint, self.ingest_params.value, scale, ratio)
            s.publisher = self.create_publisher(
                Float64MultiArray, joint_topic(joint, 'encoder_pairs'), encoder_qos())
            self.streams[joint] = s
        qos = encoder_qos(p['reliable'])
        if self.split:
            self._link_pick = JointStatePicker(self.joints)
            self._motor_pick = JointStatePicker(self.joints)
            self.create_subscription(JointState, p['motor_topic'], self._on_motor, qos)
        else:
            names = []
            for joint in self.joints:
                names += [joint, joint + p['motor_suffix']]
            self._link_pick = JointStatePicker(names)
        self.create_subscription(JointState, p['link_topic'], self._on_link, qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        self.create_timer(p['diagnostics_period_s'], self._publish_diagnostics)
        self.create_timer(max(p['batch_period_s'] * 5, 0.01), self._flush_stale)

    def _declare_plain(self):
        specs = {
            'joints': (['joint_1'], 'joint names to ingest'),
            'link_topic': ('/joint_states', 'JointState topic with the link-side positions'),
            'motor_topic': ('', 'JointState topic with the motor side; empty: motor entries '
                                'are in link_topic as <joint><motor_suffix>'),
            'motor_suffix': ('_motor', 'suffix of motor-side entries in a combined message'),
            'motor_angles': ('raw', "'raw' (input side) or 'output' (divided by the ratio)"),
            'gear_ratio': (0.0, 'total ratio; <= 0 takes it from the RV-80E geometry (81)'),
            'reliable': (True, 'RELIABLE (true) or BEST_EFFORT subscription'),
            'batch_period_s': (0.002, 'longest time a sample waits to be published [s]'),
            'diagnostics_period_s': (1.0, 'period of /diagnostics [s]'),
        }
        out = {}
        for name, (default, doc) in specs.items():
            out[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=doc, read_only=True)).value
        if out['motor_angles'] not in ('raw', 'output'):
            raise InvalidParameter(
                f"motor_angles must be 'raw' or 'output', got {out['motor_angles']!r}")
        if not 0.0 < out['batch_period_s'] <= 1.0:
            raise InvalidParameter(
                f"batch_period_s must be in (0, 1] s, got {out['batch_period_s']!r}")
        if not out['joints'] or any(not j for j in out['joints']):
            raise InvalidParameter(f"joints must be non-empty names, got {out['joints']!r}")
        return out

    def _on_link(self, msg):
        try:
            pos, vel, eff = self._link_pick.pick(msg)
            t = stamp_to_ns(msg.header.stamp)
        except InvalidInput as err:
            self.rejects.reject('bad_joint_state', str(err))
            return
        tt = np.array([t], dtype=np.int64)
        for k, joint in enumerate(self.joints):
            s = self.streams[joint]
            if self.split:
                s.pairer.add_link(s.link.process(tt, pos[k:k + 1], vel[k:k + 1], eff[k:k + 1]))
                self._emit(s, s.pairer.pop(), t)
            else:
                link = s.link.process(tt, pos[2 * k:2 * k + 1], vel[2 * k:2 * k + 1],
                                      eff[2 * k:2 * k + 1])
                motor = s.motor.process(tt, pos[2 * k + 1:2 * k + 2])
                pairs, unpaired = pair_same_stamps(link, motor, s.motor_scale)
                s.pairer.unpaired += unpaired
                self._emit(s, pairs, t)

    def _on_motor(self, msg):
        try:
            pos, _, _ = self._motor_pick.pick(msg)
            t = stamp_to_ns(msg.header.stamp)
        except InvalidInput as err:
            self.rejects.reject('bad_joint_state', str(err))
            return
        tt = np.array([t], dtype=np.int64)
        for k, joint in enumerate(self.joints):
            s = self.streams[joint]
            s.pairer.add_motor(s.motor.process(tt, pos[k:k + 1]))
            self._emit(s, s.pairer.pop(), t)

    def _emit(self, s, pairs, now_ns):
        if len(pairs):
            if not s.pending:
                s.pending_since = int(pairs.t_ns[0])
            s.pending.append(pairs.as_rows())
        if s.pending and now_ns - s.pending_since >= self.batch_ns - 1:
            self._publish(s)

    def _publish(self, s):
        rows = np.concatenate(s.pending)
        s.pending = []
        s.published += rows.shape[0]
        s.publisher.publish(to_multiarray(PAIRED_SAMPLES, rows))

    def _flush_stale(self):
        now = self.get_clock().now().nanoseconds
        for s in self.streams.values():
            if s.pending and now - s.pending_since > 4 * self.batch_ns:
                self._publish(s)

    def _publish_diagnostics(self):
        statuses = []
        for joint, s in self.streams.items():
            counts = s.counts()
            bad = sum(v for k, v in counts.items() if k not in ('published', 'link_wrap'))
            level = 'OK' if bad == 0 else 'WARN'
            counts['rejected_messages'] = self.rejects.total
            statuses.append(diagnostic_status(
                f'reducer_twin: {joint} encoder ingest', joint, level,
                'streams clean' if bad == 0 else f'{bad} samples dropped or repaired', counts))
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().nanoseconds, statuses))

    def stats(self):
        """Return per-joint counts (for tests and the demo)."""
        return {joint: s.counts() for joint, s in self.streams.items()}


def main(args=None):
    """Run the encoder_ingest node."""
    return run_nodes(EncoderIngest, args)


if __name__ == '__main__':
    raise SystemExit(main())
