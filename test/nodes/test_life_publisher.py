"""
life_publisher over real DDS: wear estimates in, remaining life and /diagnostics out.

The wear estimate is what the wear estimator publishes after twenty synthetic
windows of 10 operating hours (torque 60-120 % of rated at the paper's
speed); thresholds are set through ``life.warn_s`` / ``life.error_s`` to force
each diagnostics level, at start and while running.
"""

import itertools
import math
import re

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core import wear
from reducer_twin.core.duty_summary import DutySummary
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.life_basis import TorqueCheckFinding
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import duty_to_record, EstimatorStage, features_from_record
from reducer_twin.core.pipeline import LifeConfig
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.msg_adapters.layouts import record_values, REMAINING_LIFE, TE_BATCH, TE_FEATURES
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.life_publisher import LifePublisher
from reducer_twin.nodes.qos import latest_qos, stream_qos
from reducer_twin.nodes.torque_check import to_status
from std_msgs.msg import Float64MultiArray

pytestmark = pytest.mark.timeout(60, method='thread')

PARAMS = ReducerParams()
EXPOSURE = 10.0 * HOUR
HARDWARE_ID = 'RV-80E s/n 0042'
_ids = itertools.count()

RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)

LATE_JOINER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""Transient local like the remaining_life publisher, deep enough to keep every record."""


@pytest.fixture(scope='module')
def estimate():
    """Return ``(wear_record, te_features_record)`` after twenty windows."""
    rng = np.random.default_rng(5)
    n = 20
    torque = PARAMS.rating.rated_torque * rng.uniform(0.6, 1.2, n)
    speed = np.full(n, wear.reference_speed(PARAMS))
    increment = wear.wear_rate(torque, speed, 0.0, PARAMS) * EXPOSURE
    true_w = wear.integrate_wear(np.full(n, EXPOSURE), torque, speed, PARAMS)
    z = model_tables(PARAMS).lost_motion(true_w) + rng.normal(0.0, 0.05 * ARCMIN, n)
    stage = EstimatorStage(PARAMS)
    for k in range(n):
        rec = dict.fromkeys(TE_FEATURES.fields, math.nan)
        rec.update({'window_start_s': 2.0 * k, 'window_end_s': 2.0 * (k + 1),
                    'samples': 2000.0, 'te_pp_rad': 6.0 * ARCMIN,
                    'lost_motion_rad': float(z[k]), 'lost_motion_std_rad': 0.05 * ARCMIN})
        rec.update(duty_to_record(DutySummary(
            2.0, EXPOSURE, float(increment[k]), float(torque[k]), float(speed[k]),
            float(torque[k]), float(1.1 * torque[k]))))
        stage.process(features_from_record(rec))
    return stage.record(2.0 * n), rec


class Life:
    """A LifePublisher of a fresh joint, and a probe that feeds and hears it."""

    def __init__(self, ros, **life):
        self.ros = ros
        self.joint = f'shoulder{next(_ids)}'
        self.node = ros.add(LifePublisher(
            f'life_publisher_{self.joint}', params=PARAMS, context=ros.context,
            parameter_overrides=[
                Parameter('joint', value=self.joint),
                Parameter('hardware_id', value=HARDWARE_ID),
                Parameter('diagnostics_period_s', value=0.1),
                *(Parameter(f'life.{k}', value=float(v)) for k, v in life.items())]))
        self.probe = ros.probe()
        self.wear_pub = self.probe.publisher(joint_topic(self.joint, 'wear'), Float64MultiArray,
                                             latest_qos())
        self.features_pub = self.probe.publisher(joint_topic(self.joint, 'te_features'),
                                                 Float64MultiArray, stream_qos())
        self.life = self.probe.listen(joint_topic(self.joint, 'remaining_life'),
                                      Float64MultiArray, LATE_JOINER_QOS)
        self.diagnostics = self.probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        ros.wait_matched(self.wear_pub, self.features_pub, self.node.pub)

    def send(self, wear_record, features=None):
        """Publish the duty (if given), then a wear estimate; return its remaining life."""
        if features is not None:
            self.features_pub.publish(to_multiarray(
                TE_FEATURES, record_values(TE_FEATURES, features)))
            self.ros.spin_until(lambda: self.node.last_features is not None,
                                what='the duty at the life publisher')
        count = len(self.life) + 1
        self.wear_pub.publish(to_multiarray(WEAR_ESTIMATE,
                                            record_values(WEAR_ESTIMATE, wear_record)))
        self.ros.spin_until(lambda: len(self.life) >= count, what='a remaining_life record')
        return from_multiarray(self.life[-1], REMAINING_LIFE)

    def status(self, predicate=lambda s: True):
        """Spin until a /diagnostics status of this reducer satisfies ``predicate``."""
        name = f'reducer_twin: {self.joint} reducer'
        return self.ros.wait_status(self.diagnostics, name, predicate)


def test_remaining_life_percentiles_are_ordered_and_finite(ros, estimate):
    wear_record, features = estimate
    life = Life(ros)
    rec = life.send(wear_record, features)
    assert list(rec) == list(REMAINING_LIFE.fields)
    assert 0.0 < rec['p10_s'] <= rec['p50_s'] <= rec['p90_s'] < math.inf
    assert rec['stamp_s'] == wear_record['stamp_s']
    assert 0.0 < rec['event_state'] < 1.0 and rec['threshold_met'] == 0.0
    assert math.isfinite(rec['catalogue_life_s']) and rec['catalogue_life_s'] > 0.0
    assert rec['lost_motion_limit_rad'] == LifeConfig().lost_motion_limit
    assert rec['lost_motion_rad'] == wear_record['lost_motion_rad']


def test_diagnostics_are_stale_until_the_first_estimate(ros):
    life = Life(ros)
    status = life.status()
    assert status.level == DiagnosticStatus.STALE
    assert status.hardware_id == HARDWARE_ID
    assert status.message == 'no wear estimate yet'


@pytest.mark.parametrize('warn_h, error_h, level', [
    (1.0, 0.5, DiagnosticStatus.OK),
    (1e6, 10.0, DiagnosticStatus.WARN),
    (1e10 / HOUR, 1e10 / HOUR, DiagnosticStatus.ERROR),
], ids=['ok', 'warn', 'error'])
def test_the_diagnostics_level_follows_the_thresholds(ros, estimate, warn_h, error_h, level):
    wear_record, features = estimate
    life = Life(ros, warn_s=warn_h * HOUR, error_s=error_h * HOUR)
    rec = life.send(wear_record, features)
    assert rec['p10_s'] < 1e9, 'the thresholds above bracket this P10'
    status = life.status(lambda s: s.level != DiagnosticStatus.STALE)
    assert status.level == level
    assert status.hardware_id == HARDWARE_ID
    assert status.message.startswith('remaining life P10')
    values = ros.key_values(status)
    for key in ('wear_um', 'wear_std_um', 'rate_scale', 'lost_motion_arcmin',
                'lost_motion_std_arcmin', 'lost_motion_obs_arcmin', 'rul_p10_h',
                'rul_p50_h', 'rul_p90_h', 'catalogue_life_h', 'exposure_h', 'te_pp_arcmin',
                'updates', 'rejected_messages', 'lost_motion_limit_arcmin'):
        assert key in values, key
    assert float(values['rul_p10_h']) == pytest.approx(rec['p10_s'] / HOUR, rel=1e-5)
    assert float(values['wear_um']) == pytest.approx(wear_record['wear_m'] * 1e6, rel=1e-5)
    assert float(values['exposure_h']) == pytest.approx(200.0)
    assert float(values['lost_motion_limit_arcmin']) == pytest.approx(3.0)
    assert values['rejected_messages'] == '0'


def test_the_diagnostics_say_when_the_life_spans_rates_not_the_units_own(
        ros, estimate):
    # A twin met without state on a used reducer, a short while: ln s is still the
    # prior's, and the remaining life the physics' at this duty.
    wear_record, features = estimate
    life = Life(ros, warn_s=1.0 * HOUR, error_s=0.5 * HOUR)
    life.send({**wear_record, 'var_log_rate': 1.9 ** 2, 'trend_probability': 0.1}, features)
    status = life.status(lambda s: 'not yet resolved' in s.message)
    assert status.message.startswith('remaining life P10')
    assert status.message.endswith("; this unit's own wear rate is not yet resolved (ln-rate "
                                   'sd 1.90, resolved at 0.5): its remaining life spans the '
                                   "rates its windows cannot tell apart, the model's at this "
                                   'duty among them')


def test_a_worn_out_reducer_is_an_error_with_no_life_left(ros, estimate):
    wear_record, _ = estimate
    life = Life(ros)
    # Worn out by both models: the wear model's wear and the observed law's lost motion.
    rec = life.send({**wear_record, 'wear_m': 150e-6, 'trend_growth_rad': 4.0 * ARCMIN})
    assert rec['p10_s'] == rec['p50_s'] == rec['p90_s'] == 0.0
    status = life.status(lambda s: s.level != DiagnosticStatus.STALE)
    assert status.level == DiagnosticStatus.ERROR
    assert 'worn out' in status.message


NOT_COMPARED = ('no window held the load at the lost-motion test torque (23.5 N·m) long enough '
                'under both signs to compare the width there with the flanks of higher loads: '
                'the lost motion given is the play those flanks give')


WITHIN_ZONE = ('the lost motion read from the flanks (0.65 arcmin, their extrapolation to no '
               'load) is 0.74 +- 0.01 arcmin (104.6 standard errors) less than the width its '
               'bins give at the lost-motion test torque (23.5 N·m) less the windup there')


def _check(life, check, line, within_zone=None):
    """Publish what te_monitor found at the test torque, as te_monitor does."""
    pub = life.probe.publisher(joint_topic(life.joint, 'test_torque_check'), DiagnosticStatus,
                               latest_qos())
    life.ros.wait_matched(pub)
    finding = TorqueCheckFinding(check, line, within_zone)
    pub.publish(to_status(life.joint, finding))
    life.ros.spin_until(lambda: life.node.check.latest == finding,
                        what='the test-torque check at the life publisher')


def test_a_worn_out_verdict_on_the_flanks_play_says_the_test_torque_was_not_compared(
        ros, estimate):
    # Offline the analysis said it beside such an alarm; live, te_monitor knew it (its
    # /diagnostics key) and the reducer's ERROR said nothing of it.
    wear_record, _ = estimate
    life = Life(ros)
    _check(life, 'not compared', NOT_COMPARED)
    life.send({**wear_record, 'wear_m': 150e-6, 'trend_growth_rad': 4.0 * ARCMIN})
    status = life.status(lambda s: s.level == DiagnosticStatus.ERROR)
    assert 'worn out' in status.message
    assert status.message.endswith('; ' + NOT_COMPARED)
    assert ros.key_values(status)['test_torque_check'] == 'not compared'


def test_a_healthy_reducer_carries_the_check_without_its_line(ros, estimate):
    wear_record, features = estimate
    life = Life(ros, warn_s=1.0 * HOUR, error_s=0.5 * HOUR)
    _check(life, 'not compared', NOT_COMPARED)
    life.send(wear_record, features)
    status = life.status(lambda s: 'test_torque_check' in ros.key_values(s))
    assert status.level == DiagnosticStatus.OK
    assert 'test torque' not in status.message


def test_a_lost_motion_given_less_a_soft_zone_needs_no_such_line(ros, estimate):
    wear_record, _ = estimate
    life = Life(ros)
    _check(life, 'not compared', NOT_COMPARED)
    life.send({**wear_record, 'wear_m': 150e-6, 'trend_growth_rad': 4.0 * ARCMIN,
               'soft_zone_shortfall_rad': 1.4 * ARCMIN})
    status = life.status(lambda s: s.level == DiagnosticStatus.ERROR)
    assert 'test torque' not in status.message


def test_a_life_read_from_loads_within_a_soft_zone_says_so_whatever_its_level(ros, estimate):
    # The lost motion read below its bins' width at the test torque: the remaining life is
    # likely too long, so an OK life says it too; the play's caveat is withheld there.
    wear_record, features = estimate
    life = Life(ros, warn_s=1.0 * HOUR, error_s=0.5 * HOUR)
    _check(life, 'not compared', None, WITHIN_ZONE)
    life.send(wear_record, features)
    status = life.status(lambda s: 'test_torque_check' in ros.key_values(s))
    assert status.level == DiagnosticStatus.OK
    assert status.message.endswith('; ' + WITHIN_ZONE)
    values = ros.key_values(status)
    assert values['test_torque_check'] == 'not compared'
    assert values['lost_motion_within_zone'] == 'true'


@pytest.mark.parametrize('changes, reason', [
    ({'life.warn_s': -1.0}, 'life.warn_s'),
    ({'life.error_s': 2e9}, r'life\.error_s .* must not exceed life\.warn_s'),
    ({'life.n_samples': 10}, 'life.n_samples'),
    ({'life.lost_motion_limit': 0.0}, r'life\.lost_motion_limit must be in \(0'),
], ids=['negative', 'error-above-warn', 'few-samples', 'zero-limit'])
def test_a_bad_value_set_at_run_time_is_rejected_with_a_reason_and_nothing_changes(
        ros, changes, reason):
    life = Life(ros)
    before = {name: life.node.get_parameter(name).value for name in changes}
    config = life.node.life_params.value
    results = life.node.set_parameters([Parameter(k, value=v) for k, v in changes.items()])
    assert len(results) == 1 and not results[0].successful
    assert re.search(reason, results[0].reason), results[0].reason
    assert {name: life.node.get_parameter(name).value for name in changes} == before
    assert life.node.life_params.value == config
    assert life.node.stage.config == config


def test_set_parameters_over_the_parameter_service_rejects_and_accepts(ros, estimate):
    wear_record, features = estimate
    life = Life(ros)
    client = life.probe.create_client(SetParameters,
                                      f'/{life.node.get_name()}/set_parameters')
    request = SetParameters.Request(parameters=[
        Parameter('life.error_s', value=5e9).to_parameter_msg()])
    (result,) = ros.call(client, request).results
    assert not result.successful
    assert 'must not exceed life.warn_s' in result.reason
    assert life.node.get_parameter('life.error_s').value == LifeConfig().error_s
    # A good value is applied at once: the same estimate is now a warning.
    request = SetParameters.Request(parameters=[
        Parameter('life.warn_s', value=5e9).to_parameter_msg()])
    (result,) = ros.call(client, request).results
    assert result.successful, result.reason
    assert life.node.stage.warn_s == 5e9
    life.send(wear_record, features)
    status = life.status(lambda s: s.level != DiagnosticStatus.STALE)
    assert status.level == DiagnosticStatus.WARN


def test_bad_messages_are_rejected_counted_and_turn_the_level_to_warn(ros, estimate):
    wear_record, features = estimate
    life = Life(ros, warn_s=HOUR, error_s=0.5 * HOUR)
    life.features_pub.publish(to_multiarray(TE_BATCH, np.zeros((2, 4))))
    # The wear subscription keeps the latest sample only: let the node take this one first.
    life.wear_pub.publish(to_multiarray(TE_BATCH, np.zeros((2, 4))))
    ros.spin_until(lambda: life.node.rejects.total == 2, what='both bad messages')
    life.send(wear_record, features)
    assert life.node.rejects.counts == {'bad_wear': 1, 'bad_features': 1}
    status = life.status(lambda s: s.level != DiagnosticStatus.STALE)
    assert status.level == DiagnosticStatus.WARN
    assert ros.key_values(status)['rejected_messages'] == '2'
