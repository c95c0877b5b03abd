"""
wear_estimator over real DDS: te_features in, wear out, state persisted across restarts.

Windows are synthetic ``te_features`` records (torque 60-120 % of rated at the
paper's speed, 10 operating hours each, wear by ``wear.integrate_wear``,
lost motion by the model with 0.05 arcmin of noise); every expected estimate
is what :class:`~reducer_twin.core.pipeline.EstimatorStage` computes offline
from the same windows, so the node must match it exactly.
"""

import itertools
import subprocess

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.errors import StateFileError
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.io.state_file import backup_path, decode_state
from reducer_twin.msg_adapters.layouts import record_values, TE_BATCH, TE_FEATURES, WEAR_ESTIMATE
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.qos import stream_qos
from reducer_twin.nodes.wear_estimator import WearEstimatorNode
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from window_records import feature_records

PRIOR_WEAR = EstimatorStage(ReducerParams()).estimator.wear
"""Wear of the prior a stage without state starts from [m]."""

pytestmark = pytest.mark.timeout(60, method='thread')

PARAMS = ReducerParams()
EXPOSURE = 10.0 * HOUR
WINDOW_S = 2.0
_ids = itertools.count()

RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)

LATE_JOINER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Transient local like the publisher (latest_qos), deep enough to keep every estimate."""


@pytest.fixture(scope='module')
def records():
    """Forty te_features records of a reducer wearing at 0.8 x the model rate."""
    return feature_records(PARAMS, 40, seed=11, start_s=5000.0, window_s=WINDOW_S,
                           exposure_s=EXPOSURE)


def offline(records):
    """Return the wear record an uninterrupted EstimatorStage gives after ``records``."""
    stage = EstimatorStage(PARAMS)
    for rec in records:
        stage.process(features_from_record(rec))
    return stage.record(records[-1]['window_end_s'])


class Estimator:
    """A WearEstimatorNode on a state directory, and a probe that feeds and hears it."""

    def __init__(self, ros, state_dir, joint=None, extra=()):
        self.ros = ros
        self.extra = list(extra)
        self.joint = joint or f'hip{next(_ids)}'
        self.state = state_dir / f'{self.joint}.json'
        self.node = self.start()
        self.probe = ros.probe()
        self.pub = self.probe.publisher(joint_topic(self.joint, 'te_features'),
                                        Float64MultiArray, stream_qos())
        self.wear = self.listen()
        self.diagnostics = self.probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        ros.wait_matched(self.pub)

    def start(self):
        """Start (or restart) the node on this joint's state directory."""
        node = WearEstimatorNode(
            f'wear_estimator_{self.joint}', params=PARAMS, context=self.ros.context,
            parameter_overrides=[Parameter('joint', value=self.joint),
                                 Parameter('state_dir', value=str(self.state.parent)),
                                 Parameter('diagnostics_period_s', value=0.1),
                                 *self.extra])
        return self.ros.add(node)

    def restart(self):
        """Stop the node as a process that ends would, and start a new one on the same file."""
        self.node.stage.flush()
        self.ros.remove(self.node)
        self.node = self.start()
        self.ros.wait_matched(self.pub)
        return self.node

    def listen(self):
        """Subscribe to the wear topic (transient local); return the list of records."""
        messages = self.probe.listen(joint_topic(self.joint, 'wear'), Float64MultiArray,
                                     LATE_JOINER_QOS)
        return _Records(messages)

    def status(self, predicate=lambda s: True):
        """Spin until a /diagnostics status of this estimator satisfies ``predicate``."""
        name = f'reducer_twin: {self.joint} wear estimator'
        return self.ros.wait_status(self.diagnostics, name, predicate)

    def send(self, recs):
        """Publish te_features records one by one; spin until the node stepped each."""
        for rec in recs:
            done = sum(self.node.statuses.values()) + 1
            self.pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))
            self.ros.spin_until(lambda: sum(self.node.statuses.values()) >= done,
                                what='the estimator to step a window')
            # The node writes its state on a writer thread, in order; wait for it.
            self.node.stage.flush()

    def latest(self, records, stamp=None):
        """
        Spin until an estimate arrives (stamped ``stamp`` if given); return the newest.

        The node publishes one estimate at start, after each window (a
        replayed one included) and after a reset.
        """
        def arrived():
            return len(records) and (stamp is None or records[-1]['stamp_s'] == stamp)
        self.ros.spin_until(arrived, what=f'an estimate stamped {stamp}')
        return records[-1]


class _Records:
    """Received wear messages, read as dicts."""

    def __init__(self, messages):
        self.messages = messages

    def __len__(self):
        return len(self.messages)

    def __getitem__(self, k):
        return from_multiarray(self.messages[k], WEAR_ESTIMATE)


def same_estimate(a, b, skip=('stamp_s',)):
    """Assert two wear records carry the same estimate (stamps aside), bit for bit."""
    for field in WEAR_ESTIMATE.fields:
        if field not in skip:
            np.testing.assert_equal(a[field], b[field], err_msg=field)


def test_features_in_give_the_offline_estimate_and_a_late_subscriber_gets_the_latest(
        ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    first = est.latest(est.wear)
    # The prior of a reducer met without state: nothing observed yet.
    assert first['updates'] == 0 and first['wear_m'] == PRIOR_WEAR, 'the prior at start'
    est.send(records[:10])
    last = est.latest(est.wear, records[9]['window_end_s'])
    assert len(est.wear) == 11, 'one estimate at start, one per window'
    same_estimate(last, offline(records[:10]))
    assert last['exposure_s'] == pytest.approx(10 * EXPOSURE)
    late = est.listen()
    latest = est.latest(late)
    ros.spin_for(0.2)
    assert len(late) == 1, 'transient local, depth 1: only the latest estimate'
    same_estimate(latest, last)


def test_windows_that_carry_a_soft_zone_give_the_lost_motion_at_the_test_torque_after_a_restart(
        ros, tmp_path, records):
    # te_monitor found the play still being taken up at the test torque: the estimate
    # follows the play as before, and the lost motion published is at the test torque.
    shortfall = 0.4 * ARCMIN
    est = Estimator(ros, tmp_path)
    est.send([{**rec, 'soft_zone_shortfall_rad': shortfall} for rec in records[:10]])
    last = est.latest(est.wear, records[9]['window_end_s'])
    plain = offline(records[:10])
    assert last['soft_zone_shortfall_rad'] == shortfall
    assert last['lost_motion_rad'] == pytest.approx(plain['lost_motion_rad'] - shortfall)
    same_estimate(last, plain, skip=('stamp_s', 'lost_motion_rad', 'soft_zone_shortfall_rad'))
    # Restarted on its state file, it goes on giving the lost motion at the test torque
    # (before it gave the play until te_monitor said the soft zone again).
    heard = len(est.wear)
    node = est.restart()
    assert node.stage.soft_zone_shortfall == shortfall
    ros.spin_until(lambda: len(est.wear) > heard, what='the restarted estimate')
    again = est.wear[-1]
    assert again['soft_zone_shortfall_rad'] == shortfall
    assert again['lost_motion_rad'] == pytest.approx(last['lost_motion_rad'])
    status = est.status(lambda s: any(kv.key == 'soft_zone_shortfall_arcmin' for kv in s.values))
    values = {kv.key: kv.value for kv in status.values}
    assert float(values['soft_zone_shortfall_arcmin']) == pytest.approx(0.4, abs=1e-3)


def test_a_soft_zone_is_taken_off_the_play_no_further_than_the_width_at_the_test_torque(
        ros, tmp_path, records):
    # Windows whose play lies near the width te_monitor's comparison gives at the test
    # torque (their loads seldom pass the soft zone's knee): the lost motion published is
    # that width, not the play less the whole shortfall (which would be below zero here).
    plain = offline(records[:10])
    width = plain['lost_motion_rad'] - 0.2 * ARCMIN
    est = Estimator(ros, tmp_path)
    est.send([{**rec, 'soft_zone_shortfall_rad': 1.5 * ARCMIN, 'soft_zone_width_rad': width}
              for rec in records[:10]])
    last = est.latest(est.wear, records[9]['window_end_s'])
    assert last['lost_motion_rad'] == pytest.approx(width, abs=1e-4 * ARCMIN)
    assert last['soft_zone_shortfall_rad'] == pytest.approx(0.2 * ARCMIN, abs=1e-4 * ARCMIN)
    same_estimate(last, plain, skip=('stamp_s', 'lost_motion_rad', 'soft_zone_shortfall_rad'))


def test_the_state_file_is_replaced_atomically_after_every_window(ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    assert not est.state.exists(), 'nothing to save before the first window'
    for k, rec in enumerate(records[:5]):
        est.send([rec])
        state = decode_state(est.state.read_bytes(), est.state)
        assert state['t_end'] == rec['window_end_s']
        assert state['exposure_s'] == pytest.approx((k + 1) * EXPOSURE)
        if k:
            previous = decode_state(backup_path(est.state).read_bytes())
            assert previous['t_end'] == records[k - 1]['window_end_s']
        leftovers = sorted(p.name for p in tmp_path.iterdir()
                           if p.name not in (est.state.name, backup_path(est.state).name))
        assert leftovers == [], 'no temporary file is left behind'


def test_a_restarted_node_continues_the_estimate_and_skips_the_window_it_saw(
        ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    est.send(records[:12])
    before = est.latest(est.wear, records[11]['window_end_s'])
    node = est.restart()
    assert node.stage.restored_from == str(est.state)
    resumed = est.latest(est.listen())
    # The last observation is not state: a restarted node has none until its first window.
    same_estimate(resumed, before, skip=('stamp_s', 'lost_motion_obs_rad'))
    est.send(records[11:12])                       # the last window again, e.g. from a bag
    assert node.statuses == {'replay': 1}
    assert node.stage.estimator.exposure_s == pytest.approx(12 * EXPOSURE), \
        'exposure is not counted twice'
    est.send(records[12:20])
    same_estimate(est.latest(est.wear, records[19]['window_end_s']), offline(records[:20]))


def test_the_diagnostics_say_how_the_windows_scatter_against_their_reported_sd(
        ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    est.send(records[:12])
    est.latest(est.wear, records[11]['window_end_s'])
    learnt = est.node.stage.estimator.noise_scale
    assert learnt != 1.0, 'twelve windows teach the noise scale something'
    status = est.status(lambda s: ros.key_values(s)['updates'] == '12')
    assert float(ros.key_values(status)['window_noise_scale']) == pytest.approx(learnt, rel=1e-4)


def test_the_diagnostics_are_stale_until_a_lost_motion_is_used(ros, tmp_path, records):
    # The prior's wear moved by the model's rate was said OK, from no observation at all.
    est = Estimator(ros, tmp_path)
    status = est.status(lambda s: ros.key_values(s)['updates'] == '0')
    assert status.level == DiagnosticStatus.STALE
    assert status.message.startswith('not observed: no lost motion used yet; wear ')
    assert status.message.endswith(' um from the prior alone')
    est.send(records[:1])
    status = est.status(lambda s: ros.key_values(s)['updates'] == '1')
    assert status.level == DiagnosticStatus.OK and status.message.startswith('wear ')


def test_the_diagnostics_say_how_far_the_forecasts_fell_short(ros, tmp_path, records):
    # Windows that jump between two levels every five: no growth law foresees them.
    jumping = [dict(r, lost_motion_rad=r['lost_motion_rad'] + 0.3 * ARCMIN * (k % 10 >= 5))
               for k, r in enumerate(records)]
    est = Estimator(ros, tmp_path)
    est.send(jumping)
    est.latest(est.wear, jumping[-1]['window_end_s'])
    scale = est.node.stage.estimator.forecast_scale
    assert scale > 1.1, 'forecasts eight windows ahead missed the jumps'
    status = est.status(lambda s: ros.key_values(s)['updates'] == str(len(jumping)))
    assert float(ros.key_values(status)['forecast_scale']) == pytest.approx(scale, rel=1e-4)


def test_the_diagnostics_say_the_service_time_and_what_became_of_it(ros, tmp_path, records):
    est = Estimator(ros, tmp_path, extra=[Parameter('estimator.service_time_s',
                                                    value=2000.0 * HOUR)])
    est.send(records[:5])
    status = est.status(lambda s: ros.key_values(s)['updates'] == '5')
    values = ros.key_values(status)
    assert values['service_time'] == 'waiting for the duty'
    assert float(values['service_time_h']) == 2000.0
    est.send(records[5:15])
    status = est.status(lambda s: ros.key_values(s)['updates'] == '15')
    values = ros.key_values(status)
    verdict = est.node.stage.estimator.service_verdict
    assert values['service_time'] == 'taken' and verdict[0]
    assert float(values['service_rate_scale']) == pytest.approx(verdict[1], rel=1e-4)


def test_a_corrupt_state_file_falls_back_to_the_backup_copy(ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    est.send(records[:5])
    est.ros.remove(est.node)
    est.state.write_bytes(est.state.read_bytes()[:100])    # torn write by some other tool
    node = est.node = est.start()
    assert node.stage.restored_from == str(backup_path(est.state))
    assert node.stage.estimator.exposure_s == pytest.approx(4 * EXPOSURE)
    est.status(lambda s: ros.key_values(s)['restored_from'].endswith('.bak'))
    ros.wait_matched(est.pub)
    est.send(records[4:8])                         # the lost window comes again: not a replay
    assert node.statuses.get('replay', 0) == 0
    same_estimate(node.stage.record(0.0), offline(records[:8]))


def test_a_corrupt_state_file_without_backup_stops_the_node_naming_the_file(
        ros, tmp_path, node_program):
    state = tmp_path / 'knee.json'
    state.write_text('{"format": "reducer_twin.wear_estimator.file", "sha')
    with pytest.raises(StateFileError, match=str(state)):
        WearEstimatorNode('wear_estimator_knee', params=PARAMS, context=ros.context,
                          parameter_overrides=[Parameter('joint', value='knee'),
                                               Parameter('state_file', value=str(state))])
    result = subprocess.run(
        [node_program('wear_estimator'), '--ros-args', '-p', 'joint:=knee',
         '-p', f'state_file:={state}'], capture_output=True, text=True, timeout=60)
    assert result.returncode == 1
    assert 'Traceback' not in result.stderr
    assert 'ERROR: ' in result.stderr and str(state) in result.stderr


def test_the_reset_service_starts_a_new_reducer_and_keeps_the_history(ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    est.send(records[:10])
    worn = est.latest(est.wear, records[9]['window_end_s'])
    assert worn['wear_m'] > 0.1e-6
    client = est.probe.create_client(Trigger, joint_topic(est.joint, 'reset'))
    response = ros.call(client, Trigger.Request())
    assert response.success
    assert est.joint in response.message
    ros.spin_until(lambda: est.wear[-1]['wear_m'] != worn['wear_m'],
                   what='the estimate after the reset')
    fresh = est.wear[-1]
    assert fresh['wear_m'] == EstimatorConfig().initial_wear
    assert fresh['updates'] == worn['updates'], 'counters are kept'
    assert fresh['exposure_s'] == worn['exposure_s'], 'total exposure is kept'
    state = decode_state(est.state.read_bytes())
    assert state['events'][-1]['reason'] == 'maintenance: reducer replaced (reset service)'
    assert state['exposure_since_reset_s'] == 0.0
    est.send(records[10:11])                       # the new reducer runs on
    est.latest(est.wear, records[10]['window_end_s'])
    assert decode_state(est.state.read_bytes())['exposure_since_reset_s'] == EXPOSURE


def test_a_message_of_another_layout_is_rejected_and_counted(ros, tmp_path, records):
    est = Estimator(ros, tmp_path)
    est.pub.publish(to_multiarray(TE_BATCH, np.zeros((3, 4))))
    est.send(records[:1])
    assert est.node.rejects.counts == {'bad_features': 1}
    assert est.node.statuses == {'accepted': 1}
