"""
encoder_ingest: controller joint topics in, clean paired encoder samples out.

Subscribes to what robot controllers publish: one ``sensor_msgs/JointState``
(ros2_control's ``/joint_states``) carrying ``<joint>`` (link side) and
``<joint><motor_suffix>`` (motor side), or link and motor sides on two JointState
topics with the same joint names (``motor_topic``; a second ``joint_state_broadcaster``
publishes ros2_control's ``motor_position`` interface so: README, "ROS 2 nodes").
Motor angles are raw or already divided by the ratio (``motor_angles``), counted with the
link or against it (``motor_direction`` 1 or -1, a negative reduction); the torque
comes from the link or the motor entry (``effort_source``, ``motor_effort_units``).
Messages are taken as serialised bytes and read by
:class:`~reducer_twin.msg_adapters.jointstate_cdr.JointStateReader` (no JointState object
is built per message); a publisher that does not stamp is read on arrival times
(:class:`~reducer_twin.nodes.arrival.ArrivalStamps`); the core's
:class:`~reducer_twin.core.robot_ingest.RobotIngest` cleans, pairs and despikes them,
and each joint's clean samples are published on ``/reducer_twin/<joint>/encoder_pairs``
(layout ``encoder_pairs``) in small batches (``batch_period_s``), with counts on
``/diagnostics``. Composed with the TE monitors (``twin_bringup``), the batches are
handed to them directly (:meth:`EncoderIngest.attach`), as rclcpp's intra-process
communication does; the topic is then published only while something subscribes.
"""

from rclpy.node import Node
from reducer_twin.core.effort_source import EFFORT_SOURCES, MOTOR_EFFORT_UNITS
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.ingest import IngestConfig
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import Geometry
from reducer_twin.core.robot_ingest import check_streams, RobotIngest
from reducer_twin.core.robot_ingest import STREAMS
from reducer_twin.core.stamp_clock import retimed_message
from reducer_twin.msg_adapters.jointstate_cdr import JointStateReader
from reducer_twin.msg_adapters.jointstate_cdr import MSGTYPE as JOINT_STATE
from reducer_twin.msg_adapters.layouts import PAIRED_SAMPLES
from reducer_twin.msg_adapters.ros import JointStatePicker
from reducer_twin.nodes.arrival import ArrivalStamps
from reducer_twin.nodes.diagnostics import ingest_statuses, publish_diagnostics
from reducer_twin.nodes.intra_process import SharedOutput
from reducer_twin.nodes.parameters import check_choice, declare_plain, SpecParameters
from reducer_twin.nodes.qos import encoder_qos, UnheardPublishers
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes
from reducer_twin.nodes.settings import IngestSettings
from reducer_twin.nodes.timers import create_spread_timer, LISTENERS_PERIOD_S
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


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
        s = SpecParameters(self, '', IngestSettings()).value
        ratio = s.gear_ratio or total_ratio(Geometry())
        self.batch_ns = int(s.batch_period_s * 1e9)
        self.split = bool(p['motor_topic'])
        self.ingest = RobotIngest(self.joints, ratio, self.ingest_params.value, self.split,
                                  p['motor_angles'], p['effort_source'], p['motor_effort_units'],
                                  p['motor_direction'], p['effort_scale'])
        self.outputs = {joint: SharedOutput(self.create_publisher(
            Float64MultiArray, joint_topic(joint, 'encoder_pairs'), encoder_qos()),
            PAIRED_SAMPLES) for joint in self.joints}
        self._raw = {'link': [], 'motor': []}
        self._raw_since = None
        self._retimed_said = False
        self._topics = {'link': p['link_topic'], 'motor': p['motor_topic']}
        self._stamps = ArrivalStamps(self, self._topics)
        qos = encoder_qos(p['reliable'])
        self.unheard = UnheardPublishers(self, p['reliable'])
        if self.split:
            self._link_pick = JointStatePicker(self.joints)
            self._motor_pick = JointStatePicker(self.joints)
            self._motor_reader = JointStateReader()
            self.create_subscription(JointState, p['motor_topic'], self._on_motor, qos, raw=True,
                                     event_callbacks=self.unheard.callbacks(p['motor_topic']))
        else:
            self._link_pick = JointStatePicker(
                [x for joint in self.joints for x in (joint, joint + p['motor_suffix'])])
        self._link_reader = JointStateReader()
        self.create_subscription(JointState, p['link_topic'], self._on_link, qos, raw=True,
                                 event_callbacks=self.unheard.callbacks(p['link_topic']))
        publish_diagnostics(self, self._statuses)
        if self.batch_ns > 0:   # with 0 nothing waits: no timer to wake the executor
            self.create_timer(max(s.batch_period_s * 5, 0.01), self._flush_stale)
        create_spread_timer(self, LISTENERS_PERIOD_S, self._check_listeners)

    def _declare_plain(self):
        out = declare_plain(self, {
            **STREAMS,
            'reliable': (True, 'RELIABLE (true) or BEST_EFFORT subscription')})
        check_choice('motor_angles', out['motor_angles'], ('raw', 'output'))
        check_choice('effort_source', out['effort_source'], EFFORT_SOURCES)
        check_choice('motor_effort_units', out['motor_effort_units'], MOTOR_EFFORT_UNITS)
        check_streams(out['joints'], out['link_topic'], out['motor_topic'], out['motor_suffix'])
        return out

    def _on_link(self, payload):
        self._buffer('link', self._link_reader, self._link_pick, payload)

    def _on_motor(self, payload):
        self._buffer('motor', self._motor_reader, self._motor_pick, payload)

    def _buffer(self, side, reader, picker, payload):
        try:
            t, names, *fields = reader.read(payload)
            pos, vel, eff = picker.pick_fields(names, *fields)
        except InvalidInput as err:
            self.rejects.reject('bad_joint_state', str(err))
            return
        t = self._stamps.stamp(side, t)
        self._raw[side].append((t, pos, vel, eff))
        if self._raw_since is None:
            self._raw_since = t
        # With batch_period_s 0 the message goes on at once, not with the next one.
        if t - self._raw_since >= self.batch_ns - 1 or t < self._raw_since:
            self._process()

    def _process(self):
        """Clean the buffered rows of all joints at once, pair and publish per joint."""
        self._raw_since = None
        link, self._raw['link'] = self._raw['link'], []
        motor, self._raw['motor'] = self._raw['motor'], []
        for k, rows in self.ingest.process(link, motor):
            self.outputs[self.joints[k]].emit(rows)
        if self.ingest.link.clock.active and not self._retimed_said:
            self._retimed_said = True
            self.get_logger().warning(retimed_message(self._topics['link'],
                                                      self.ingest.link.clock))

    def attach(self, joint, sink):
        """
        Hand the clean pairs of ``joint`` to an in-process consumer.

        Parameters
        ----------
        joint : str
            One of the ingested joints.
        sink : callable
            Called with each batch, an ``(n, 5)`` array in the
            ``encoder_pairs`` layout (stamp [s], motor and link angle [rad],
            effort [N*m], link velocity [rad/s]). It must not keep a
            reference it later modifies: the array is not copied.

        Raises
        ------
        InvalidParameter
            If ``joint`` is not ingested by this node.

        """
        if joint not in self.outputs:
            raise InvalidParameter(f'joint {joint!r} is not ingested here; joints: '
                                   f'{list(self.outputs)}')
        self.outputs[joint].sinks.append(sink)

    def _check_listeners(self):
        for out in self.outputs.values():
            out.check_listeners()
        self.unheard.check_types(set(self._topics.values()) - {''}, JOINT_STATE)

    def _flush_stale(self):
        if self._raw_since is None:
            return
        now = self.get_clock().now().nanoseconds
        if now - self._raw_since > 4 * self.batch_ns:
            self._process()

    def counts(self):
        """Return per-joint counts of every ingestion rule (for diagnostics and tests)."""
        return {joint: {**self.ingest.counts(k), 'published': out.published}
                for k, (joint, out) in enumerate(self.outputs.items())}

    def _statuses(self):
        return ingest_statuses(self.counts(), self.rejects, self.unheard,
                               self._stamps.unstamped_topics())


def main(args=None):
    """Run the encoder_ingest node."""
    return run_nodes(EncoderIngest, args)


if __name__ == '__main__':
    raise SystemExit(main())
