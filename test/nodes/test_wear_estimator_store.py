"""
wear_estimator with a fleet store: the live twin joins the reducer's history across bags.

Real DDS, real SQLite. Windows are the synthetic ``te_features`` records of
``window_records`` stamped from 2026-01-01T00:00:00Z (where simulated bags start),
2 s of stream and 200 operating hours each (an aging factor of 360 000), so a bag
simulated from hour 2000 of the same robot starts after nine live windows. What the
store must hold is what the bag analysis computes from the same windows
(:class:`~reducer_twin.analysis.stages.JointBack`), and what the node estimates.
"""

import itertools
import json
import subprocess

from cli_runs import run_cli
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from full_disk import fill, small_tmpfs
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.analysis.pipeline import analyze_bag
from reducer_twin.analysis.simulate import START_NS
from reducer_twin.analysis.stages import JointBack
from reducer_twin.cli import main
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.life_basis import TorqueCheckFinding
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import EstimatorStage, features_from_record, LifeConfig
from reducer_twin.core.units import ARCMIN, HOUR
from reducer_twin.fleet.store import FleetStore, iso_from_ns
from reducer_twin.msg_adapters.layouts import record_values, TE_FEATURES, WEAR_ESTIMATE
from reducer_twin.msg_adapters.ros import from_multiarray, to_multiarray
from reducer_twin.nodes.qos import latest_qos, stream_qos
from reducer_twin.nodes.torque_check import to_status
from reducer_twin.nodes.wear_estimator import WearEstimatorNode
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger
from window_records import feature_records

pytestmark = pytest.mark.timeout(120, method='thread')

PARAMS = ReducerParams()
AGING = 360_000.0
WINDOW_S = 2.0
EXPOSURE = WINDOW_S * AGING                 # 200 operating hours per window
START_S = START_NS * 1e-9
_ids = itertools.count()

LATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(scope='module')
def records():
    """Twenty windows from 2026-01-01T00:00:00Z, 200 h each, of a reducer at 0.8 x the rate."""
    return feature_records(PARAMS, 20, seed=5, start_s=START_S, window_s=WINDOW_S,
                           exposure_s=EXPOSURE)


def offline(records):
    """Return the wear and life records the bag analysis computes from ``records``."""
    back = JointBack('joint', PARAMS, LifeConfig())
    outs = [back.process(dict(r)) for r in records]
    return np.array([o['wear'] for o in outs]), np.array([o['life'] for o in outs]), back


class LiveEstimator:
    """A WearEstimatorNode with a fleet store, and a probe that feeds and hears it."""

    def __init__(self, ros, tmp_path, store=None, joint=None, robot='r7', period=60.0,
                 state_dir=None):
        self.ros = ros
        self.joint = joint or f'elbow{next(_ids)}'
        self.robot = robot
        self.store = store or tmp_path / 'fleet.db'
        self.period = period
        self.state_dir = state_dir or tmp_path / 'state'
        self.node = self.start()
        self.probe = ros.probe()
        self.pub = self.probe.publisher(joint_topic(self.joint, 'te_features'),
                                        Float64MultiArray, stream_qos())
        self.wear = self.probe.listen(joint_topic(self.joint, 'wear'), Float64MultiArray,
                                      LATE_QOS)
        self.diagnostics = self.probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        ros.wait_matched(self.pub)
        # The estimate at start (transient local) arrives once the wear topic matched.
        ros.spin_until(lambda: len(self.wear) > 0, what='the estimate at start')

    def start(self, state_dir=None):
        """Start (or restart) the node, on ``state_dir`` if given."""
        self.state_dir = state_dir or self.state_dir
        node = WearEstimatorNode(
            f'wear_estimator_{self.joint}', params=PARAMS, context=self.ros.context,
            parameter_overrides=[Parameter('joint', value=self.joint),
                                 Parameter('state_dir', value=str(self.state_dir)),
                                 Parameter('store', value=str(self.store)),
                                 Parameter('robot', value=self.robot),
                                 Parameter('store_period_s', value=self.period),
                                 Parameter('diagnostics_period_s', value=0.1)])
        return self.ros.add(node)

    def stop(self):
        """Stop the node as its program does (close: last state and segment written)."""
        self.node.close()
        self.ros.remove(self.node)

    def restart(self, state_dir=None):
        """Stop the node and start a new one on the same store."""
        self.stop()
        self.node = self.start(state_dir)
        self.ros.wait_matched(self.pub)
        return self.node

    def send(self, recs):
        """Publish te_features records one by one; spin until the node stepped each."""
        for rec in recs:
            done = sum(self.node.statuses.values()) + 1
            self.pub.publish(to_multiarray(TE_FEATURES, record_values(TE_FEATURES, rec)))
            self.ros.spin_until(lambda: sum(self.node.statuses.values()) >= done,
                                what='the estimator to step a window')
        self.node.stage.flush()

    def status(self, predicate):
        """Spin until a wear estimator status satisfies ``predicate``; return its key/values."""
        status = self.ros.wait_status(self.diagnostics,
                                      f'reducer_twin: {self.joint} wear estimator', predicate)
        return status, self.ros.key_values(status)


def fleet(store, capsys):
    """Return the rows of ``reducer-twin fleet --store STORE --json``."""
    capsys.readouterr()
    code = main(['fleet', '--store', str(store), '--json'])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out)['reducers']


def cli(capsys, *argv):
    """Run ``reducer-twin ARGV`` in this process; return (code, out, err)."""
    capsys.readouterr()
    return run_cli(argv, capsys)


def test_live_windows_become_segments_that_fleet_lists_with_the_nodes_estimate(
        ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path, period=0.2)
    est.send(records[:5])
    ros.spin_until(lambda: est.node.live.windows_written == 5,
                   what='the store timer to write the first windows')
    est.send(records[5:9])
    assert est.node.flush_store() == 0
    node = est.node.stage.estimator
    [row] = fleet(est.store, capsys)
    assert (row['robot'], row['joint'], row['bags']) == ('r7', est.joint, 0)
    assert row['live_segments'] >= 2 and row['windows'] == 9
    assert row['hours_observed'] == pytest.approx(node.exposure_s / HOUR, rel=1e-12)
    assert row['hours_observed'] == row['hours_live'] == pytest.approx(9 * 200.0)
    assert row['wear_um'] == pytest.approx(node.wear * 1e6, rel=1e-12)
    assert row['wear_std_um'] == pytest.approx(node.wear_std * 1e6, rel=1e-12)
    assert row['last_seen'] == '2026-01-01T00:00:18Z' == iso_from_ns(
        round(records[8]['window_end_s'] * 1e9))
    assert row['verdict'] == 'OK' and row['rul_p10_h'] > 1000.0
    # Every window as the bag analysis would have stored it, and as the node published it.
    wear, life, back = offline(records[:9])
    with FleetStore(est.store) as store:
        [reducer] = store.reducers()
        trend = store.trend(reducer.row_id)
        assert reducer.state == back.state()
    np.testing.assert_array_equal(trend.features, [record_values(TE_FEATURES, r)
                                                   for r in records[:9]])
    np.testing.assert_array_equal(trend.wear, wear)
    np.testing.assert_array_equal(trend.life, life)
    ends = [r['window_end_s'] for r in records[:9]]
    # The store is written; the last estimates may still be on their way over DDS.
    ros.spin_until(lambda: sum(from_multiarray(m, WEAR_ESTIMATE)['stamp_s'] in ends
                               for m in est.wear) >= len(ends),
                   what='every window estimate published')
    published = [from_multiarray(m, WEAR_ESTIMATE) for m in est.wear]
    published = [record_values(WEAR_ESTIMATE, p) for p in published if p['stamp_s'] in ends]
    np.testing.assert_array_equal(published, wear)
    assert len(trend.bag_starts_h) == 1, 'one live session, however many segments'
    status, values = est.status(lambda s: s.values and 'store_segments_written' in
                                {kv.key for kv in s.values})
    assert status.level == DiagnosticStatus.OK and values['robot'] == 'r7'


def test_the_live_history_carries_what_te_monitor_found_at_the_test_torque(
        ros, tmp_path, records, capsys):
    # The fleet row of a bag says it; one of a live reducer had nothing to say it from.
    est = LiveEstimator(ros, tmp_path)
    pub = est.probe.publisher(joint_topic(est.joint, 'test_torque_check'), DiagnosticStatus,
                              latest_qos())
    ros.wait_matched(pub)
    pub.publish(to_status(est.joint, TorqueCheckFinding('none found')))
    ros.spin_until(lambda: est.node.live.test_torque_check == TorqueCheckFinding('none found'),
                   what='the check at the wear estimator')
    est.send(records[:3])
    assert est.node.flush_store() == 0
    [row] = fleet(est.store, capsys)
    assert row['test_torque_check'] == 'none found' and row['inputs'] == []


def test_a_restarted_node_continues_from_the_store_when_it_is_newer_than_its_state_file(
        ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path, state_dir=tmp_path / 'a')
    est.send(records[:5])
    # Another machine (no state file) takes over the same reducer from the store.
    node = est.restart(state_dir=tmp_path / 'b')
    assert node.stage.restored_from.startswith('fleet store ')
    assert node.stage.estimator.state_dict() == offline(records[:5])[2].state()['estimator']
    est.send(records[5:10])
    # Back on the first machine: its state file (5 windows) is older than the store (10).
    node = est.restart(state_dir=tmp_path / 'a')
    assert node.stage.restored_from.startswith('fleet store ')
    est.send(records[10:12])
    est.stop()
    stage = EstimatorStage(PARAMS)
    for rec in records[:12]:
        stage.process(features_from_record(rec))
    assert node.stage.estimator.state_dict() == stage.estimator.state_dict()
    [row] = fleet(est.store, capsys)
    assert (row['bags'], row['live_segments'], row['windows']) == (0, 3, 12)
    assert row['hours_observed'] == pytest.approx(12 * 200.0)
    with FleetStore(est.store) as store:
        assert store.reducers()[0].state['estimator'] == stage.estimator.state_dict()


def test_a_node_started_from_the_store_keeps_the_soft_zone_its_history_found(
        ros, tmp_path, records, capfd):
    # The lost motion was given at the test torque (te_monitor found a soft zone); a node
    # on another machine takes the reducer over from the store: until its own te_monitor
    # finds it again, it goes on giving the lost motion there, and says so.
    shortfall = 0.4 * ARCMIN
    est = LiveEstimator(ros, tmp_path, state_dir=tmp_path / 'a')
    est.send([{**rec, 'soft_zone_shortfall_rad': shortfall} for rec in records[:5]])
    node = est.restart(state_dir=tmp_path / 'b')
    assert node.stage.soft_zone_shortfall == shortfall
    est.send(records[5:7])
    end = records[6]['window_end_s']
    ros.spin_until(lambda: from_multiarray(est.wear[-1], WEAR_ESTIMATE)['stamp_s'] == end,
                   what='the estimate of the last window')
    wear = from_multiarray(est.wear[-1], WEAR_ESTIMATE)
    assert wear['soft_zone_shortfall_rad'] == shortfall
    assert wear['lost_motion_rad'] == pytest.approx(offline(records[:7])[0][-1][
        WEAR_ESTIMATE.fields.index('lost_motion_rad')] - shortfall)
    _, values = est.status(lambda s: any(kv.key == 'soft_zone_shortfall_arcmin'
                                         for kv in s.values))
    assert float(values['soft_zone_shortfall_arcmin']) == pytest.approx(0.4)
    said = [x for x in capfd.readouterr().err.splitlines() if 'an earlier recording' in x]
    assert len(said) == 1 and 'arcmin wider than the width there' in said[0]
    est.stop()


def test_a_node_whose_state_file_is_newer_keeps_it(ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path, state_dir=tmp_path / 'a')
    est.send(records[:3])
    est.stop()
    # Without the store the node ran on: its file is newer than the store.
    plain = WearEstimatorNode(
        f'wear_estimator_{est.joint}', params=PARAMS, context=ros.context,
        parameter_overrides=[Parameter('joint', value=est.joint),
                             Parameter('state_dir', value=str(tmp_path / 'a'))])
    ros.add(plain)
    ros.wait_matched(est.pub)
    est.node = plain
    est.send(records[3:6])
    ros.remove(plain)
    node = est.node = est.start()
    assert node.stage.restored_from == str(tmp_path / 'a' / f'{est.joint}.json')
    assert node.stage.estimator.updates == 6


def test_a_bag_recorded_after_the_live_session_continues_the_same_reducer(
        ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path, joint='joint_1', robot='r9')
    est.send(records[:9])                     # [0, 1800] h, ends at 00:00:18
    est.stop()
    with FleetStore(est.store) as store:
        live_state = store.reducers()[0].state
    life = ['--hours', 2000, '--aging-factor', AGING, '--rate-hz', 250, '--seed', 11,
            '--robot', 'r9']
    code, _, err = cli(capsys, 'simulate', '--out', tmp_path / 'later', '--start-hours', 2000,
                       *life)
    assert code == 0, err
    code, out, err = cli(capsys, 'analyze', tmp_path / 'later', '--store', est.store, '--out',
                         tmp_path / 'out', '--json')
    assert code == 0, err
    # The same as analysing the bag by hand from the state the live node stored.
    by_hand = analyze_bag(tmp_path / 'later', tmp_path / 'hand',
                          initial_states={'joint_1': live_state})
    summary = by_hand.joints['joint_1'].summary()
    [row] = fleet(est.store, capsys)
    assert (row['bags'], row['live_segments']) == (1, 1)
    assert row['hours_observed'] == pytest.approx(1800.0 + 2000.0, rel=1e-3)
    assert row['wear_um'] == pytest.approx(summary['wear_um'], rel=1e-12)
    assert row['rul_p50_h'] == summary['rul_p50_h']
    with FleetStore(est.store) as store:
        [reducer] = store.reducers()
        assert len(store.trend(reducer.row_id).bag_starts_h) == 2
    # A bag over the live hours is refused like any older bag, and cannot be rebuilt in.
    code, _, err = cli(capsys, 'simulate', '--out', tmp_path / 'early', *life)
    assert code == 0, err
    code, _, err = cli(capsys, 'analyze', tmp_path / 'early', '--store', est.store, '--out',
                       tmp_path / 'out2')
    errors = [line for line in err.splitlines() if line.startswith('ERROR:')]
    assert code == 1 and len(errors) == 1, err
    assert 'before the end of the stored history of r9/joint_1' in errors[0]
    assert 'watched live' in errors[0]
    code, _, err = cli(capsys, 'analyze', tmp_path / 'early', '--store', est.store, '--out',
                       tmp_path / 'out3', '--rebuild')
    assert code != 0 and 'live segments' in err and 'Traceback' not in err, err
    assert fleet(est.store, capsys) == [row]


def test_the_reset_service_records_a_replacement_in_the_store(ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path)
    est.send(records[:4])
    client = est.probe.create_client(Trigger, joint_topic(est.joint, 'reset'))
    assert ros.call(client, Trigger.Request()).success
    est.send(records[4:7])
    assert est.node.flush_store() == 0            # both reducers' windows in one flush
    rows = {r['verdict'] == 'RETIRED': r for r in fleet(est.store, capsys)}
    assert rows[True]['windows'] == 4 and rows[True]['live_segments'] == 1
    assert rows[False]['windows'] == 3 and rows[False]['hours_observed'] == \
        pytest.approx(600.0)
    assert rows[True]['retired_at'] == rows[False]['installed_at']
    assert rows[False]['wear_um'] == pytest.approx(est.node.stage.estimator.wear * 1e6)
    with FleetStore(est.store) as store:
        [event] = store.events()
    assert event['kind'] == 'replaced' and 'reset service' in event['note']
    assert event['at_ns'] == round(records[3]['window_end_s'] * 1e9) + 1


def test_a_second_writer_holding_the_store_never_holds_the_stream(
        ros, tmp_path, records, capsys):
    est = LiveEstimator(ros, tmp_path)
    est.send(records[:2])
    assert est.node.flush_store() == 0
    holder = FleetStore(est.store)
    holder.lock_for_writing()                     # e.g. an analyze --store run
    try:
        est.send(records[2:5])
        assert est.node.flush_store() == 3, 'the flush is left for the next one'
        est.send(records[5:7])                    # the stream goes on meanwhile
        assert est.node.statuses == {'accepted': 7}
        status, values = est.status(lambda s: s.level == DiagnosticStatus.WARN and any(
            kv.key == 'store_windows_waiting' and kv.value == '5' for kv in s.values))
        assert 'another process is writing' in values['store_busy']
    finally:
        holder.close()
    assert est.node.flush_store() == 0
    [row] = fleet(est.store, capsys)
    assert row['windows'] == 7 and row['wear_um'] == pytest.approx(
        est.node.stage.estimator.wear * 1e6, rel=1e-12)
    est.status(lambda s: s.level == DiagnosticStatus.OK)


@pytest.fixture
def small_disk(tmp_path):
    """Mount a 1 MiB tmpfs: a disk that really fills up."""
    with small_tmpfs(tmp_path / 'disk', 1 << 20) as where:
        yield where


def test_a_full_disk_keeps_the_stored_state_says_error_and_recovers(
        ros, tmp_path, records, small_disk, capsys):
    est = LiveEstimator(ros, tmp_path, store=small_disk / 'fleet.db')
    est.send(records[:3])
    assert est.node.flush_store() == 0
    filler = fill(small_disk)
    est.send(records[3:8])
    assert est.node.flush_store() == 5
    status, values = est.status(lambda s: s.level == DiagnosticStatus.ERROR)
    error = values['store_error']
    assert str(est.store) in error and 'disk' in error and 'keeps its previous state' in error
    assert values['store_flushes_failed'] == '1'
    assert est.node.statuses == {'accepted': 8}, 'the estimate goes on'
    filler.unlink()
    [row] = fleet(est.store, capsys)
    assert row['windows'] == 3, 'the store kept its previous state, nothing half-written'
    assert est.node.flush_store() == 0
    [row] = fleet(est.store, capsys)
    assert row['windows'] == 8 and row['hours_observed'] == pytest.approx(8 * 200.0)
    est.status(lambda s: s.level == DiagnosticStatus.OK)


@pytest.mark.parametrize('overrides, fragment', [
    ([Parameter('store', value='x.db')], 'robot must be a name'),
    ([Parameter('store', value='x.db'), Parameter('robot', value='two words')],
     "got 'two words'"),
    ([Parameter('store', value='x.db'), Parameter('robot', value='r1'),
      Parameter('store_period_s', value=0.0)], r'store_period_s must be in \[0\.01, 86400\] s'),
], ids=['no robot', 'a robot name with a space', 'no period'])
def test_a_store_without_a_robot_or_with_a_bad_period_is_refused_by_name(
        ros, tmp_path, overrides, fragment):
    with pytest.raises(InvalidParameter, match=fragment):
        WearEstimatorNode('wear_estimator_bad', params=PARAMS, context=ros.context,
                          parameter_overrides=[Parameter('state_file', value='none'),
                                               *overrides])


def test_a_file_that_is_not_a_fleet_store_stops_the_program_naming_it(
        tmp_path, node_program):
    store = tmp_path / 'notes.db'
    store.write_text('not a database\n' * 200)
    result = subprocess.run(
        [node_program('wear_estimator'), '--ros-args', '-p', 'joint:=knee', '-p',
         'state_file:=none', '-p', f'store:={store}', '-p', 'robot:=r1'],
        capture_output=True, text=True, timeout=60)
    assert result.returncode == 1 and 'Traceback' not in result.stderr
    assert 'ERROR: parameter store: ' in result.stderr and str(store) in result.stderr


BRINGUP_YAML = """twin:
  joints: [{joint}]
  aging_factor: 360000.0
  window_s: 2.0
  state_dir: {state_dir}
  simulate: true
  robot: cell1-r1
  store: {store}
  store_period_s: 1.0
"""


def test_the_bringup_writes_every_joint_into_twin_store(
        tmp_path, node_program, run_for, capsys):
    joint = f'wrist{next(_ids)}'
    config = tmp_path / 'twin.yaml'
    store = tmp_path / 'fleet.db'
    config.write_text(BRINGUP_YAML.format(joint=joint, state_dir=tmp_path / 'state',
                                          store=store))
    alive, code, _, err = run_for([node_program('twin_bringup'), '--ros-args', '-p',
                                   f'config:={config}'], 10.0)
    assert alive and code == 0, err[-3000:]
    [row] = fleet(store, capsys)
    assert (row['robot'], row['joint'], row['bags']) == ('cell1-r1', joint, 0)
    assert row['live_segments'] >= 1 and row['windows'] >= 1 and row['hours_observed'] > 0
    with FleetStore(store) as fs:
        reducer = fs.reducers()[0]
        # The stream, not the store, sets the estimate: the state file agrees with it.
        state = json.loads((tmp_path / 'state' / f'{joint}.json').read_text())['state']
    assert reducer.state['estimator']['t_end'] == state['t_end']
    assert reducer.exposure_s == pytest.approx(state['exposure_s'], rel=1e-9)
