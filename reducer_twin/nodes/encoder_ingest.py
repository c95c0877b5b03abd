"""
encoder_ingest: controller joint topics in, clean paired encoder samples out.

Subscribes to what robot controllers publish, in either form:

* one ``sensor_msgs/JointState`` (ros2_control's ``/joint_states``) carrying
  ``<joint>`` (link side) and ``<joint><motor_suffix>`` (motor side), or
* link and motor sides on two JointState topics with the same joint names
  (``motor_topic`` set). ros2_control exports a motor encoder as a joint state
  interface (``motor_position``), which only ``/dynamic_joint_states`` carries;
  a second ``joint_state_broadcaster`` with ``use_local_topics: true`` and
  ``map_interface_to_joint_state: {position: motor_position}`` publishes it as
  such a motor topic (README, "ROS 2 nodes"). The node does not subscribe to
  ``control_msgs`` types, so the package does not depend on them; recorded
  DynamicJointState is read by ``reducer-twin analyze``.

Motor angles are raw (input side) or already divided by the gear ratio
(``motor_angles: output``). The torque is read from the link entry, the motor
entry (in motor units, times the ratio, or joint units: ``motor_effort_units``),
or the link entry where it has one (``effort_source: auto``). The subscriptions
take the messages as their serialised bytes, read by
:class:`~msg_adapters.jointstate_cdr.JointStateReader` (the same values rclpy
would give, without building a message object of names and arrays per
controller tick). Every stream goes through the core ingestion
rules (:mod:`reducer_twin.core.ingest`); clean, time-aligned samples are
published per joint on ``/reducer_twin/<joint>/encoder_pairs``
(``Float64MultiArray``, layout ``encoder_pairs``) in small batches
(``batch_period_s``), and counts go to ``/diagnostics``.

Composed with the TE monitors in one process (``twin_bringup``), the batches
are handed to them directly (:meth:`EncoderIngest.attach`), as rclcpp's
intra-process communication does for composed nodes; the topic is then
published only while something outside subscribes to it (a recorder, a
monitor in another process), which saves a serialisation and a DDS hop per
batch and joint.
"""

from diagnostic_msgs.msg import DiagnosticArray
from msg_adapters.jointstate_cdr import JointStateReader
from msg_adapters.layouts import PAIRED_SAMPLES
from msg_adapters.ros import BatchPublisherMessage, diagnostic_array, diagnostic_status
from msg_adapters.ros import JointStatePicker
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.ingest import choose_effort, EFFORT_SOURCES, IngestConfig, Pairer
from reducer_twin.core.ingest import motor_effort_scale, MOTOR_EFFORT_UNITS, SpikeFilter
from reducer_twin.core.ingest import SpikeFilterBank
from reducer_twin.core.ingest import StreamCleaner
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import Geometry
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import diagnostics_qos, encoder_qos
from reducer_twin.nodes.rejects import RejectCounter
from reducer_twin.nodes.runtime import run_nodes
from reducer_twin.nodes.timers import create_background_timer, create_spread_timer
from reducer_twin.nodes.timers import LISTENERS_PERIOD_S
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


class _JointOutput:
    """Pairing state, pending rows and publisher of one joint."""

    def __init__(self, name, config, motor_scale, ratio, effort='link', effort_scale=1.0):
        self.name = name
        self.pairer = Pairer(config, motor_scale, effort=effort,
                             motor_effort_scale=effort_scale)
        self.spikes = SpikeFilter(ratio, config)
        self.motor_scale = motor_scale
        self.published = 0
        self.publisher = None
        self.message = BatchPublisherMessage(PAIRED_SAMPLES)
        self.sinks = []
        self.listened = True

    def emit(self, rows):
        """Hand ``rows`` to the in-process consumers; publish them if anyone subscribes."""
        self.published += rows.shape[0]
        for sink in self.sinks:
            sink(rows)
        if self.listened:
            self.publisher.publish(self.message.fill(rows))


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
        self.effort_source = p['effort_source']
        self.effort_scale = motor_effort_scale(p['motor_effort_units'], p['motor_angles'], ratio)
        self.batch_ns = int(p['batch_period_s'] * 1e9)
        self.split = bool(p['motor_topic'])
        cfg = self.ingest_params.value
        # Combined form: one cleaner, columns link_1, motor_1, link_2, motor_2, ...
        self.link = StreamCleaner(cfg)
        self.motor = StreamCleaner(cfg) if self.split else None
        self.scale = scale
        self.spikes = SpikeFilterBank(ratio, len(self.joints), cfg)
        self.outputs = {}
        for joint in self.joints:
            out = _JointOutput(joint, cfg, scale, ratio, self.effort_source, self.effort_scale)
            out.publisher = self.create_publisher(
                Float64MultiArray, joint_topic(joint, 'encoder_pairs'), encoder_qos())
            self.outputs[joint] = out
        self._raw = {'link': [], 'motor': []}
        self._raw_since = None
        qos = encoder_qos(p['reliable'])
        # The controller streams are taken as their serialised bytes and read by a
        # JointStateReader: no JointState object (names, arrays) is built per message.
        if self.split:
            self._link_pick = JointStatePicker(self.joints)
            self._motor_pick = JointStatePicker(self.joints)
            self._motor_reader = JointStateReader()
            self.create_subscription(JointState, p['motor_topic'], self._on_motor, qos,
                                     raw=True)
        else:
            names = []
            for joint in self.joints:
                names += [joint, joint + p['motor_suffix']]
            self._link_pick = JointStatePicker(names)
        self._link_reader = JointStateReader()
        self.create_subscription(JointState, p['link_topic'], self._on_link, qos, raw=True)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())
        create_background_timer(self, p['diagnostics_period_s'], self._publish_diagnostics)
        if self.batch_ns > 0:   # with 0 nothing waits: no timer to wake the executor
            self.create_timer(max(p['batch_period_s'] * 5, 0.01), self._flush_stale)
        create_spread_timer(self, LISTENERS_PERIOD_S, self._check_listeners)

    def _declare_plain(self):
        specs = {
            'joints': (['joint_1'], 'joint names to ingest'),
            'link_topic': ('/joint_states', 'JointState topic with the link-side positions'),
            'motor_topic': ('', 'JointState topic with the motor side; empty: motor entries '
                                'are in link_topic as <joint><motor_suffix>'),
            'motor_suffix': ('_motor', 'suffix of motor-side entries in a combined message'),
            'motor_angles': ('raw', "'raw' (input side) or 'output' (divided by the ratio)"),
            'effort_source': ('auto', "torque from the 'link' entry, the 'motor' entry, or "
                                      "'auto' (link where it has one, else motor)"),
            'motor_effort_units': ('auto', "motor entry's effort: 'motor' torque (times the "
                                           "ratio), 'joint' units, or 'auto' (motor torque "
                                           'when motor_angles is raw)'),
            'gear_ratio': (0.0, 'total ratio; <= 0 takes it from the RV-80E geometry (81)'),
            'reliable': (True, 'RELIABLE (true) or BEST_EFFORT subscription'),
            'batch_period_s': (0.002, 'longest time a sample waits to be published [s]; 0: '
                                      'every controller message at once'),
            'diagnostics_period_s': (1.0, 'period of /diagnostics [s]'),
        }
        out = {}
        for name, (default, doc) in specs.items():
            out[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=doc, read_only=True)).value
        if out['motor_angles'] not in ('raw', 'output'):
            raise InvalidParameter(
                f"motor_angles must be 'raw' or 'output', got {out['motor_angles']!r}")
        for name, allowed in (('effort_source', EFFORT_SOURCES),
                              ('motor_effort_units', MOTOR_EFFORT_UNITS)):
            if out[name] not in allowed:
                raise InvalidParameter(f'{name} must be one of '
                                       f'{", ".join(repr(a) for a in allowed)}, got {out[name]!r}')
        if not 0.0 <= out['batch_period_s'] <= 1.0:
            raise InvalidParameter(
                f"batch_period_s must be in [0, 1] s, got {out['batch_period_s']!r}")
        if not out['joints'] or any(not j for j in out['joints']):
            raise InvalidParameter(f"joints must be non-empty names, got {out['joints']!r}")
        if out['motor_topic'] and out['motor_topic'] == out['link_topic']:
            link = out['link_topic']
            raise InvalidParameter(f'motor_topic must differ from link_topic ({link!r}); '
                                   "leave it '' when the motor entries are in link_topic")
        if not out['motor_topic'] and not out['motor_suffix']:
            raise InvalidParameter('motor_suffix must not be empty when the motor entries are '
                                   'in link_topic: <joint> and <joint><motor_suffix> would be '
                                   "the same entry; e.g. '_motor'")
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
        clean_link = _clean(self.link, link)
        if self.split:
            clean_motor = _clean(self.motor, motor)
            for k, out in enumerate(self.outputs.values()):
                if clean_link is not None:
                    out.pairer.add_link(clean_link.column(k))
                if clean_motor is not None:
                    out.pairer.add_motor(clean_motor.column(k))
                self._publish(out, out.pairer.pop())
        elif clean_link is not None and len(clean_link):
            self._pair_all(clean_link)

    def _pair_all(self, clean):
        """Pair, despike and publish every joint of a combined-form batch at once."""
        position = clean.position
        finite = np.isfinite(position)
        link = position[:, 0::2]
        motor = position[:, 1::2] * self.scale
        if finite.all():
            paired, unpaired = np.ones(link.shape, dtype=bool), None
        else:
            link_ok, motor_ok = finite[:, 0::2], finite[:, 1::2]
            paired = link_ok & motor_ok
            unpaired = np.count_nonzero(link_ok ^ motor_ok, axis=0)
        keep = self.spikes.keep(motor, link, paired)
        n, j = link.shape
        # Joint-major, so that each joint's rows are one contiguous block.
        rows = np.empty((j, n, 5))
        rows[:, :, 0] = clean.t_ns * 1e-9
        rows[:, :, 1] = motor.T
        rows[:, :, 2] = link.T
        rows[:, :, 3] = choose_effort(clean.effort[:, 0::2], clean.effort[:, 1::2],
                                      self.effort_source, self.effort_scale).T
        rows[:, :, 4] = clean.velocity[:, 0::2].T
        all_kept = keep is paired and unpaired is None
        for k, out in enumerate(self.outputs.values()):
            if unpaired is not None:
                out.pairer.unpaired += int(unpaired[k])
            joint_rows = rows[k] if all_kept else rows[k][keep[:, k]]
            if joint_rows.shape[0]:
                out.emit(joint_rows)

    def _publish(self, out, pairs):
        if len(pairs):
            rows = pairs.as_rows()
            keep = out.spikes.keep(rows[:, 1], rows[:, 2])
            rows = rows[keep]
            if rows.shape[0]:
                out.emit(rows)

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
        # Without an in-process consumer the topic is the only way out: always published.
        for out in self.outputs.values():
            out.listened = not out.sinks or out.publisher.get_subscription_count() > 0

    def _flush_stale(self):
        if self._raw_since is None:
            return
        now = self.get_clock().now().nanoseconds
        if now - self._raw_since > 4 * self.batch_ns:
            self._process()

    def counts(self):
        """Return per-joint counts of every ingestion rule (for diagnostics and tests)."""
        result = {}
        for k, (joint, out) in enumerate(self.outputs.items()):
            c = {}
            sides = ((('link', self.link, [k]), ('motor', self.motor, [k])) if self.split
                     else (('stream', self.link, [2 * k, 2 * k + 1]),))
            for side, cleaner, columns in sides:
                for reason, count in cleaner.counts_for(columns).items():
                    c[f'{side}_{reason}'] = count
                c[f'{side}_missing'] = cleaner.missing
            c['unpaired'] = out.pairer.unpaired
            c.update(out.spikes.counts if self.split else self.spikes.counts(k))
            c['published'] = out.published
            result[joint] = c
        return result

    def _publish_diagnostics(self):
        statuses = []
        for joint, counts in self.counts().items():
            bad = sum(v for k, v in counts.items()
                      if k not in ('published', 'step') and not k.endswith('_wrap'))
            counts['rejected_messages'] = self.rejects.total
            statuses.append(diagnostic_status(
                f'reducer_twin: {joint} encoder ingest', joint, 'OK' if bad == 0 else 'WARN',
                'streams clean' if bad == 0 else f'{bad} samples dropped or repaired', counts))
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().nanoseconds, statuses))


def _clean(cleaner, rows):
    """Run buffered ``(t, pos, vel, eff)`` rows through a cleaner; None if there are none."""
    if not rows:
        return None
    if len(rows) == 1:      # the live case: one controller message at a time
        t, pos, vel, eff = rows[0]
        return cleaner.process(np.array([t], dtype=np.int64), pos[None, :], vel[None, :],
                               eff[None, :])
    t = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    pos = np.stack([r[1] for r in rows])
    vel = np.stack([r[2] for r in rows])
    eff = np.stack([r[3] for r in rows])
    return cleaner.process(t, pos, vel, eff)


def main(args=None):
    """Run the encoder_ingest node."""
    return run_nodes(EncoderIngest, args)


if __name__ == '__main__':
    raise SystemExit(main())
