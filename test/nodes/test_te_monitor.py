"""
te_monitor over real DDS: encoder_pairs of a known TE in, TE batches and window features out.

The pairs come from the core's joint simulator (robot profile with gravity
load, 8 um of initial wear, aging factor 3.6e5 so that a 2 s window is 200
operating hours), stamped from a wall-clock epoch and sent as the
``encoder_ingest`` node sends them: ``encoder_pairs`` batches of 100 rows.
"""

import itertools
import math
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.core.window_analysis import WindowAnalyzer
from reducer_twin.msg_adapters.layouts import PAIRED_SAMPLES, TE_BATCH, TE_FEATURES
from reducer_twin.msg_adapters.ros import batch_array, from_multiarray, to_multiarray
from reducer_twin.nodes.qos import encoder_qos, latest_qos
from reducer_twin.nodes.runtime import WORKER
from reducer_twin.nodes.te_monitor import TEMonitor
from reducer_twin.nodes.wear_estimator import WearEstimatorNode
from scipy.signal import butter, sosfiltfilt
from std_msgs.msg import Float64MultiArray, MultiArrayDimension
from std_srvs.srv import Trigger
from te_streams import soft_zone_swing, within_zone_swing

pytestmark = pytest.mark.timeout(60, method='thread')

PARAMS = ReducerParams()
RATIO = 81.0
AGING = 3.6e5
SAMPLES = 8000
_ids = itertools.count()

RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope='module')
def simulated():
    """8 s of a 1 kHz robot joint, as encoder_pairs rows with wall-clock stamps."""
    sim = JointSimulator(PARAMS, SimConfig(profile='robot', exact_mesh=False,
                                           aging_factor=AGING, initial_wear_m=8e-6, seed=4))
    batch = sim.step(SAMPLES)
    t0 = float(time.time() // 1 - 10.0)
    rows = np.column_stack([t0 + batch.t, batch.motor_angle, batch.link_angle, batch.effort,
                            batch.link_velocity])
    return batch, rows


class Monitor:
    """A TEMonitor of a fresh joint, and a probe that feeds it and listens to it."""

    def __init__(self, ros, extra=(), joint=None):
        self.ros = ros
        self.joint = joint or f'wrist{next(_ids)}'
        self.node = ros.add(TEMonitor(
            f'te_monitor_{self.joint}', params=PARAMS, context=ros.context,
            parameter_overrides=[
                Parameter('joint', value=self.joint), Parameter('aging_factor', value=AGING),
                Parameter('analysis_period_s', value=0.05),
                Parameter('diagnostics_period_s', value=0.1), *extra]))
        self.probe = ros.probe()
        self.pub = self.probe.publisher(joint_topic(self.joint, 'encoder_pairs'),
                                        Float64MultiArray, encoder_qos())
        self.te = self.probe.listen(joint_topic(self.joint, 'te'), Float64MultiArray,
                                    RECEIVE_QOS)
        self.features = self.probe.listen(joint_topic(self.joint, 'te_features'),
                                          Float64MultiArray, RECEIVE_QOS)
        self.diagnostics = self.probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        ros.wait_matched(self.pub, self.node.te_pub, self.node.feat_pub)

    def feed(self, rows, batch=100):
        """Publish rows as encoder_pairs batches; spin until the node has taken them all."""
        expected = self.node.samples + rows.shape[0]
        for start in range(0, rows.shape[0], batch):
            self.pub.publish(to_multiarray(PAIRED_SAMPLES, rows[start:start + batch]))
            self.ros.executor.spin_once(timeout_sec=0.0)
        self.ros.spin_until(lambda: self.node.samples >= expected,
                            what=f'{expected} samples at the TE monitor')

    def status(self, predicate):
        """Spin until a /diagnostics status of this monitor satisfies ``predicate``."""
        name = f'reducer_twin: {self.joint} transmission error'
        return self.ros.wait_status(self.diagnostics, name, predicate)


def test_te_batches_are_link_minus_motor_over_the_ratio(ros, simulated):
    batch, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    ros.spin_until(lambda: sum(m.layout.dim[0].size for m in monitor.te) >= SAMPLES,
                   what='every TE sample')
    te = np.concatenate([batch_array(m, TE_BATCH) for m in monitor.te])
    np.testing.assert_array_equal(te[:, 0], rows[:, 0])
    np.testing.assert_array_equal(te[:, 1], rows[:, 2])
    np.testing.assert_allclose(te[:, 2], rows[:, 2] - rows[:, 1] / RATIO, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(te[:, 3], rows[:, 3])
    # It is the simulator's TE up to the encoders' noise, counts and 50 us sampling offset.
    err = te[:, 2] - batch.true_te
    assert np.std(err) < 0.3 * ARCMIN


def test_windows_arrive_with_the_layout_fields_and_a_finite_lost_motion(ros, simulated):
    batch, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    ros.spin_until(lambda: len(monitor.features) >= 3, what='three te_features windows')
    records = [from_multiarray(m, TE_FEATURES) for m in monitor.features]
    for rec in records:
        assert list(rec) == list(TE_FEATURES.fields)
        assert rec['window_start_s'] < rec['window_end_s']
        assert rec['samples'] > 1000 and rec['te_pp_rad'] > 0.0
        assert rec['duration_s'] == pytest.approx(rec['window_end_s'] - rec['window_start_s'],
                                                  abs=2e-3)
        assert rec['exposure_s'] == pytest.approx(AGING * rec['duration_s'], rel=1e-9)
        assert rec['archard_increment_m'] > 0.0
    finite = [r for r in records if math.isfinite(r['lost_motion_rad'])]
    assert len(finite) >= 2, 'the robot cycle reverses its torque in most windows'
    lost_motion = model_tables(PARAMS).lost_motion
    for rec in finite:
        k = int(np.searchsorted(rows[:, 0], 0.5 * (rec['window_start_s'] + rec['window_end_s'])))
        truth = float(lost_motion(batch.true_wear[k]))
        assert rec['lost_motion_rad'] == pytest.approx(truth, rel=0.05)
        assert 0.0 < rec['lost_motion_std_rad'] < 0.1 * ARCMIN
    assert monitor.node.windows == len(records)


def test_windows_are_what_the_offline_analysis_gives_for_the_same_samples(ros, simulated):
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    ros.spin_until(lambda: len(monitor.features) >= 3, what='three te_features windows')
    stream = compute_te(rows[:, 0], rows[:, 1], rows[:, 0], rows[:, 2], RATIO, max_gap_s=0.05)
    offline = WindowAnalyzer(PARAMS, aging_factor=AGING).update(stream, rows[:, 3], rows[:, 4])
    live = [from_multiarray(m, TE_FEATURES) for m in monitor.features]
    assert len(live) == len(offline)
    for rec, f in zip(live, offline):
        assert (rec['window_start_s'], rec['window_end_s']) == (f.t_start, f.t_end)
        np.testing.assert_allclose(rec['te_pp_rad'], f.te_pp, rtol=1e-12)
        np.testing.assert_allclose(rec['lost_motion_rad'], f.lost_motion, rtol=1e-6)
        np.testing.assert_allclose(rec['exposure_s'], f.duty.exposure_s, rtol=1e-12)


def test_diagnostics_report_samples_windows_and_lost_motion(ros, simulated):
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    status = monitor.status(lambda s: ros.key_values(s)['samples'] == str(SAMPLES)
                            and int(ros.key_values(s)['windows']) >= 2)
    values = ros.key_values(status)
    assert status.level == DiagnosticStatus.OK
    assert status.hardware_id == monitor.joint
    assert values['rejected_messages'] == '0'
    assert 0.5 < float(values['lost_motion_arcmin']) < 5.0
    assert float(values['te_pp_arcmin']) > 0.0
    assert 'latency_p99_ms' in values


def bad_batches(rows):
    """Messages on an encoder_pairs topic whose layout is not PAIRED_SAMPLES."""
    wrong_label = to_multiarray(TE_BATCH, rows[:10, :4])
    record = to_multiarray(TE_FEATURES, np.zeros(len(TE_FEATURES.fields)))
    short = to_multiarray(PAIRED_SAMPLES, rows[:10])
    short.data = short.data[:-1]
    unlabelled = Float64MultiArray(data=rows[:10].ravel().tolist())
    wrong_fields = to_multiarray(PAIRED_SAMPLES, rows[:10])
    wrong_fields.layout.dim[1] = MultiArrayDimension(label=PAIRED_SAMPLES.label, size=4,
                                                     stride=4)
    return [wrong_label, record, short, unlabelled, wrong_fields]


def test_bad_layouts_are_rejected_and_counted_and_the_monitor_carries_on(ros, simulated):
    _, rows = simulated
    monitor = Monitor(ros)
    bad = bad_batches(rows)
    for msg in bad:
        monitor.pub.publish(msg)
    # Past the first window, read before the friction can be told from the load.
    monitor.feed(rows[:5000])
    assert monitor.node.rejects.counts == {'bad_layout': len(bad)}
    assert monitor.node.samples == 5000
    status = monitor.status(lambda s: ros.key_values(s)['samples'] == '5000'
                            and ros.key_values(s)['observed_windows'] != '0')
    assert status.level == DiagnosticStatus.WARN
    assert ros.key_values(status)['rejected_messages'] == str(len(bad))


def test_rows_one_at_a_time_give_the_batch_te_and_a_stopped_stream_is_published_in_full(
        ros, simulated):
    # One row per call is the live case (a cheaper path); the rows left when the stream
    # stops go out with the next analysis, not with a timer of their own.
    _, rows = simulated
    monitor = Monitor(ros)
    for k in range(500):
        monitor.node.take_pairs(rows[k:k + 1])
    monitor.node.take_pairs(rows[500:700])
    ros.spin_until(lambda: sum(m.layout.dim[0].size for m in monitor.te) >= 700,
                   what='all 700 TE rows')
    got = np.concatenate([batch_array(m, TE_BATCH) for m in monitor.te])
    np.testing.assert_array_equal(got[:, 0], rows[:700, 0])
    np.testing.assert_array_equal(got[:, 1], rows[:700, 2])
    np.testing.assert_array_equal(got[:, 3], rows[:700, 3])
    np.testing.assert_allclose(got[:, 2], rows[:700, 2] - rows[:700, 1] / RATIO,
                               rtol=0, atol=1e-15)
    assert monitor.node.latency_stats()['count'] == 700


def test_fed_in_process_the_monitor_publishes_te_only_while_someone_listens(ros, simulated):
    batch, rows = simulated
    joint = f'wrist{next(_ids)}'
    node = ros.add(TEMonitor(f'te_monitor_{joint}', params=PARAMS, subscribe=False,
                             context=ros.context, parameter_overrides=[
                                 Parameter('joint', value=joint),
                                 Parameter('aging_factor', value=AGING)]))
    pairs_topic = joint_topic(joint, 'encoder_pairs')
    assert all(s.topic_name != pairs_topic for s in node.subscriptions)
    sent = []                           # what the monitor hands its real TE publisher
    publish = node.te_pub.publish
    node.te_pub.publish = lambda msg: (sent.append(msg), publish(msg))
    # Nobody listens to the TE topic: the monitor computes TE and windows, publishes no TE.
    ros.spin_until(lambda: not node._te_listened, what='the monitor to see no TE subscriber')
    sent.clear()
    for start in range(0, 4000, 10):
        node.take_pairs(rows[start:start + 10])
    ros.spin_for(0.1)
    node.flush_latency()
    assert node.samples == 4000 and node.latency_stats()['count'] == 4000
    assert sent == []
    probe = ros.probe()
    te = probe.listen(joint_topic(joint, 'te'), Float64MultiArray, RECEIVE_QOS)
    ros.wait_matched(node.te_pub)
    ros.spin_until(lambda: node._te_listened, what='the monitor to see the TE subscriber')
    for start in range(4000, 6000, 10):
        node.take_pairs(rows[start:start + 10])
    ros.spin_until(lambda: sum(m.layout.dim[0].size for m in te) >= 2000, what='2000 TE rows')
    assert sum(m.layout.dim[0].size for m in sent) == 2000
    got = np.concatenate([batch_array(m, TE_BATCH) for m in te])
    np.testing.assert_array_equal(got[:, 0], rows[4000:6000, 0])
    np.testing.assert_allclose(got[:, 2], rows[4000:6000, 2] - rows[4000:6000, 1] / RATIO,
                               rtol=0, atol=1e-15)
    node.analyze_now()
    assert node.windows >= 1


def test_without_effort_the_diagnostics_are_stale_with_the_reason_never_ok(ros, simulated):
    _, rows = simulated
    blind = rows.copy()
    blind[:, 3] = np.nan        # a controller that publishes no effort
    monitor = Monitor(ros)
    monitor.feed(blind)
    status = monitor.status(lambda s: 'no effort' in s.message)
    assert status.level == DiagnosticStatus.STALE
    assert status.message.startswith('not observed: no effort on /reducer_twin/')
    assert ros.key_values(status)['observed_windows'] == '0'


def test_a_link_angle_computed_from_the_motor_is_an_error_naming_the_missing_encoder(
        ros, simulated, capfd):
    # A robot without an encoder at the reducer's output publishes the motor's angle over
    # the ratio as the joint's: read as a reducer, a new unit tighter than nominal.
    _, rows = simulated
    derived = rows.copy()
    derived[:, 2] = derived[:, 1] / RATIO
    monitor = Monitor(ros)
    monitor.feed(derived)
    status = monitor.status(lambda s: 'link angle follows' in s.message)
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith('not observed: the link angle follows the motor angle '
                                     'divided by the reduction ratio')
    assert "not read by an encoder at the reducer's output" in status.message
    err = capfd.readouterr().err
    assert 'not observed: the link angle follows' in err and 'opposite sign' not in err


def test_with_effort_the_diagnostics_say_ok_once_a_window_gave_a_lost_motion(ros, simulated):
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    status = monitor.status(lambda s: s.level == DiagnosticStatus.OK)
    assert int(ros.key_values(status)['observed_windows']) >= 1


def test_effort_that_stops_after_a_lost_motion_turns_the_diagnostics_to_warn_saying_since_when(
        ros, simulated):
    # Once observed, a monitor whose effort stopped kept saying OK: the wear estimate
    # stood as of the last lost motion, and nothing said so.
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    monitor.status(lambda s: s.level == DiagnosticStatus.OK)
    span = rows[-1, 0] - rows[0, 0] + 1e-3
    for k in range(1, 4):           # 24 s more, without effort
        blind = rows.copy()
        blind[:, 0] += k * span
        blind[:, 3] = np.nan
        monitor.feed(blind)
    status = monitor.status(lambda s: 'no lost motion for' in s.message)
    assert status.level == DiagnosticStatus.WARN
    assert 'no effort on /reducer_twin/' in status.message
    assert float(ros.key_values(status)['seconds_since_lost_motion']) >= 20.0


def test_an_effort_of_the_other_sign_is_an_error_with_the_setting_that_reads_it(
        ros, simulated, capfd):
    # A drive that reports its effort with the other sign gave a wear of a few um with an
    # sd of 10 um, presented as observed.
    _, rows = simulated
    monitor = Monitor(ros)
    span = rows[-1, 0] - rows[0, 0] + 1e-3
    for k in range(3):
        flipped = rows.copy()
        flipped[:, 0] += k * span
        flipped[:, 3] *= -1.0
        monitor.feed(flipped)
    status = monitor.status(lambda s: 'opposite sign' in s.message)
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith('not observed: the effort has the opposite sign')
    assert 'effort_scale' in status.message
    # From the window that decided it on, no lost motion is published.
    analyzer = monitor.node.twin.analyzer
    assert analyzer.fit.windows_effort_fault >= 1
    assert analyzer.windows_observed < analyzer.windows_emitted
    # Said once on the node's log (stderr) too.
    logged = [x for x in capfd.readouterr().err.splitlines() if 'opposite sign' in x]
    assert len(logged) == 1 and '[ERROR]' in logged[0] and monitor.joint in logged[0]


def test_a_velocity_field_in_degrees_is_replaced_by_the_angles_rate_and_said(
        ros, simulated, capfd):
    # Read as it is, a velocity field in another form (zeros, deg/s, the motor's speed,
    # the other sense) gave a confident wrong wear and remaining life, and OK.
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(_velocity_in_degrees(rows))
    status = monitor.status(lambda s: 'velocity field' in s.message)
    assert status.level == DiagnosticStatus.WARN
    assert 'reads 57.' in status.message and 'degrees per second' in status.message
    assert status.message.endswith('the rate of the link angle is used instead')
    assert 57.0 < float(ros.key_values(status)['velocity_scale']) < 58.0
    # Every sample's speed came from the link angle, those before the verdict too.
    analyzer = monitor.node.twin.analyzer
    assert analyzer.derived_velocity == analyzer.samples_seen == len(rows)
    logged = [x for x in capfd.readouterr().err.splitlines() if 'velocity field' in x]
    assert len(logged) == 1 and '[WARN]' in logged[0] and monitor.joint in logged[0]


def _velocity_in_degrees(rows):
    out = rows.copy()
    out[:, 4] = np.degrees(rows[:, 4])
    return out


def _held(rows, column, hold):
    out = rows.copy()
    out[:, column] = rows[(np.arange(len(rows)) // hold) * hold, column]
    return out


def _link_bits(rows, bits):
    out = rows.copy()
    quantum = 2.0 * math.pi / 2 ** bits
    out[:, 2] = np.round(rows[:, 2] / quantum) * quantum
    return out


def _late(rows, samples):
    out = rows.copy()
    out[samples:, 4] = rows[:-samples, 4]
    return out


def _ripple(rows, rms_nm):
    sos = butter(4, [5.0, 50.0], btype='band', fs=1000.0, output='sos')
    ripple = sosfiltfilt(sos, np.random.default_rng(8).normal(size=len(rows)))
    out = rows.copy()
    out[:, 3] += ripple * rms_nm / ripple.std()
    return out


@pytest.mark.parametrize('alter, said', [
    (lambda rows: _held(rows, 3, 10),
     'the effort repeats itself on successive samples: it changes at about 100 Hz on a '
     '1000 Hz stream'),
    (lambda rows: _held(rows, 2, 4),
     'the link encoder repeats its reading on successive samples while the joint moves: '
     'updated at about 250 Hz on a 1000 Hz stream'),
    (lambda rows: _ripple(rows, 0.02 * 784.0),
     "the effort's noise is correlated over successive samples (band-limited or filtered)"),
    (lambda rows: _link_bits(rows, 17),
     'the link encoder moves in steps of 0.16 arcmin at the output: a lost motion that grows'),
    (lambda rows: _late(rows, 20),
     'the velocity field lags the rate of the link angle by'),
], ids=['held effort', 'held link', 'effort ripple', '17-bit link', 'velocity 20 ms late'])
def test_an_input_read_otherwise_than_published_turns_the_diagnostics_to_warn(
        ros, simulated, capfd, alter, said):
    # Held between slower updates, a ripple below the sample rate, a coarse link encoder, a
    # velocity that lags: each is read as well as it can be and said, on the node's log once
    # and in /diagnostics (WARN).
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(alter(rows))
    status = monitor.status(lambda s: said in s.message)
    assert status.level == DiagnosticStatus.WARN
    logged = [x for x in capfd.readouterr().err.splitlines() if said in x]
    assert len(logged) == 1 and '[WARN]' in logged[0] and monitor.joint in logged[0]


def test_a_play_still_taken_up_at_the_test_torque_is_said_with_its_width_as_a_key_value(
        ros, capfd):
    # 1.5 arcmin of soft zone to a knee at 5 % of rated: 0.9 arcmin wide at the 3 % test
    # torque, the catalogue's lost motion. The monitor says so (WARN, once on its log) and
    # gives the width and the play as numbers; the effort is a torque sensor's.
    t, theta, omega, te, effort = soft_zone_swing(1.5, 0.05)
    rows = np.column_stack([float(time.time() // 1 - 70.0) + t, RATIO * (theta - te), theta,
                            effort, omega])
    monitor = Monitor(ros, [Parameter('friction_in_effort', value=0)])
    monitor.feed(rows)
    status = monitor.status(lambda s: 'narrower than the flanks' in s.message)
    assert status.level == DiagnosticStatus.WARN
    values = ros.key_values(status)
    assert float(values['lost_motion_at_test_torque_arcmin']) == pytest.approx(0.9, rel=0.15)
    assert float(values['soft_zone_play_arcmin']) == pytest.approx(1.5, rel=0.15)
    assert values['test_torque_check'] == 'soft zone'
    logged = [x for x in capfd.readouterr().err.splitlines() if 'narrower than the' in x]
    assert len(logged) == 1 and '[WARN]' in logged[0] and monitor.joint in logged[0]


def test_what_the_test_torque_comparison_found_is_published_for_the_life_publisher(ros, simulated):
    # The life publisher sees only the wear estimate: an alarm resting on the loaded flanks'
    # play, the width at the test torque never compared, said nothing of it live.
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    analyzer = monitor.node.twin.analyzer
    ros.spin_until(lambda: analyzer.test_torque_check is not None, what='a comparison')
    WORKER.wait_idle()
    # Transient local: a life publisher started later hears the latest.
    heard = monitor.probe.listen(joint_topic(monitor.joint, 'test_torque_check'),
                                 DiagnosticStatus, latest_qos())
    ros.spin_until(lambda: heard, what='the test-torque check')
    # The model's own simulator: compared, no soft zone found, so no line.
    assert heard[-1].name == monitor.joint and heard[-1].level == DiagnosticStatus.OK
    assert ros.key_values(heard[-1]) == {'test_torque_check': 'none found', 'line': '',
                                         'within_zone': ''}
    assert analyzer.test_torque_check == 'none found' and heard[-1].message == ''
    # Not published again while nothing changes: 8 s more of stream, more windows.
    windows = analyzer.windows_emitted
    later = rows.copy()
    later[:, 0] += rows[-1, 0] - rows[0, 0] + 1e-3
    monitor.feed(later)
    ros.spin_until(lambda: analyzer.windows_emitted > windows, what='more windows')
    WORKER.wait_idle()
    ros.spin_for(0.2)
    assert analyzer.test_torque_check == 'none found' and len(heard) == 1


def test_a_lost_motion_read_below_its_bins_width_is_published_for_the_life(ros):
    # Loads that never leave a soft zone (60 N·m, its knee at 80): the flanks read 0.5 arcmin
    # of play, the width at the test torque less the windup is 0.5 + 3 * 23.5 / 80 = 1.38.
    # te_monitor said it on its own /diagnostics; the reducer's life, too long, said nothing.
    t, theta, omega, te, effort = within_zone_swing(0.5, 3.0, 80.0)
    rows = np.column_stack([float(time.time() // 1 - 70.0) + t, RATIO * (theta - te), theta,
                            effort, omega])
    monitor = Monitor(ros, [Parameter('friction_in_effort', value=0)])
    heard = monitor.probe.listen(joint_topic(monitor.joint, 'test_torque_check'),
                                 DiagnosticStatus, latest_qos())
    monitor.feed(rows)
    ros.spin_until(lambda: heard and ros.key_values(heard[-1])['within_zone'],
                   what='the within-zone line')
    values = ros.key_values(heard[-1])
    assert values['within_zone'] == monitor.node.twin.analyzer.within_zone
    assert 'less than the width its bins give at the lost-motion test torque' in \
        values['within_zone']
    # Its caveat is withheld: the lost motion read is not the play, more than the width.
    assert values['test_torque_check'] == 'not compared' and values['line'] == ''
    assert heard[-1].level == DiagnosticStatus.WARN
    assert heard[-1].message == values['within_zone']
    # The windows from then on carry the gap to that width (a negative shortfall), so the
    # wear estimator gives the lost motion no lower than it.
    said = monitor.node.twin.analyzer.within_zone_said
    ros.spin_until(lambda: len(monitor.features) >= monitor.node.twin.analyzer.windows_emitted,
                   what='every window on te_features')
    last = from_multiarray(monitor.features[-1], TE_FEATURES)
    assert last['soft_zone_shortfall_rad'] < -0.2 * ARCMIN
    assert last['soft_zone_width_rad'] == pytest.approx(said['width'], rel=0.1)


def _swing_rows(seed, t0, late_s):
    """encoder_pairs rows of the soft-zone swing, the link encoder read ``late_s`` early."""
    t, theta, omega, te, effort = soft_zone_swing(1.5, 0.05, seed=seed)
    link, velocity = np.interp(t - late_s, t, theta), np.interp(t - late_s, t, omega)
    return np.column_stack([t0 + t, RATIO * (theta - te), link, effort, velocity])


def test_a_restarted_monitor_continues_with_the_time_offset_and_soft_zone_it_learnt(
        ros, tmp_path, capfd):
    # A controller restarts, the monitor with it. Without its state the next windows learnt
    # the encoders' offset again (no lost motion meanwhile) and carried no soft zone until
    # it was said again, five standard errors over two windows later: the estimator gave
    # the play, 0.6 arcmin above the lost motion at the test torque, meanwhile.
    path = tmp_path / 'wrist.te_monitor.json'
    extra = [Parameter('friction_in_effort', value=0), Parameter('aging_factor', value=1.0),
             Parameter('state_file', value=str(path))]
    t0 = float(time.time() // 1 - 100.0)
    first = Monitor(ros, extra)
    rows = _swing_rows(0, t0, 0.004)
    for start in range(0, rows.shape[0], 500):  # analysed every 0.5 s of stream, as live
        first.feed(rows[start:start + 500])
        first.node.analyze_now()
    said = first.node.twin.soft_zone
    offset = first.node.twin.calibration.to_carry
    assert said is not None and offset == pytest.approx(-0.004, abs=2e-4)
    first.node.close()
    ros.remove(first.node)
    assert path.exists()
    capfd.readouterr()
    again = Monitor(ros, extra, joint=first.joint)
    logged = capfd.readouterr().err
    assert f'{first.joint}: link encoder time offset {offset * 1e6:.1f} us carried over' in logged
    assert 'soft-zone check continued' in logged and f'(state {path})' in logged
    again.feed(_swing_rows(1, t0 + 60.0, 0.004)[:10000])
    again.node.analyze_now()
    ros.spin_until(lambda: len(again.features) >= 4, what='4 windows of the restarted monitor')
    first_window = from_multiarray(again.features[0], TE_FEATURES)
    assert first_window['soft_zone_shortfall_rad'] == pytest.approx(said['shortfall'], rel=0.05)
    status = again.status(lambda s: 'narrower than the flanks' in s.message)
    assert ros.key_values(status)['state_file'] == str(path)


def test_a_reset_of_the_estimator_starts_the_monitors_window_analysis_afresh_once(
        ros, tmp_path, capfd):
    # A replaced reducer's windows carried the old one's soft zone, and the estimator, reset
    # for the new reducer, took it off their lost motion.
    path = tmp_path / 'wrist.te_monitor.json'
    extra = [Parameter('friction_in_effort', value=0), Parameter('aging_factor', value=1.0),
             Parameter('state_file', value=str(path))]
    monitor = Monitor(ros, extra)
    rows = _swing_rows(0, float(time.time() // 1 - 100.0), 0.0)
    for start in range(0, rows.shape[0], 2000):
        monitor.feed(rows[start:start + 2000])
        monitor.node.analyze_now()
    assert monitor.node.twin.soft_zone is not None
    estimator = ros.add(WearEstimatorNode(
        f'wear_estimator_{monitor.joint}', params=PARAMS, context=ros.context,
        parameter_overrides=[Parameter('joint', value=monitor.joint),
                             Parameter('state_file', value=str(tmp_path / 'est.json'))]))
    client = monitor.probe.create_client(Trigger, joint_topic(monitor.joint, 'reset'))
    assert ros.call(client, Trigger.Request()).success
    twin = monitor.node.twin
    ros.spin_until(lambda: twin.maintenance is not None, what='the maintenance event')
    WORKER.wait_idle()
    assert twin.maintenance.startswith('maintenance event 1 after ')
    assert twin.soft_zone is None and twin.analyzer.fit.soft_zone.windows == 0
    monitor.node.close()
    assert 'window analysis started afresh, the time offset kept' in capfd.readouterr().err
    # Restarted, the monitor hears the same event again (transient-local) and keeps what it
    # learnt since: an event is followed once.
    ros.remove(monitor.node)
    again = Monitor(ros, extra, joint=monitor.joint)
    ros.wait_matched(estimator.events)
    ros.spin_until(lambda: again.node.state.heard > 0, what='the event heard again')
    WORKER.wait_idle()
    assert again.node.twin.maintenance == twin.maintenance
    assert 'started afresh' not in capfd.readouterr().err


def test_a_motor_that_turns_another_number_of_times_than_the_ratio_is_logged_once(
        ros, simulated, capfd):
    # Refused for what its TE then shows; the line, in the log and after the refusal in
    # /diagnostics, names the ratio the encoders show.
    _, rows = simulated
    other = rows.copy()
    other[:, 1] *= 101.0 / 81.0
    monitor = Monitor(ros)
    monitor.feed(other)
    status = monitor.status(lambda s: 'the motor encoder turns' in s.message)
    assert status.level != DiagnosticStatus.OK and status.message.startswith('not observed')
    logged = [x for x in capfd.readouterr().err.splitlines() if 'the motor encoder turns' in x]
    assert len(logged) == 1 and '[WARN]' in logged[0] and monitor.joint in logged[0]
    assert 'where the configured reduction ratio is 81' in logged[0]


def test_a_true_velocity_field_is_used_as_published(ros, simulated):
    _, rows = simulated
    monitor = Monitor(ros)
    monitor.feed(rows)
    status = monitor.status(lambda s: s.level == DiagnosticStatus.OK)
    assert 0.95 < float(ros.key_values(status)['velocity_scale']) < 1.05
    assert monitor.node.twin.analyzer.derived_velocity == 0


def test_a_stream_that_stops_turns_the_diagnostics_to_warn_never_ok(ros, simulated):
    # The controller stopped publishing the joint (or renamed it): the analysis stood where
    # it was and the diagnostics kept saying OK.
    _, rows = simulated
    monitor = Monitor(ros, extra=[Parameter('silent_after_s', value=1.0)])
    monitor.feed(rows)
    monitor.status(lambda s: s.level == DiagnosticStatus.OK)
    status = monitor.status(lambda s: 'no encoder pairs for' in s.message)
    assert status.level == DiagnosticStatus.WARN
    assert 'stopped publishing this joint' in status.message
    assert float(ros.key_values(status)['seconds_since_pairs']) >= 1.0


def test_an_error_found_after_a_warning_is_logged_and_its_windows_still_published(
        ros, simulated, capfd):
    # Both lines came from one logging call whose severity was chosen at run time: rclpy
    # refuses a call site's second severity, so the error raised in the worker, was never
    # logged, and that batch's windows were not published.
    _, rows = simulated
    degrees = _velocity_in_degrees(rows)
    monitor = Monitor(ros)
    monitor.feed(degrees)
    monitor.status(lambda s: 'velocity field' in s.message)
    span = rows[-1, 0] - rows[0, 0] + 1e-3
    for k in range(1, 4):
        flipped = degrees.copy()
        flipped[:, 0] += k * span
        flipped[:, 3] *= -1.0
        monitor.feed(flipped)
    monitor.status(lambda s: 'opposite sign' in s.message)
    err = capfd.readouterr().err.splitlines()
    assert len([x for x in err if 'velocity field' in x and '[WARN]' in x]) == 1
    assert len([x for x in err if 'opposite sign' in x and '[ERROR]' in x]) == 1
    assert not [x for x in err if 'Logger severity' in x]
    analyzer = monitor.node.twin.analyzer
    ros.spin_until(lambda: len(monitor.features) >= analyzer.windows_emitted,
                   what='every window on te_features')
