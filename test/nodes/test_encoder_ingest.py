"""
encoder_ingest over real DDS: controller JointState in, encoder_pairs batches out.

A probe node publishes what robot controllers publish, in both forms the node
accepts: (a) one ``/joint_states`` carrying ``<joint>`` and ``<joint>_motor``
(ros2_control's joint_state_broadcaster with a motor interface; arrays sized
to all joints, unavailable interfaces NaN), and (b) link and motor sides on
two topics with the same names at different rates (1 kHz link, 500 Hz
motor). Motor angles are raw (input side) or already divided by the ratio.
Stamps are a wall-clock time 10 s in the past, so the node's stale-batch
flush works as on a live robot.
"""

import itertools
import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.msg_adapters.layouts import PAIRED_SAMPLES
from reducer_twin.msg_adapters.ros import batch_array, make_joint_state
from reducer_twin.nodes.encoder_ingest import EncoderIngest
from reducer_twin.nodes.qos import encoder_qos
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

pytestmark = pytest.mark.timeout(60, method='thread')

RATIO = 81.0
"""Total ratio of the RV-80E (paper Table 4), the node's default."""

MS = 1_000_000
_ids = itertools.count()

RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                         reliability=ReliabilityPolicy.RELIABLE)


def link_angle(k, t_s):
    """Link angle of joint ``k`` at ``t_s`` seconds of stream [rad]: a smooth robot move."""
    return 0.2 * k + 0.5 * np.sin(2.0 * math.pi * 0.5 * t_s) + 0.3 * t_s


def motor_angle(k, t_s):
    """Raw (input-side) motor angle of joint ``k``: ratio x link plus a TE of 1 arcmin."""
    return RATIO * (link_angle(k, t_s) + 2.9e-4 * np.sin(2.0 * math.pi * 3.0 * t_s)) + 7.0


class Robot:
    """
    A fake controller: joint names, topics and the messages it sends.

    Parameters
    ----------
    ros : RosHarness
        The test's harness.
    split : bool
        Form (b), two topics; else form (a), one combined topic.
    motor_angles : str
        ``'raw'`` or ``'output'`` (reported divided by the ratio).
    motor_direction : int
        -1: the motor angles are published in the reversed sense (and the node told so).

    """

    def __init__(self, ros, split=False, motor_angles='raw', joints=2, batch_period_s=0.002,
                 extra=(), motor_direction=1):
        n = next(_ids)
        self.ros = ros
        self.joints = [f'arm{n}_j{k + 1}' for k in range(joints)]
        self.link_topic = f'/robot{n}/joint_states'
        self.motor_topic = f'/robot{n}/motor_states' if split else ''
        self.split = split
        # Published motor angle = true angle / scale (a reversed encoder: negative).
        self.scale = motor_direction * (RATIO if motor_angles == 'output' else 1.0)
        self.t0 = (time.time_ns() // MS - 10_000) * MS
        self.node = ros.add(EncoderIngest(
            f'encoder_ingest_{n}', context=ros.context, parameter_overrides=[
                Parameter('joints', value=self.joints),
                Parameter('link_topic', value=self.link_topic),
                Parameter('motor_topic', value=self.motor_topic),
                Parameter('motor_angles', value=motor_angles),
                Parameter('motor_direction', value=motor_direction),
                Parameter('batch_period_s', value=batch_period_s),
                Parameter('diagnostics_period_s', value=0.1), *extra]))
        self.probe = ros.probe()
        self.link_pub = self.probe.publisher(self.link_topic, JointState, encoder_qos())
        self.motor_pub = (self.probe.publisher(self.motor_topic, JointState, encoder_qos())
                          if split else None)
        # The probe hears its own link topic: once it has, the node's reader has the samples.
        self.echo = self.probe.listen(self.link_topic, JointState, RECEIVE_QOS)
        self.pairs = {j: self.probe.listen(joint_topic(j, 'encoder_pairs'), Float64MultiArray,
                                           RECEIVE_QOS) for j in self.joints}
        self.diagnostics = self.probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        self.sent = 0
        ros.wait_matched(self.link_pub, *([self.motor_pub] if split else []),
                         *(out.publisher for out in self.node.outputs.values()))

    def stamp(self, k):
        """Stamp of sample ``k`` [ns] (1 kHz)."""
        return self.t0 + k * MS

    def combined(self, k, overrides=None):
        """Form (a) message of sample ``k``, names in a controller's own order plus a gripper."""
        t_s = k * 1e-3
        names, pos, vel, eff = ['gripper'], [0.01], [0.0], [1.0]
        for j, name in reversed(list(enumerate(self.joints))):
            names += [name + '_motor', name]
            pos += [motor_angle(j, t_s) / self.scale, link_angle(j, t_s)]
            vel += [math.nan, 0.3 + math.pi * 0.5 * math.cos(math.pi * t_s)]
            eff += [math.nan, 100.0 * (j + 1) * math.cos(t_s)]
        for name, value in (overrides or {}).items():
            pos[names.index(name)] = value
        return make_joint_state(self.stamp(k), names, pos, vel, eff)

    def link_only(self, k):
        """Form (b) link message of sample ``k``."""
        t_s = k * 1e-3
        return make_joint_state(
            self.stamp(k), self.joints, [link_angle(j, t_s) for j in range(len(self.joints))],
            [0.3] * len(self.joints), [50.0 * (j + 1) for j in range(len(self.joints))])

    def motor_only(self, k):
        """Form (b) motor message of sample ``k``."""
        return make_joint_state(self.stamp(k), self.joints,
                                [motor_angle(j, k * 1e-3) / self.scale
                                 for j in range(len(self.joints))])

    def send(self, messages):
        """
        Publish ``(publisher, message)`` pairs in order, 20 at a time.

        The node's reader keeps 200 samples (KEEP_LAST): the probe waits to
        hear its own link messages before sending more.
        """
        for start in range(0, len(messages), 20):
            for pub, msg in messages[start:start + 20]:
                pub.publish(msg)
                if pub is self.link_pub:
                    self.sent += 1
            self.ros.spin_until(lambda: len(self.echo) >= self.sent, what='the link echo')

    def rows(self, joint):
        """Return every encoder_pairs row received for ``joint``, oldest first."""
        batches = [batch_array(m, PAIRED_SAMPLES) for m in self.pairs[joint]]
        return np.concatenate(batches) if batches else np.zeros((0, 5))

    def wait_rows(self, joint, n):
        """Spin until ``n`` rows of ``joint`` arrived; return them."""
        self.ros.spin_until(lambda: sum(m.layout.dim[0].size for m in self.pairs[joint]) >= n,
                            what=f'{n} encoder pairs of {joint}')
        return self.rows(joint)

    def status(self, joint, predicate=lambda s: True):
        """Spin until a /diagnostics status of this node's ``joint`` satisfies ``predicate``."""
        name = f'reducer_twin: {joint} encoder ingest'
        return self.ros.wait_status(self.diagnostics, name, predicate)


def expected_stamps_s(robot, ks):
    """Stamps of samples ``ks`` in seconds, as the node sends them."""
    return np.array([robot.stamp(k) for k in ks]) * 1e-9


# -- form (a): one JointState with <joint> and <joint>_motor ----------------------------------


def test_effort_only_on_the_motor_entry_in_motor_units_becomes_output_torque(ros):
    # A controller that reports the motor current's torque on the motor interface only.
    robot = Robot(ros)
    n = 200
    messages = []
    for k in range(n):
        msg = robot.combined(k)
        eff = list(msg.effort)
        for j, name in enumerate(robot.joints):
            eff[list(msg.name).index(name + '_motor')] = 100.0 * (j + 1) * math.cos(k * 1e-3) \
                / RATIO
            eff[list(msg.name).index(name)] = math.nan
        msg.effort = eff
        messages.append((robot.link_pub, msg))
    robot.send(messages)
    ks = np.arange(n)
    for j, joint in enumerate(robot.joints):
        rows = robot.wait_rows(joint, n)
        np.testing.assert_allclose(rows[:, 3], 100.0 * (j + 1) * np.cos(ks * 1e-3), rtol=1e-12)


def test_effort_on_the_motor_topic_in_joint_units_is_read_with_the_parameters(ros):
    robot = Robot(ros, split=True, extra=(Parameter('effort_source', value='motor'),
                                          Parameter('motor_effort_units', value='joint')))
    n = 200
    messages = []
    for k in range(n):
        link = robot.link_only(k)
        link.effort = []
        motor = robot.motor_only(k)
        motor.effort = [25.0 * (j + 1) for j in range(len(robot.joints))]
        messages += [(robot.motor_pub, motor), (robot.link_pub, link)]
    robot.send(messages)
    for j, joint in enumerate(robot.joints):
        rows = robot.wait_rows(joint, n - 5)
        np.testing.assert_allclose(rows[:, 3], 25.0 * (j + 1))


def test_an_unknown_effort_source_stops_the_node_naming_the_allowed_values(ros):
    with pytest.raises(InvalidParameter, match="effort_source must be one of 'auto', 'link'"):
        EncoderIngest('bad_effort', context=ros.context, parameter_overrides=[
            Parameter('effort_source', value='elbow')])


@pytest.mark.parametrize('name, value, reason', [
    ('motor_direction', 2, r'motor_direction must be 1 \(the motor encoder counts with the '
                           r'link\) or -1 \(against it\), got 2'),
    ('effort_scale', 0.0, 'effort_scale must be a number of magnitude 1e-6 to'),
])
def test_a_bad_motor_direction_or_effort_scale_stops_the_node_naming_it(
        ros, name, value, reason):
    with pytest.raises(InvalidParameter, match=reason):
        EncoderIngest('bad_stream', context=ros.context,
                      parameter_overrides=[Parameter(name, value=value)])


@pytest.mark.parametrize('motor_angles, motor_direction', [
    ('raw', 1), ('output', 1), ('raw', -1)], ids=['raw', 'output', 'raw, counting against'])
def test_combined_joint_states_become_aligned_encoder_pairs(ros, motor_angles, motor_direction):
    robot = Robot(ros, motor_angles=motor_angles, motor_direction=motor_direction)
    n = 300
    robot.send([(robot.link_pub, robot.combined(k)) for k in range(n)])
    ks = np.arange(n)
    for j, joint in enumerate(robot.joints):
        rows = robot.wait_rows(joint, n)
        assert rows.shape == (n, 5)
        np.testing.assert_allclose(rows[:, 0], expected_stamps_s(robot, ks), rtol=0, atol=1e-6)
        # Shared stamps: motor and link of one message stay together to < 1e-9 rad.
        np.testing.assert_allclose(rows[:, 1], motor_angle(j, ks * 1e-3), rtol=0, atol=1e-9)
        np.testing.assert_allclose(rows[:, 2], link_angle(j, ks * 1e-3), rtol=0, atol=1e-9)
        np.testing.assert_allclose(rows[:, 3], 100.0 * (j + 1) * np.cos(ks * 1e-3))
        assert np.isfinite(rows[:, 4]).all()
        counts = robot.node.counts()[joint]
        assert counts['published'] == n
        assert counts['stream_missing'] == 0 and counts['unpaired'] == 0
        assert counts['stream_non_finite'] == counts['spike'] == 0
    status = robot.status(robot.joints[0], lambda s: s.values and robot.ros.key_values(s).get(
        'published') == str(n))
    assert status.level == DiagnosticStatus.OK
    assert status.hardware_id == robot.joints[0]
    assert status.message == 'streams clean'
    values = robot.ros.key_values(status)
    assert values['stream_missing'] == '0' and values['unpaired'] == '0'
    assert values['rejected_messages'] == '0'


def test_nan_positions_glitches_and_holes_are_dropped_and_counted(ros):
    robot = Robot(ros)
    j1, j2 = robot.joints
    nan = {50: {j2: math.nan, j2 + '_motor': math.nan},      # j2's position interface is down
           80: {j1 + '_motor': math.nan}}                      # only j1's motor value is lost
    glitch = 150
    messages = []
    for k in range(300):
        if k == 120:
            continue                                           # a lost message: a stamp hole
        msg = robot.combined(k, nan.get(k))
        if k == glitch:
            msg = robot.combined(k, {j1: link_angle(0, k * 1e-3) + 0.05})   # a link glitch
        messages.append((robot.link_pub, msg))
    robot.send(messages)
    rows1 = robot.wait_rows(j1, 297)
    rows2 = robot.wait_rows(j2, 298)
    stamps = expected_stamps_s(robot, range(300))
    np.testing.assert_allclose(rows1[:, 0], np.delete(stamps, [80, 120, glitch]), atol=1e-6)
    np.testing.assert_allclose(rows2[:, 0], np.delete(stamps, [50, 120]), atol=1e-6)
    c1, c2 = robot.node.counts()[j1], robot.node.counts()[j2]
    assert (c1['unpaired'], c2['unpaired']) == (1, 0)
    assert (c1['spike'], c2['spike']) == (1, 0)
    assert c1['stream_missing'] == c2['stream_missing'] == 1
    assert c1['stream_non_finite'] + c2['stream_non_finite'] >= 3
    status = robot.status(j1, lambda s: robot.ros.key_values(s).get('published') == '297')
    assert status.level == DiagnosticStatus.WARN
    assert 'dropped or repaired' in status.message


def test_stamps_taken_on_arrival_are_re_timed_counted_and_said(ros, capfd):
    # A driver that stamps each message when it receives it: 0.3 ms sd about the 1 kHz
    # tick. The samples are re-timed on that clock, in the order they came (none dropped
    # as out of order), counted in /diagnostics and said once in the log.
    robot = Robot(ros)
    j1 = robot.joints[0]
    rng = np.random.default_rng(4)
    jitter = np.round(rng.normal(0.0, 0.3 * MS, 600)).astype(np.int64)
    messages = []
    for k in range(600):
        msg = robot.combined(k)
        stamp = robot.stamp(k) + int(jitter[k])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        messages.append((robot.link_pub, msg))
    robot.send(messages)
    status = robot.status(j1, lambda s: robot.ros.key_values(s).get('stream_retimed')
                          == str(600 - 257))
    assert status.level == DiagnosticStatus.WARN
    rows = robot.wait_rows(j1, 590)
    # Only the deciding stamps, passed as they came, can be out of order (about 1 %).
    assert robot.node.counts()[j1]['stream_out_of_order'] <= 8
    # After the 257 stamps that decide, the pairs carry the controller's tick, not the
    # arrival stamp (the median of 31 stamps: about a fifth of the scatter left).
    ticks = expected_stamps_s(robot, range(600))
    tail = rows[rows[:, 0] > ticks[300], 0]
    late = tail - ticks[np.abs(tail[:, None] - ticks[None, :]).argmin(axis=1)]
    assert tail.size >= 285 and np.abs(late).max() < 0.4e-3
    assert np.std(late) < 0.1e-3 and abs(np.median(late)) < 0.2e-3
    assert 're-timed' in capfd.readouterr().err


def test_a_controller_that_never_stamps_is_read_on_arrival_times_and_said(ros, capfd):
    # Every header stamp zero (a driver that leaves header.stamp unset): every sample
    # after the first was dropped as a stamp that does not advance.
    robot = Robot(ros)
    j1 = robot.joints[0]
    messages = []
    for k in range(300):
        msg = robot.combined(k)
        msg.header.stamp.sec = msg.header.stamp.nanosec = 0
        messages.append((robot.link_pub, msg))
    before = robot.node.get_clock().now().nanoseconds * 1e-9
    robot.send(messages)
    rows = robot.wait_rows(j1, 290)
    after = robot.node.get_clock().now().nanoseconds * 1e-9
    assert np.all((rows[:, 0] >= before) & (rows[:, 0] <= after)), 'stamped on arrival'
    assert np.all(np.diff(rows[:, 0]) > 0)
    status = robot.status(j1, lambda s: 'unstamped_topics' in robot.ros.key_values(s))
    assert status.level == DiagnosticStatus.WARN and 'arrival times taken' in status.message
    assert robot.ros.key_values(status)['unstamped_topics'] == robot.link_topic
    err = capfd.readouterr().err
    assert err.count(f'every header stamp on {robot.link_topic} is zero') == 1, err


def test_non_finite_counts_belong_to_the_joint_that_had_them(ros):
    robot = Robot(ros)
    j1, j2 = robot.joints
    robot.send([(robot.link_pub, robot.combined(k, {j2: math.nan} if k == 30 else None))
                for k in range(60)])
    robot.wait_rows(j1, 60)
    counts = robot.node.counts()
    assert counts[j2]['stream_non_finite'] == 1
    assert counts[j1]['stream_non_finite'] == 0


def test_bad_messages_are_rejected_counted_and_warned_about_once(ros, capfd):
    robot = Robot(ros)
    j1 = robot.joints[0]
    bad = [
        make_joint_state(robot.stamp(1000), ['elbow', 'elbow_motor'], [0.0, 0.0]),
        make_joint_state(robot.stamp(1001), [j1, j1 + '_motor'], [0.0, 0.0]),   # j2 missing
    ]
    short = robot.combined(1002)
    short.position = short.position[:-1]                       # 4 names, 3 positions
    bad.append(short)
    long_vel = robot.combined(1003)
    long_vel.velocity = list(long_vel.velocity) + [0.0]
    bad.append(long_vel)
    messages = []
    for k in range(200):
        messages.append((robot.link_pub, robot.combined(k)))
        if k % 40 == 10:
            messages.append((robot.link_pub, bad[(k // 40) % len(bad)]))
    robot.send(messages)
    rows = robot.wait_rows(j1, 200)
    assert rows.shape[0] == 200, 'the node keeps working between bad messages'
    assert robot.node.rejects.counts == {'bad_joint_state': 5}
    status = robot.status(j1, lambda s: robot.ros.key_values(s).get('published') == '200')
    assert robot.ros.key_values(status)['rejected_messages'] == '5'
    # Never 'streams clean' beside dropped messages: a controller whose messages all lack
    # the configured names would otherwise read as a quiet, clean stream.
    assert status.level == DiagnosticStatus.WARN
    assert status.message.startswith('5 messages dropped, the latest: ')
    err = capfd.readouterr().err
    assert err.count('dropped a message (bad_joint_state)') == 1, err[-2000:]
    assert 'JointState lacks' in err


# -- form (b): link and motor on two topics, different rates ----------------------------------


@pytest.mark.parametrize('motor_angles', ['raw', 'output'])
def test_split_streams_at_1khz_and_500hz_are_paired_by_interpolation(ros, motor_angles):
    robot = Robot(ros, split=True, motor_angles=motor_angles)
    n = 301                                         # ends on a motor sample: all can pair
    messages = []
    for k in range(n):
        messages.append((robot.link_pub, robot.link_only(k)))
        if k % 2 == 0:
            messages.append((robot.motor_pub, robot.motor_only(k)))
    robot.send(messages)
    ks = np.arange(n)
    t_motor = ks[::2] * 1e-3
    for j, joint in enumerate(robot.joints):
        rows = robot.wait_rows(joint, n)
        assert rows.shape == (n, 5)
        np.testing.assert_allclose(rows[:, 0], expected_stamps_s(robot, ks), atol=1e-6)
        np.testing.assert_allclose(rows[:, 2], link_angle(j, ks * 1e-3), rtol=0, atol=1e-9)
        # Linear interpolation of the 500 Hz motor samples at the 1 kHz link stamps.
        interp = np.interp(ks * 1e-3, t_motor, motor_angle(j, t_motor))
        np.testing.assert_allclose(rows[:, 1], interp, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rows[::2, 1], motor_angle(j, t_motor), rtol=0, atol=1e-9)
        # ... which is within its curvature error of the true motor angle: |a|max h^2 / 8,
        # |a|max about ratio x 0.5 x pi^2 rad/s^2 at the motor, h = 2 ms.
        np.testing.assert_allclose(rows[:, 1], motor_angle(j, ks * 1e-3), rtol=0,
                                   atol=RATIO * 0.5 * math.pi ** 2 * 0.002 ** 2 / 8 * 1.1)
        counts = robot.node.counts()[joint]
        assert counts['link_missing'] == counts['motor_missing'] == counts['unpaired'] == 0
        assert counts['published'] == n
    status = robot.status(robot.joints[1], lambda s: robot.ros.key_values(s).get(
        'published') == str(n))
    assert status.level == DiagnosticStatus.OK


def test_a_silent_motor_topic_shows_as_unpaired_samples_and_a_warning(ros):
    robot = Robot(ros, split=True)
    robot.send([(robot.link_pub, robot.link_only(k)) for k in range(200)])
    joint = robot.joints[0]
    # Given up: the link samples more than max_gap_s (50 ms) older than the newest one.
    status = robot.status(joint, lambda s: robot.ros.key_values(s).get('unpaired') == '149')
    assert status.level == DiagnosticStatus.WARN
    assert robot.ros.key_values(status)['published'] == '0'
    assert robot.rows(joint).shape[0] == 0


BEST_EFFORT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200,
                         reliability=ReliabilityPolicy.BEST_EFFORT)


def test_a_best_effort_controller_is_an_error_naming_the_setting_not_a_quiet_stream(
        ros, capfd):
    # Its messages never reach a RELIABLE subscription: the stream only looked quiet.
    robot = Robot(ros)
    robot.probe.publisher(robot.link_topic, JointState, BEST_EFFORT)
    status = robot.status(robot.joints[0], lambda s: 'cannot match' in s.message)
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith(f'a publisher of {robot.link_topic} offers a QoS this '
                                     'subscription cannot match (RELIABILITY): none of its '
                                     'messages are received; it publishes BEST_EFFORT: set '
                                     'reliable to false')
    assert ros.key_values(status)['unheard_topics'] == robot.link_topic
    assert 'cannot match (RELIABILITY)' in capfd.readouterr().err


def test_with_reliable_false_a_best_effort_controller_is_heard(ros):
    robot = Robot(ros, extra=[Parameter('reliable', value=False)])
    best_effort = robot.probe.publisher(robot.link_topic, JointState, BEST_EFFORT)
    ros.wait_matched(best_effort)
    for k in range(100):           # best effort: a few may be lost, so no echo is awaited
        best_effort.publish(robot.combined(k))
        if k % 20 == 19:
            ros.spin_for(0.05)
    assert robot.wait_rows(robot.joints[0], 50).shape[0] >= 50
    assert not robot.node.unheard.topics


def test_a_link_topic_of_another_type_is_an_error_naming_the_type(ros):
    # /dynamic_joint_states given as the link topic: DDS matches nothing and says nothing.
    robot = Robot(ros)                        # its probe hears /diagnostics
    wrong = f'{robot.link_topic}_array'
    other = Context()                         # its own participant, as another process
    rclpy.init(context=other, signal_handler_options=SignalHandlerOptions.NO)
    try:
        publisher = rclpy.create_node('other_type_publisher', context=other)
        publisher.create_publisher(Float64MultiArray, wrong, 10)
        joint = f'typed_{next(_ids)}'
        ros.add(EncoderIngest(f'encoder_ingest_{joint}', context=ros.context,
                              parameter_overrides=[
                                  Parameter('joints', value=[joint]),
                                  Parameter('link_topic', value=wrong),
                                  Parameter('diagnostics_period_s', value=0.1)]))
        status = ros.wait_status(robot.diagnostics, f'reducer_twin: {joint} encoder ingest',
                                 lambda s: 'publish' in s.message)
        assert status.level == DiagnosticStatus.ERROR
        assert status.message.startswith(
            f'the publishers of {wrong} publish std_msgs/msg/Float64MultiArray, not '
            'sensor_msgs/msg/JointState: none of their messages are received')
        assert ros.key_values(status)['unheard_topics'] == wrong
        # A JointState publisher on it: the topic is heard, the error no longer stands.
        heard = robot.probe.publisher(wrong, JointState, encoder_qos())
        status = ros.wait_status(robot.diagnostics, f'reducer_twin: {joint} encoder ingest',
                                 lambda s: 'publish' not in s.message)
        assert status.level != DiagnosticStatus.ERROR
        robot.probe.destroy_publisher(heard)
        publisher.destroy_node()
    finally:
        rclpy.try_shutdown(context=other)


# -- composed in one process: pairs handed over directly ---------------------------------------


def test_in_process_consumers_get_every_pair_and_the_topic_only_while_subscribed(ros):
    robot = Robot(ros)
    j1, j2 = robot.joints
    handed = []
    robot.node.attach(j1, handed.append)
    robot.send([(robot.link_pub, robot.combined(k)) for k in range(200)])
    # Someone subscribes to j1's topic (the probe): published as well, the same rows.
    published = robot.wait_rows(j1, 200)
    np.testing.assert_array_equal(np.concatenate(handed), published)
    # The probe leaves j1's topic: the consumer still gets every pair, the topic goes quiet.
    topic = joint_topic(j1, 'encoder_pairs')
    sub = next(s for s in robot.probe.subscriptions if s.topic_name == topic)
    robot.probe.destroy_subscription(sub)
    out = robot.node.outputs[j1]
    robot.ros.spin_until(lambda: not out.listened, what='ingest to see no subscriber of j1')
    before = len(robot.pairs[j1])
    robot.send([(robot.link_pub, robot.combined(k)) for k in range(200, 400)])
    robot.wait_rows(j2, 400)                      # j2 has no in-process consumer: published
    robot.ros.spin_until(lambda: sum(r.shape[0] for r in handed) >= 400,
                         what='400 pairs handed to the consumer')
    rows = np.concatenate(handed)
    np.testing.assert_allclose(rows[:, 0], expected_stamps_s(robot, np.arange(400)), atol=1e-6)
    assert len(robot.pairs[j1]) == before
    assert robot.node.counts()[j1]['published'] == 400


def test_without_batching_each_message_reaches_the_consumer_before_the_next_is_sent(ros):
    # batch_period_s 0 (the bringup's setting): a sample must not wait for the next message.
    robot = Robot(ros, batch_period_s=0.0)
    handed = []
    robot.node.attach(robot.joints[0], handed.append)
    for k in range(6):
        robot.link_pub.publish(robot.combined(k))
        robot.ros.spin_until(lambda: sum(r.shape[0] for r in handed) == k + 1,
                             what=f'pair {k} handed on on its own')
    rows = np.concatenate(handed)
    np.testing.assert_allclose(rows[:, 0], expected_stamps_s(robot, np.arange(6)), atol=1e-6)
    np.testing.assert_allclose(rows[:, 2], [link_angle(0, k * 1e-3) for k in range(6)])


def test_a_consumer_of_a_joint_not_ingested_is_refused(ros):
    robot = Robot(ros)
    with pytest.raises(InvalidParameter, match="joint 'elbow' is not ingested here"):
        robot.node.attach('elbow', print)


def test_the_effort_scale_parameter_turns_a_current_into_the_output_torque(ros):
    # A drive that reports a current in A with the other sign: -2.5 N*m per A at the output
    # (given as a whole number too: -1 at the command line is an integer).
    robot = Robot(ros, extra=[Parameter('effort_scale', value=-2.5)])
    n = 200
    robot.send([(robot.link_pub, robot.combined(k)) for k in range(n)])
    ks = np.arange(n)
    for j, joint in enumerate(robot.joints):
        rows = robot.wait_rows(joint, n)
        np.testing.assert_allclose(rows[:, 3], -2.5 * 100.0 * (j + 1) * np.cos(ks * 1e-3))
    whole = Robot(ros, extra=[Parameter('effort_scale', value=-1)])
    assert whole.node.ingest.torque_scale == -1.0
